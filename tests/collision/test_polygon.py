"""The 2-D convex hull of the horizontal exit (:func:`polygon`): the vertices qhull (scipy's
``ConvexHull``) finds, counter-clockwise, for random sets, duplicates, exactly and nearly
collinear points (a lying cylinder's silhouette); and no ``scipy.spatial`` import."""
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial import ConvexHull, QhullError

from immersim.models.collision.exit import polygon


def _qhull(P):
    """qhull's vertices, or the points themselves where it finds no 2-D hull (and False)."""
    try:
        return P[ConvexHull(P).vertices], True
    except QhullError:
        return P, False


def _from_lowest(P):
    """``P`` rolled to start at its lowest (then leftmost) vertex."""
    return np.roll(P, -int(np.lexsort((P[:, 0], P[:, 1]))[0]), axis=0) if len(P) >= 3 else P


def _cases(gen):
    for k in range(400):
        kind = k % 4
        if kind == 0:
            yield gen.normal(size=(int(gen.integers(1, 40)), 2)) * gen.uniform(0.1, 100.0)
        elif kind == 1:   # duplicates and exactly collinear points (some sets all on a line)
            yield gen.integers(0, 4, (int(gen.integers(1, 20)), 2)).astype(float)
        elif kind == 2:   # a yawed box: top and bottom corners on the same footprint
            c = np.array([[x, y] for x in (-1.0, 1.0) for y in (-2.0, 2.0)] * 2)
            th = gen.uniform(0.0, 2.0 * np.pi)
            yield c @ np.array([[np.cos(th), np.sin(th)], [-np.sin(th), np.cos(th)]]) + gen.uniform(-50.0, 50.0, 2)
        else:   # a lying cylinder (16 sides) at a random yaw: long rows of nearly collinear points
            ang = np.linspace(0.0, 2.0 * np.pi, 17)[:-1]
            pts = np.array([[np.cos(a), zz, np.sin(a)] for a in ang for zz in (-3.0, 3.0)])
            th = gen.uniform(0.0, 2.0 * np.pi)
            yield pts[:, :2] @ np.array([[np.cos(th), np.sin(th)], [-np.sin(th), np.cos(th)]]) + gen.uniform(-50.0, 50.0, 2)


def test_polygon_has_qhulls_vertices_counter_clockwise():
    for P in _cases(np.random.default_rng(0)):
        (ref, hull), got = _qhull(P), polygon(P)
        assert got.shape == ref.shape and np.array_equal(_from_lowest(got), _from_lowest(ref))
        if hull:   # counter-clockwise: positive area
            assert np.sum(got[:, 0] * np.roll(got[:, 1], -1) - np.roll(got[:, 0], -1) * got[:, 1]) > 0.0


@pytest.mark.parametrize("P", [np.zeros((0, 2)), np.array([[1.0, 2.0]]), np.array([[0.0, 0.0], [1.0, 1.0]]),
                               np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]])])
def test_fewer_than_three_points_or_a_line_are_the_points_themselves(P):
    assert np.array_equal(polygon(P), P)


def test_polygon_imports_no_scipy_spatial():
    code = ("import sys, numpy as np\nfrom immersim.models.collision.exit import polygon\n"
            "polygon(np.random.default_rng(0).normal(size=(30, 2)))\nprint('scipy.spatial' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False"]

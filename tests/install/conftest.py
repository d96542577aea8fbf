"""The wheel of the checkout installed into a fresh venv outside it (built once per session)."""
from __future__ import annotations

import pytest

from tests.install.isolated import build_dists, make_wheel_env, remove, scratch_dir


@pytest.fixture(scope="session")
def dists_and_env():
    """(sdist, wheel, WheelEnv); everything under one scratch folder outside the checkout
    and the temporary folder, removed at the end."""
    root = scratch_dir("immersim-wheel-")
    try:
        sdist, wheel = build_dists(root / "dist")
        yield sdist, wheel, make_wheel_env(root / "env", wheel)
    finally:
        remove(root)

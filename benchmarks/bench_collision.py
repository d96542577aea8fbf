"""Benchmark of the collision unit: the thesis's workloads for every backend beside raw python-fcl.

Run: ``python benchmarks/bench_collision.py [--quick]`` -> ``results/collision/`` (markdown
tables, CSV, PNG plots, README with the measured figures against the issue's targets).

Workloads (thesis §4.5 and §5.7):

* tables 4-1 / 5-1 / 5-2: a missile against one tank of 5.4k .. 26.4k triangles, intersecting
  (hit) and close but apart (miss); time per query of each backend and of raw python-fcl
  (``fcl.collide`` then, without contact, ``fcl.distance`` on the same BVHs);
* table 5-3: a missile diving onto one tank of a field of 1 .. 5040 tanks (26.4k triangles
  each, one shared BVH); time per step of each backend and of raw python-fcl (the same
  ``DynamicAABBTreeCollisionManager`` queries with python-fcl's default callbacks), plus the
  cost of a step in which nothing moves;
* table 5-5: the ST sweep of the basis-point detector (time, basis points, DN, accuracy);
  the n x m sweep of the honeycomb detector;
* accuracy: >= 1000 random missile poses around a tank (quick: 150): contact flag of each
  thesis backend against FCL's exact answer (false positives / negatives) and distance error.
"""
from __future__ import annotations

import argparse
import logging
import os
import platform
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import fcl
from immersim.models.collision import BackendConfig, make_backend, parse_scene
from immersim.models.collision.fcl_backend import fcl_transform
from immersim.models.collision.geometry import pose_matrix

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "results" / "collision"
RNG_SEED = 2010
FMU_MAX_DISTANCE = 2.0  # m, the FMU's default max_distance
#: the collision unit's scene and pairs in campus_drive
CAMPUS_COLLISION = {
    "scene": ("box:name=avatar_1,sx=4,sy=2,sz=4.4,dynamic=1;box:name=avatar_2,sx=4,sy=2,sz=4.4,dynamic=1;"
              "box:name=avatar_3,sx=4,sy=2,sz=4.4,dynamic=1;missile:x=5,y=20,z=12,pitch=0.564;"
              "sphere:name=entity_1,r=1,dynamic=1;sphere:name=entity_2,r=1,dynamic=1;sphere:name=entity_3,r=1,dynamic=1;"
              "sphere:name=entity_4,r=1,dynamic=1;tank:name=tank_a,tris=5.4k,x=57.19,y=60.37,yaw=2.2408;"
              "tank:name=tank_b,tris=5.4k,x=50.71,y=74.25,yaw=3.0124;tank:name=tank_c,tris=5.4k,x=68.98,y=57.30,yaw=1.8448;"
              "tanks:n=4,tris=5.4k,spacing=12,x=20,y=20"),
    "pairs": ("avatar_1 vs tank_a (horizontal); avatar_2 vs tank_b (horizontal); avatar_3 vs tank_c (horizontal); "
              "missile vs any tank*; avatar_1 vs any entity_*"),
}
CAMPUS_REPS = 5  # repetitions of each variant in the campus_drive replay (interleaved step by step)
AB_REPS = 12  # repetitions of the A/B and shortcut replays (--ab)
#: ms; the collision model's share of the 0.33 ms per step of campus_drive at 100x real time that this replay is held to (mean
#: per step, outputs identical to the baseline), and the speed-up over the baseline asked with it
CAMPUS_TARGET_MS, CAMPUS_TARGET_SPEEDUP = 0.07, 2.0


def random_poses(n, lo, hi, rng, margin=1.0):
    """Missile centres uniform in the box [lo - margin, hi + margin], orientations uniform."""
    c = rng.uniform(lo - margin, hi + margin, size=(n, 3))
    ang = rng.uniform(-np.pi, np.pi, size=(n, 3))
    ang[:, 1] /= 2
    return np.c_[c, ang]


def classify(scene, poses, pair="missile vs tank"):
    """Exact contact flags and distances (FCL) of each pose."""
    ref = make_backend("fcl", scene, pair, BackendConfig(ccd=False))
    flags, dist = [], []
    for p in poses:
        r = ref.query([p]).pairs[0]
        flags.append(r.in_contact)
        dist.append(r.distance)
    return np.array(flags), np.array(dist)


def time_queries(be, poses, reps=1):
    """Median and mean seconds per query over changing poses (no cache hits)."""
    ts = []
    for _ in range(reps):
        for p in poses:
            t = time.perf_counter()
            be.query([p])
            ts.append(time.perf_counter() - t)
    return float(np.median(ts)), float(np.mean(ts))


class RawPair:
    """Raw python-fcl on one pair: collide, then distance if apart (same BVHs)."""

    def __init__(self, fcl_backend, a, b):
        self.oa = fcl.CollisionObject(fcl_backend.fclo.geoms[fcl_backend.scene.bodies[a].mesh_key], fcl.Transform())
        self.ob = fcl.CollisionObject(fcl_backend.fclo.geoms[fcl_backend.scene.bodies[b].mesh_key],
                                      fcl_transform(fcl_backend.T[b]))
        self.creq = fcl.CollisionRequest(num_max_contacts=32, enable_contact=True)
        self.dreq = fcl.DistanceRequest(enable_nearest_points=True)

    def query(self, poses):
        self.oa.setTransform(fcl_transform(pose_matrix(poses[0])))
        cres = fcl.CollisionResult()
        if fcl.collide(self.oa, self.ob, self.creq, cres) == 0:
            fcl.distance(self.oa, self.ob, self.dreq, fcl.DistanceResult())


class RawField:
    """Raw python-fcl on a field: the same static manager queried with default callbacks."""

    def __init__(self, fcl_backend, a):
        be = fcl_backend
        self.manager = fcl.DynamicAABBTreeCollisionManager()
        self.manager.registerObjects([fcl.CollisionObject(be.fclo.geoms[be.scene.bodies[i].mesh_key],
                                                          fcl_transform(be.T[i])) for i in be.fclo.static_idx])
        self.manager.setup()
        self.obj = fcl.CollisionObject(be.fclo.geoms[be.scene.bodies[a].mesh_key], fcl.Transform())
        self.creq = fcl.CollisionRequest(num_max_contacts=32, enable_contact=True)
        self.dreq = fcl.DistanceRequest(enable_nearest_points=True)

    def query(self, poses):
        self.obj.setTransform(fcl_transform(pose_matrix(poses[0])))
        cd = fcl.CollisionData(self.creq)
        self.manager.collide(self.obj, cd, fcl.defaultCollisionCallback)
        if not cd.result.is_collision:
            dd = fcl.DistanceData(self.dreq)
            self.manager.distance(self.obj, dd, fcl.defaultDistanceCallback)


def md_table(header, rows):
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for r in rows:
        out.append("| " + " | ".join(f"{x:.4g}" if isinstance(x, float) else str(x) for x in r) + " |")
    return "\n".join(out) + "\n"


def write_csv(name, header, rows):
    with open(OUT / name, "w") as f:
        f.write(",".join(header) + "\n")
        for r in rows:
            f.write(",".join(f"{x:.6g}" if isinstance(x, float) else str(x) for x in r) + "\n")


# -- workloads --------------------------------------------------------------------------------
def bench_triangles(quick, rng):
    """Tables 4-1, 5-1, 5-2: time per query vs tank triangles, hit and miss."""
    tris_list = [5442, 6646, 8676, 10114, 10772, 20174, 26432]
    if quick:
        tris_list = [5442, 10114, 26432]
    n_poses = 8 if quick else 25
    rows = []
    for tris in tris_list:
        scene = parse_scene(f"tank:tris={tris};missile:z=8")
        lo, hi = scene.mesh(0).bounds
        cand = random_poses(400, lo, hi, rng, margin=0.8)
        flags, dist = classify(scene, cand)
        hit = cand[flags][:n_poses]
        miss = cand[(~flags) & (dist > 0.02) & (dist < 0.8)][:n_poses]
        fb = make_backend("fcl", scene, "missile vs tank", BackendConfig(ccd=False))
        raw = RawPair(fb, 1, 0)
        for case, poses in (("hit", hit), ("miss", miss)):
            row = [tris, case]
            t_raw = time_queries(raw, poses, reps=3)[0]
            row.append(t_raw * 1e3)
            for name in ("fcl", "honeycomb", "basis_point"):
                be = make_backend(name, scene, "missile vs tank", BackendConfig(ccd=False))
                reps = 3 if name == "fcl" else 1
                row.append(time_queries(be, poses, reps)[0] * 1e3)
            rows.append(row)
            print(f"  tris {tris} {case}: " + ", ".join(f"{x:.3f}" for x in row[2:]) + " ms", flush=True)
    header = ["triangles", "case", "raw python-fcl ms", "fcl ms", "honeycomb ms", "basis_point ms"]
    return header, rows


def field_trajectory(scene, n_steps=40):
    """Missile diving (1.2 rad nose down, 15 m/s) onto the tank nearest the field's centre."""
    poses = scene.poses()[:-1]
    centre = poses[:, :2].mean(0)
    k = int(np.argmin(np.linalg.norm(poses[:, :2] - centre, axis=1)))
    x, y = poses[k, :2]
    return [[x + 0.3, y + 0.2, 8.0 - 0.2 * s, 0.0, 1.2, 0.0] for s in range(n_steps)]


def bench_field(quick, rng):
    """Table 5-3: time per step vs number of tanks; rest cost."""
    ns = [1, 20, 40, 60, 150, 540, 1040, 2540, 5040]
    if quick:
        ns = [1, 150, 1040, 5040]
    rows, ratio_rows = [], []
    for n in ns:
        scene = parse_scene(f"tanks:n={n},tris=26.4k;missile:z=8")
        traj = field_trajectory(scene, 30 if quick else 40)
        t0 = time.perf_counter()
        fb = make_backend("fcl", scene, "missile vs any tank", BackendConfig(ccd=False))
        setup = time.perf_counter() - t0
        fb_ccd = make_backend("fcl", scene, "missile vs any tank")
        fb_md = make_backend("fcl", scene, "missile vs any tank", BackendConfig(max_distance=FMU_MAX_DISTANCE))
        raw = RawField(fb, len(scene.bodies) - 1)
        # interleave raw and backend step by step (same poses, same machine load)
        reps = 5 if quick else 10
        t_raw, t_fcl, t_ccd, t_md = [], [], [], []
        for _ in range(reps):
            for p in traj:
                t = time.perf_counter(); raw.query([p]); t_raw.append(time.perf_counter() - t)
                t = time.perf_counter(); fb.query([p]); t_fcl.append(time.perf_counter() - t)
                t = time.perf_counter(); fb_ccd.query([p]); t_ccd.append(time.perf_counter() - t)
                t = time.perf_counter(); fb_md.query([p]); t_md.append(time.perf_counter() - t)
        # nothing moves: cached result
        fb.query([traj[-1]])
        t_rest = []
        for _ in range(200):
            t = time.perf_counter(); fb.query([traj[-1]]); t_rest.append(time.perf_counter() - t)
        hc = make_backend("honeycomb", scene, "missile vs any tank", BackendConfig())
        bp = make_backend("basis_point", scene, "missile vs any tank", BackendConfig())
        t_hc = time_queries(hc, traj[::3])[0]
        t_bp = time_queries(bp, traj[::3])[0]
        t_raw, t_fcl, t_ccd = (np.array(x) for x in (t_raw, t_fcl, t_ccd))
        rows.append([n, np.median(t_raw) * 1e3, np.median(t_fcl) * 1e3, np.median(t_ccd) * 1e3,
                     np.median(t_rest) * 1e3, t_hc * 1e3, t_bp * 1e3, setup, np.median(t_md) * 1e3])
        ratio_rows.append([n, float(np.median(t_fcl) / np.median(t_raw)), float(t_fcl.sum() / t_raw.sum()),
                           float(np.median(t_ccd) / np.median(t_raw))])
        print(f"  tanks {n}: " + ", ".join(f"{x:.3f}" for x in rows[-1][1:]), flush=True)
    header = ["tanks", "raw python-fcl ms", "fcl ms", "fcl+ccd ms", "fcl at rest ms", "honeycomb ms",
              "basis_point ms", "fcl setup s", f"fcl+ccd max_distance={FMU_MAX_DISTANCE:g} ms"]
    return header, rows, ["tanks", "fcl/raw (medians)", "fcl/raw (totals)", "fcl+ccd/raw (medians)"], ratio_rows


def accuracy(be, poses, flags, dist):
    fp = fn = 0
    errs, near, ts = [], [], []
    for p, f, d in zip(poses, flags, dist):
        t = time.perf_counter()
        r = be.query([p]).pairs[0]
        ts.append(time.perf_counter() - t)
        fp += bool(r.in_contact and not f)
        fn += bool(f and not r.in_contact)
        if not f and not r.in_contact:
            errs.append(abs(r.distance - d))
            if d < 0.3:
                near.append(abs(r.distance - d))
    errs = np.array(errs) if errs else np.array([np.nan])
    near = np.array(near) if near else np.array([np.nan])
    return fp, fn, float(np.median(errs)), float(np.percentile(errs, 95)), float(np.median(ts)), \
        float(np.median(near))


def bench_accuracy(quick, rng):
    """Contact flags and distances of every backend vs FCL on random poses."""
    n = 150 if quick else 1000
    scene = parse_scene("tank:tris=5.4k;missile:z=8")
    lo, hi = scene.mesh(0).bounds
    poses = random_poses(n, lo, hi, rng, margin=1.0)
    flags, dist = classify(scene, poses)
    rows = []
    for name, cfg, label in (("fcl", BackendConfig(ccd=False), "fcl"),
                             ("honeycomb", BackendConfig(), "honeycomb 8x8 (d = 0, at rest)"),
                             ("basis_point", BackendConfig(st=0.05), "basis_point ST=0.05")):
        be = make_backend(name, scene, "missile vs tank", cfg)
        if name == "honeycomb":
            be.fixed_threshold = 0.0
        fp, fn, e50, e95, t, enear = accuracy(be, poses, flags, dist)
        rows.append([label, n, int(flags.sum()), fp, fn, e50, e95, enear, t * 1e3])
        print(f"  accuracy {label}: FP {fp} FN {fn} err50 {e50:.4f} err95 {e95:.4f} t {t*1e3:.2f} ms", flush=True)
    header = ["backend", "poses", "exact contacts", "false positives", "false negatives",
              "median |distance error| m", "p95 |distance error| m", "median |error| m, exact < 0.3 m",
              "median ms/query"]
    return header, rows, (scene, poses, flags, dist)


def bench_st(quick, rng, acc_data):
    """Table 5-5: the ST sweep of basis_point (missile in contact with a 26.4k tank) and
    accuracy of each ST on random poses around the 5.4k tank."""
    sts = [0.004, 0.005, 0.01, 0.04, 0.05, 0.07, 0.1]
    if quick:
        sts = [0.01, 0.05, 0.1]
    big = parse_scene("tank:tris=26.4k;missile:z=8")
    lo, hi = big.mesh(0).bounds
    cand = random_poses(200, lo, hi, rng, margin=0.5)
    flags, _ = classify(big, cand)
    hit = cand[flags][: (3 if quick else 6)]
    scene, poses, aflags, adist = acc_data
    rows = []
    for st in sts:
        be = make_backend("basis_point", big, "missile vs tank", BackendConfig(st=st))
        n_hit = 2 if st < 0.01 else len(hit)
        t = time_queries(be, hit[:n_hit])[0]
        stats = dict(be.last_stats)
        n_acc = 0 if st < 0.01 else (40 if quick else 200)
        if n_acc:
            bea = make_backend("basis_point", scene, "missile vs tank", BackendConfig(st=st))
            fp, fn, e50, _, _, _ = accuracy(bea, poses[:n_acc], aflags[:n_acc], adist[:n_acc])
            err_rate = (fp + fn) / n_acc
        else:
            fp = fn = -1
            e50 = err_rate = float("nan")
        rows.append([st, stats.get("dn", 0), stats.get("bp_sp", 0), stats.get("bp_scn", 0), t * 1e3, n_acc, fp, fn,
                     err_rate, e50])
        print(f"  ST {st}: {rows[-1][1:]}", flush=True)
    header = ["ST", "DN", "BP SP_a", "BP SCN", "ms/query (hit, 26.4k)", "accuracy poses", "FP", "FN",
              "flag error rate", "median |dist err| m"]
    return header, rows


def bench_cells(quick, rng, acc_data):
    """Honeycomb n x m sweep: time and accuracy (at rest, d = 0)."""
    cells = [2, 4, 8, 16, 32] if not quick else [2, 8, 32]
    scene, poses, flags, dist = acc_data
    n_acc = 60 if quick else 300
    rows = []
    for c in cells:
        be = make_backend("honeycomb", scene, "missile vs tank", BackendConfig(cells_n=c, cells_m=c))
        be.fixed_threshold = 0.0
        fp, fn, e50, e95, t, _ = accuracy(be, poses[:n_acc], flags[:n_acc], dist[:n_acc])
        rows.append([f"{c}x{c}", n_acc, fp, fn, (fp + fn) / n_acc, e50, t * 1e3])
        print(f"  cells {c}x{c}: {rows[-1][1:]}", flush=True)
    header = ["cells n x m", "poses", "FP", "FN", "flag error rate", "median |dist err| m", "median ms/query"]
    return header, rows


def plots(tri, field, st, cells):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, case in zip(axes, ("hit", "miss")):
        rows = [r for r in tri[1] if r[1] == case]
        x = [r[0] / 1000 for r in rows]
        for j, label in enumerate(tri[0][2:], start=2):
            ax.plot(x, [r[j] for r in rows], "o-", label=label.replace(" ms", ""))
        ax.set_yscale("log")
        ax.set_xlabel("tank triangles (thousands)")
        ax.set_ylabel("ms per query")
        ax.set_title(f"missile vs tank, {case} (tables 4-1, 5-1, 5-2)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(OUT / "time_vs_triangles.png", dpi=120)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 4))
    x = [r[0] for r in field[1]]
    for j, label in enumerate(field[0][1:7], start=1):
        ax.plot(x, [r[j] for r in field[1]], "o-", label=label.replace(" ms", ""))
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.axhline(1.0, color="k", ls=":", lw=1)
    ax.set_xlabel("tanks (26.4k triangles each)")
    ax.set_ylabel("ms per step")
    ax.set_title("missile in a tank field (table 5-3)")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(OUT / "time_vs_tanks.png", dpi=120)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 4))
    pts = [(r[4], r[8], r[0]) for r in st[1] if np.isfinite(r[8])]
    ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label="basis_point (ST sweep)")
    for p in pts:
        ax.annotate(f"ST={p[2]}", (p[0], p[1]), fontsize=7)
    ax.plot([r[6] for r in cells[1]], [r[4] for r in cells[1]], "s-", label="honeycomb (n x m sweep)")
    for r in cells[1]:
        ax.annotate(r[0], (r[6], r[4]), fontsize=7)
    ax.set_xscale("log")
    ax.set_xlabel("ms per query")
    ax.set_ylabel("contact-flag error rate vs FCL")
    ax.set_title("time vs error")
    ax.legend()
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(OUT / "time_vs_error.png", dpi=120)
    plt.close(fig)


def machine():
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                                text=True).stdout.strip()
    except OSError:
        commit = "?"
    cpu = "?"
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        import trimesh.ray
        ray = "embree (embreex)" if trimesh.ray.has_embree else "trimesh ray_triangle (pure numpy)"
    except Exception:
        ray = "?"
    return commit, os.cpu_count(), cpu, platform.python_version(), ray


# -- campus_drive replay (before/after) ----------------------------------------------------------
def _baseline_package(commit, dest):
    """Extract ``models/collision`` of ``commit`` (self-contained: relative imports only) and
    import it as the package ``collision_<commit>``."""
    import importlib
    import io
    import tarfile

    name = f"collision_{commit}"
    tar = subprocess.run(["git", "-C", str(ROOT), "archive", commit, "models/collision"],
                         check=True, capture_output=True).stdout
    with tarfile.open(fileobj=io.BytesIO(tar)) as tf:
        tf.extractall(dest, filter="data")
    pkg = Path(dest) / name
    if not pkg.exists():
        (Path(dest) / "models" / "collision").rename(pkg)
    sys.path.insert(0, str(dest))
    return importlib.import_module(name)


def _outputs(res):
    """Everything a query reports (per pair and the counters), for exact comparisons."""
    return [(p.in_contact, float(p.distance), float(p.depth), tuple(np.asarray(p.point, float).tolist()),
             tuple(np.asarray(p.normal, float).tolist()), float(p.toi), float(p.closing_speed), int(p.partner))
            for p in res.pairs] + [(res.n_bodies, res.n_candidates, res.n_narrow, res.at_rest)]


class Deviation:
    """Step-by-step comparison of two models' outputs on the same inputs: exact equality per
    step, and the largest deviation of each output (where they differ)."""

    FIELDS = ("distance", "depth", "point", "normal", "toi", "closing_speed")

    def __init__(self):
        self.steps = self.equal = self.flags = self.partners = self.counters = 0
        self.worst = {f: 0.0 for f in self.FIELDS}

    def add(self, res, ref):
        self.steps += 1
        self.equal += _outputs(res) == _outputs(ref)
        self.counters += (res.n_candidates, res.n_narrow, res.at_rest) != (ref.n_candidates, ref.n_narrow, ref.at_rest)
        for p, q in zip(res.pairs, ref.pairs):
            self.flags += bool(p.in_contact) != bool(q.in_contact)
            self.partners += int(p.partner) != int(q.partner)
            for f in self.FIELDS:
                d = float(np.max(np.abs(np.asarray(getattr(p, f), float) - np.asarray(getattr(q, f), float))))
                self.worst[f] = max(self.worst[f], d)

    def summary(self) -> str:
        w = self.worst
        return (f"identical in {self.equal} of {self.steps} steps; contact flags differ in {self.flags} pair-steps, "
                f"partners in {self.partners}, counters in {self.counters} steps; largest |difference|: distance "
                f"{w['distance']:.2g} m, depth {w['depth']:.2g} m, normal {w['normal']:.2g}, time of impact "
                f"{w['toi']:.2g} s, closing speed {w['closing_speed']:.2g} m/s, point {w['point']:.2g} m")


def _campus_params():
    """The collision unit's scene and pairs in campus_drive (the workload stays fixed whatever
    the scenario's syntax)."""
    return dict(CAMPUS_COLLISION)


def _campus_inputs(log):
    """The collision unit's parameters in campus_drive.toml and its logged inputs in ``log``:
    per step one flat tuple of the dynamic bodies' 6 pose numbers, as the FMU passes them."""
    from immersim.orchestrator.mcapio import read_series

    params = _campus_params()
    n_dyn = len(parse_scene(params["scene"]).dynamic)
    axes = ("x", "y", "z", "roll", "pitch", "yaw")
    series = read_series(log, ["coll.body*"])
    poses = np.stack([np.stack([series[f"coll.body[{i + 1}].{ax}"][1] for ax in axes], 1)
                      for i in range(n_dyn)], 1)  # (steps, bodies, 6)
    return params, [tuple(p.ravel().tolist()) for p in poses]


def bench_campus(log, baseline=None, reps=None, baseline_max_distance=FMU_MAX_DISTANCE):
    """Replay the collision unit's logged inputs of a campus_drive run through the model:
    this tree (FMU default: chunked exact distances, max_distance 2 m), its whole-mesh path
    (``chunk_faces = 0``), max_distance = inf (exact distances), and optionally the model
    of an earlier commit with ``baseline_max_distance``, interleaved step by step. Returns
    header, rows, the number of steps and the output comparisons (name -> Deviation) of this
    tree's variants at the FMU default max_distance against the baseline (first repetition)."""
    import tempfile

    reps = CAMPUS_REPS if reps is None else reps
    params, poses = _campus_inputs(log)
    scene_spec, pairs = params["scene"], params["pairs"]
    this = f"this tree, max_distance = {FMU_MAX_DISTANCE:g} m (FMU default, chunked distances)"
    mesh = f"this tree, max_distance = {FMU_MAX_DISTANCE:g} m, chunk_faces = 0 (whole-mesh distances)"
    variants = [(this, lambda: make_backend("fcl", parse_scene(scene_spec), pairs,
                                            BackendConfig(max_distance=FMU_MAX_DISTANCE))),
                (mesh, lambda: make_backend("fcl", parse_scene(scene_spec), pairs,
                                            BackendConfig(max_distance=FMU_MAX_DISTANCE, chunk_faces=0))),
                ("this tree, max_distance = inf (exact distances, chunked)",
                 lambda: make_backend("fcl", parse_scene(scene_spec), pairs, BackendConfig()))]
    tmp = tempfile.mkdtemp(prefix="bench_collision_")
    base = None
    if baseline:
        old = _baseline_package(baseline, tmp)
        base = f"commit {baseline}, max_distance = {baseline_max_distance:g} m"
        variants.append((base, lambda: old.make_backend("fcl", old.parse_scene(scene_spec), pairs,
                                                         old.BackendConfig(max_distance=baseline_max_distance))))
    times = {name: [] for name, _ in variants}
    cpu = {name: 0.0 for name, _ in variants}
    compare = base is not None and baseline_max_distance == FMU_MAX_DISTANCE
    dev = {this: Deviation(), mesh: Deviation()} if compare else {}
    # two passes: this tree against the baseline alone (in turns in each step: the model as the FMU
    # runs it, no other variant's cache misses in between), then the other variants; the outputs
    # are compared with the baseline's of the first repetition
    made = dict(variants)
    first = [this] + ([base] if base is not None else [])
    ref = []
    for names in (first, [name for name, _ in variants if name not in first]):
        for rep in range(reps):
            bes = [(name, made[name]()) for name in names]
            for k in range(len(poses)):
                out = {}
                for name, be in (bes if (rep + k) % 2 == 0 else bes[::-1]):
                    c, t = time.thread_time(), time.perf_counter()
                    out[name] = be.query(poses[k], 0.033)
                    times[name].append(time.perf_counter() - t)
                    cpu[name] += time.thread_time() - c
                if rep == 0 and base is not None:
                    if base in out:
                        ref.append(out[base])
                    for name, d in dev.items():
                        if name in out:
                            d.add(out[name], ref[k])
    rows = []
    for name, _ in variants:
        t = np.array(times[name]) * 1e3
        rows.append([name, float(np.mean(t)), float(np.median(t)), float(np.percentile(t, 95)),
                     float(t.max()), 1e3 * cpu[name] / reps / len(poses)])
    header = ["model", "mean ms/step", "median ms/step", "p95 ms/step", "max ms/step", "CPU ms/step (mean)"]
    # per step the median over the repetitions (ms), for the steps that changed
    per_step = {name: np.median(np.array(times[name]).reshape(reps, len(poses)), 0) * 1e3 for name, _ in variants}
    changed = None
    if base is not None:
        diff = per_step[this] - per_step[base]
        top = np.argsort(-np.abs(diff))[:8]
        changed = (["step", "t (s)", f"{this} ms", f"{base} ms", "difference ms"],
                   [[int(k), round(0.033 * k, 3), float(per_step[this][k]), float(per_step[base][k]), float(diff[k])]
                    for k in sorted(top.tolist())],
                   float(per_step[this].sum()), float(per_step[base].sum()))
    return header, rows, len(poses), dev, changed


def fcl_share(log, reps=3):
    """The share of python-fcl's pairwise calls (``fcl.distance``, ``fcl.collide``; the broad
    phase's manager calls not included) in the campus_drive replay of this tree (FMU default):
    (ms per step of the whole query, ms per step inside those calls, calls per run), the
    medians over ``reps`` runs with the calls timed (a wrapper around each call)."""
    import types

    import immersim.models.collision.chunks as chunks_mod
    import immersim.models.collision.fcl_backend as fcl_mod

    params, poses = _campus_inputs(log)
    spent = [0.0, 0]
    clock = time.perf_counter

    def timed(fn):
        def call(*args):
            t = clock()
            out = fn(*args)
            spent[0] += clock() - t
            spent[1] += 1
            return out
        return call

    wrapped = types.SimpleNamespace(**{k: getattr(fcl, k) for k in dir(fcl) if not k.startswith("__")})
    wrapped.distance, wrapped.collide = timed(fcl.distance), timed(fcl.collide)
    totals, inside, calls = [], [], 0
    fcl_mod.fcl = chunks_mod.fcl = wrapped
    try:
        for _ in range(reps):
            be = make_backend("fcl", parse_scene(params["scene"]), params["pairs"],
                              BackendConfig(max_distance=FMU_MAX_DISTANCE))
            spent[:] = [0.0, 0]
            t = clock()
            for p in poses:
                be.query(p, 0.033)
            totals.append(clock() - t)
            inside.append(spent[0])
            calls = spent[1]
    finally:
        fcl_mod.fcl = chunks_mod.fcl = fcl
    n = len(poses)
    return 1e3 * float(np.median(totals)) / n, 1e3 * float(np.median(inside)) / n, calls


def fmu_rest_cost(n_calls=300):
    """Median us of an fmi2DoStep whose inputs did not change, through FMPy (campus scene and
    the 5040-tank field)."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    from immersim.orchestrator.build import build_unit

    path = build_unit(ROOT / "fmus" / "collision", Path(os.environ.get("TMPDIR", "/tmp")) / "bench_collision_fmu")
    md = read_model_description(path)
    unzipped = extract(path)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    params = _campus_params()
    out = []
    for label, scene, pairs in (("campus_drive scene and pairs", params["scene"], params["pairs"]),
                                ("5040-tank field, missile vs any tank", "tanks:n=5040,tris=5.4k;missile:z=8",
                                 "missile vs any tank")):
        s = FMU2Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName="rest")
        s.instantiate()
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        s.setString([vr["scene"], vr["pairs"]], [scene, pairs])
        s.exitInitializationMode()
        t_now, ts = 0.0, []
        for k in range(n_calls + 2):
            t = time.perf_counter()
            s.doStep(t_now, 0.033)
            ts.append(time.perf_counter() - t)
            t_now += 0.033
        s.terminate()
        s.freeInstance()
        out.append([label, float(np.median(ts[2:]) * 1e6)])
    return ["scene", "median us per unchanged fmi2DoStep"], out


def _loop_figures(run_output):
    """The ``loop ...`` line of an ``immersim run`` output and, from it, ms per step of the
    whole loop and of the collision unit (None when the file holds no such line)."""
    import re

    text = Path(run_output).read_text()
    line = next((l.strip() for l in text.splitlines() if l.startswith("loop ")), None)
    steps = re.search(r"(\d+) steps to t =", text)
    if line is None or steps is None:
        return None
    n = int(steps.group(1))
    loop = float(re.match(r"loop ([\d.]+) s", line).group(1))
    coll = re.search(r"coll ([\d.]+) s", line)
    return line, n, 1e3 * loop / n, (1e3 * float(coll.group(1)) / n if coll else float("nan"))


def _loop_text(run_output):
    figs = _loop_figures(run_output)
    if figs is None:
        return [f"({run_output} holds no `loop` line of `immersim run`.)", ""]
    line, n, loop_ms, coll_ms = figs
    return [f"The run that wrote the log (`immersim run scenarios/campus_drive.toml`, same commit and machine) "
            f"reported: `{line}`, i.e. {loop_ms:.3f} ms per step for the whole loop and {coll_ms:.3f} ms for the "
            f"collision unit (FMU calls included) over {n} steps. campus_drive's 100x real-time target needs <= 0.33 ms per "
            f"step for the loop: **{'met' if loop_ms <= 0.33 else 'NOT met'}** (the collision unit alone takes "
            f"{coll_ms:.3f} ms of those 0.33 ms).", ""]


def campus_main(log, baseline, baseline_max_distance=FMU_MAX_DISTANCE, run_output=None):
    commit, ncpu, cpu, py, _ = machine()
    ch, crows, n_steps, dev, changed = bench_campus(log, baseline, baseline_max_distance=baseline_max_distance)
    rh, rrows = fmu_rest_cost()
    share_total, share_fcl, share_calls = fcl_share(log)
    write_csv("campus_replay.csv", ch, crows)
    write_csv("fmu_rest.csv", rh, rrows)
    mean, cpu_ms = crows[0][1], crows[0][5]
    text = [
        "## campus_drive: the collision unit's inputs replayed through the model",
        "",
        f"Command: `python benchmarks/bench_collision.py --campus {log}"
        f"{' --baseline ' + baseline if baseline else ''}"
        f"{' --baseline-max-distance %g' % baseline_max_distance if baseline and baseline_max_distance != FMU_MAX_DISTANCE else ''}"
        f"{' --run-output ' + str(run_output) if run_output else ''}` "
        f"(log of `immersim run scenarios/campus_drive.toml`, {n_steps} steps of 33 ms, scene and pairs of the "
        f"scenario, each step's poses passed as the FMU passes them, one flat tuple of 6 numbers per dynamic body; "
        f"this tree and the baseline run {CAMPUS_REPS} times, interleaved step by step (taking turns at going "
        f"first), then the other variants likewise; CPU: thread CPU time). Commit `{commit}`, "
        f"{ncpu} CPUs ({cpu}), Python {py}.",
        "",
        md_table(ch, crows),
    ]
    for name, d in dev.items():
        text += [f"* `{name}` against commit {baseline} (same max_distance; exact comparison of every pair's "
                 f"contact flag, distance, depth, point, normal, time of impact, closing speed and partner and of the "
                 f"counters): {d.summary()}.", ""]
    if baseline:
        r0, rb = crows[0], crows[-1]
        same = bool(dev) and all(d.equal == d.steps for name, d in dev.items() if name.endswith("chunked distances)"))
        text += [f"This tree against commit {baseline} (same inputs, interleaved): mean {r0[1] / rb[1]:.2f}x, median "
                 f"{r0[2] / rb[2]:.2f}x, p95 {r0[3] / rb[3]:.2f}x, max {r0[4] / rb[4]:.2f}x of the baseline's time per step.",
                 "",
                 f"Target: mean <= {CAMPUS_TARGET_MS:g} ms per step and at least {CAMPUS_TARGET_SPEEDUP:g}x cheaper than "
                 f"the baseline, outputs identical: mean {r0[1]:.3f} ms, {rb[1] / r0[1]:.2f}x, outputs "
                 f"{'identical' if same else 'NOT identical'}: "
                 f"**{'met' if r0[1] <= CAMPUS_TARGET_MS and rb[1] / r0[1] >= CAMPUS_TARGET_SPEEDUP and same else 'NOT met'}**.",
                 ""]
    if changed is not None:
        sh, srows, s_this, s_base = changed
        text += [f"The eight steps whose time changed most (median of the {CAMPUS_REPS} repetitions per step; sum over all "
                 f"{n_steps} steps: {s_this:.1f} ms for this tree, {s_base:.1f} ms for commit {baseline}):", "",
                 md_table(sh, srows), ""]
    if dev:
        text += ["Where the chunked outputs differ from the whole-mesh ones it is the reported nearest point of a pair "
                 "whose nearest points are not unique (an avatar box's vertical edge parallel to a tank's vertical "
                 "side face: a segment of nearest points; both are exact nearest points), and the normal and time "
                 "of impact by round-off; distances agree to round-off and contacts (flags, depths, points, partners) "
                 "are identical (see `models/collision/chunks.py` and `fmus/collision/README.md`). Against a baseline "
                 "before the distance triangulation (`models/collision/fans.py`, exact distances on the tank turret "
                 "caps re-triangulated) and the axis-radius bound of conservative advancement, distances, nearest "
                 "points and times of impact of the missile differ by round-off, and the times of impact of the "
                 "avatars' bounces (conservative advancement with fewer, longer steps) by less than the 1e-4 m "
                 "tolerance over their closing speed, with n_narrow counting the fewer iterations.", ""]
    text += [
        f"The model costs **{mean:.3f} ms** per step on average ({cpu_ms:.3f} ms CPU; median {crows[0][2]:.3f} ms) "
        + (f"against {crows[-1][1]:.3f} ms ({crows[-1][5]:.3f} ms CPU) for commit {baseline}. " if baseline else ". ")
        + "The 100x real-time target of campus_drive leaves 0.33 ms per step for the whole loop of campus_drive (three units, logging and master) at "
        f"100x real time: the collision model alone takes {100 * cpu_ms / 0.33:.0f} % of it (CPU). Far pairs (every member's AABB at least max_distance away) cost nothing while a face-motion "
        "bound says they are still far; the median step is the bookkeeping of 8 moving bodies. The mean is the "
        "physics of the steps where an avatar is within 2 m of its tank (one chunk query each: about 45 us of "
        "numpy for the chunks' box bounds and 10-20 us of fcl, plus the pair's bookkeeping), contacts, "
        "conservative advancement when an avatar turns a quarter turn in one step next to a tank in a bounce "
        "(16-20 iterations of about 0.12 ms, each a chunk query and an interpolated pose) and the missile: "
        "its nose comes down near the centre of tank_0's turret cap, which the tank mesh builds as a fan of "
        "~580 triangles all meeting there; the exact distances run on a distance triangulation of the same "
        "surface (`models/collision/fans.py`), so its approach steps cost one whole-mesh query of 0.1-0.2 ms "
        "(against 1-5 ms on the fan) and its impact step's conservative advancement about ten; its contact tests "
        "keep the fan (fcl's penetration depth is per triangle pair): about 0.25 ms each while it moves into the "
        "tank.",
        "",
        f"Of this tree's replay ({share_total:.3f} ms per step in a run with python-fcl's pairwise calls timed), "
        f"{share_fcl:.3f} ms per step are spent inside `fcl.distance` and `fcl.collide` ({share_calls} calls per "
        f"run; the broad phase's tree queries not counted). Outputs identical to an earlier commit bit for bit "
        f"need the same fcl numbers: either the same calls, or calls that provably return the same bits; Python "
        f"and numpy take the rest.",
        "",
        *(_loop_text(run_output) if run_output else []),
        "At rest (no input changed), one `fmi2DoStep` through FMPy:",
        "",
        md_table(rh, rrows),
    ]
    (OUT / "campus.md").write_text("\n".join(text))
    readme = OUT / "README.md"
    if readme.exists():  # refresh the section of the last full run in place
        body = readme.read_text()
        head = "## campus_drive (separate run)"
        if head in body:
            i = body.index(head)
            j = body.find("\n## ", i + len(head))
            new = "\n".join(text).replace("## campus_drive", head, 1)
            readme.write_text(body[:i] + new + ("\n" + body[j:] if j >= 0 else "\n"))
    print("\n".join(text))



# -- A/B against another tree's model (one run, interleaved) ----------------------------------------
def _package_at(path, name):
    """Import the ``models/collision`` folder ``path`` of another checkout as package ``name``
    (self-contained: relative imports only)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, Path(path) / "__init__.py",
                                                  submodule_search_locations=[str(path)])
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def _interleaved(models, inputs, reps, fresh=True, dt=0.033):
    """Thread CPU seconds per query of each model (name -> list, ``reps x len(inputs)``), all
    models queried at each input in turns (the order reversed every other step), and whether
    their outputs were identical at every input of the first repetition. ``models``: name ->
    a function making the model, called per repetition when ``fresh`` (else once)."""
    times = {name: [] for name in models}
    same = True
    clock = time.thread_time
    bes = None
    for rep in range(reps):
        if fresh or bes is None:
            bes = [(name, make()) for name, make in models.items()]
        for k, p in enumerate(inputs):
            out = []
            for name, be in (bes if (rep + k) % 2 == 0 else bes[::-1]):
                t = clock()
                res = be.query(p, dt) if name != "raw" else be.query(p)
                times[name].append(clock() - t)
                if rep == 0 and name != "raw":
                    out.append(_outputs(res))
            same = same and all(o == out[0] for o in out)
    return times, same


def bench_ab(tree, log=None, reps=10):
    """This tree's model against the one of checkout ``tree``: the 5040-tank field (26.4k
    triangles, missile vs any tank) per step with raw python-fcl, a step in which nothing
    moves, and with ``log`` the collision unit's inputs of a campus_drive run replayed; every
    variant interleaved step by step, thread CPU time. Returns header, rows."""
    base = _package_at(Path(tree) / "models" / "collision", "collision_ab_base")
    spec = "tanks:n=5040,tris=26.4k;missile:z=8"
    scenes = {"this": parse_scene(spec), "base": base.parse_scene(spec)}
    traj = [[p] for p in field_trajectory(scenes["this"], 30)]
    mods = {"this": (make_backend, BackendConfig), "base": (base.make_backend, base.BackendConfig)}
    rows = []

    def row(label, t_this, t_base, raw=None, stat=np.median):
        a, b = float(stat(t_this)) * 1e3, float(stat(t_base)) * 1e3
        extra = [a / raw, b / raw] if raw else ["", ""]
        rows.append([label, a, b, a / b] + extra)

    configs = (("ccd off", dict(ccd=False)), ("ccd on", {}), (f"max_distance = {FMU_MAX_DISTANCE:g} m", dict(max_distance=FMU_MAX_DISTANCE)))
    for label, kw in configs:
        models = {tag: (lambda tag=tag, kw=kw: mods[tag][0]("fcl", scenes[tag], "missile vs any tank", mods[tag][1](**kw)))
                  for tag in mods}
        if label == "ccd off":
            models["raw"] = lambda: RawField(make_backend("fcl", scenes["this"], "missile vs any tank"),
                                             len(scenes["this"].bodies) - 1)
        times, same = _interleaved(models, traj, reps, fresh=False)
        if label == "ccd off":
            raw = float(np.median(times["raw"])) * 1e3
        row(f"5040-tank field step, {label}{'' if same else ' (outputs DIFFER)'}", times["this"], times["base"], raw)
    rest = {tag: (lambda tag=tag: mods[tag][0]("fcl", scenes[tag], "missile vs any tank", mods[tag][1](ccd=False)))
            for tag in mods}
    times, same = _interleaved(rest, [traj[-1]] * 500, 1, fresh=False)
    row("5040-tank field, step in which nothing moved", times["this"][1:], times["base"][1:])
    rows.append(["raw python-fcl, 5040-tank field step", raw, raw, 1.0, 1.0, 1.0])
    if log:
        params, poses = _campus_inputs(log)
        camp = {tag: (lambda tag=tag: mods[tag][0]("fcl", (parse_scene if tag == "this" else base.parse_scene)(params["scene"]),
                                                     params["pairs"], mods[tag][1](max_distance=FMU_MAX_DISTANCE)))
                for tag in mods}
        times, same = _interleaved(camp, poses, AB_REPS)
        row(f"campus_drive replay, mean per step{'' if same else ' (outputs DIFFER)'}", times["this"], times["base"],
            stat=np.mean)
        per_step = lambda t: np.median(np.reshape(t, (AB_REPS, -1)), 0)  # noqa: E731
        row("campus_drive replay, sum of the per-step medians (a whole replay)", per_step(times["this"]),
            per_step(times["base"]), stat=np.sum)
        row("campus_drive replay, median per step", times["this"], times["base"])
    header = ["figure (thread CPU time)", "this tree ms", "baseline ms", "this / baseline", "this / raw",
              "baseline / raw"]
    return header, rows


def bench_shortcuts(log, reps=None):
    """Each :class:`Shortcuts` switch off against all on: the campus_drive replay of ``log``
    and the 5040-tank field at the FMU's max_distance, interleaved; thread CPU per step: the
    mean, the sum over the steps of their medians over the repetitions (a whole run, robust to
    a noisy repetition) and the median step."""
    from immersim.models.collision import Shortcuts

    reps = AB_REPS if reps is None else reps
    params, poses = _campus_inputs(log)
    field = parse_scene("tanks:n=5040,tris=26.4k;missile:z=8")
    traj = [[p] for p in field_trajectory(field, 30)]
    names = ["all on"] + [f"{f} off" for f in Shortcuts.__dataclass_fields__]
    switch = lambda name: Shortcuts() if name == "all on" else Shortcuts(**{name[:-4]: False})  # noqa: E731
    rows = []
    for label, make, inputs in (
            ("campus_drive replay", lambda name: make_backend("fcl", parse_scene(params["scene"]), params["pairs"],
                                                                BackendConfig(max_distance=FMU_MAX_DISTANCE), switch(name)),
             poses),
            ("5040-tank field", lambda name: make_backend("fcl", field, "missile vs any tank",
                                                            BackendConfig(max_distance=FMU_MAX_DISTANCE), switch(name)),
             traj)):
        times, same = _interleaved({n: (lambda n=n: make(n)) for n in names}, inputs, reps, fresh=inputs is poses)
        stats = {n: (float(np.mean(t)) * 1e3, float(np.median(np.reshape(t, (reps, -1)), 0).sum()) * 1e3,
                     float(np.median(t)) * 1e3) for n, t in times.items()}
        on = stats["all on"]
        for n in names[1:]:
            off = stats[n]
            rows.append([label, n] + [x for k in range(3) for x in (on[k], off[k], off[k] / on[k])]
                        + ["yes" if same else "NO"])
    return ["workload", "variant", "all on: mean ms/step", "variant", "ratio", "all on: sum of step medians ms",
            "variant", "ratio", "all on: median step ms", "variant", "ratio", "outputs identical"], rows


def ab_main(tree, baseline_name, log=None):
    commit, ncpu, cpu, py, _ = machine()
    header, rows = bench_ab(tree, log)
    write_csv("ab.csv", header, rows)
    text = ["# collision model A/B", "",
            f"Command: `python benchmarks/bench_collision.py --ab CHECKOUT{' --campus LOG' if log else ''}` with "
            f"CHECKOUT a work tree of `{baseline_name}`{' and LOG a campus_drive log' if log else ''}. Commit "
            f"`{commit}` against `{baseline_name}`, {ncpu} CPUs ({cpu}), Python {py}. Every variant (and raw "
            "python-fcl) queried at each step in turns, thread CPU time; medians unless marked mean. The machine "
            "is shared: only ratios within this run are compared.", "",
            md_table(header, rows)]
    if log:
        sh, srows = bench_shortcuts(log)
        write_csv("shortcuts.csv", sh, srows)
        text += ["## Shortcuts (each switched off against all on)", "",
                 f"`Shortcuts` of `models/collision/backend.py`, {AB_REPS} repetitions; thread CPU per step: mean, "
                 "sum over the steps of their median (a whole run) and the median step; FMU default max_distance; "
                 "ratio > 1: the shortcut saves that much.", "",
                 md_table(sh, srows)]
    (OUT / "ab.md").write_text("\n".join(text))
    print("\n".join(text))


# -- start-up: import and instantiation in fresh processes ----------------------------------------
_STARTUP = """
import json, sys, time
t0 = time.perf_counter()
sys.path.insert(0, sys.argv[1])
import collision_pkg as C
t1 = time.perf_counter()
p = json.loads(sys.argv[2])
scene = C.parse_scene(p["scene"])
t2 = time.perf_counter()
be = C.make_backend("fcl", scene, p["pairs"], C.BackendConfig(max_distance=2.0))
t3 = time.perf_counter()
be.query(tuple(float(x) for i in scene.dynamic for x in scene.bodies[i].pose), 0.033)
t4 = time.perf_counter()
print(json.dumps([t1 - t0, t2 - t1, t3 - t2, t4 - t3, t4 - t0, [m for m in ("trimesh", "scipy.spatial", "fcl") if m in sys.modules]]))
"""


def bench_startup(trees, runs=7):
    """Per tree (name -> its models/collision folder), in fresh processes taking turns: the
    package's import time (``python -X importtime``, cumulative) and, on campus_drive's scene
    and pairs, the wall time of import, scene, backend, first query and their sum (medians, ms)."""
    import json
    import re
    import tempfile

    dirs = {}
    for name, folder in trees.items():
        d = tempfile.mkdtemp(prefix="bench_startup_")
        os.symlink(Path(folder).resolve(), Path(d) / "collision_pkg")
        dirs[name] = d
    imp = {n: [] for n in trees}
    inst = {n: [] for n in trees}
    for r in range(runs):
        for name in (list(trees) if r % 2 == 0 else list(trees)[::-1]):
            out = subprocess.run([sys.executable, "-X", "importtime", "-c", "import sys; sys.path.insert(0, sys.argv[1]); "
                                  "import collision_pkg", dirs[name]], capture_output=True, text=True, check=True)
            imp[name].append(int(re.search(r"\|\s*(\d+) \| collision_pkg$", out.stderr, re.M).group(1)) / 1e3)
            out = subprocess.run([sys.executable, "-c", _STARTUP, dirs[name], json.dumps(CAMPUS_COLLISION)], capture_output=True,
                                 text=True, check=True)
            inst[name].append(json.loads(out.stdout))
    header = ["tree", "import of the model package ms (importtime)", "instantiate: import ms", "scene ms", "backend ms",
              "first query ms", "total ms", "heavy modules loaded"]
    rows = []
    for name in trees:
        t = np.median(np.array([x[:5] for x in inst[name]]), 0) * 1e3
        rows.append([name, float(np.median(imp[name]))] + [float(x) for x in t] + [", ".join(inst[name][0][5])])
    return header, rows


def startup_main(tree, baseline_name, runs=7):
    commit, ncpu, cpu, py, _ = machine()
    trees = {f"this tree ({commit})": ROOT / "models" / "collision"}
    if tree:
        trees[baseline_name] = Path(tree) / "models" / "collision"
    header, rows = bench_startup(trees, runs)
    text = ["# collision unit start-up", "",
            f"Command: `python benchmarks/bench_collision.py --startup{' --ab CHECKOUT' if tree else ''}`"
            f"{' with CHECKOUT a work tree of `' + baseline_name + '`' if tree else ''}. {ncpu} CPUs ({cpu}), Python {py}. "
            f"{runs} fresh processes per tree, taking turns; medians. Import: `python -X importtime` of the model "
            "package alone (cumulative). Instantiate: wall time in a fresh process of the import, `parse_scene` of "
            "campus_drive's scene, `make_backend('fcl', ...)` with its pairs (max_distance 2 m) and the first query.", "",
            md_table(header, rows)]
    (OUT / "startup.md").write_text("\n".join(text))
    print("\n".join(text))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer sizes and poses (about 2 minutes)")
    ap.add_argument("--campus", metavar="LOG", help="only: replay a campus_drive MCAP log (-> campus.md)")
    ap.add_argument("--baseline", metavar="COMMIT", help="with --campus: also replay the model of COMMIT")
    ap.add_argument("--run-output", metavar="FILE",
                    help="with --campus: the output of the `immersim run` that wrote LOG (its loop timing is quoted)")
    ap.add_argument("--baseline-max-distance", type=float, default=FMU_MAX_DISTANCE,
                    help="with --baseline: the max_distance of the baseline model (m; its FMU default)")
    ap.add_argument("--ab", metavar="CHECKOUT",
                    help="only: this tree's model against CHECKOUT's on the 5040-tank field (-> ab.md)")
    ap.add_argument("--ab-name", default="baseline", help="with --ab: how the baseline is named in ab.md")
    ap.add_argument("--startup", action="store_true",
                    help="only: import and instantiation time in fresh processes (with --ab: also CHECKOUT's; -> startup.md)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    warnings.simplefilter("ignore")
    OUT.mkdir(parents=True, exist_ok=True)
    if args.startup:
        startup_main(args.ab, args.ab_name)
        return
    if args.ab:
        ab_main(args.ab, args.ab_name, args.campus)
        return
    if args.campus:
        campus_main(args.campus, args.baseline, args.baseline_max_distance, args.run_output)
        return
    rng = np.random.default_rng(RNG_SEED)
    t_start = time.perf_counter()
    print("accuracy ...", flush=True)
    acc_h, acc_rows, acc_data = bench_accuracy(args.quick, rng)
    print("triangles ...", flush=True)
    tri = bench_triangles(args.quick, rng)
    print("tank field ...", flush=True)
    fh, frows, rh, rrows = bench_field(args.quick, rng)
    print("ST sweep ...", flush=True)
    st = bench_st(args.quick, rng, acc_data)
    print("cells sweep ...", flush=True)
    cells = bench_cells(args.quick, rng, acc_data)
    plots(tri, (fh, frows), st, cells)
    write_csv("triangles.csv", *tri)
    write_csv("field.csv", fh, frows)
    write_csv("field_ratio.csv", rh, rrows)
    write_csv("accuracy.csv", acc_h, acc_rows)
    write_csv("st_sweep.csv", *st)
    write_csv("cells_sweep.csv", *cells)
    elapsed = time.perf_counter() - t_start
    commit, ncpu, cpu, py, ray = machine()
    by_n = {r[0]: r for r in frows}
    ratio_5040 = {r[0]: r for r in rrows}.get(5040)
    big = by_n.get(5040)
    lines = [
        "# collision benchmark",
        "",
        f"Command: `python benchmarks/bench_collision.py{' --quick' if args.quick else ''}` "
        f"({elapsed:.0f} s). Commit `{commit}`, {ncpu} CPUs ({cpu}), Python {py}, ray casting: {ray}. "
        "The machine is shared with other jobs: single figures move by tens of per cent between runs; "
        "backend and raw python-fcl are interleaved step by step so their ratio is robust.",
        "",
        "## Targets",
        "",
    ]
    if big is not None and ratio_5040 is not None:
        r_med, r_tot = ratio_5040[1], ratio_5040[2]
        lines += [
            f"* FMU default backend (`fcl`) within 1.2x of raw python-fcl on the same queries (5040-tank field, "
            f"collide + distance per step): **{r_med:.2f}x** (ratio of medians), {r_tot:.2f}x (ratio of totals): "
            f"**{'met' if r_med <= 1.2 else 'NOT met'}**. With continuous collision (time of impact, which raw "
            f"python-fcl does not compute) {ratio_5040[3]:.2f}x. Over all field sizes of this run the ratio of "
            f"medians spans {min(r[1] for r in rrows):.2f}x .. {max(r[1] for r in rrows):.2f}x and the ratio of "
            f"totals {min(r[2] for r in rrows):.2f}x .. {max(r[2] for r in rrows):.2f}x (table below): the fixed "
            f"per-step Python cost (pose check, bookkeeping, per-candidate callbacks) is about 0.1 ms, so the ratio "
            f"exceeds 1.2 where a step's narrow phase is cheap.",
            f"* 5040-tank scene <= 1 ms per step: fcl backend median **{big[2]:.3f} ms** "
            f"(with time of impact {big[3]:.3f} ms; raw python-fcl {big[1]:.3f} ms): "
            f"**{'met' if big[2] <= 1.0 else 'NOT met'}**"
            f"{'' if big[3] <= 1.0 else ' without time of impact only'}.",
            f"* Nothing moves: a cached step of the 5040-tank scene costs {big[4] * 1e3:.1f} us (median).",
            "* The missile (192 triangles) keeps fcl's whole-mesh distance query in all these workloads: the chunked "
            "exact distances of the FMU default (`chunk_faces = 32`) serve bodies of at most 64 triangles (boxes such "
            "as campus_drive's avatars) against meshes of at least 1024; their effect shows in the campus_drive replay. "
            "The backend's exact distances run on the tank's distance triangulation (its turret caps, fans of "
            "slivers, re-triangulated: `models/collision/fans.py`); raw python-fcl here queries the tank mesh "
            "itself, fans included, for both collide and distance.",
        ]
    if big is not None and len(big) > 8:
        lines.append(f"* 5040-tank field with the FMU's default `max_distance = {FMU_MAX_DISTANCE:g} m` (and time of "
                     f"impact): median **{big[8]:.3f} ms** per step. Not comparable with raw python-fcl, which "
                     "computes the exact distance to the nearest tank however far it is; this reports "
                     "`max_distance` then.")
    for name in ("ab.md", "startup.md", "campus.md"):  # separate runs (--ab, --startup, --campus)
        part = OUT / name
        if part.exists():
            lines += ["", part.read_text().replace("# ", "## ", 1).replace("## ", "## (separate run) ", 1)]
    lines += ["", "Measured effects behind design choices of the model: `design.md`."]
    lines += [
        "",
        "## Accuracy against FCL (random missile poses around a 5.4k tank)",
        "",
        "Exact answer: FCL (its distances match an independent brute-force vertex-triangle / edge-edge "
        "computation to 1e-7 m in `tests/collision/test_fcl_backend.py`). Honeycomb runs at rest (threshold "
        "d = 0): with motion it flags contacts one step ahead by design. Distance errors over poses both call "
        "apart; the thesis backends' distances are estimates (basis_point: nearest feature at the scan "
        "resolution; honeycomb: section gap along the depth axis) and, for bodies their cull rejects, bounds "
        "(sphere or AABB gap), hence the large median over all poses; the column `exact < 0.3 m` restricts it "
        "to near misses.",
        "",
        md_table(acc_h, acc_rows),
        "## Time vs triangles (tables 4-1, 5-1, 5-2)",
        "",
        "Median ms per query over changing poses; `hit`: the missile intersects the tank, `miss`: 2 cm .. 0.8 m "
        "apart. Continuous collision off for all (raw python-fcl has none).",
        "",
        md_table(*tri),
        "![time vs triangles](time_vs_triangles.png)",
        "",
        "## Time vs number of tanks (table 5-3)",
        "",
        "Missile diving onto the central tank (26.4k triangles each, one shared BVH); median ms per step. "
        "`fcl at rest`: a step in which no pose changed.",
        "",
        md_table(fh, frows),
        md_table(rh, rrows),
        "![time vs tanks](time_vs_tanks.png)",
        "",
        "## basis_point ST sweep (table 5-5)",
        "",
        "Time per query with the missile in contact with the 26.4k tank; BP counts and DN of the last query; "
        "flag errors on the first random poses of the accuracy set (small ST: timing only).",
        "",
        md_table(*st),
        "## honeycomb n x m sweep",
        "",
        md_table(*cells),
        "![time vs error](time_vs_error.png)",
        "",
        "## Reading the thesis's claims",
        "",
        "The thesis reports 3.5-13.5 ms per detection for basis_point (table 5-1) and 4-12 ms for honeycomb "
        "(table 4-1) on 2010 hardware in C++. Here they are numpy/trimesh re-implementations, compared with FCL's "
        "compiled BVH traversal; the tables above are what they measure on this machine, whatever they show.",
    ]
    (OUT / "README.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {OUT} in {elapsed:.0f} s")


if __name__ == "__main__":
    sys.exit(main() or 0)

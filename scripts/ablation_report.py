"""Run the issue-6 ablations on campus_drive and write ``results/ablation/README.md``.

Runs ``immersim sweep`` on ``scenarios/sweeps/campus_backends.toml`` (collision backend) and
``scenarios/sweeps/campus_prediction.toml`` (dead-reckoning order x WAN latency) into
``results/ablation/backends`` and ``results/ablation/prediction`` (summary.csv, comparison plots;
the per-run MCAP files are git-ignored), then writes the README with the command, commit,
machine and the summary tables.

Usage::

    .venv/bin/python scripts/ablation_report.py [-j 2] [--skip-run]
"""
from __future__ import annotations

import argparse
import csv
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "results" / "ablation"
SWEEPS = {"backends": "campus_backends.toml", "prediction": "campus_prediction.toml",
          "tank_field_n": "tank_field_n.toml"}
IMMERSIM = Path(sys.executable).with_name("immersim")


def machine() -> str:
    cpu = platform.processor()
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            cpu = line.split(":", 1)[1].strip()
            break
    return f"{os.cpu_count()} cores, {cpu}, Python {platform.python_version()}"


def table(path: Path, skip=("run", "reason", "mcap", "t_end_s")) -> tuple:
    rows = list(csv.DictReader(path.open()))
    cols = [c for c in rows[0] if c not in skip]

    def fmt(v: str) -> str:
        try:
            x = float(v)
        except ValueError:
            return v
        return f"{x:.4g}"

    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(fmt(r[c]) for c in cols) + " |" for r in rows]
    return lines, rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-j", type=int, default=2)
    ap.add_argument("--skip-run", action="store_true", help="only rewrite the README from the summaries")
    ap.add_argument("--only", choices=list(SWEEPS), action="append", help="run only these sweeps")
    args = ap.parse_args()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip()
    walls = {}
    for name, sweep in SWEEPS.items():
        if args.skip_run or (args.only and name not in args.only):
            continue
        t0 = time.perf_counter()
        subprocess.run([str(IMMERSIM), "sweep", f"scenarios/sweeps/{sweep}", "-o", f"results/ablation/{name}",
                        "-j", str(args.j)], cwd=ROOT, check=True)
        walls[name] = time.perf_counter() - t0
    tb, rb = table(OUT / "backends" / "summary.csv")
    tp, rp = table(OUT / "prediction" / "summary.csv")
    tn, _ = table(OUT / "tank_field_n" / "summary.csv", skip=("run", "reason", "mcap", "t_end_s", "coll.scene"))
    by = {r["coll.backend"]: r for r in rb}
    f = lambda r, k: float(r[k])  # noqa: E731
    pred = {(int(float(r["net.prediction_order"])), float(r["net.latency_ms"])): r for r in rp}
    lats = sorted({k[1] for k in pred})
    wall = ", ".join(f"{k} {v:.0f} s" for k, v in walls.items()) or "not re-run (--skip-run)"
    pngs = {n: sorted(p.name for p in (OUT / n).glob("*.png")) for n in SWEEPS}
    text = f"""# Ablations on campus_drive (issue 6, item 3)

Command (runs both sweeps and rewrites this file):

    .venv/bin/python scripts/ablation_report.py -j {args.j}

which runs

    immersim sweep scenarios/sweeps/campus_backends.toml -o results/ablation/backends -j {args.j}
    immersim sweep scenarios/sweeps/campus_prediction.toml -o results/ablation/prediction -j {args.j}
    immersim sweep scenarios/sweeps/tank_field_n.toml -o results/ablation/tank_field_n -j {args.j}

Commit `{commit}`, {machine()}, shared with other engineers' jobs (times are indicative).
Sweep wall time: {wall}. Each run is the full `scenarios/campus_drive.toml` (20 s, 607 steps,
network + collision + platform in the closed loop, full logging). Per-run MCAPs are not committed
(`.gitignore`); `summary.csv` and the comparison plots are.

## Collision backend (`backends/`)

{chr(10).join(tb)}

Plots: {", ".join(f"`backends/{p}`" for p in pngs["backends"])}.

`contact_p`: share of the steps in which pair p (`avatar_p vs tank_X`) reports contact; `missile_hit`:
the missile reached a field tank; `jolt_max`: player 1's largest bounce |dv| (m/s) = the jolt sent to
the platform; `stroke_max`: largest actuator stroke (m); `coll_s`: wall time in the collision unit.

* fcl and basis_point see the same contacts (same steps) and the same bounces within
  {100 * abs(f(by['basis_point'], 'jolt_max') / f(by['fcl'], 'jolt_max') - 1):.1f} % (player 1: {f(by['fcl'], 'jolt_max'):.2f} vs
  {f(by['basis_point'], 'jolt_max'):.2f} m/s).
* honeycomb holds contact longer ({f(by['honeycomb'], 'contact_1') / max(f(by['fcl'], 'contact_1'), 1e-12):.1f}x the steps for avatar 1,
  {f(by['honeycomb'], 'contact_2') / max(f(by['fcl'], 'contact_2'), 1e-12):.0f}x for avatar 2; it flags contact one step ahead by design and already at
  t = 0 for pair 2, see below) and its normal is axis-aligned (the depth axis), so player 1's bounce is
  {100 * (1 - f(by['honeycomb'], 'jolt_max') / f(by['fcl'], 'jolt_max')):.0f} % smaller ({f(by['honeycomb'], 'jolt_max'):.2f} m/s).
* Collision unit time: basis_point {f(by['basis_point'], 'coll_s') / f(by['fcl'], 'coll_s'):.2f}x and honeycomb
  {f(by['honeycomb'], 'coll_s') / f(by['fcl'], 'coll_s'):.2f}x of fcl's. fcl spends most of its time in exact mesh-mesh distances of
  the avatar boxes to the 5.4k-triangle tanks, every step (see `results/scenarios/bench.md`).
* The stroke reaches the 0.12 m limit in every variant (the washout reference is clamped while
  the avatar accelerates), so this metric cannot separate the jolts; the jolt's own effect on the
  strokes is isolated in `results/scenarios/collision_jolt_strokes.png`.
* honeycomb reports pair 2 in contact in the initial output (t = 0, avatar 16 m from the tank):
  its displacement threshold counts the move from the scene spec's pose (origin) to the initial
  input pose. Reported to the collision unit's owner.

## Dead-reckoning order x WAN latency (`prediction/`)

{chr(10).join(tp)}

Plots: {", ".join(f"`prediction/{p}`" for p in pngs["prediction"])}.

`incons_max`: largest position error of a displayed copy (eq. 3-1/3-2, m), `incons_mean`: its mean
over the steps, `incons_rms`: RMS of the per-frame RMS over copies, `bytes_per_step`: traffic.

""" + "\n".join(
        f"* WAN {lat:g} ms: mean inconsistency order 0 -> 1 falls "
        f"{f(pred[(0, lat)], 'incons_mean') / f(pred[(1, lat)], 'incons_mean'):.0f}x, order 1 -> 2 a further "
        f"{f(pred[(1, lat)], 'incons_mean') / f(pred[(2, lat)], 'incons_mean'):.1f}x; the peak is "
        f"{f(pred[(0, lat)], 'incons_max'):.2f} / {f(pred[(1, lat)], 'incons_max'):.2f} / {f(pred[(2, lat)], 'incons_max'):.2f} m "
        f"for order 0 / 1 / 2; order 2 costs {100 * (f(pred[(2, lat)], 'bytes_per_step') / f(pred[(1, lat)], 'bytes_per_step') - 1):.0f} % more bytes."
        for lat in lats) + """
* The peak does not improve beyond order 1 (and is larger than order 0's at high latency): it comes
  from the bounces, which dead reckoning extrapolates straight through the obstacle until the next
  state record arrives; it grows with the latency.

## Missile vs N tanks (`tank_field_n/`, scenario tank_field, 4 s, collision unit alone)

N = 1, 10, 100, 1000, 5040 tanks of 5.4k triangles (ids: n-N_backend), fcl and basis_point:

""" + "\n".join(tn) + """

The missile touches tank_0 at the same step for every N and both backends (`contact` = share of
steps in contact); the broad phase keeps the candidates at most 3 (fcl) / 1 (basis_point) whatever
N is, so the collision unit's time (`coll_s`) hardly grows from 1 to 5040 tanks; `wall_s`
includes building the field (one shared tank BVH).
"""
    (OUT / "README.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()

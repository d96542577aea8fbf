"""A/B of the network's scale figure against another commit, in one run.

The scale configuration of bench_network (1000 render nodes = 250 groups x 4, 10,000 free
entities, 2000 m scene, seed 4, every frame published, display error measured): each round
runs this tree and the baseline tree (``git archive BASE models fmus``, imported ahead of the
installed package) in fresh processes, alternated; each run reports the median CPU time of
its steps after 5 warm-up steps. Quoted: medians over the rounds and their ratio.

Usage: ``.venv/bin/python benchmarks/bench_scale_ab.py [--base COMMIT] [--this COMMIT] [--rounds N] [--steps N] [--quick]``
(default base: ``1998c63``, the network before its option groups and its defaults ownerless
entities, STATE to neighbour nodes and a frame clock per node; ``--this``: this side from a
commit too, so that other units' uncommitted edits stay out of it). Writes ``results/network/scale_ab.md``.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT, stamp  # noqa: E402

OUT = ROOT / "results" / "network" / "scale_ab.md"
DEFAULT_BASE = "1998c63"
CHILD = r"""
import json, sys, time
if sys.argv[1]:
    sys.path.insert(0, sys.argv[1])
import numpy as np
import immersim.models.network as net
from immersim.models.network import NetworkConfig, NetworkModel
make = getattr(NetworkConfig, "from_flat", NetworkConfig)   # (a tree before the option groups: flat keywords)
cfg = make(groups=250, render_nodes=4, entities=10_000, scene_size=2000.0, avatar_start="uniform", seed=4)
m = NetworkModel(cfg)
for _ in range(5):
    m.step(0.033)
cpu = []
for _ in range(int(sys.argv[2])):
    c0 = time.process_time()
    m.step(0.033)
    cpu.append(time.process_time() - c0)
print(json.dumps({"cpu_ms": float(np.median(cpu)) * 1e3, "where": net.__file__}))
"""


def _run(path: str, steps: int) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, path, str(steps)], capture_output=True, text=True, cwd=ROOT,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default=DEFAULT_BASE)
    ap.add_argument("--this", default="", help="a commit for this side too (default: this checkout's work tree)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--quick", action="store_true", help="3 rounds of 15 steps")
    args = ap.parse_args(argv)
    if args.quick:
        args.rounds, args.steps = 3, 15
    base = subprocess.run(["git", "rev-parse", "--short", args.base], cwd=ROOT, capture_output=True, text=True,
                          check=True).stdout.strip()
    this = (subprocess.run(["git", "rev-parse", "--short", args.this], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout.strip() if args.this else "")
    with tempfile.TemporaryDirectory() as tmp, tempfile.TemporaryDirectory() as tmp_this:
        for commit, where in ((base, tmp), (this, tmp_this)):
            if commit:
                pkg = Path(where) / "immersim"
                pkg.mkdir()
                archive = subprocess.run(["git", "archive", commit, "models", "fmus"], cwd=ROOT, capture_output=True,
                                         check=True)
                subprocess.run(["tar", "-x", "-C", str(pkg)], input=archive.stdout, check=True)
                (pkg / "__init__.py").write_text("")
        here, there = [], []
        for _ in range(args.rounds):
            a = _run(tmp_this if this else "", args.steps)
            b = _run(tmp, args.steps)
            assert b["where"].startswith(tmp) and a["where"].startswith(tmp_this) == bool(this)
            here.append(a["cpu_ms"])
            there.append(b["cpu_ms"])
    mh, mb = float(np.median(here)), float(np.median(there))
    lines = ["# Network scale step: this tree against a baseline commit (A/B in one run)", "",
             stamp(".venv/bin/python benchmarks/bench_scale_ab.py " + " ".join(sys.argv[1:] if argv is None else argv)), "",
             f"Baseline `{base}`; 1000 render nodes (250 x 4), 10,000 entities, {args.steps} steps after 5 warm-up "
             f"steps, {args.rounds} alternated rounds in fresh processes; CPU time per 33 ms step (median of the "
             "steps, then of the rounds).", "",
             "| tree | per round (ms) | median (ms) |", "|---|---|---|",
             f"| {this or 'this'} | {', '.join(f'{x:.1f}' for x in here)} | {mh:.1f} |",
             f"| {base} | {', '.join(f'{x:.1f}' for x in there)} | {mb:.1f} |", "",
             f"Ratio this / baseline: {mh / mb:.3f} (target: not slower, <= 1 within the noise of a shared machine: "
             f"{'met' if mh / mb <= 1.05 else 'NOT met'}).", ""]
    OUT.write_text("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())

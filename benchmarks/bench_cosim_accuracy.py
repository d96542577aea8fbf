"""Co-simulation accuracy: error against a fine-step reference vs master algorithm,
input extrapolation and macro step, as work-precision diagrams (issue 7, item 2).

For each study scenario the same models are coupled

* once as the **reference**: 1 ms macro step, Gauss-Seidel with linear extrapolation, every
  platform integrated by CVODE BDF with rtol 1e-10, atol 1e-12;
* then for every master algorithm (jacobi, gauss-seidel) x extrapolation (zoh, linear) x macro
  step (33 ms for the product; 16.5, 8.25, 4.125 ms for the study) with the product's unit
  settings (platform: rk4, 2 substeps per macro step).

All macro steps divide 33 ms (and the network unit's frame grid ``k * 33 ms``), so the errors
are taken at the common time points ``k * 33 ms``: the maximum absolute difference to the
reference of chosen signals (platform strokes and pose, network avatar positions). Wall time is
the run's loop time (``RunResult.timing["loop"]``), measured in the same process.

Run: ``python benchmarks/bench_cosim_accuracy.py [--quick]`` -> ``results/cosim/``.
``--quick``: 2 s of simulated time and the macro steps 33 and 16.5 ms only.
"""
from __future__ import annotations

import argparse
import csv
import logging
import math
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Tuple

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT, stamp  # noqa: E402

from immersim.orchestrator.execution import run_scenario  # noqa: E402
from immersim.orchestrator.mcapio import read_series  # noqa: E402

OUT = ROOT / "results" / "cosim"
SCEN = Path(__file__).resolve().parent / "scenarios"
GRID_NS = 33_000_000  # common time points k * 33 ms
ALGORITHMS = ("jacobi", "gauss-seidel")
EXTRAPOLATIONS = ("zoh", "linear")
STEPS_MS = (33.0, 16.5, 8.25, 4.125)
DEFAULT = ("gauss-seidel", "zoh")


@dataclass
class Study:
    """One study scenario: its file, platform instances (for the reference integrator) and the
    error groups, each a name -> glob patterns over logged ``unit.variable`` (same unit in a group)."""

    name: str
    file: Path
    platforms: Tuple[str, ...]
    groups: Dict[str, List[str]] = field(default_factory=dict)


def studies() -> List[Study]:
    """The two studies. ``scenarios/<name>.toml`` is used when it exists and logs the signals,
    else the study scenario in ``benchmarks/scenarios/``."""
    return [
        Study("platform_tracking", SCEN / "platform_tracking.toml", ("leader", "follower"), {
            "follower strokes [m]": ["follower.stroke*"],
            "follower pose y,z [m]": ["follower.pose.[yz]"],
            "leader strokes [m]": ["leader.stroke*"],
        }),
        Study("campus_drive", SCEN / "campus_drive.toml", ("platform",), {
            "platform strokes [m]": ["platform.stroke*"],
            "platform pose x,y,z [m]": ["platform.pose.[xyz]"],
            "avatar positions [m]": ["net.avatar?[12]?.[xy]"],
        }),
    ]


def _grid_samples(series: Dict[str, Tuple[np.ndarray, np.ndarray, str]]) -> Dict[str, Dict[int, float]]:
    """Each signal's values at the common time points, keyed by integer k of ``k * 33 ms``."""
    out = {}
    for name, (t, v, _unit) in series.items():
        ns = np.rint(t * 1e9).astype(np.int64)
        keep = ns % GRID_NS == 0
        out[name] = dict(zip((ns[keep] // GRID_NS).tolist(), v[keep].tolist()))
    return out


def run_one(study: Study, overrides: Dict, tmp: Path, tag: str):
    """Run one variant; return (loop wall s, samples by signal)."""
    mcap = tmp / f"{study.name}_{tag}.mcap"
    res = run_scenario(study.file, mcap, overrides=overrides)
    patterns = [p for ps in study.groups.values() for p in ps]
    return res.timing.get("loop", float("nan")), _grid_samples(read_series(mcap, patterns))


def max_errors(study: Study, ref: Dict[str, Dict[int, float]], run: Dict[str, Dict[int, float]]) -> Dict[str, float]:
    """Max |run - ref| over the common time points, per error group."""
    import fnmatch

    out = {}
    for group, patterns in study.groups.items():
        worst = 0.0
        for name in ref:
            if not any(fnmatch.fnmatchcase(name, p) for p in patterns):
                continue
            ks = sorted(set(ref[name]) & set(run[name]))
            if not ks:
                raise RuntimeError(f"{study.name}: no common time points for {name}")
            a = np.array([run[name][k] for k in ks])
            b = np.array([ref[name][k] for k in ks])
            worst = max(worst, float(np.max(np.abs(a - b))) if np.all(np.isfinite(a)) else math.inf)
        out[group] = worst
    return out


def fitted_order(steps: List[float], errs: List[float]) -> float:
    """Least-squares slope of log(error) over log(step)."""
    x, y = np.log(steps), np.log(np.maximum(errs, 1e-300))
    return float(np.polyfit(x, y, 1)[0]) if len(steps) >= 2 else float("nan")


def plot(study: Study, rows: List[Dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = list(study.groups)
    fig, axes = plt.subplots(1, len(groups), figsize=(5 * len(groups), 4.2), squeeze=False)
    styles = {("jacobi", "zoh"): ("tab:red", "o--"), ("jacobi", "linear"): ("tab:orange", "s-"),
              ("gauss-seidel", "zoh"): ("tab:blue", "o--"), ("gauss-seidel", "linear"): ("tab:green", "s-")}
    for ax, g in zip(axes[0], groups):
        for (alg, ex), (color, fmt) in styles.items():
            rs = sorted((r for r in rows if r["algorithm"] == alg and r["extrapolation"] == ex),
                        key=lambda r: -r["step_ms"])
            if not rs:
                continue
            ax.loglog([r[g] for r in rs], [r["wall_s"] for r in rs], fmt, color=color, label=f"{alg}, {ex}")
            for r in rs:
                ax.annotate(f"{r['step_ms']:g}", (r[g], r["wall_s"]), fontsize=7, xytext=(3, 3),
                            textcoords="offset points")
        ax.set_xlabel(f"max error, {g}")
        ax.set_ylabel("wall time of the run [s]")
        ax.set_title(g, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].legend(fontsize=8)
    fig.suptitle(f"{study.name}: work-precision (labels: macro step in ms)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def study_rows(study: Study, steps_ms: Tuple[float, ...], stop: float, tmp: Path) -> Tuple[List[Dict], float]:
    base = {"simulation.stop": stop}
    ref_over = dict(base, **{"simulation.step": 0.001, "simulation.algorithm": "gauss-seidel",
                             "simulation.extrapolation": "linear"})
    for p in study.platforms:
        ref_over.update({f"{p}.integrator": "cvode_bdf", f"{p}.rtol": 1e-10, f"{p}.atol": 1e-12})
    print(f"{study.name}: reference (1 ms, cvode_bdf rtol 1e-10) ...", flush=True)
    ref_wall, ref = run_one(study, ref_over, tmp, "ref")
    rows = []
    for h in steps_ms:
        for alg in ALGORITHMS:
            for ex in EXTRAPOLATIONS:
                over = dict(base, **{"simulation.step": h / 1000.0, "simulation.algorithm": alg,
                                     "simulation.extrapolation": ex})
                wall, run = run_one(study, over, tmp, f"{alg}_{ex}_{h:g}")
                row = {"scenario": study.name, "step_ms": h, "algorithm": alg, "extrapolation": ex,
                       "wall_s": wall}
                row.update(max_errors(study, ref, run))
                rows.append(row)
                print(f"  {h:g} ms {alg:12s} {ex:6s} wall {wall:6.2f} s  " +
                      "  ".join(f"{g.split(' [')[0]} {row[g]:.3g}" for g in study.groups), flush=True)
    return rows, ref_wall


def summarise(study: Study, rows: List[Dict], steps_ms) -> List[str]:
    """Markdown: table, fitted orders, ranking at 33 ms and over the study."""
    groups = list(study.groups)
    lines = [f"### {study.name}", "", f"![work-precision]({study.name}_work_precision.png)", "",
             "| macro step [ms] | algorithm | extrapolation | wall [s] | " + " | ".join(f"max err {g}" for g in groups) + " |",
             "|---|---|---|---|" + "---|" * len(groups)]
    for r in rows:
        lines.append(f"| {r['step_ms']:g} | {r['algorithm']} | {r['extrapolation']} | {r['wall_s']:.2f} | "
                     + " | ".join(f"{r[g]:.3g}" for g in groups) + " |")
    lines += ["", "Fitted order of the error in the macro step (slope of log max error over log h):", "",
              "| algorithm | extrapolation | " + " | ".join(groups) + " |", "|---|---|" + "---|" * len(groups)]
    for alg in ALGORITHMS:
        for ex in EXTRAPOLATIONS:
            rs = sorted((r for r in rows if r["algorithm"] == alg and r["extrapolation"] == ex), key=lambda r: r["step_ms"])
            lines.append(f"| {alg} | {ex} | " + " | ".join(
                f"{fitted_order([r['step_ms'] for r in rs], [r[g] for r in rs]):.2f}" for g in groups) + " |")
    lines.append("")
    return lines


def score(rows: List[Dict], groups: List[str], step_ms: float) -> Dict[Tuple[str, str], float]:
    """Geometric mean over the error groups of the error relative to the default, at one step."""
    at = {(r["algorithm"], r["extrapolation"]): r for r in rows if r["step_ms"] == step_ms}
    d = at.get(DEFAULT)
    out = {}
    for key, r in at.items():
        ratios = [r[g] / d[g] for g in groups if d[g] > 0 and math.isfinite(r[g])]
        out[key] = float(np.exp(np.mean(np.log(ratios)))) if ratios else float("nan")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2 s simulated, macro steps 33 and 16.5 ms")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    steps = STEPS_MS[:2] if args.quick else STEPS_MS
    stop = 2.0 if args.quick else 4.0
    OUT.mkdir(parents=True, exist_ok=True)
    all_rows: List[Dict] = []
    md: List[str] = []
    verdict: List[str] = []
    ref_walls = {}
    with tempfile.TemporaryDirectory(prefix="bench_cosim_") as tmp:
        for st in studies():
            rows, ref_walls[st.name] = study_rows(st, steps, stop, Path(tmp))
            all_rows += rows
            plot(st, rows, OUT / f"{st.name}_work_precision.png")
            md += summarise(st, rows, steps)
            groups = list(st.groups)
            for h in steps:
                sc = score(rows, groups, h)
                best = min(sc, key=lambda k: sc[k])
                verdict.append(f"| {st.name} | {h:g} | " + " | ".join(
                    f"{sc.get((a, e), float('nan')):.3g}" for a in ALGORITHMS for e in EXTRAPOLATIONS)
                    + f" | {best[0]}, {best[1]} |")
    keys = ["scenario", "step_ms", "algorithm", "extrapolation", "wall_s"]
    with open(OUT / "accuracy.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(keys + ["group", "max_error"])
        for r in all_rows:
            for g, v in r.items():
                if g not in keys:
                    w.writerow([r[k] for k in keys] + [g, repr(v)])
    cmd = "python benchmarks/bench_cosim_accuracy.py" + (" --quick" if args.quick else "")
    head = [
        "# Co-simulation accuracy: master algorithm x extrapolation x macro step", "", stamp(cmd), "",
        "Generated by `benchmarks/bench_cosim_accuracy.py` (do not edit by hand; the analysis below is",
        "computed from the measured numbers).", "",
        f"Scenarios: `benchmarks/scenarios/platform_tracking.toml` (§6.4.2-style offset steps in Y, roll, Z at multiples of 33 ms on a",
        "leader platform, mirrored by a follower platform whose pose reference is the leader's pose) and",
        "`benchmarks/scenarios/campus_drive.toml` (2 players; avatar 1 drives the platform by washout; avatar 1",
        "against two tanks in the collision unit, contact fed back to the network), "
        f"{stop:g} s simulated each.",
        "Reference: the same coupling at 1 ms macro step, Gauss-Seidel + linear, platforms on CVODE BDF",
        "(rtol 1e-10, atol 1e-12); reference wall time: " +
        ", ".join(f"{k} {v:.1f} s" for k, v in ref_walls.items()) + ".",
        "Variants: product unit settings (platform rk4, 2 substeps per macro step). Errors are the maximum",
        "absolute difference to the reference at the common time points k x 33 ms (every macro step here",
        "divides 33 ms and the network unit's frame grid). Wall time: the run's step loop, one run each,",
        "on a shared 2-core machine (expect +-20 % noise).", "",
        "## Which combination is better", "",
        "Score = geometric mean over the error groups of (max error / max error of the current default",
        "gauss-seidel + zoh) at the same macro step; < 1 is better than the default.", "",
        "| scenario | macro step [ms] | " + " | ".join(f"{a}, {e}" for a in ALGORITHMS for e in EXTRAPOLATIONS)
        + " | best |",
        "|---|---|" + "---|" * 5] + verdict + [""]
    at33 = [line for line in verdict if "| 33 |" in line]
    winners = {line.rsplit("|", 2)[-2].strip() for line in at33}
    if len(winners) == 1:
        w = winners.pop()
        head.append(f"At the product's 33 ms macro step the best combination in both scenarios is **{w}**"
                    + (" (the current default)." if w == ", ".join(DEFAULT) else
                       f" -- not the current default ({', '.join(DEFAULT)})."))
    else:
        head.append("At 33 ms the best combination differs between the scenarios: " + "; ".join(at33))
    head += ["", "Why: Jacobi feeds every connection with the previous step's output (one macro step of",
             "delay on every coupling), Gauss-Seidel only on the connections that close a cycle (here the",
             "collision -> network contact feedback); zero-order hold makes the coupling error first order",
             "in h, linear extrapolation/interpolation (mid-step value, see orchestrator/master.py) second",
             "order for smooth signals -- the fitted orders below show how far each scenario follows that.",
             "Discrete events (a contact's onset, network frames and packet arrivals) are not smooth: there",
             "the error is set by when the event is seen, and extrapolating across a jump can overshoot.",
             "Wall time hardly depends on the algorithm or extrapolation (the master's share is",
             "negligible next to the units), so the more accurate combination costs nothing extra.", "",
             "## Results", ""]
    (OUT / "README.md").write_text("\n".join(head + md) + "\n")
    print(f"wrote {OUT / 'README.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Co-simulation accuracy: error against a fine-step reference vs master algorithm,
input extrapolation and macro step, as work-precision diagrams.

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

Studies: two coupled study scenarios in ``benchmarks/scenarios/`` (4 s, all four macro steps) and
the shipped ``scenarios/campus_drive.toml`` and ``scenarios/platform_tracking.toml`` (5 s, 33 to
8.25 ms). Each study's rows go to ``results/cosim/<study>.json``; the README, CSV and plots are
rebuilt from every saved study, so ``--studies NAME`` reruns one study only.

Run: ``python benchmarks/bench_cosim_accuracy.py [--quick]`` -> ``results/cosim/``.
``--quick``: the two study scenarios, 2 s of simulated time, macro steps 33 and 16.5 ms.
"""
from __future__ import annotations

import argparse
import csv
import json
import logging
import math
import time
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import ROOT, stamp  # noqa: E402

from immersim.orchestrator.execution import run_scenario  # noqa: E402
from immersim.orchestrator.mcapio import read_series  # noqa: E402
from immersim.orchestrator.patterns import matches  # noqa: E402

OUT = ROOT / "results" / "cosim"
SCEN = Path(__file__).resolve().parent / "scenarios"
GRID_NS = 33_000_000  # common time points k * 33 ms
ALGORITHMS = ("jacobi", "gauss-seidel")
EXTRAPOLATIONS = ("zoh", "linear")
STEPS_MS = (33.0, 16.5, 8.25, 4.125)
BASELINE = ("gauss-seidel", "zoh")  # the scores' reference (the default before 2026-12-01)
DEFAULT = ("gauss-seidel", "linear")  # orchestrator default (orchestrator/scenario.py), chosen from these studies


@dataclass
class Study:
    """One study scenario: its file, platform instances (for the reference integrator) and the
    error groups, each a name -> patterns over logged ``unit.variable`` (``*``/``?`` wildcards, brackets
    literal, as everywhere in immersim: orchestrator/patterns.py)."""

    name: str
    file: Path
    platforms: Tuple[str, ...]
    groups: Dict[str, List[str]] = field(default_factory=dict)
    #: glob of a Boolean signal (e.g. a contact flag): errors are also reported before its first rise
    #: in the reference, where the coupling is smooth, and the ranking uses that window
    event: Optional[List[str]] = None
    #: full-mode simulated time and macro steps when not the defaults (the shipped scenarios are slower)
    stop: Optional[float] = None
    steps: Optional[Tuple[float, ...]] = None


META = ("scenario", "step_ms", "algorithm", "extrapolation", "wall_s", "ref_spread", "k_event")
BEFORE = " before contact"


def row_groups(rows: List[Dict]) -> List[str]:
    return [k for k in rows[0] if k not in META]


def ranked_groups(rows: List[Dict]) -> List[str]:
    gs = row_groups(rows)
    return [g for g in gs if g.endswith(BEFORE)] or gs


def studies() -> List[Study]:
    """The study scenarios (``benchmarks/scenarios/``) and the shipped ones (``scenarios/``,
    names ending in ``_product``; run them with ``--studies``)."""
    prod = ROOT / "scenarios"
    return [
        Study("platform_tracking", SCEN / "platform_tracking.toml", ("leader", "follower"), {
            "follower strokes [m]": ["follower.stroke*"],
            "follower pose y,z [m]": ["follower.pose.y", "follower.pose.z"],
            "leader strokes [m]": ["leader.stroke*"],
        }),
        Study("campus_drive", SCEN / "campus_drive.toml", ("platform",), {
            "platform strokes [m]": ["platform.stroke*"],
            "platform pose x,y,z [m]": ["platform.pose.x", "platform.pose.y", "platform.pose.z"],
            "avatar positions [m]": [f"net.avatar[{i}].{c}" for i in (1, 2) for c in "xy"],
        }, event=["coll.pair[1].in_contact"]),
        Study("campus_drive_product", prod / "campus_drive.toml", ("plat",), {
            "platform strokes [m]": ["plat.stroke*"],
            "platform pose x,y,z [m]": ["plat.pose.x", "plat.pose.y", "plat.pose.z"],
            "avatar positions [m]": [f"net.avatar[{i}].{c}" for i in (1, 2, 3) for c in "xy"],
        }, event=[f"coll.pair[{i}].in_contact" for i in (1, 2, 3)], stop=5.0, steps=(33.0, 16.5, 8.25)),
        Study("platform_tracking_product", prod / "platform_tracking.toml", ("plat_y", "plat_yz"), {
            "strokes [m]": ["plat_*.stroke*"],
            "pose y,z [m]": ["plat_*.pose.y", "plat_*.pose.z"],
        }, stop=5.0, steps=(33.0, 16.5, 8.25)),
    ]


def _grid_samples(series: Dict[str, Tuple[np.ndarray, np.ndarray, str]]) -> Dict[str, Dict[int, float]]:
    """Each signal's values at the common time points, keyed by integer k of ``k * 33 ms``."""
    out = {}
    for name, (t, v, _unit) in series.items():
        ns = np.rint(t * 1e9).astype(np.int64)
        keep = ns % GRID_NS == 0
        out[name] = dict(zip((ns[keep] // GRID_NS).tolist(), v[keep].tolist()))
    return out


def _grid_events(series: Dict[str, Tuple[np.ndarray, np.ndarray, str]]) -> Dict[str, Dict[int, float]]:
    """Each event signal's largest value over every grid interval ``((k-1) 33 ms, k 33 ms]``,
    keyed by k: an event shorter than 33 ms (a contact of a few 1 ms steps in the reference) is
    seen at the grid point that ends its interval."""
    out = {}
    for name, (t, v, _unit) in series.items():
        ns = np.rint(t * 1e9).astype(np.int64)
        k = -(-ns // GRID_NS)  # ceil
        d: Dict[int, float] = {}
        for ki, vi in zip(k.tolist(), np.asarray(v, dtype=float).tolist()):
            d[ki] = max(d.get(ki, vi), vi)
        out[name] = d
    return out


def run_one(study: Study, overrides: Dict, tmp: Path, tag: str):
    """Run one variant; return (loop wall s, samples by signal)."""
    mcap = tmp / f"{study.name}_{tag}.mcap"
    res = run_scenario(study.file, mcap, overrides=overrides)
    patterns = [p for ps in study.groups.values() for p in ps]
    samples = _grid_samples(read_series(mcap, patterns))
    if study.event:
        samples.update(_grid_events(read_series(mcap, list(study.event))))
    return res.timing.get("loop", float("nan")), samples


def event_k(study: Study, ref: Dict[str, Dict[int, float]]) -> Optional[int]:
    """First grid index k whose interval ((k-1) 33 ms, k 33 ms] holds the study's event in the reference."""

    if not study.event:
        return None
    ks = [k for name, series in ref.items() if matches(name, study.event)
          for k, v in series.items() if v > 0.5]
    return min(ks) if ks else None


def max_errors(study: Study, ref: Dict[str, Dict[int, float]], run: Dict[str, Dict[int, float]],
               k_event: Optional[int] = None) -> Dict[str, float]:
    """Max |run - ref| over the common time points, per error group; with ``k_event`` also over
    the points before it (groups named ``<group> before contact``)."""
    out = {}
    out.update(_max_errors(study, ref, run, None))
    if k_event is not None:
        out.update({g + BEFORE: v for g, v in _max_errors(study, ref, run, k_event).items()})
    return out


def _max_errors(study, ref, run, k_end):

    out = {}
    for group, patterns in study.groups.items():
        worst = 0.0
        for name in ref:
            if not matches(name, patterns):
                continue
            ks = sorted(k for k in set(ref[name]) & set(run[name]) if k_end is None or k < k_end)
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

    groups = row_groups(rows)
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
    # the reference's own uncertainty: the same 1 ms coupling with zero-order hold
    _, ref_zoh = run_one(study, dict(ref_over, **{"simulation.extrapolation": "zoh"}), tmp, "ref_zoh")
    k_ev = event_k(study, ref)
    spread = max_errors(study, ref, ref_zoh, k_ev)
    print(f"  reference spread (1 ms zoh vs linear): {spread}", flush=True)
    rows = []
    for h in steps_ms:
        for alg in ALGORITHMS:
            for ex in EXTRAPOLATIONS:
                over = dict(base, **{"simulation.step": h / 1000.0, "simulation.algorithm": alg,
                                     "simulation.extrapolation": ex})
                wall, run = run_one(study, over, tmp, f"{alg}_{ex}_{h:g}")
                row = {"scenario": study.name, "step_ms": h, "algorithm": alg, "extrapolation": ex,
                       "wall_s": wall}
                row.update(max_errors(study, ref, run, k_ev))
                row["ref_spread"] = spread
                row["k_event"] = k_ev
                rows.append(row)
                print(f"  {h:g} ms {alg:12s} {ex:6s} wall {wall:6.2f} s  " +
                      "  ".join(f"{g.replace(' [m]', '')} {row[g]:.3g}" for g in row_groups(rows)), flush=True)
    return rows, ref_wall


def _event_note(study: Study, rows: List[Dict]) -> str:
    k = rows[0].get("k_event")
    if k is not None:
        return (f" First contact in the reference at t = {k * GRID_NS / 1e9:.3f} s; the columns "
                "'... before contact' take only the time points before it.")
    if study.event:
        return (f" The reference run has no contact ({', '.join(study.event)} never set): a variant that sees a "
                "contact differs from it by that contact's effect.")
    return ""


def summarise(study: Study, rows: List[Dict], steps_ms) -> List[str]:
    """Markdown: table, fitted orders, ranking at 33 ms and over the study."""
    groups = row_groups(rows)
    spread = rows[0]["ref_spread"]
    z33 = {g: max(r[g] for r in rows if r["step_ms"] == max(steps_ms) and r["extrapolation"] == "zoh") for g in groups}
    lines = [f"### {study.name}", "", f"![work-precision]({study.name}_work_precision.png)", "",
             "Check of the reference: the same 1 ms coupling with zoh differs from it by "
             + ", ".join(f"{g} {spread[g]:.2g}" for g in groups)
             + f"; a first-order zoh error would be the {max(steps_ms):g} ms zoh error x 1/{max(steps_ms):g} = "
             + ", ".join(f"{z33[g] / max(steps_ms):.2g}" for g in groups)
             + ". Where the two agree the 1 ms zoh run is in its asymptotic range and the 1 ms linear reference "
             "(second order) is far more accurate than any variant below; where the difference is much larger, "
             "a discrete event (contact onset) is seen at a different step and errors after it are event-timing "
             "errors, not smooth coupling errors."
             + _event_note(study, rows), "",
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
    d = at.get(BASELINE)
    out = {}
    for key, r in at.items():
        ratios = [r[g] / d[g] for g in groups if d[g] > 0 and math.isfinite(r[g])]
        out[key] = float(np.exp(np.mean(np.log(ratios)))) if ratios else float("nan")
    return out


def report(results: Dict[str, Dict]) -> str:
    """README text from the saved results of every study (``results/cosim/<study>.json``)."""
    md: List[str] = []
    verdict: List[str] = []
    descr: List[str] = []
    all_groups = {st.name: list(st.groups) for st in studies()}
    for name, res in results.items():
        rows, steps = res["rows"], res["steps_ms"]
        st = next(x for x in studies() if x.name == name)
        sm = summarise(st, rows, steps)
        md += sm[:2] + [f"Command: `{res['command']}`, commit `{res['commit']}`, {res['date']}; {res['stop']:g} s "
                        f"simulated; reference wall time {res['ref_wall']:.1f} s.", ""] + sm[2:]
        groups = ranked_groups(rows)
        for h in steps:
            sc = score(rows, groups, h)
            best = min(sc, key=lambda k: sc[k])
            verdict.append(f"| {name} | {h:g} | " + " | ".join(
                f"{sc.get((a, e), float('nan')):.3g}" for a in ALGORITHMS for e in EXTRAPOLATIONS)
                + f" | {best[0]}, {best[1]} |")
        descr.append(f"`{st.file.relative_to(ROOT)}`")
    head = [
        "# Co-simulation accuracy: master algorithm x extrapolation x macro step", "",
        stamp("python benchmarks/bench_cosim_accuracy.py [--quick] [--studies NAME ...]"), "",
        "Generated by `benchmarks/bench_cosim_accuracy.py` from the per-study results `results/cosim/<study>.json`",
        "(each study states the command, commit and date of its own run below); do not edit by hand.", "",
        "Studies: " + ", ".join(descr) + ".",
        "`benchmarks/scenarios/platform_tracking.toml`: §6.4.2-style offset steps in Y, roll, Z at multiples of",
        "33 ms on a leader platform, mirrored by a follower platform whose pose reference is the leader's pose;",
        "`benchmarks/scenarios/campus_drive.toml`: 2 players, avatar 1 drives the platform by washout and bounces",
        "off a tank in the collision unit (contact fed back to the network); the `_product` studies are the",
        "shipped `scenarios/*.toml` (shortened).",
        "Reference: the same coupling at 1 ms macro step, Gauss-Seidel + linear, platforms on CVODE BDF",
        "(rtol 1e-10, atol 1e-12). Variants: the scenario's unit settings (platform rk4, 2 substeps per macro",
        "step). Errors: maximum absolute difference to the reference at the common time points k x 33 ms",
        "(every macro step here divides 33 ms and the network unit's frame grid). Wall time: the run's step",
        "loop, one run each, on a shared 2-core machine (noisy: +-50 % between runs).", "",
        "## Which combination is better", "",
        "Score = geometric mean over the error groups of (max error / max error of gauss-seidel + zoh, the",
        "previous default) at the same macro step; < 1 is better than it. In studies with a",
        "contact the score uses the error groups before the first contact (smooth coupling); the whole-run",
        "errors, dominated by when the contact is seen, are in the tables below.", "",
        "| scenario | macro step [ms] | " + " | ".join(f"{a}, {e}" for a in ALGORITHMS for e in EXTRAPOLATIONS)
        + " | best |",
        "|---|---|" + "---|" * 5] + verdict + [""]
    at33 = [line for line in verdict if "| 33 |" in line and "_product" not in line]
    winners = {line.rsplit("|", 2)[-2].strip() for line in at33}
    if len(winners) == 1:
        w = winners.pop()
        head.append(f"At the product's 33 ms macro step the best combination in the coupled study scenarios is "
                    f"**{w}**" + (" (the current default)." if w == ", ".join(DEFAULT) else
                                  f" -- not the current default ({', '.join(DEFAULT)})."))
    else:
        head.append("At 33 ms the best combination differs between the study scenarios: " + "; ".join(at33))
    prod = [line for line in verdict if "| 33 |" in line and "_product" in line]
    if prod:
        head.append("")
        head.append("On the shipped scenarios at 33 ms (scores as above: jacobi+zoh, jacobi+linear, gauss-seidel+zoh, "
                    "gauss-seidel+linear): " + "; ".join(
                        f"{ln.split('|')[1].strip()} {', '.join(x.strip() for x in ln.split('|')[3:7])}" for ln in prod)
                    + ". There all four lie within a factor "
                    + f"{max(max(v, 1 / v) for ln in prod for v in map(float, [x for x in ln.split('|')[3:7]])):.2f}"
                    + " of each other: the error is dominated by what no master setting changes -- scenario input "
                    "signals sampled at the start of each step (platform_tracking_product has no connections: all "
                    "four identical; campus_drive_product's avatars are driven by such signals) and contact events "
                    "seen at different steps.")
    head += ["", "Why: Jacobi feeds every connection with the previous step's output (one macro step of",
             "delay on every coupling), Gauss-Seidel only on the connections that close a cycle (here the",
             "collision -> network contact feedback). Zero-order hold makes the coupling error first order",
             "in h -- with Gauss-Seidel the destination holds y(t+h) over the step (it leads by h/2), with Jacobi",
             "y(t) (it lags by h/2): the same error magnitude, which is why both zoh columns score about 1.",
             "Linear extrapolation/interpolation feeds the mid-step value (orchestrator/master.py), which",
             "cancels that h/2 offset and makes the error second order for smooth signals; Gauss-Seidel +",
             "linear interpolates between known values, Jacobi + linear extrapolates, so its constant is larger.",
             "Discrete events (a contact's onset, network frames and packet arrivals) are not smooth: there",
             "the error is set by the step in which the event is seen. Wall time does not depend on the",
             "algorithm or extrapolation beyond the machine's noise (the master's share is well under 1 % of the",
             "loop), so the more accurate combination costs nothing.",
             "Scenario input signals (`[[inputs]]`) are sampled at the start of each macro step and held",
             "(orchestrator/manipulators.py): a smooth signal then lags by h/2, a first-order error that no",
             "master setting removes (visible in `platform_tracking_product`, whose two platforms are driven",
             "by sine inputs only).", "",
             "**The default.** From these studies Gauss-Seidel + linear is the orchestrator's default",
             "(`simulation.extrapolation = \"linear\"`, `orchestrator/scenario.py`): second order on smooth",
             "couplings at no cost, and within a few per cent of zero-order hold where events dominate.",
             "Linear applies only to Real sources of variability `continuous`; a connection carrying an",
             "event-like signal says `extrapolation = \"zoh\"` for itself: `scenarios/campus_drive.toml` does so",
             "for the contact normals (extrapolating across a contact's onset overshoots) and for the one-step",
             "collision jolt pulse (interpolation would halve it and spread it over two steps).",
             "", "## Results", ""]
    return "\n".join(head + md) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2 s simulated, macro steps 33 and 16.5 ms")
    ap.add_argument("--studies", nargs="*", default=None,
                    help="studies to (re)run (default: all; --quick: platform_tracking campus_drive): "
                         + ", ".join(st.name for st in studies()))
    ap.add_argument("--stop", type=float, default=None, help="simulated seconds (default 4, quick 2)")
    ap.add_argument("--steps", type=float, nargs="*", default=None, help="macro steps in ms (divisors of 33)")
    ap.add_argument("--report-only", action="store_true", help="rebuild README/CSV/plots from the saved JSON")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    argv_studies = args.studies is not None
    if args.studies is None:
        args.studies = ["platform_tracking", "campus_drive"] if args.quick else [st.name for st in studies()]
    quick_or_default = STEPS_MS[:2] if args.quick else STEPS_MS
    OUT.mkdir(parents=True, exist_ok=True)
    from common import commit
    cmd = "python benchmarks/bench_cosim_accuracy.py" + (" --quick" if args.quick else "") + \
        (f" --studies {' '.join(args.studies)}" if argv_studies else "") + \
        (f" --stop {args.stop:g}" if args.stop else "") + \
        (f" --steps {' '.join(f'{h:g}' for h in args.steps)}" if args.steps else "")
    if not args.report_only:
        with tempfile.TemporaryDirectory(prefix="bench_cosim_") as tmp:
            for st in studies():
                if st.name not in args.studies:
                    continue
                steps = tuple(args.steps) if args.steps else (st.steps if st.steps and not args.quick else quick_or_default)
                stop = args.stop or (2.0 if args.quick else st.stop or 4.0)
                rows, ref_wall = study_rows(st, steps, stop, Path(tmp))
                (OUT / f"{st.name}.json").write_text(json.dumps({
                    "rows": rows, "steps_ms": list(steps), "stop": stop, "ref_wall": ref_wall, "command": cmd,
                    "commit": commit(), "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}, indent=1))
    results = {}
    for st in studies():
        f = OUT / f"{st.name}.json"
        if f.exists():
            results[st.name] = json.loads(f.read_text())
            plot(st, results[st.name]["rows"], OUT / f"{st.name}_work_precision.png")
    keys = ["scenario", "step_ms", "algorithm", "extrapolation", "wall_s"]
    with open(OUT / "accuracy.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(keys + ["group", "max_error"])
        for res in results.values():
            for r in res["rows"]:
                for g, v in r.items():
                    if g not in keys and g != "ref_spread":
                        w.writerow([r[k] for k in keys] + [g, repr(v)])
    (OUT / "README.md").write_text(report(results))
    print(f"wrote {OUT / 'README.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main() or 0)

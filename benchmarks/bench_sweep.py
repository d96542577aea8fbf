"""A campus_drive sweep on Dask workers without a shared disk vs the local process pool.

The same sweep (prediction order x WAN latency over ``scenarios/campus_drive.toml``) runs
twice, side by side in one invocation:

* ``local``: ``immersim sweep -j W`` on this machine's spawned processes;
* ``dask``: W Dask workers, each started in its own private mount namespace where the
  checkout, the temporary folder and the user's cache are hidden (each with its own home and
  cache, immersim installed from the wheel of this checkout), and a scheduler in this process.

Both start cold (a fresh compiled-library cache for the local pool, fresh workers for Dask);
the FMUs are built before either sweep is timed. Reported: wall time of each, the logs brought back and whether each is
equal to the local one, and the shipping cost: the seconds spent storing the FMUs on the
workers, reading the logs back, scattering the FMUs and writing the logs here (row timing
``ship``, summed over the runs, an upper bound since parts overlap with running), against the
Dask sweep's wall time; the Dask sweep's extra wall time over the local pool bounds every
overhead (shipping, scheduling) together. Logs are compared record for record (every
schema, channel, metadata and message, bit for bit; see ``log_records``) and byte for byte.

Usage: ``python benchmarks/bench_sweep.py [--quick] [--runs N] [--stop S] [--workers W]``
(quick: 6 runs of 2 s). Writes ``results/sweep/README.md``.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from common import ROOT, stamp  # noqa: E402

from tests.install.isolated import (IsolatedWorker, build_dists, log_records, make_wheel_env, remove,  # noqa: E402
                                    scratch_dir, wait_for_workers)

LATENCIES = [10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0, 100.0]


def sweep_text(runs: int, stop: float) -> str:
    orders = [0, 1, 2]
    lat = LATENCIES[:max(1, -(-runs // len(orders)))]
    assert len(orders) * len(lat) == runs, f"--runs must be 3 x (1..{len(LATENCIES)})"
    return f"""scenario = "../campus_drive.toml"
[grid]
"net.prediction_order" = {orders}
"net.latency_ms" = {lat}
"simulation.stop" = [{stop}]
[metrics]
incons_max = {{ signal = "net.inconsistency_max", reduce = "max" }}
incons_mean = {{ signal = "net.inconsistency_max", reduce = "mean" }}
bytes_per_step = {{ signal = "net.bytes", reduce = "mean" }}
jolt_max = {{ signal = "net.avatar[1].jolt", reduce = "max" }}
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="6 runs of 2 s")
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--stop", type=float, default=20.0, help="simulated s per run (campus_drive: 20)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--keep", action="store_true", help="keep the scratch folder (logs, wheel, workers' homes)")
    args = ap.parse_args(argv)
    if args.quick:
        args.runs, args.stop = 6, 2.0
    cmd = "python benchmarks/bench_sweep.py" + (" --quick" if args.quick else
                                                f" --runs {args.runs} --stop {args.stop:g} --workers {args.workers}")
    scratch = scratch_dir("immersim-bench-sweep-")
    try:
        return run(args, cmd, scratch)
    finally:
        if args.keep:
            print(f"kept {scratch}")
        else:
            remove(scratch)


def run(args, cmd: str, scratch: Path) -> int:
    import distributed

    from immersim.orchestrator.examples import copy_examples
    from immersim.orchestrator.sweep import read_summary, run_sweep

    os.environ["IMMERSIM_BUILD_DIR"] = str(scratch / "build")
    os.environ["IMMERSIM_CACHE_DIR"] = str(scratch / "casadi")  # cold compiled-library cache, as the workers'
    copy_examples(scratch / "ex", ["sweeps/campus_prediction"])
    sweepfile = scratch / "ex" / "sweeps" / "bench.toml"
    sweepfile.write_text(sweep_text(args.runs, args.stop))

    print("building the wheel ...", flush=True)
    _, wheel = build_dists(scratch / "dist")
    env = make_wheel_env(scratch / "env", wheel)

    from immersim.orchestrator.build import build_all

    build_all()  # the FMUs both sweeps use, built before either is timed
    print(f"local pool: {args.runs} runs on {args.workers} processes ...", flush=True)
    t0 = time.perf_counter()
    local = run_sweep(sweepfile, scratch / "local", workers=args.workers, check=False, progress=False)
    t_local = time.perf_counter() - t0

    cluster = distributed.LocalCluster(n_workers=0, processes=False, protocol="tcp", host="127.0.0.1",
                                       scheduler_port=0, dashboard_address=":0")
    workers = []
    try:
        for i in range(args.workers):
            workers.append(IsolatedWorker(env, cluster.scheduler_address, scratch / f"worker{i}"))
        with distributed.Client(cluster) as client:
            wait_for_workers(client, args.workers, workers)
            print(f"dask: {args.runs} runs on {args.workers} isolated workers ...", flush=True)
            t0 = time.perf_counter()
            remote = run_sweep(sweepfile, scratch / "remote", scheduler=cluster.scheduler_address, check=False,
                               progress=False)
            t_dask = time.perf_counter() - t0
    finally:
        for w in workers:
            w.stop()
        cluster.close()

    done = [r for r in local.rows if r.mcap]
    back = [r for r in remote.rows if r.mcap and (scratch / "remote" / r.mcap).exists()]
    back_names = {r.mcap for r in back}
    same = [r for r in done if r.mcap in back_names
            and log_records(scratch / "remote" / r.mcap) == log_records(scratch / "local" / r.mcap)]
    same_bytes = [r for r in done if r.mcap in back_names
                  and (scratch / "remote" / r.mcap).read_bytes() == (scratch / "local" / r.mcap).read_bytes()]
    timing = {"wall_time_s", "loop_time_s"}
    strip = [[{k: v for k, v in row.items() if k not in timing} for row in read_summary(d / "summary.csv")]
             for d in (scratch / "local", scratch / "remote")]
    ship = sum(r.timing.get("ship", 0.0) for r in remote.rows)
    fmu_bytes = sum(p.stat().st_size for p in (scratch / "build").glob("*.fmu"))
    log_bytes = sum((scratch / "remote" / r.mcap).stat().st_size for r in back)
    completed = sum(r.status == "completed" for r in remote.rows)
    ok_ship = ship / t_dask < 0.10
    ok_back = len(back) == len(same) == args.runs and strip[0] == strip[1]

    out = ROOT / "results" / "sweep"
    out.mkdir(parents=True, exist_ok=True)
    lines = [
        "# Sweeps on a Dask cluster without a shared disk",
        "",
        stamp(cmd),
        f"{args.runs} variants of `scenarios/campus_drive.toml` ({args.stop:g} s simulated each; prediction order "
        f"0/1/2 x WAN latency), on {args.workers} local processes and on {args.workers} Dask workers each in its "
        "own mount namespace (checkout, temporary folder and the user's cache hidden; own home and cache; "
        "immersim from the wheel). Both start cold (no compiled library cached); the FMUs are built before either is timed.",
        "",
        "| | local pool | Dask, no shared disk |",
        "|---|---|---|",
        f"| wall time of the sweep | {t_local:.1f} s | {t_dask:.1f} s |",
        f"| runs completed | {sum(r.status == 'completed' for r in local.rows)} / {args.runs} | {completed} / {args.runs} |",
        f"| logs under -o | {len(done)} | {len(back)} |",
        f"| logs equal to the local ones record for record (every message's bytes) | | {len(same)} / {args.runs} |",
        f"| logs equal to the local ones byte for byte (chunk layout included) | | {len(same_bytes)} / {args.runs} |",
        f"| summary.csv equal except timings | | {'yes' if strip[0] == strip[1] else 'NO'} |",
        "",
        f"Shipping: {len(list((scratch / 'build').glob('*.fmu')))} FMU files ({fmu_bytes / 1e6:.1f} MB) sent once to "
        f"each of {args.workers} workers, {args.runs} logs ({log_bytes / 1e6:.1f} MB) brought back. Time spent on it "
        f"(worker: storing FMUs, reading the log; client: its share of the scatter, writing the log), summed over "
        f"the runs: **{ship:.2f} s = {100 * ship / t_dask:.2f} % of the Dask sweep's wall time** (not in it: the "
        f"time Dask's connections take to carry the bytes, here over loopback; target < 10 %: "
        f"{'met' if ok_ship else 'NOT met'}). The Dask sweep took {t_dask / t_local:.3f}x the local pool's wall "
        "time. The two sweeps run one after the other (local first) on a machine shared with other jobs, so "
        "this ratio carries the load of the moment; within it are every Dask overhead together (shipping, "
        "scheduling, the workers' imports) against the pool's spawned processes.",
        "",
        f"Logs back and bit-identical, {args.runs} of {args.runs}: {'met' if ok_back else 'NOT met'} "
        f"({len(same)} of {args.runs} logs hold the local run's schemas, channels, metadata and every message "
        "bit for bit, in the same order).",
        "",
        "Bit-identical is checked record for record (`tests/install/isolated.py: log_records`): the log "
        "writer cuts its compressed chunks on wall-clock time (flushed every second so a killed run keeps its "
        "steps), so where a chunk ends, and where the closing `run` metadata falls between chunks, depends on "
        "how fast the run went: two runs of one scenario on this machine give different files with the same "
        "records. A run shorter than a second of wall time gives the same bytes too (the row above).",
        "",
    ]
    (out / "README.md").write_text("\n".join(lines))
    print("\n".join(lines))
    return 0 if ok_back and ok_ship else 1


if __name__ == "__main__":
    sys.exit(main())

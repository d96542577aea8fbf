"""A sweep on Dask workers that cannot see the client's folders (a private mount namespace
hides the checkout, the temporary folder and the user's cache) and run immersim from the
wheel: every log comes back under -o, record for record (every message's bytes) the log of the
same sweep run on local processes, and failed runs are reported as they are locally (a partial log kept)."""
from __future__ import annotations

import shutil

import cloudpickle
import pytest

from immersim.orchestrator.mcapio import read_info
from immersim.orchestrator.sweep import read_summary, run_sweep
from immersim.orchestrator.system import sha256

from tests.install import isolated
from tests.install.isolated import (IsolatedWorker, ROOT, log_records, remove, scratch_dir, wait_for_workers,
                                    worker_view)
from tests.orchestrator.helpers import oscillator_scenario

distributed = pytest.importorskip("distributed")

FAULT = '[[faults]]\ntarget = "m2.x_other"\nat = 3.0\nvalue = nan\n'
SWEEP = """
scenario = "osc.toml"

[grid]
"simulation.algorithm" = ["jacobi", "gauss-seidel"]
"simulation.extrapolation" = ["zoh", "linear"]

[[variants]]
name = "copied_fmu"              # a file FMU: the same bytes as osc.fmu, so nothing more to ship
"m1:fmu" = "copy/osc_copy.fmu"

[[variants]]
name = "long-run"                # meets the NaN forced at 3 s: fails, its log keeps the steps done
"simulation.stop" = 3.5

[[variants]]
name = "missing_fmu"             # fails before it starts
"m1:fmu" = "nowhere/other_osc.fmu"

[metrics]
x1_max = { signal = "m1.x", reduce = "max" }
x2_final = { signal = "m2.x", reduce = "final" }
"""
TIMING = {"wall_time_s", "loop_time_s"}


def test_sweep_on_isolated_workers_brings_back_the_local_logs(dists_and_env, test_fmus, tmp_path):
    _, _, env = dists_and_env
    (tmp_path / "copy").mkdir()
    fmu = shutil.copyfile(test_fmus["oscillator"], tmp_path / "osc.fmu")
    shutil.copyfile(fmu, tmp_path / "copy" / "osc_copy.fmu")
    oscillator_scenario(tmp_path, fmu, step=0.01, stop=1.0, extra=FAULT)
    sweepfile = tmp_path / "isolated.toml"
    sweepfile.write_text(SWEEP)

    local = run_sweep(sweepfile, tmp_path / "local", workers=2, check=False, progress=False)

    folder = scratch_dir("immersim-worker-")
    cluster = distributed.LocalCluster(n_workers=0, processes=False, protocol="tcp", host="127.0.0.1",
                                       scheduler_port=0, dashboard_address=":0")
    try:
        with IsolatedWorker(env, cluster.scheduler_address, folder, nworkers=2) as worker, \
                distributed.Client(cluster) as client:
            wait_for_workers(client, 2, [worker])
            cloudpickle.register_pickle_by_value(isolated)  # the workers have no tests/ to import it from
            probe = [str(ROOT / "pyproject.toml"), str(sweepfile), str(fmu)]
            for view in client.run(worker_view, probe).values():
                assert not any(view["sees"].values()), view
                assert view["immersim"].startswith(str(env.root / "venv")), view
                assert view["cache"] == str(folder / "home" / ".cache" / "immersim")
            remote = run_sweep(sweepfile, tmp_path / "remote", scheduler=cluster.scheduler_address, check=False,
                               progress=False)
            shipped = sorted(p.name for p in (folder / "home/.cache/immersim/shipped").iterdir())
    finally:
        cluster.close()
        remove(folder)

    statuses = ["completed"] * 5 + ["failed"] * 2
    assert [r.status for r in remote.rows] == [r.status for r in local.rows] == statuses
    assert [r.reason for r in remote.rows] == [r.reason for r in local.rows]
    assert "m2: input x_other = nan at t = 3" in remote.rows[5].reason
    assert "FmuLoadError: unit m1: FMU" in remote.rows[6].reason and "not found" in remote.rows[6].reason
    assert shipped == [f"{sha256(fmu)}.fmu"]  # one file crossed over, named by its hash
    logs = [r.mcap for r in local.rows[:6]]
    assert all(logs) and [r.mcap for r in remote.rows[:6]] == logs and not remote.rows[6].mcap
    for name in logs:  # every schema, channel, message and metadata record bit for bit
        remote_log, local_log = log_records(tmp_path / "remote" / name), log_records(tmp_path / "local" / name)
        assert len(remote_log[1]) > 100 and remote_log == local_log, name
    run = read_info(tmp_path / "remote" / logs[5]).metadata["run"]
    assert (run["status"], run["steps_done"]) == ("failed", "300")  # every step before t = 3 s
    strip = [[{k: v for k, v in row.items() if k not in TIMING} for row in read_summary(d / "summary.csv")]
             for d in (tmp_path / "local", tmp_path / "remote")]
    assert strip[0] == strip[1]


"""Ablation sweeps: run a grid of scenario variants in parallel, summarise and compare them.

A sweep file (TOML) names a base scenario and the variants to run::

    scenario = "../campus_drive.toml"     # relative to the sweep file

    [grid]                                # cartesian product of override values
    "simulation.algorithm" = ["jacobi", "gauss-seidel"]
    "coll.backend" = ["fcl", "basis_point"]
    "net:fmu" = ["network", "other/network.fmu"]   # swap a unit's FMU (path relative to the sweep file)

    [[variants]]                          # explicit extra runs (overrides on the base scenario)
    name = "baseline"
    "simulation.step" = 0.01

    [metrics]                             # one number per run, computed from its MCAP log
    max_err = { signal = "net.inconsistency_max", reduce = "max" }  # max|min|mean|rms|final|absmax
    late = { signal = "plat.stroke*", reduce = "absmax", after = 2.0 }  # * ? wildcards; t >= 2 s
    hit = { signal = "coll.pair[1].in_contact", reduce = "max" }       # brackets are literal
    wall_s = "wall_time"                  # built-ins: wall_time, loop_time, realtime_factor,
    plat_s = "unit_time:plat"             #   steps, status, unit_time:<unit>

    [plot]                                # or [[plot]] for several figures
    x = "simulation.step"
    y = ["max_err"]
    hue = "coll.backend"                  # optional; default: every other override that varies
    logx = true                           # optional log axes

Override keys are those of :func:`immersim.orchestrator.scenario.load_scenario`:
``"unit.param"``, ``"simulation.<stop|step|start|algorithm|extrapolation|tolerance>"`` and
``"unit:fmu"``. Every variant is checked against the scenario before anything runs, so a bad
sweep file fails at once with a :class:`ScenarioError` naming the file and the key.

Runs execute in worker processes (``spawn`` start method: pythonfmu FMUs embed the
interpreter, so forking a process that has loaded FMUs is unsafe) or, given a scheduler
address, as tasks on a Dask cluster that needs no shared disk: a task carries its scenario and
FMUs and brings its log back (:mod:`.shipping`). Each run writes one MCAP file, under the
output folder, and its metrics are computed from it. A failed
run does not stop the sweep: its row in ``summary.csv`` says ``failed`` and why, and
:func:`run_sweep` raises :class:`SweepFailed` at the end (the CLI exits non-zero).
"""
from .common import BUILTIN_METRICS, REDUCERS, SweepFailed  # noqa: F401
from .core import *  # noqa: F401,F403
from .executors import *  # noqa: F401,F403
from .runs import *  # noqa: F401,F403
from .spec import *  # noqa: F401,F403
from .summary import *  # noqa: F401,F403

"""Benchmarks of the network unit -> results/network/.

1. inconsistency vs latency for every prediction order and ownership rule;
2. messages and bytes per 33 ms step vs number of render nodes for every topology (log-log
   exponents fitted with np.polyfit);
3. scale: 1000 render nodes (250 groups x 4) and 10,000 free entities, wall time of a 33 ms
   step against the real-time target (<= 33 ms).

4. campus: the campus_drive / campus_idle configuration (3 players x 3 render nodes, 8 or 0
   entities) through the FMU class's ``do_step`` (model + wrapper), CPU time per 33 ms step.

   Also the built network.fmu under FMPy (doStep and reading the outputs back), and with
   ``--baseline DIR`` the in-process runs alternated with another commit's tree.

5. campus replay (``--campus-log LOG``): the network inputs of a real campus_drive run, read from
   its log, replayed through the FMU class's ``do_step``; with ``--baseline DIR`` another
   tree's runs alternate with this tree's and every output of every step is compared bit for bit.

6. paths (``--only paths``): what each shortcut of :class:`Paths` buys, A/B in one run: the campus
   steps (4.) and the scale step (3.) with one shortcut switched to its plain form against the
   default, fresh processes alternated, CPU medians; writes ``paths.md``.

7. ownerless (``--only ownerless``): entities outside every ownership region without an owner
   (``NetworkConfig.consistency.ownerless``, §3.6.3) against keeping the last owner, over WAN latencies: the
   display error, published objects, traffic, releases and claims; writes ``ownerless.md``.

   state_traffic (``--only state_traffic``): STATE records to every viewer of the object against
   the owner's neighbour nodes only (``NetworkConfig.net.state_traffic``, §3.3): display error over
   WAN latencies and traffic vs render nodes of both; writes ``state_traffic.md``.

   frame_phase (``--only frame_phase``): display error vs sub-frame WAN latency with the frame
   clocks in phase and at the groups' seeded phases (``NetworkConfig.scene.frame_phase``); writes
   ``latency_phase.md``.

8. campus_drive loop (``--loop-ab DIR``): ``immersim run scenarios/campus_drive.toml`` of this
   checkout and of another commit's whole package in ``DIR`` (``mkdir -p DIR/immersim && git
   archive COMMIT api models orchestrator fmus scenarios | tar -x -C DIR/immersim && cp -r
   DIR/immersim/api/. DIR/immersim/``), alternated in fresh processes: the loop time and the
   network unit's share that the command prints, medians; writes ``loop_ab.md``.

Usage: python benchmarks/bench_network.py [--quick] [--only scale,campus,paths,ownerless,state_traffic,frame_phase] [--baseline DIR]
       [--campus-log LOG] [--loop-ab DIR] [--rounds N]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from dataclasses import fields
from pathlib import Path

import numpy as np

from immersim.models.network import LinkClass, NetworkConfig, NetworkModel

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "results" / "network"
T = 0.033
# ownership variants: label -> (rule, reading of eq. 3-12)
RULES = {"mahalanobis": ("mahalanobis", "frame"), "mahalanobis_reach": ("mahalanobis", "reach"),
         "euclidean": ("euclidean", "frame"), "none": ("none", "frame")}
NETWORK_DIR = str(ROOT / "fmus" / "network")


def machine() -> str:
    cpu = "unknown CPU"
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{os.cpu_count()} cores (nproc), {cpu}, Python {platform.python_version()}, numpy {np.__version__}"


def commit() -> str:
    try:
        return subprocess.check_output(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, text=True).strip()
    except Exception:  # noqa: BLE001
        return "unknown"


def run(cfg: NetworkConfig, steps: int, warm: int = 5):
    m = NetworkModel(cfg)
    out = [m.step(T) for _ in range(steps)]
    return m, out[warm:]


def bench_latency(quick: bool):
    lat = [0.0, 10.0, 25.0, 100.0] if quick else [0.0, 5.0, 10.0, 20.0, 30.0, 40.0, 66.0, 100.0, 200.0]
    steps = 60 if quick else 180
    rows = []
    base = NetworkConfig.from_flat(groups=8, render_nodes=2, entities=300, scene_size=200.0, ownership_min_axis=2.0, seed=1)
    for order in (0, 1, 2):
        for label, (rule, foci) in RULES.items():
            for L in lat:
                cfg = base.replace(prediction_order=order, ownership=rule, ownership_foci=foci,
                             links={"lan": LinkClass(0.3, 0.1, 0.0, 1000.0),
                                    "wan": LinkClass(L, 0.2 * L, 0.0, 100.0)})
                m, out = run(cfg, steps)
                rows.append(dict(order=order, ownership=label, latency_ms=L,
                                 rms=np.mean([s.inconsistency_rms for s in out]),
                                 max=np.max([s.inconsistency_max for s in out]),
                                 handovers=m.totals.handovers, rejected=m.totals.rejected_updates,
                                 handovers_per_min=m.totals.handovers / (m.totals.frames * T / 60.0),
                                 contacts=m.totals.contacts, remote_contacts=m.totals.remote_contacts,
                                 bytes_per_step=m.totals.bytes / steps))
    return rows


def bench_traffic(quick: bool):
    groups = [2, 4, 8, 16, 32] if quick else [2, 4, 8, 16, 32, 64]
    rows = []
    for topo, rule in TRAFFIC_CASES:
        for g in groups:
            cfg = NetworkConfig.from_flat(groups=g, render_nodes=4, entities=10 * g, scene_size=1000.0, topology=topo,
                                          avatar_start="uniform", seed=2, state_traffic=rule)
            m, out = run(cfg, 12, warm=2)
            rows.append(dict(topology=_traffic_label(topo, rule), nodes=g * 4, groups=g,
                             messages=np.mean([s.messages for s in out]), bytes=np.mean([s.bytes for s in out]),
                             dropped=np.sum([s.dropped_frames for s in out]),
                             rms=np.mean([s.inconsistency_rms for s in out])))
    fits = {}
    for topo, rule in TRAFFIC_CASES:
        label = _traffic_label(topo, rule)
        r = [x for x in rows if x["topology"] == label]
        n = np.log([x["nodes"] for x in r])
        fits[label] = (np.polyfit(n, np.log([x["messages"] for x in r]), 1)[0],
                       np.polyfit(n, np.log([x["bytes"] for x in r]), 1)[0])
    return rows, fits


#: (topology, STATE rule) of the traffic sweep; a full mesh broadcasts (no rule)
TRAFFIC_CASES = (("hybrid_p2p", "neighbour_nodes"), ("hybrid_p2p", "object_view"),
                 ("client_server", "neighbour_nodes"), ("client_server", "object_view"), ("full_mesh", "neighbour_nodes"))


def _traffic_label(topo: str, rule: str) -> str:
    return topo if topo == "full_mesh" else f"{topo}/{rule}"


def bench_scale(quick: bool):
    steps = 30 if quick else 100
    res = []
    for dis, measure in ((0.0, True), (0.1, True), (0.0, False), (0.1, False)):
        cfg = NetworkConfig.from_flat(groups=250, render_nodes=4, entities=10_000, scene_size=2000.0, avatar_start="uniform",
                                      dis_threshold=dis, seed=4, measure=measure)
        t0 = time.perf_counter()
        m = NetworkModel(cfg)
        t_init = time.perf_counter() - t0
        for _ in range(5):
            m.step(T)
        times, cpu, out = [], [], []
        load0 = os.getloadavg()[0]
        for _ in range(steps):
            t0, c0 = time.perf_counter(), time.process_time()
            out.append(m.step(T))
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        times, cpu = np.array(times) * 1e3, np.array(cpu) * 1e3
        res.append(dict(dis_threshold=dis, measure=measure, nodes=cfg.n_render, entities=cfg.entities, init_s=t_init,
                        median_ms=float(np.median(times)), p90_ms=float(np.percentile(times, 90)),
                        max_ms=float(times.max()), cpu_max_ms=float(cpu.max()),
                        cpu_median_ms=float(np.median(cpu)), load=0.5 * (load0 + os.getloadavg()[0]),
                        mean_ms=float(times.mean()), rt_factor=33.0 / float(np.median(times)),
                        messages=float(np.mean([s.messages for s in out])),
                        mbytes=float(np.mean([s.bytes for s in out])) / 1e6,
                        rms=float(np.mean([s.inconsistency_rms for s in out]))))
    return res


def scale_cpu(steps: int, dis: float, paths: dict = None, fmu_dir: str = NETWORK_DIR):
    """Median CPU time (ms) of the scale step (1000 render nodes, 10,000 entities, every frame
    or DIS ``dis``) over ``steps`` steps after 5 warm-up steps, with ``paths`` (fields of :class:`Paths`)."""
    from immersim.models.network import Paths
    cfg = NetworkConfig.from_flat(groups=250, render_nodes=4, entities=10_000, scene_size=2000.0, avatar_start="uniform",
                                  dis_threshold=dis, seed=4)
    m = NetworkModel(cfg, Paths(**(paths or {})))
    for _ in range(5):
        m.step(T)
    cpu = []
    for _ in range(steps):
        c0 = time.process_time()
        m.step(T)
        cpu.append(time.process_time() - c0)
    return float(np.median(cpu)) * 1e3


#: one shortcut (or a pair that only acts together) at a time in its plain form, for bench_paths
CAMPUS_SWITCHES = [("memo_pairs", dict(memo_pairs=-1)), ("reuse_views", dict(reuse_views=False)),
                   ("scalar_view", dict(scalar_view=-1)), ("few_records", dict(few_records=-1)),
                   ("rest_display", dict(rest_display=False)), ("float_batch", dict(float_batch=-1)),
                   ("merge_draws", dict(merge_draws=False)), ("scalar_grid", dict(scalar_grid=-1)),
                   ("scalar_owners", dict(scalar_owners=-1)), ("scalar_messages", dict(scalar_messages=-1)),
                   ("scalar_avatars + scalar_entities", dict(scalar_avatars=-1, scalar_entities=-1)),
                   ("rest_skip", dict(rest_skip=False)), ("scalar_contacts", dict(scalar_contacts=-1))]
SCALE_SWITCHES = [("groups_min_pairs", dict(groups_min_pairs=10 ** 12))]


def bench_paths(quick: bool, log: str = ""):
    """Each shortcut against the default, A/B in one run (fresh processes, the variants in turn,
    the order reversed every other round): campus CPU medians per step (us), with ``log`` also
    the mean and median of campus_drive's logged inputs replayed (:func:`campus_replay`), and the
    scale step's (ms), medians over the rounds, and their ratio to the default's."""
    import tempfile

    from immersim.models.network import Paths
    rounds, steps = (2, 300) if quick else (3, 600)
    inputs = ""
    if log:
        inputs = str(Path(tempfile.mkdtemp(prefix="bench_net_paths_")) / "inputs.json")
        with open(inputs, "w") as f:
            json.dump(campus_log_inputs(log), f)
    variants = [("default (every shortcut)", {})] + CAMPUS_SWITCHES + [("all (Paths.plain())", "plain")]
    camp = {name: [] for name, _ in variants}
    for rnd in range(rounds):
        for name, kw in (variants if rnd % 2 == 0 else variants[::-1]):
            kw = {f.name: getattr(Paths.plain(), f.name) for f in fields(Paths)} if kw == "plain" else kw
            r = in_tree(None, "campus_inprocess", steps, paths=kw)
            rp = in_tree(None, "campus_replay", inputs, passes=2, paths=kw) if log else {}
            camp[name].append((1e3 * r[0]["cpu_median_ms"], 1e3 * r[1]["cpu_median_ms"],
                               rp.get("cpu_mean_us", np.nan), rp.get("cpu_median_us", np.nan)))
    campus_rows = []
    med = {name: [float(np.median([x[j] for x in v])) for j in range(4)] for name, v in camp.items()}
    d0 = med[variants[0][0]]
    for name, _ in variants:
        d = med[name]
        campus_rows.append(dict(plain=name, drive_us=d[0], drive_ratio=d[0] / d0[0], idle_us=d[1], idle_ratio=d[1] / d0[1],
                                replay_mean_us=d[2], replay_mean_ratio=d[2] / d0[2], replay_median_ratio=d[3] / d0[3]))
    srounds, ssteps = (2, 10) if quick else (2, 20)
    scale_rows = []
    for dis in (0.0, 0.1):
        svar = [("default (every shortcut)", {})] + SCALE_SWITCHES
        got = {name: [] for name, _ in svar}
        for rnd in range(srounds):
            for name, kw in (svar if rnd % 2 == 0 else svar[::-1]):
                got[name].append(in_tree(None, "scale_cpu", ssteps, dis, paths=kw))
        s0 = np.median(got[svar[0][0]])
        for name, _ in svar:
            s = np.median(got[name])
            scale_rows.append(dict(plain=name, dis_threshold=dis, cpu_median_ms=s, ratio=s / s0,
                                   rounds=", ".join(f"{x:.1f}" for x in got[name])))
    return campus_rows, scale_rows


def bench_ownerless(quick: bool):
    """The bench_latency scene (8 groups x 2 render nodes, 300 entities, 200 m, order 1,
    mahalanobis) with and without ``ownerless``, per WAN latency: mean RMS and max display error,
    objects published, bytes per step, hand-overs, releases and claims per simulated minute."""
    steps = 90 if quick else 300
    base = NetworkConfig.from_flat(groups=8, render_nodes=2, entities=300, scene_size=200.0, ownership_min_axis=2.0, seed=1)
    rows = []
    for L in ((0.0, 100.0) if quick else (0.0, 25.0, 100.0)):
        for ownerless in (False, True):
            cfg = base.replace(ownerless=ownerless, links={"lan": LinkClass(0.3, 0.1, 0.0, 1000.0),
                                                           "wan": LinkClass(L, 0.2 * L, 0.0, 100.0)})
            m, out = run(cfg, steps)
            minutes = len(out) * T / 60.0
            rows.append(dict(latency_ms=L, ownerless=ownerless, rms=np.mean([s.inconsistency_rms for s in out]),
                             max=np.max([s.inconsistency_max for s in out]),
                             published=np.mean([s.published for s in out]),
                             bytes_per_step=np.mean([s.bytes for s in out]),
                             handovers_per_min=sum(s.handovers for s in out) / minutes,
                             released_per_min=sum(s.released for s in out) / minutes,
                             claimed_per_min=sum(s.claimed for s in out) / minutes,
                             ownerless_share=float(np.mean(m.owner[cfg.groups:] < 0))))
    return rows


def bench_state_traffic(quick: bool):
    """Both ``state_traffic`` rules (object_view, neighbour_nodes; hybrid_p2p), each with and
    without ownerless entities: (1) the bench_latency scene (8 groups x 2 render nodes, 300
    entities, 200 m, order 1, mahalanobis) per WAN latency: display error, STATE records sent and
    bytes per step; (2) ``NetworkConfig(seed=0)``, 600 steps; (3) the bench_traffic scenes (4
    render nodes per group, 10 entities per group, 1000 m, avatars uniform) per node count:
    messages and bytes per step and the log-log exponents."""
    steps = 90 if quick else 300
    base = NetworkConfig.from_flat(groups=8, render_nodes=2, entities=300, scene_size=200.0, ownership_min_axis=2.0, seed=1)
    cases = [(rule, own) for own in (True, False) for rule in ("neighbour_nodes", "object_view")]
    err = []
    for L in ((0.0, 100.0) if quick else (0.0, 25.0, 100.0)):
        for rule, own in cases:
            cfg = base.replace(state_traffic=rule, ownerless=own, links={"lan": LinkClass(0.3, 0.1, 0.0, 1000.0),
                                                                          "wan": LinkClass(L, 0.2 * L, 0.0, 100.0)})
            m, out = run(cfg, steps)
            err.append(dict(latency_ms=L, state_traffic=rule, ownerless=own,
                            rms=np.mean([s.inconsistency_rms for s in out]), max=np.max([s.inconsistency_max for s in out]),
                            messages=np.mean([s.messages for s in out]), bytes_per_step=np.mean([s.bytes for s in out]),
                            state_bytes_per_step=m.totals.by_type.get("STATE", 0) / steps))
    for rule, own in cases:   # the default configuration (4 x 3 nodes, 100 m), 600 steps
        n = 150 if quick else 600
        m, out = run(NetworkConfig.from_flat(seed=0, state_traffic=rule, ownerless=own), n)
        err.append(dict(latency_ms="default (20)", state_traffic=rule, ownerless=own,
                        rms=np.mean([s.inconsistency_rms for s in out]), max=np.max([s.inconsistency_max for s in out]),
                        messages=np.mean([s.messages for s in out]), bytes_per_step=np.mean([s.bytes for s in out]),
                        state_bytes_per_step=m.totals.by_type.get("STATE", 0) / n))
    traffic = []
    for rule, own in cases:
        for g in ([2, 4, 8, 16, 32] if quick else [2, 4, 8, 16, 32, 64]):
            cfg = NetworkConfig.from_flat(groups=g, render_nodes=4, entities=10 * g, scene_size=1000.0, avatar_start="uniform",
                                          seed=2, state_traffic=rule, ownerless=own)
            m, out = run(cfg, 12, warm=2)
            traffic.append(dict(state_traffic=rule, ownerless=own, nodes=g * 4, messages=np.mean([s.messages for s in out]),
                                bytes=np.mean([s.bytes for s in out]), rms=np.mean([s.inconsistency_rms for s in out])))
    fits = {}
    for rule, own in cases:
        r = [x for x in traffic if x["state_traffic"] == rule and x["ownerless"] == own]
        n = np.log([x["nodes"] for x in r])
        fits[f"{rule}, ownerless {own}"] = (np.polyfit(n, np.log([x["messages"] for x in r]), 1)[0],
                                            np.polyfit(n, np.log([x["bytes"] for x in r]), 1)[0])
    return err, traffic, fits


#: the target's latencies (ms) and the sub-frame sweep of bench_frame_phase
PHASE_TARGET = (0.0, 5.0, 10.0, 20.0, 30.0, 40.0)
PHASE_SWEEP = (0.0, 1.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 33.0, 40.0, 50.0, 66.0)


def phase_rms(L: float, phase: bool, groups: int, seed: int, steps: int = 100, jitter: float = 0.0) -> float:
    """Mean RMS display error of parked avatars (``groups``) and 40 entities, order 0, WAN
    latency ``L`` ms (exponential jitter of mean ``jitter`` ms, none by default), no bandwidth
    limit, per 33 ms step after 5 warm-up steps. Every entity keeps an owner and every viewer
    gets its records (``ownerless`` False, ``object_view``): with order 0 an ownerless entity is
    not predicted at all, which would hide the latency."""
    cfg = NetworkConfig.from_flat(groups=groups, entities=40, driven_groups=groups, seed=seed, prediction_order=0,
                                  frame_phase=phase, ownerless=False, state_traffic="object_view",
                                  links={"lan": LinkClass(0.3, 0.0, 0.0, 0.0), "wan": LinkClass(L, jitter, 0.0, 0.0)})
    return float(np.mean([s.inconsistency_rms for s in run(cfg, steps)[1]]))


def bench_frame_phase(quick: bool):
    """Display error vs sub-frame WAN latency with every frame clock in phase and with the
    groups' seeded phases (``frame_phase``): the sweep for 4 groups (seed 2) and 8 groups (seed
    0), and over seeds 0-7 how often the mean RMS is strictly increasing over PHASE_TARGET."""
    sweep = []
    for groups, seed in ((4, 2), (8, 0)):
        for phase in (False, True):
            e = [phase_rms(L, phase, groups, seed) for L in (PHASE_TARGET if quick else PHASE_SWEEP)]
            sweep.append(dict(groups=groups, seed=seed, frame_phase=phase,
                              **{f"{L:g}": f"{x:.4f}" for L, x in zip(PHASE_TARGET if quick else PHASE_SWEEP, e)}))
    seeds = []
    for groups in (4, 8):
        for phase, jitter in ((False, 0.0), (True, 0.0), (False, 5.0), (True, 5.0)):
            ok = [all(b > a for a, b in zip(e, e[1:]))
                  for e in ([phase_rms(L, phase, groups, s, jitter=jitter) for L in PHASE_TARGET]
                            for s in range(2 if quick else 8))]
            seeds.append(dict(groups=groups, frame_phase=phase, jitter_ms=jitter,
                              strictly_increasing=f"{sum(ok)} of {len(ok)}",
                              seeds=" ".join(str(s) for s, x in enumerate(ok) if x) or "-"))
    return sweep, seeds


def flapping_run(seed: int, steps: int = 280, **kw):
    """The flapping scene (3 groups x 2 render nodes, 15 entities, 30 m, avatars uniform, contacts
    on; ``kw``: more config fields) run ``steps`` frames: the entities' owners per frame
    (steps + 1, 15), the largest entity and avatar speeds per frame (m/s), and the model."""
    m = NetworkModel(NetworkConfig.from_flat(groups=3, render_nodes=2, entities=15, seed=seed, scene_size=30.0,
                                             avatar_start="uniform", **kw))
    hist, ev, av = [m.owner[3:].copy()], [], []
    for _ in range(steps):
        m.step(T)
        hist.append(m.owner[3:].copy())
        ev.append(np.hypot(*m.world.evel.T).max())
        av.append(np.abs(m.world.speed).max())
    return np.array(hist), np.array(ev), np.array(av), m


def reverted(H: np.ndarray) -> tuple:
    """Hand-overs in the owners per frame ``H`` (frames, entities), and those whose entity is
    back with its previous owner within 2 frames."""
    n = rev = 0
    for col in H.T:
        for k in np.flatnonzero(col[1:] != col[:-1]) + 1:
            n += 1
            rev += any(col[k + j] == col[k - 1] for j in (1, 2) if k + j < len(col))
    return n, rev


def bench_handover(quick: bool):
    """Hand-overs and their reverts (:func:`reverted`), contacts and entity speeds over seeds 0-7
    of :func:`flapping_run`, with the default hand-over hold and without one."""
    rows = []
    for kw in ({}, {"handover_hold_s": 0.0}):
        n = rev = contacts = 0
        excess = -np.inf
        for seed in range(2 if quick else 8):
            H, ev, av, m = flapping_run(seed, **kw)
            a, b = reverted(H)
            n, rev, contacts = n + a, rev + b, contacts + m.totals.contacts
            excess = max(excess, ev.max() - (m.cfg.world.entity_speed + av.max()))
        rows.append(dict(handover_hold_s=m.cfg.consistency.handover_hold_s, seeds=seed + 1, handovers=n,
                         reverted_within_2_frames=rev, share=f"{100 * rev / max(n, 1):.1f} %", contacts=contacts,
                         speed_excess=f"{excess:.3f}"))
    return rows


#: the campus scenes' network parameters, and the driven case's constant driver inputs
CAMPUS = (("campus_drive (driving)", 8, True), ("campus_idle (at rest)", 0, False))
CAMPUS_DRIVE = ((0.8, 0.0), (0.7, 0.1), (0.6, -0.2))


def network_class(fmu_dir: str = NETWORK_DIR):
    """The FMU class of ``fmu_dir``'s ``network_fmu.py`` (another tree's for a baseline run,
    with that tree's ``immersim`` first on ``PYTHONPATH``)."""
    sys.path.insert(0, fmu_dir)
    from network_fmu import network
    return network


def campus_slave(network, entities: int, name: str):
    """An instance of the FMU class ``network`` at the campus scenes' size (3 players x 3 render
    nodes, ``entities`` free entities, seed 0, order 1), out of initialization mode."""
    s = network(instance_name=name, resources=str(ROOT), visible=False, logging_callback=None)
    s.values.update(players=3, render_nodes=3, entities=entities, seed=0, prediction_order=1)
    s.setup_experiment(0.0, None, None)
    s.exit_initialization_mode()
    return s


def in_tree(tree, fn: str, *args, **kwargs):
    """``fn(*args, fmu_dir=..., **kwargs)``, a function of this module, in a fresh process on
    ``tree``'s code (a directory with another commit's ``immersim``, put first on ``PYTHONPATH``,
    and its ``network_fmu.py``) or this tree's (None); returns its (JSON) result."""
    fmu_dir = NETWORK_DIR if tree is None else str(Path(tree) / "immersim" / "fmus" / "network")
    call = ", ".join([*map(repr, args), f"fmu_dir={fmu_dir!r}", *(f"{k}={v!r}" for k, v in kwargs.items())])
    code = (f"import json, sys; sys.path.insert(0, {str(ROOT / 'benchmarks')!r}); "
            f"import bench_network; print(json.dumps(bench_network.{fn}({call})))")
    env = dict(os.environ)
    if tree is not None:
        env["PYTHONPATH"] = tree
    return json.loads(subprocess.check_output([sys.executable, "-c", code], env=env, cwd="/", text=True))


def campus_inprocess(steps: int, fmu_dir: str = NETWORK_DIR, paths: dict = None):
    """CPU and wall time of the FMU class's do_step (model + wrapper, in process) at the campus
    scenes' size; ``fmu_dir`` holds the ``network_fmu.py`` to load (another tree's for a
    baseline run, with that tree's ``immersim`` first on ``PYTHONPATH``); ``paths``: fields of
    :class:`Paths` for the model (this tree only; the model is remade with them after set-up)."""
    network = network_class(fmu_dir)
    res = []
    for label, entities, drive in CAMPUS:
        s = campus_slave(network, entities, "bench")
        if paths:
            from immersim.models.network import Paths   # (this tree's: a baseline tree may have none)

            s.model = NetworkModel(s.model.cfg, Paths(**paths))   # (a fresh model: the same state)
        if drive:
            for p, (thr, steer) in enumerate(CAMPUS_DRIVE, start=1):
                s.values[f"avatar[{p}].throttle"], s.values[f"avatar[{p}].steer"] = thr, steer
        unchanged = [0]
        step_model = s.step_model

        def counted(t, h):
            r = step_model(t, h)
            unchanged[0] += r is True        # OUTPUTS_UNCHANGED
            return r

        s.step_model = counted
        wall, cpu = [], []
        load0 = os.getloadavg()[0]
        for k in range(steps):
            t0, c0 = time.perf_counter(), time.process_time()
            s.do_step(k * T, T)
            wall.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        wall, cpu = np.array(wall[10:]) * 1e3, np.array(cpu[10:]) * 1e3
        res.append(dict(scene=label, steps=steps, median_ms=float(np.median(wall)), p90_ms=float(np.percentile(wall, 90)),
                        cpu_median_ms=float(np.median(cpu)), cpu_mean_ms=float(cpu.mean()),
                        load=0.5 * (load0 + os.getloadavg()[0]), at_rest=bool(s.values["at_rest"]),
                        unchanged=unchanged[0]))
    return res


def campus_fmpy(steps: int):
    """The built network.fmu under plain FMPy (FMU2Slave): wall and CPU time of doStep (the
    C boundary included) and of reading every output back (getReal/getInteger/getBoolean, what
    a master does each step)."""
    import shutil

    from fmpy import read_model_description

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from common import fmpy_slave

    from immersim.orchestrator.build import build_unit, default_build_dir

    path = build_unit(ROOT / "fmus" / "network", default_build_dir())
    md = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    outs = {t: [v.valueReference for v in md.modelVariables if v.causality == "output" and v.type == t]
            for t in ("Real", "Integer", "Boolean")}
    res = []
    for label, entities, drive in CAMPUS:
        fmu, tmp = fmpy_slave(path, md, "bench_net_")
        fmu.enterInitializationMode()
        fmu.setInteger([vr["players"], vr["render_nodes"], vr["entities"], vr["seed"], vr["prediction_order"]],
                       [3, 3, entities, 0, 1])
        fmu.exitInitializationMode()
        if drive:
            for p, (thr, steer) in enumerate(CAMPUS_DRIVE, start=1):
                fmu.setReal([vr[f"avatar[{p}].throttle"], vr[f"avatar[{p}].steer"]], [thr, steer])
        step_w, step_c, get_w = [], [], []
        for k in range(steps):
            t0, c0 = time.perf_counter(), time.process_time()
            fmu.doStep(currentCommunicationPoint=k * T, communicationStepSize=T)
            t1, c1 = time.perf_counter(), time.process_time()
            fmu.getReal(outs["Real"])
            fmu.getInteger(outs["Integer"])
            fmu.getBoolean(outs["Boolean"])
            step_w.append(t1 - t0)
            step_c.append(c1 - c0)
            get_w.append(time.perf_counter() - t1)
        fmu.terminate()
        fmu.freeInstance()
        shutil.rmtree(tmp, ignore_errors=True)
        res.append(dict(scene=label, steps=steps, dostep_median_ms=1e3 * float(np.median(step_w[10:])),
                        dostep_cpu_median_ms=1e3 * float(np.median(step_c[10:])),
                        get_median_ms=1e3 * float(np.median(get_w[10:]))))
    return res


def bench_campus(quick: bool, baseline: str = "", rounds: int = 3):
    """Campus-size cost: in process (model + wrapper) and through FMPy. With ``baseline`` (a
    directory holding another commit's ``immersim/models`` and ``immersim/fmus``), the in-process
    runs of that tree and of this one alternate in fresh processes, ``rounds`` rounds (the
    order reversed every other round)."""
    steps = 200 if quick else 600
    if not baseline:
        return campus_inprocess(steps), campus_fmpy(steps), []
    rows = []
    trees = [(Path(b).name, b) for b in baseline.split(",")] + [("current", None)]   # (several: comma-separated)
    for rnd in range(rounds):
        for code, tree in (trees if rnd % 2 == 0 else trees[::-1]):
            rows += [dict(r, code=code, round=rnd + 1) for r in in_tree(tree, "campus_inprocess", steps)]
    current = [r for r in rows if r["code"] == "current" and r["round"] == rounds]
    return current, campus_fmpy(steps), rows


#: the inputs of the network unit that campus_drive's log holds (``net.`` stripped when set)
LOG_INPUTS = ["net.avatar*.throttle", "net.avatar*.steer", "net.contact*"]


def campus_log_inputs(log: str):
    """The network inputs of a campus_drive log (``immersim run scenarios/campus_drive.toml -o LOG
    --set log.encoding='"json"' --set net:process=0``): the communication points (integer ns,
    shape (n + 1,)) and, per step ``k`` = 1..n, the inputs the unit had in that step (the
    values logged at its end, ``contact[p].active`` as bool)."""
    from immersim.orchestrator.mcapio import read_series

    ser = read_series(log, LOG_INPUTS)
    names = sorted(ser)
    t_ns = [round(float(x) * 1e9) for x in ser[names[0]][0]]
    cols = [[bool(x) for x in ser[n][1].tolist()] if n.endswith(".active") else ser[n][1].tolist() for n in names]
    steps = [{n[4:]: c[k] for n, c in zip(names, cols)} for k in range(1, len(t_ns))]
    return t_ns, steps


def campus_replay(inputs_path: str, fmu_dir: str = NETWORK_DIR, passes: int = 3, outputs_path: str = "",
                  paths: dict = None):
    """Replay campus_drive's logged inputs through the FMU class's ``do_step`` in process
    (model + wrapper + the base class's checks), ``passes`` times with a fresh instance each;
    the first pass warms up. Step ``k`` sets the logged inputs and steps from the log's
    ``t[k-1]`` by ``t[k] - t[k-1]`` (the master's ns times as seconds), timed with
    ``perf_counter_ns`` and ``thread_time_ns``. ``outputs_path``: every output of every step of
    the last pass (float64, (n, outputs), bools and integers as floats) saved there (.npy).
    Returns the per-step CPU and wall times (us) of the passes after the first. ``paths``: fields
    of :class:`Paths` for the model (this tree only, as in :func:`campus_inprocess`)."""
    network = network_class(fmu_dir)
    with open(inputs_path) as f:
        t_ns, steps = json.load(f)
    outs = [v.name for v in network.VARIABLES if v.causality == "output"]
    cpu, wall, table_ = [], [], []
    for rep in range(passes):
        s = campus_slave(network, 8, "replay")
        if paths:
            from immersim.models.network import Paths

            s.model = NetworkModel(s.model.cfg, Paths(**paths))
        v, do_step = s.values, s.do_step
        keep = outputs_path and rep == passes - 1
        for k, ins in enumerate(steps, start=1):
            v.update(ins)
            t0, h = t_ns[k - 1] / 1e9, (t_ns[k] - t_ns[k - 1]) / 1e9
            w0, c0 = time.perf_counter_ns(), time.thread_time_ns()
            ok = do_step(t0, h)
            c1, w1 = time.thread_time_ns(), time.perf_counter_ns()
            if not ok:
                raise RuntimeError(f"campus replay: step {k} failed: {s.failed}")
            if rep:
                cpu.append((c1 - c0) * 1e-3)
                wall.append((w1 - w0) * 1e-3)
            if keep:
                table_.append([float(v[n]) for n in outs])
    if outputs_path:
        np.save(outputs_path, np.array(table_))
    return dict(steps=len(steps), passes=passes - 1, cpu_mean_us=float(np.mean(cpu)), cpu_median_us=float(np.median(cpu)),
                wall_mean_us=float(np.mean(wall)), wall_median_us=float(np.median(wall)))


def bench_campus_log(log: str, baseline: str = "", rounds: int = 3):
    """campus_drive's logged inputs replayed (:func:`campus_replay`) in fresh processes, this
    tree and (``baseline``) another tree alternated, round by round (which one goes first
    alternates too); every output of every step of each run is compared with this tree's
    first run, bit for bit. Returns the rows, the number of runs whose outputs differ, and
    whether the first run's outputs equal those the log holds (the replay is faithful)."""
    import tempfile

    tmp = Path(tempfile.mkdtemp(prefix="bench_net_replay_"))
    inputs = str(tmp / "inputs.json")
    with open(inputs, "w") as f:
        json.dump(campus_log_inputs(log), f)
    trees = [("current", None)] + ([("baseline", baseline)] if baseline else [])
    rows, ref, differ = [], None, 0
    for rnd in range(rounds):
        for code, tree in (trees if rnd % 2 == 0 else trees[::-1]):
            out = str(tmp / f"{code}_{rnd}.npy")
            load0 = os.getloadavg()[0]
            r = in_tree(tree, "campus_replay", inputs, outputs_path=out)
            got = np.load(out)
            if ref is None:
                ref = got
            same = got.shape == ref.shape and np.array_equal(got.view(np.uint64), ref.view(np.uint64))
            differ += not same
            rows.append(dict(r, code=code, round=rnd + 1, load=0.5 * (load0 + os.getloadavg()[0]),
                             outputs="identical" if same else "DIFFER"))
    # the replay against the run that wrote the log: each logged output after step k, k = 1..n
    from immersim.orchestrator.mcapio import read_series

    logged = read_series(log, ["net.*"])
    outs = [v.name for v in network_class().VARIABLES if v.causality == "output"]
    as_logged = all(np.array_equal(logged["net." + n][1][1:].astype(float), ref[:, i]) for i, n in enumerate(outs))
    return rows, differ, as_logged


SCALE_COLS = (["dis_threshold", "measure", "nodes", "entities", "init_s", "median_ms", "p90_ms", "max_ms", "mean_ms",
               "cpu_median_ms", "cpu_max_ms", "load", "rt_factor", "messages", "mbytes", "rms"],
              {"init_s": "{:.2f}", "median_ms": "{:.1f}", "p90_ms": "{:.1f}", "max_ms": "{:.1f}", "mean_ms": "{:.1f}",
               "cpu_median_ms": "{:.1f}", "cpu_max_ms": "{:.1f}", "load": "{:.1f}",
               "rt_factor": "{:.2f}", "messages": "{:.0f}", "mbytes": "{:.2f}", "rms": "{:.4f}"})
CAMPUS_COLS = (["scene", "steps", "median_ms", "p90_ms", "cpu_median_ms", "cpu_mean_ms", "load", "at_rest", "unchanged"],
               {"median_ms": "{:.3f}", "p90_ms": "{:.3f}", "cpu_median_ms": "{:.3f}", "cpu_mean_ms": "{:.3f}",
                "load": "{:.1f}"})
FMPY_COLS = (["scene", "steps", "dostep_median_ms", "dostep_cpu_median_ms", "get_median_ms"],
             {"dostep_median_ms": "{:.3f}", "dostep_cpu_median_ms": "{:.3f}", "get_median_ms": "{:.3f}"})
REPLAY_COLS = (["code", "round", "steps", "passes", "cpu_mean_us", "cpu_median_us", "wall_mean_us", "wall_median_us",
                "load", "outputs"],
               {"cpu_mean_us": "{:.1f}", "cpu_median_us": "{:.1f}", "wall_mean_us": "{:.1f}",
                "wall_median_us": "{:.1f}", "load": "{:.1f}"})
PATHS_CAMPUS_COLS = (["plain", "drive_us", "drive_ratio", "idle_us", "idle_ratio", "replay_mean_us", "replay_mean_ratio",
                      "replay_median_ratio"],
                     {"drive_us": "{:.1f}", "drive_ratio": "{:.3f}", "idle_us": "{:.1f}", "idle_ratio": "{:.3f}",
                      "replay_mean_us": "{:.1f}", "replay_mean_ratio": "{:.3f}", "replay_median_ratio": "{:.3f}"})
PATHS_SCALE_COLS = (["plain", "dis_threshold", "cpu_median_ms", "ratio", "rounds"],
                    {"cpu_median_ms": "{:.1f}", "ratio": "{:.3f}"})
OWNERLESS_COLS = (["latency_ms", "ownerless", "rms", "max", "published", "bytes_per_step", "handovers_per_min",
                   "released_per_min", "claimed_per_min", "ownerless_share"],
                  {"rms": "{:.4f}", "max": "{:.3f}", "published": "{:.1f}", "bytes_per_step": "{:.0f}",
                   "handovers_per_min": "{:.0f}", "released_per_min": "{:.0f}", "claimed_per_min": "{:.0f}",
                   "ownerless_share": "{:.2f}"})
STATE_ERR_COLS = (["latency_ms", "state_traffic", "ownerless", "rms", "max", "messages", "bytes_per_step", "state_bytes_per_step"],
                  {"rms": "{:.4f}", "max": "{:.3f}", "messages": "{:.1f}", "bytes_per_step": "{:.0f}",
                   "state_bytes_per_step": "{:.0f}"})
STATE_TRAFFIC_COLS = (["state_traffic", "ownerless", "nodes", "messages", "bytes", "rms"],
                      {"messages": "{:.1f}", "bytes": "{:.0f}", "rms": "{:.4f}"})
AB_COLS = (["scene", "code", "round", "median_ms", "cpu_median_ms", "load", "unchanged"],
           {"median_ms": "{:.3f}", "cpu_median_ms": "{:.3f}", "load": "{:.1f}"})


def only(parts, quick: bool, baseline: str = "", log: str = "", rounds: int = 3) -> None:
    """Run some parts only and write their tables (the README is then edited by hand)."""
    head = f"<!-- {' '.join(sys.argv)} at {commit()} on {machine()} -->\n"
    if "campus" in parts:
        cur, fm, ab = bench_campus(quick, baseline, rounds)
        text = (head + "In process (FMU class `do_step`: model + wrapper):\n\n" + table(cur, *CAMPUS_COLS)
                + "\nThrough FMPy (built network.fmu, `FMU2Slave.doStep`; `get`: reading every output):\n\n"
                + table(fm, *FMPY_COLS))
        if ab:
            text += (f"\nAlternated with the baseline tree `{baseline}` (fresh process per run):\n\n"
                     + table(ab, *AB_COLS) + "\nMedian over the rounds of the CPU median per step (ms): "
                     + "; ".join(f"{scene}: " + ", ".join(
                         f"{code} {np.median([r['cpu_median_ms'] for r in ab if r['scene'] == scene and r['code'] == code]):.3f}"
                         for code in dict.fromkeys(r["code"] for r in ab))
                                 for scene in dict.fromkeys(r["scene"] for r in ab)) + "\n")
        (OUT / "campus.md").write_text(text)
        print(text)
    if "paths" in parts:
        camp, scale = bench_paths(quick, log)
        text = (head + "One shortcut of `Paths` in its plain form (column `plain`) against the default: the campus "
                "scenes' FMU step (model + wrapper, CPU median per step, us; drive: 3 players driving, 8 "
                "entities; idle: at rest, no entities; replay: campus_drive's logged inputs, `--campus-log`, CPU mean "
                "per step, the sum a run costs) and the 1000-node / 10,000-entity step (CPU median, ms); "
                "fresh processes, the variants in turn; ratio > 1: the shortcut saves that share.\n\n"
                + table(camp, *PATHS_CAMPUS_COLS) + "\n" + table(scale, *PATHS_SCALE_COLS))
        (OUT / "paths.md").write_text(text)
        print(text)
    if "ownerless" in parts:
        text = (head + "Entities outside every ownership region: `ownerless` True (the default: no owner, nobody "
                "publishes them after the owner's last record, every node shows its own prediction, the scene's "
                "entity law from its last record, claimed again by a region or a touching avatar; §3.6.3) against "
                "False (the last owner keeps them); STATE to neighbour nodes (the default). 8 groups x 2 render nodes, 300 entities, "
                "200 m scene, order 1, mahalanobis, WAN jitter 20 % of the latency; per 33 ms step after 5 "
                "warm-up steps; `ownerless_share`: entities without an owner at the end.\n\n"
                + table(bench_ownerless(quick), *OWNERLESS_COLS))
        (OUT / "ownerless.md").write_text(text)
        print(text)
    if "state_traffic" in parts:
        err, traffic, fits = bench_state_traffic(quick)
        text = (head + "Who gets a published object's STATE record: `object_view` (every master whose 9-cell "
                "neighbourhood holds the object) against `neighbour_nodes` (the default: only those whose avatar is in "
                "the 9-cell neighbourhood of the owner's avatar, §3.3), each with `ownerless` entities (the default, "
                "§3.6.3) and with last owners keeping them. Display error over WAN latencies: 8 groups x 2 "
                "render nodes, 300 entities, 200 m scene, order 1, mahalanobis, WAN jitter 20 % of the latency; "
                "per 33 ms step after 5 warm-up steps; last rows: `NetworkConfig.from_flat(seed=0)` (4 groups x 3 render nodes, "
                "32 entities, 100 m, WAN 20 ms + 5 ms exponential jitter), 600 steps.\n\n" + table(err, *STATE_ERR_COLS)
                + "\nTraffic vs render nodes (hybrid_p2p, 4 render nodes and 10 entities per group, 1000 m scene, "
                "avatars uniform, 10 steps after 2 warm-up):\n\n" + table(traffic, *STATE_TRAFFIC_COLS)
                + "\nLog-log exponents (messages, bytes): "
                + ", ".join(f"{k} {a:.2f}, {b:.2f}" for k, (a, b) in fits.items()) + "\n")
        (OUT / "state_traffic.md").write_text(text)
        print(text)
    if "frame_phase" in parts:
        sweep, seeds = bench_frame_phase(quick)
        lat = PHASE_TARGET if quick else PHASE_SWEEP
        text = (head + "Mean RMS display error (m) vs WAN latency (ms, column heads): parked avatars, 40 entities, "
                "order 0, no jitter, no bandwidth limit, every entity owned and sent to every viewer (`ownerless` "
                "False, `object_view`), 95 steps after 5 warm-up steps; `frame_phase` False: every frame clock in "
                "phase, True (the default): every node's clock at its own seeded phase, a group on its master's, the "
                "slaves locked to it (§3.5.2).\n\n"
                + table(sweep, ["groups", "seed", "frame_phase"] + [f"{L:g}" for L in lat])
                + "\nSeeds 0-7 whose mean RMS is strictly increasing over L = "
                + ", ".join(f"{L:g}" for L in PHASE_TARGET) + " ms:\n\n"
                + table(seeds, ["groups", "frame_phase", "jitter_ms", "strictly_increasing", "seeds"])
                + "\n`jitter_ms` 5: the default WAN jitter (exponential, mean 5 ms), the same draws at every latency.\n")
        (OUT / "latency_phase.md").write_text(text)
        print(text)
    if "handover" in parts:
        text = (head + "Hand-overs of the flapping scene (3 groups x 2 render nodes, 15 entities, 30 m scene, avatars "
                "uniform, contacts on, 280 steps, seeds 0-7): how many return to their previous owner within 2 frames, "
                "with the default hand-over hold and without one; `speed_excess`: the largest entity speed minus "
                "(the entities' start speed + the fastest avatar's speed), <= 0 when no collision adds speed.\n\n"
                + table(bench_handover(quick), ["handover_hold_s", "seeds", "handovers", "reverted_within_2_frames",
                                                "share", "contacts", "speed_excess"]))
        (OUT / "handover.md").write_text(text)
        print(text)
    if "scale" in parts:
        (OUT / "scale.md").write_text(head + table(bench_scale(quick), *SCALE_COLS))
        print((OUT / "scale.md").read_text())


def campus_log_report(log: str, baseline: str, rounds: int) -> None:
    """Run :func:`bench_campus_log` and write ``campus_replay.md`` (the runs, and per tree the
    mean over rounds of the per-step mean and median CPU time)."""
    rows, differ, as_logged = bench_campus_log(log, baseline, rounds)
    text = (f"<!-- {' '.join(sys.argv)} at {commit()} on {machine()} -->\n"
            f"campus_drive's logged network inputs (`{log}`) replayed through the FMU class's `do_step` "
            f"(model + wrapper + base-class checks), per-step CPU (`thread_time_ns`) and wall time, "
            f"{rows[0]['passes']} timed passes of {rows[0]['steps']} steps per run after one warm-up pass, "
            f"a fresh process per run, the trees alternated:\n\n" + table(rows, *REPLAY_COLS))
    summary = {}
    for code in ("current", "baseline"):
        r = [x for x in rows if x["code"] == code]
        if r:
            summary[code] = (float(np.mean([x["cpu_mean_us"] for x in r])), float(np.mean([x["cpu_median_us"] for x in r])))
            text += f"\n{code}: CPU per step mean {summary[code][0]:.1f} us, median {summary[code][1]:.1f} us (mean over rounds)"
    if "baseline" in summary:
        c, b = summary["current"], summary["baseline"]
        text += (f"\ncurrent / baseline: mean {c[0] / b[0]:.3f} ({100 * (1 - c[0] / b[0]):.1f} % less), "
                 f"median {c[1] / b[1]:.3f} ({100 * (1 - c[1] / b[1]):.1f} % less)")
    text += (f"\noutputs of every step: {'identical in every run' if not differ else f'DIFFER in {differ} run(s)'} "
             f"(bit for bit against the first run); equal to the outputs in the log: {as_logged}\n")
    (OUT / "campus_replay.md").write_text(text)
    print(text)


def loop_ab(base: str, rounds: int, this: str = "") -> None:
    """campus_drive's loop, this checkout (or the package in ``this``, made as ``base``) against
    the whole package of another commit in ``base`` (see the module docstring), alternated;
    writes ``loop_ab.md``."""
    import re
    import resource
    import tempfile

    out = Path(tempfile.mkdtemp(prefix="bench_net_loop_")) / "run.mcap"
    def tree(d):
        return (d, str(Path(d) / "immersim" / "scenarios" / "campus_drive.toml"), {"PYTHONPATH": d})

    runs = {"this": tree(this) if this else (str(ROOT), str(ROOT / "scenarios" / "campus_drive.toml"), {}),
            "baseline": tree(base)}
    got = {k: [] for k in runs}
    for rnd in range(rounds):
        for code in (("this", "baseline") if rnd % 2 == 0 else ("baseline", "this")):
            cwd, scenario, extra = runs[code]
            ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            res = subprocess.run([sys.executable, "-m", "immersim.orchestrator.cli", "run", scenario, "-q", "-o", str(out)],
                                 cwd=cwd, env=dict(os.environ, **extra), capture_output=True, text=True, check=True)
            ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            text = res.stdout + res.stderr
            got[code].append((float(re.search(r"loop ([0-9.]+) s", text).group(1)),
                              float(re.search(r"net ([0-9.]+) s", text).group(1)), os.getloadavg()[0],
                              ru1.ru_utime + ru1.ru_stime - ru0.ru_utime - ru0.ru_stime))
    rows = [dict(code=c, loop_s=", ".join(f"{x[0]:.3f}" for x in v), loop_median_s=float(np.median([x[0] for x in v])),
                 net_median_s=float(np.median([x[1] for x in v])), cpu_median_s=float(np.median([x[3] for x in v])),
                 load=float(np.mean([x[2] for x in v])))
            for c, v in got.items()]
    ratio = rows[0]["loop_median_s"] / rows[1]["loop_median_s"]
    text = (f"<!-- {' '.join(sys.argv)} at {commit()} on {machine()} -->\n"
            f"`immersim run scenarios/campus_drive.toml -q` (607 steps, 20 s), this checkout and the baseline package "
            f"alternated, {rounds} runs each; `loop` and `net` as the command prints them (wall s), `cpu`: the "
            f"whole command's CPU time (user + system, start-up included):\n\n"
            + table(rows, ["code", "loop_s", "loop_median_s", "net_median_s", "cpu_median_s", "load"],
                    {"loop_median_s": "{:.3f}", "net_median_s": "{:.3f}", "cpu_median_s": "{:.2f}", "load": "{:.1f}"})
            + f"\nloop this / baseline: {ratio:.3f} (target within 10 %: {'met' if ratio <= 1.10 else 'NOT met'}); "
            f"command CPU this / baseline: {rows[0]['cpu_median_s'] / rows[1]['cpu_median_s']:.3f}\n")
    (OUT / "loop_ab.md").write_text(text)
    print(text)


def table(rows, cols, fmt=None):
    fmt = fmt or {}
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append("| " + " | ".join((fmt.get(c, "{}")).format(r[c]) for c in cols) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer points and steps (about a minute)")
    ap.add_argument("--only", default="", help="comma-separated parts to run alone: scale, campus, paths, ownerless, state_traffic, frame_phase, handover")
    ap.add_argument("--baseline", default="", help="campus: directory with another commit's immersim/models and "
                    "immersim/fmus (git archive COMMIT models fmus | tar -x -C DIR/immersim; touch DIR/immersim/__init__.py), "
                    "alternated with this tree")
    ap.add_argument("--campus-log", default="", help="replay the network inputs of this campus_drive log (immersim "
                    "run scenarios/campus_drive.toml -o LOG --set log.encoding='\"json\"' --set net:process=0) "
                    "through the FMU class, this tree and --baseline alternated, outputs compared bit for bit; "
                    "writes campus_replay.md")
    ap.add_argument("--rounds", type=int, default=3, help="--campus-log, --loop-ab, --only campus with --baseline: rounds of alternated runs")
    ap.add_argument("--loop-ab", default="", help="directory with another commit's whole immersim package: "
                    "campus_drive's loop alternated with this checkout's; writes loop_ab.md")
    ap.add_argument("--loop-this", default="", help="--loop-ab: a package directory made the same way for this "
                    "side (e.g. this commit without the work tree's uncommitted edits)")
    args = ap.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    if args.loop_ab:
        loop_ab(args.loop_ab, args.rounds, args.loop_this)
        return
    if args.only:   # (--campus-log: the replayed inputs of the paths part)
        only(set(args.only.split(",")), args.quick, args.baseline, args.campus_log, args.rounds)
        return
    if args.campus_log:
        campus_log_report(args.campus_log, args.baseline, args.rounds)
        return
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t_all = time.perf_counter()
    lat_rows = bench_latency(args.quick)
    traffic_rows, fits = bench_traffic(args.quick)
    scale = bench_scale(args.quick)
    wall = time.perf_counter() - t_all

    # plots
    fig, axes = plt.subplots(1, 3, figsize=(14, 4), sharey=True)
    for ax, order in zip(axes, (0, 1, 2)):
        for rule in RULES:
            r = [x for x in lat_rows if x["order"] == order and x["ownership"] == rule]
            ax.plot([x["latency_ms"] for x in r], [x["rms"] for x in r], "o-", label=rule)
        ax.set_title(f"dead reckoning order {order}")
        ax.set_xlabel("WAN latency (ms), jitter 20 %")
        ax.grid(True)
    axes[0].set_ylabel("RMS inconsistency (m), eq. 3-1/3-2")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(OUT / "inconsistency_vs_latency.png", dpi=110)
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    for topo in fits:
        r = [x for x in traffic_rows if x["topology"] == topo]
        ax[0].loglog([x["nodes"] for x in r], [x["messages"] for x in r], "o-", label=f"{topo} (k={fits[topo][0]:.2f})")
        ax[1].loglog([x["nodes"] for x in r], [x["bytes"] for x in r], "o-", label=f"{topo} (k={fits[topo][1]:.2f})")
    for a, name in zip(ax, ("messages", "bytes")):
        a.set_xlabel("render nodes")
        a.set_ylabel(f"{name} per 33 ms step")
        a.grid(True, which="both")
        a.legend()
    fig.tight_layout()
    fig.savefig(OUT / "traffic_vs_nodes.png", dpi=110)

    # tables
    lat_tab = table(lat_rows, ["order", "ownership", "latency_ms", "rms", "max", "handovers", "handovers_per_min",
                               "rejected", "contacts", "remote_contacts", "bytes_per_step"],
                    {"rms": "{:.4f}", "max": "{:.3f}", "bytes_per_step": "{:.0f}", "handovers_per_min": "{:.0f}"})
    tr_tab = table(traffic_rows, ["topology", "nodes", "messages", "bytes", "dropped", "rms"],
                   {"messages": "{:.0f}", "bytes": "{:.0f}", "rms": "{:.4f}"})
    sc_tab = table(scale, *SCALE_COLS)
    fit_lines = "\n".join(f"- `{t}`: messages ~ n^{k[0]:.2f}, bytes ~ n^{k[1]:.2f}" for t, k in fits.items())
    best = min(s["median_ms"] for s in scale if s["measure"])
    best_any = min(s["median_ms"] for s in scale)
    verdict = "met" if best <= 33.0 else "NOT met"
    order_means = {o: np.mean([x["rms"] for x in lat_rows if x["order"] == o and x["latency_ms"] > 0]) for o in (0, 1, 2)}
    rule_remote = {r: sum(x["remote_contacts"] for x in lat_rows if x["ownership"] == r) for r in RULES}
    rule_hand = {r: sum(x["handovers"] for x in lat_rows if x["ownership"] == r) for r in RULES}
    head = f"""Command: `python benchmarks/bench_network.py{' --quick' if args.quick else ''}` (total {wall:.0f} s)
Commit: `{commit()}` (the working tree may hold later uncommitted edits of other units)
Machine: {machine()}; shared with other jobs while it ran, so times are noisy.

"""
    sections = {"scale.md": f"""# Scale: 1000 render nodes, 10,000 entities (target: a 33 ms step in <= 33 ms)

250 groups x 4 render nodes (+250 control platforms, 1 supernode), 10,000 free entities,
2 km scene (10x10 grid of 200 m cells), hybrid P2P, dead reckoning order 1, every frame
(`dis_threshold` 0) and DIS updates at 0.1 m; `measure` False skips the per-copy display
error of eq. 3-1/3-2 (the network behaves identically, only the metric is not computed), to
show what the protocol simulation costs by itself.

{sc_tab}
Best median wall time per 33 ms step with the metrics {best:.1f} ms: target **{verdict}**
(real-time factor {33.0 / best:.2f}); without the display metric {best_any:.1f} ms. `cpu_median_ms` is the process CPU time per step and `load` the 1-minute
load average of the machine during the run (2 cores shared with other jobs): the wall times
include waiting for a core. With DIS updates the display error of eq. 3-1/3-2 comes from
record groups (one evaluation per distinct record and object, updated only where a copy
changed; `models/network/display.py`); when every frame is published (`dis_threshold` 0)
nearly every one of the ~235,000 copies gets a new record each frame, so the error is
evaluated per copy and the ~206,000 cache writes per frame dominate.
""",
                "traffic_vs_nodes.md": f"""# Traffic vs number of render nodes (4 render nodes per group, 10 entities per group, 1 km scene)

{tr_tab}
Fitted log-log exponents:
{fit_lines}

Full mesh grows as n^2 in messages; hybrid P2P stays near-linear in messages. Its bytes stay
super-linear because a FRAME PDU carries the whole 9-cell view and the view's entity count
grows with the entity density (the scene and its 10x10 grid are fixed).
""",
                "inconsistency_vs_latency.md": f"""# Inconsistency vs latency, every prediction order and ownership rule

8 groups x 2 render nodes, 300 entities, 200 m scene, WAN jitter 20 % of the latency.
Mean RMS inconsistency over latencies > 0: order 0 {order_means[0]:.4f} m, order 1 {order_means[1]:.4f} m,
order 2 {order_means[2]:.4f} m. Remote contacts (collision answered by a non-owner after a WAN
report), summed over the sweep: {rule_remote}; hand-overs: {rule_hand}.
`mahalanobis` reads eq. 3-12 with the foci one frame apart (a = 30 D >> D/2, so the region
is almost a sphere shifted by D/2 and behaves like `euclidean`); `mahalanobis_reach` puts the
foci a = D Scale apart, a region stretched ahead of the avatar.

The defaults hold: entities outside every region have no owner and every node predicts them
with the scene's entity law (§3.6.3), STATE goes to neighbour nodes (§3.3), every node's frame
clock has its own phase (so even L = 0 shows an error: a record waits for the viewer's next
frame). The sweep has points below one frame (5-30 ms); here, with jitter, contacts and
hand-overs, the order 1-2 errors between them lie within the run's noise; the clean sub-frame
figure (parked avatars, no jitter) is `latency_phase.md`. Order 0 predicts nothing, so an entity without an owner stays where its last
record put it: metres of error with a region rule, against `none` (fixed owners, published
every frame).

Findings. Dead reckoning is what cuts the display error (mean RMS per order above). Among
orders 1 and 2 the ownership rule barely moves the display error (a hand-over makes the
viewers reject the old owner's records still in flight until the new owner's first record
arrives). Its effect is on traffic and interactions: with a region rule most entities are
ownerless and unpublished (bytes per step about 30 % below `none`), and collisions answered by
a remote owner after a WAN report (remote contacts above) are far fewer than with `none`.
`handovers_per_min`: hand-overs between two owners per simulated minute.

{lat_tab}
Plots: `inconsistency_vs_latency.png`, `traffic_vs_nodes.png`.
"""}
    for name, text in sections.items():   # (README.md: the table of current figures, kept by hand)
        (OUT / name).write_text(head + text)
        print(head + text)


if __name__ == "__main__":
    sys.exit(main() or 0)

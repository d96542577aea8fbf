"""Closed-loop plots of the reference scenarios, regenerated from fresh runs.

Runs ``scenarios/campus_drive.toml`` (with and without the collision-jolt connection, so the
jolt's own effect on the strokes can be isolated), ``scenarios/network_stress.toml`` (latency
burst) and ``scenarios/platform_tracking.toml``, then writes PNG plots and a README with the
command, commit, machine and the measured figures to ``results/scenarios/``.

Usage::

    .venv/bin/python scripts/closed_loop_plots.py [--out results/scenarios] [--stop 10]
"""
from __future__ import annotations

import argparse
import logging
import platform
import re
import subprocess
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from immersim.orchestrator.execution import run_scenario  # noqa: E402
from immersim.orchestrator.mcapio import read_series  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCEN = ROOT / "scenarios"
log = logging.getLogger("closed_loop_plots")

JOLT_CONNECTION = re.compile(r"\[\[connections\]\][^\n]*\nfrom = \"net\.avatar\[1\]\.jolt_acc\"[^\n]*\n"
                             r"to = \"plat\.jolt\"\n(?:gain = [0-9.]+\n)?(?:extrapolation = [^\n]*\n)?")


def series(path: Path, name: str):
    """(t, y) of one logged signal ``unit.var`` (brackets are escaped for the glob)."""
    pat = name.replace("[", "[[]")
    t, y, _ = read_series(path, [pat])[name]
    return t, y


def without_jolt(src: Path, dst: Path) -> Path:
    """A copy of campus_drive with the net.avatar[1].jolt_acc -> plat.jolt connection removed."""
    text, n = JOLT_CONNECTION.subn("", src.read_text())
    if n != 1:
        raise RuntimeError(f"{src}: jolt connection not found exactly once ({n})")
    dst.write_text(text)
    return dst


def campus_plots(out: Path, tmp: Path, stop: float) -> dict:
    """Collision -> bounce -> jolt -> strokes on player 1's platform."""
    ov = {"simulation.stop": stop}
    run_scenario(SCEN / "campus_drive.toml", tmp / "campus.mcap", overrides=ov)
    nj = without_jolt(SCEN / "campus_drive.toml", SCEN / ".campus_drive_nojolt.tmp.toml")
    try:
        run_scenario(nj, tmp / "campus_nojolt.mcap", overrides=ov)
    finally:
        nj.unlink()
    a, b = tmp / "campus.mcap", tmp / "campus_nojolt.mcap"
    t, contact = series(a, "coll.pair[1].in_contact")
    _, dist = series(a, "coll.pair[1].distance")
    _, active = series(a, "net.contact[1].active")
    _, jolt_net = series(a, "net.avatar[1].jolt")
    _, jolt_plat = series(a, "plat.jolt")
    _, vx = series(a, "net.avatar[1].vx")
    _, vy = series(a, "net.avatar[1].vy")
    t_hit = float(t[np.flatnonzero(contact > 0)[0]])
    t_jolt = float(t[np.flatnonzero(jolt_plat > 0)[0]])
    strokes = np.array([series(a, f"plat.stroke[{i}]")[1] for i in range(1, 7)])
    strokes0 = np.array([series(b, f"plat.stroke[{i}]")[1] for i in range(1, 7)])
    diff = strokes - strokes0

    fig, ax = plt.subplots(4, 1, figsize=(9, 10), sharex=True)
    ax[0].plot(t, dist, label="coll.pair[1].distance (avatar_1 vs tank_a) [m]")
    ax[0].step(t, contact, where="post", label="coll.pair[1].in_contact")
    ax[0].step(t, active, where="post", ls="--", label="net.contact[1].active (next step)")
    ax[0].set_ylim(-0.2, 5)
    ax[0].legend(fontsize=8)
    ax[1].plot(t, np.hypot(vx, vy), label="avatar 1 speed [m/s]")
    ax[1].step(t, jolt_net, where="post", label="net.avatar[1].jolt |dv| [m/s]")
    ax[1].step(t, jolt_plat, where="post", ls="--", label="plat.jolt = 0.03 jolt_acc [m/s2]")
    ax[1].legend(fontsize=8)
    for i in range(6):
        ax[2].plot(t, strokes[i] * 1e3, label=f"stroke[{i + 1}]")
        ax[3].plot(t, diff[i] * 1e3, label=f"stroke[{i + 1}]")
    ax[2].set_ylabel("stroke [mm]")
    ax[2].legend(fontsize=7, ncol=3)
    ax[3].set_ylabel("stroke with jolt - without [mm]")
    ax[3].set_xlabel("t [s]")
    for x in ax:
        x.axvline(t_hit, color="k", lw=0.6, ls=":")
    ax[0].set_title(f"campus_drive: avatar 1 hits tank_a at {t_hit:.3f} s -> bounce -> platform jolt at {t_jolt:.3f} s")
    fig.tight_layout()
    fig.savefig(out / "collision_jolt_strokes.png", dpi=110)
    plt.close(fig)
    win = (t >= t_jolt) & (t <= t_jolt + 1.5)
    return {"t_hit": t_hit, "t_jolt": t_jolt, "jolt": float(jolt_plat.max()),
            "stroke_diff_max_mm": float(np.abs(diff[:, win]).max() * 1e3),
            "stroke_diff_before_mm": float(np.abs(diff[:, t < t_jolt]).max() * 1e3),
            "stroke_absmax_mm": float(np.abs(strokes).max() * 1e3),
            "outside_steps": int(np.count_nonzero(series(a, "plat.flag.outside_workspace")[1]))}


def burst_plot(out: Path, tmp: Path) -> dict:
    """Inconsistency spike after the x10 latency burst of network_stress."""
    p = tmp / "stress.mcap"
    run_scenario(SCEN / "network_stress.toml", p)
    t, imax = series(p, "net.inconsistency_max")
    _, irms = series(p, "net.inconsistency_rms")
    _, scale = series(p, "net.latency_scale")
    _, dropped = series(p, "net.dropped_frames")
    burst = scale > 1
    t0, t1 = float(t[burst][0]), float(t[burst][-1]) + 0.033
    fig, ax = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    ax[0].plot(t, imax * 100, label="inconsistency_max [cm]")
    ax[0].plot(t, irms * 100, label="inconsistency_rms [cm]")
    ax[0].axvspan(t0, t1, color="orange", alpha=0.25, label="latency_scale = 10")
    ax[0].legend(fontsize=8)
    ax[0].set_title("network_stress (404 nodes): spatio-temporal inconsistency (eq. 3-1/3-2) around a latency burst")
    ax[1].step(t, scale, where="post", label="net.latency_scale")
    ax[1].step(t, dropped, where="post", label="net.dropped_frames")
    ax[1].legend(fontsize=8)
    ax[1].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(out / "latency_burst_inconsistency.png", dpi=110)
    plt.close(fig)
    before, during = t < t0, (t >= t0) & (t < t1)
    after = (t >= t1) & (t < t1 + 0.5)
    late = t >= t1 + 0.5
    return {"t0": t0, "t1": t1, "before": float(imax[before].max()), "during": float(imax[during].max()),
            "after": float(imax[after].max()), "late": float(imax[late].max()),
            "rms_before": float(irms[before].mean()), "rms_peak": float(irms.max())}


def tracking_plot(out: Path, tmp: Path) -> dict:
    """§6.4.2: Y sine and YZ ellipse from an offset start."""
    p = tmp / "tracking.mcap"
    run_scenario(SCEN / "platform_tracking.toml", p)
    fig, ax = plt.subplots(1, 3, figsize=(13, 4))
    t, y = series(p, "plat_y.pose.y")
    _, ry = series(p, "plat_y.ref.y")
    ax[0].plot(t, ry * 1e3, "--", label="ref.y")
    ax[0].plot(t, y * 1e3, label="pose.y")
    ax[0].set_title("plat_y: Y sine (a_y = 50 mm)")
    ax[0].set_xlabel("t [s]")
    ax[0].set_ylabel("mm")
    ax[0].legend()
    _, y2 = series(p, "plat_yz.pose.y")
    _, z2 = series(p, "plat_yz.pose.z")
    _, ry2 = series(p, "plat_yz.ref.y")
    _, rz2 = series(p, "plat_yz.ref.z")
    ax[1].plot(ry2 * 1e3, rz2 * 1e3, "--", label="reference ellipse")
    ax[1].plot(y2 * 1e3, z2 * 1e3, label="pose (from home)")
    ax[1].set_aspect("equal")
    ax[1].set_xlabel("Y [mm]")
    ax[1].set_ylabel("Z [mm]")
    ax[1].set_title("plat_yz: YZ ellipse, offset start")
    ax[1].legend(fontsize=8)
    err = np.hypot(y2 - ry2, z2 - rz2)
    err1 = np.abs(y - ry)
    ax[2].semilogy(t, np.maximum(err1, 1e-9) * 1e3, label="plat_y |Y - Y_ref|")
    ax[2].semilogy(t, np.maximum(err, 1e-9) * 1e3, label="plat_yz |(Y,Z) - ref|")
    ax[2].set_xlabel("t [s]")
    ax[2].set_ylabel("error vs raw reference [mm]")
    ax[2].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "platform_tracking.png", dpi=110)
    plt.close(fig)
    return {"err_y_late_mm": float(err1[t > 3].max() * 1e3), "err_yz_late_mm": float(err[t > 3].max() * 1e3),
            "err_yz_start_mm": float(err.max() * 1e3)}


def machine() -> str:
    cpu = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    nproc = subprocess.run(["nproc"], capture_output=True, text=True).stdout.strip()
    return f"{nproc} cores, {cpu or platform.processor()}, Python {platform.python_version()}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "results" / "scenarios"))
    ap.add_argument("--stop", type=float, default=10.0, help="campus_drive stop time, s")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=ROOT).stdout.strip()
    with tempfile.TemporaryDirectory(prefix="closed_loop_") as d:
        tmp = Path(d)
        c = campus_plots(out, tmp, args.stop)
        b = burst_plot(out, tmp)
        k = tracking_plot(out, tmp)
    text = f"""# Closed-loop plots of the reference scenarios

Regenerated from fresh runs by

    .venv/bin/python scripts/closed_loop_plots.py --stop {args.stop:g}

at commit `{commit}` on {machine()}. The benchmark (real-time factor, time per unit) is in
[bench.md](bench.md).

## `collision_jolt_strokes.png` — a collision felt on the motion platform (campus_drive)

The closed loop `net -> coll -> net` and `net -> plat` of `scenarios/campus_drive.toml`
({args.stop:g} s). Top: distance and contact flag of pair 1 (`avatar_1 vs tank_a`) and the
network's contact input in the same step (the collision unit steps first on the network's last
poses; the network reads its contacts fresh).
Second: avatar 1's speed, the bounce's velocity change `net.avatar[1].jolt` and the platform's
`plat.jolt` input. Third: the six actuator strokes. Bottom: strokes of this run minus those of
the same run with the `net.avatar[1].jolt_acc -> plat.jolt` connection removed: the jolt's own
contribution to the strokes.

Measured: avatar 1 touches tank_a at t = {c['t_hit']:.3f} s; the network bounces it
(restitution 0.5) and `plat.jolt` = {c['jolt']:.2f} at t = {c['t_jolt']:.3f} s (the step it is reported in).
The jolt changes the strokes by up to {c['stroke_diff_max_mm']:.1f} mm within 1.5 s
(difference before the jolt: {c['stroke_diff_before_mm']:.2g} mm); the largest stroke of the run is
{c['stroke_absmax_mm']:.1f} mm (limit 120 mm); `plat.flag.outside_workspace` (the washout reference
clamped to the workspace) is set in {c['outside_steps']} steps.

## `latency_burst_inconsistency.png` — inconsistency spike after a latency burst (network_stress)

`scenarios/network_stress.toml`: 4 players x 100 render nodes (404 nodes online), the input
`net.latency_scale` steps from 1 to 10 at {b['t0']:.3f} s and back at {b['t1']:.3f} s.
`inconsistency_max` (largest position error of any copy displayed by a non-owner master,
eq. 3-1/3-2, dead reckoning order 1):

| window | max inconsistency |
|---|---|
| before the burst | {b['before'] * 100:.2f} cm |
| during the burst | {b['during'] * 100:.2f} cm |
| 0.5 s after it | {b['after'] * 100:.2f} cm |
| later | {b['late'] * 100:.2f} cm |

RMS over copies: {b['rms_before'] * 100:.2f} cm on average before the burst, peak {b['rms_peak'] * 100:.2f} cm.
The spike outlasts the burst by the in-flight delay of the last slow updates, then returns to the
pre-burst level.

## `platform_tracking.png` — §6.4.2 experiments (platform_tracking)

`scenarios/platform_tracking.toml`: computed-torque tracking of a Y sine (a_y = 50 mm, 0.5 Hz) and
of a YZ ellipse (a_y = 50 mm, a_z = 25 mm) whose reference starts 50 mm from the platform's home
pose (the thesis's 2 m amplitudes scaled into the workspace, as SPEC requires). Error against the
raw reference after 3 s: {k['err_y_late_mm']:.2f} mm (Y sine), {k['err_yz_late_mm']:.2f} mm (ellipse); the
ellipse's start offset ({k['err_yz_start_mm']:.1f} mm) is closed by the critically damped reference prefilter
(omega_f = 15 rad/s). The residual is the prefilter's lag; `plat.track_err` (error against the
prefiltered reference) stays at rounding level because computed torque cancels the model exactly.
"""
    (out / "README.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()

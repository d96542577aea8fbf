"""Drive Debian's headless Chromium over the DevTools protocol: open a page, wait for a
condition, collect script errors, evaluate JavaScript, take a screenshot.

Used by the report's browser test and ``benchmarks/bench_analysis.py``. ``chromium()`` is the
browser's path; under CI (``CI=true``) a missing browser is an error, not a skip (``.ci/run``
installs it).
"""
from __future__ import annotations

import asyncio
import base64
import json
import os
import re
import shutil
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import List, Optional


def chromium() -> Optional[str]:
    """Path of the chromium binary, or None."""
    return shutil.which("chromium") or shutil.which("chromium-browser")


@dataclass
class PageRun:
    """What happened while a page loaded."""

    load_s: float                       # navigation start -> the ready condition held
    cpu_s: float = float("nan")         # CPU time of the browser's processes over that span
    errors: List[str] = field(default_factory=list)   # uncaught exceptions, console.error, error log entries
    values: dict = field(default_factory=dict)         # results of the ``evaluate`` expressions


def tree_cpu_s(root: int) -> float:
    """User + system CPU seconds of process ``root`` and its live descendants (Linux /proc)."""
    parent, cpu = {}, {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        parent[int(d.name)] = int(fields[1])
        cpu[int(d.name)] = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    tree, frontier = {root}, [root]
    while frontier:
        kids = [p for p, pp in parent.items() if pp in frontier and p not in tree]
        tree.update(kids)
        frontier = kids
    return sum(cpu.get(p, 0.0) for p in tree)


class _Cdp:
    def __init__(self, ws) -> None:
        self.ws, self.next_id, self.events, self.pending = ws, 0, [], {}

    async def pump(self) -> None:
        async for raw in self.ws:
            msg = json.loads(raw)
            if "id" in msg and msg["id"] in self.pending:
                self.pending.pop(msg["id"]).set_result(msg)
            elif "method" in msg:
                self.events.append(msg)

    async def call(self, method: str, session: Optional[str] = None, **params) -> dict:
        self.next_id += 1
        fut = asyncio.get_running_loop().create_future()
        self.pending[self.next_id] = fut
        msg = {"id": self.next_id, "method": method, "params": params}
        if session:
            msg["sessionId"] = session
        await self.ws.send(json.dumps(msg))
        reply = await asyncio.wait_for(fut, 60)
        if "error" in reply:
            raise RuntimeError(f"{method}: {reply['error']}")
        return reply.get("result", {})


def _errors(events: List[dict]) -> List[str]:
    out = []
    for e in events:
        p = e.get("params", {})
        if e["method"] == "Runtime.exceptionThrown":
            d = p["exceptionDetails"]
            out.append(d.get("exception", {}).get("description") or d.get("text", "exception"))
        elif e["method"] == "Runtime.consoleAPICalled" and p.get("type") == "error":
            out.append(" ".join(str(a.get("value", a.get("description", ""))) for a in p.get("args", [])))
        elif e["method"] == "Log.entryAdded" and p["entry"].get("level") == "error":
            out.append(p["entry"].get("text", ""))
    return out


async def _run(url: str, ready: str, evaluate: dict, screenshot: Optional[Path], width: int,
               timeout: float) -> PageRun:
    import websockets

    # (a helper process of chromium may still write into the profile for a moment after the
    # browser is gone: the whole process group is ended, and a last write does not fail the run)
    with tempfile.TemporaryDirectory(prefix="immersim_chromium_", ignore_cleanup_errors=True) as profile:
        proc = subprocess.Popen([chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                                 "--remote-debugging-port=0", f"--user-data-dir={profile}", "about:blank"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                start_new_session=True)
        try:
            ws_url = None
            deadline = time.monotonic() + timeout
            while ws_url is None and time.monotonic() < deadline:
                line = proc.stderr.readline()
                if not line and proc.poll() is not None:
                    raise RuntimeError(f"chromium exited with {proc.returncode} before DevTools started")
                m = re.search(r"DevTools listening on (ws://\S+)", line)
                ws_url = m.group(1) if m else None
            async with websockets.connect(ws_url, max_size=None) as ws:
                cdp = _Cdp(ws)
                pump = asyncio.create_task(cdp.pump())
                target = (await cdp.call("Target.createTarget", url="about:blank"))["targetId"]
                session = (await cdp.call("Target.attachToTarget", targetId=target, flatten=True))["sessionId"]
                for domain in ("Runtime", "Log", "Page"):
                    await cdp.call(f"{domain}.enable", session)
                await cdp.call("Emulation.setDeviceMetricsOverride", session, width=width, height=900,
                               deviceScaleFactor=1, mobile=False)
                c0 = tree_cpu_s(proc.pid)
                t0 = time.perf_counter()
                await cdp.call("Page.navigate", session, url=url)
                load_s = None
                while time.perf_counter() - t0 < timeout:
                    r = await cdp.call("Runtime.evaluate", session, expression=ready, returnByValue=True)
                    if r.get("result", {}).get("value"):
                        load_s = time.perf_counter() - t0
                        break
                    if _errors(cdp.events):
                        break
                    await asyncio.sleep(0.02)
                run = PageRun(load_s if load_s is not None else float("nan"), tree_cpu_s(proc.pid) - c0)
                for name, expr in evaluate.items():
                    r = await cdp.call("Runtime.evaluate", session, expression=expr, returnByValue=True,
                                       awaitPromise=True)
                    run.values[name] = r.get("result", {}).get("value")
                if screenshot is not None:
                    h = (await cdp.call("Runtime.evaluate", session, returnByValue=True,
                                        expression="document.documentElement.scrollHeight"))["result"]["value"]
                    await cdp.call("Emulation.setDeviceMetricsOverride", session, width=width, height=int(h),
                                   deviceScaleFactor=1, mobile=False)
                    await asyncio.sleep(0.3)
                    shot = await cdp.call("Page.captureScreenshot", session, format="png")
                    screenshot.parent.mkdir(parents=True, exist_ok=True)
                    screenshot.write_bytes(base64.b64decode(shot["data"]))
                await asyncio.sleep(0.05)   # late error events
                run.errors = _errors(cdp.events)
                if load_s is None and not run.errors:
                    run.errors.append(f"the page was not ready ({ready}) within {timeout} s")
                pump.cancel()
                return run
        finally:
            _end_group(proc, signal.SIGTERM)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                pass
            _end_group(proc, signal.SIGKILL)   # what is left of the group (zygote, crash handler)
            proc.wait()


def _end_group(proc: subprocess.Popen, sig: int) -> None:
    try:
        os.killpg(proc.pid, sig)
    except ProcessLookupError:
        pass


def open_page(path: Path, ready: str = "document.readyState === 'complete'", evaluate: Optional[dict] = None,
              screenshot: Optional[Path] = None, width: int = 1280, timeout: float = 60.0) -> PageRun:
    """Load ``path`` (a local HTML file) in headless Chromium until JavaScript ``ready`` is true.

    Parameters
    ----------
    evaluate : dict of name -> JavaScript expression, optional
        Evaluated after the page is ready; results (JSON values) in ``PageRun.values``.
    screenshot : Path, optional
        PNG of the whole page (``width`` wide).
    """
    if chromium() is None:
        raise RuntimeError("chromium is not installed (apt-get install chromium)")
    return asyncio.run(_run(Path(path).resolve().as_uri(), ready, evaluate or {}, screenshot, width, timeout))


def require_chromium():
    """Skip the calling test when chromium is missing, except under CI, where it is an error."""
    import pytest

    if chromium() is None:
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail("chromium is not installed: .ci/run installs it (apt-get install chromium)")
        pytest.skip("chromium is not installed (apt-get install chromium)")


"""immersim installed from its wheel outside the checkout, and Dask workers that cannot see
the client's folders (used by ``tests/install`` and ``benchmarks/bench_sweep.py``).

:func:`build_dists` builds the sdist and, from it, the wheel (``python -m build``), as a
release would. :func:`make_wheel_env` installs the wheel into a fresh virtual environment
(no pip, no system site-packages) whose third-party dependencies are those of the running
interpreter, reached through a ``.pth`` line: only third-party packages, never the checkout
(an editable install's finder in that folder is not activated by a plain path entry).

:class:`IsolatedWorker` starts ``dask worker`` in a private mount namespace (``unshare``; as
root, else in a user namespace) where the checkout, the temporary folder and the user's
cache folder of the client are empty tmpfs mounts: the worker has its own home, cache and
working folder, and the wheel's immersim.
"""
from __future__ import annotations

import os
import shlex
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Sequence, Tuple

ROOT = Path(__file__).resolve().parents[2]


def build_dists(dest: Path) -> Tuple[Path, Path]:
    """Build the sdist of the checkout and the wheel from that sdist into ``dest``."""
    dest.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "build", "-q", "--outdir", str(dest), str(ROOT)], check=True,
                   capture_output=True, text=True)
    return next(dest.glob("immersim-*.tar.gz")), next(dest.glob("immersim-*.whl"))


@dataclass
class WheelEnv:
    """A virtual environment holding immersim from a wheel (``root/venv``)."""

    root: Path
    deps: Path  # the third-party packages (site-packages of the interpreter that made it)

    @property
    def python(self) -> Path:
        return self.root / "venv" / "bin" / "python"

    @property
    def immersim(self) -> Path:
        return self.root / "venv" / "bin" / "immersim"

    @property
    def deps_mount(self) -> Path:
        """Where an isolated worker sees ``deps`` (a bind mount; see :class:`IsolatedWorker`)."""
        return self.root / "deps"

    def env(self, home: Path) -> Dict[str, str]:
        """A clean environment: ``home`` as HOME, its ``.cache`` as the cache folder, no
        PYTHONPATH, no IMMERSIM_BUILD_DIR."""
        return {"PATH": f"{self.python.parent}:/usr/bin:/bin", "HOME": str(home), "XDG_CACHE_HOME": str(home / ".cache"),
                "LANG": "C.UTF-8", "PYTHONNOUSERSITE": "1"}


def make_wheel_env(root: Path, wheel: Path) -> WheelEnv:
    """Install ``wheel`` (no dependencies) into a new venv ``root/venv``."""
    root.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(root / "venv")], check=True)
    deps = Path(sysconfig.get_paths()["purelib"])
    env = WheelEnv(root, deps)
    env.deps_mount.mkdir(exist_ok=True)
    site = subprocess.run([str(env.python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()
    # the isolated worker's view first (empty outside it), then the interpreter's own folder
    Path(site, "zz_third_party.pth").write_text(f"{env.deps_mount}\n{deps}\n")
    subprocess.run([sys.executable, "-m", "pip", "--python", str(env.python), "install", "-q", "--no-deps",
                    "--no-index", str(wheel)], check=True, capture_output=True, text=True)
    return env


def hidden_paths(extra: Sequence[Path] = ()) -> List[Path]:
    """The client's folders a worker must not see: the checkout, the temporary folder, the
    user's cache folder, and ``extra``."""
    out = [ROOT, Path(tempfile.gettempdir()), Path.home() / ".cache", *map(Path, extra)]
    return [p.resolve() for p in out if p.exists()]


class IsolatedWorker:
    """``dask worker ADDRESS`` from ``env``, in a mount namespace without ``hidden_paths()``.

    ``folder`` (outside every hidden path) becomes the worker's home, cache and working
    folder. Stop it with :meth:`stop` (or use it as a context manager).
    """

    def __init__(self, env: WheelEnv, address: str, folder: Path, nworkers: int = 1,
                 hide: Sequence[Path] = ()) -> None:
        self.folder = folder
        home = folder / "home"
        (home / ".cache").mkdir(parents=True, exist_ok=True)
        hidden = hidden_paths(hide)
        for p in (env.root, folder):
            if any(p.resolve().is_relative_to(h) for h in hidden):
                raise ValueError(f"{p} lies in a folder the worker must not see")
        mounts = [f"mount --bind {shlex.quote(str(env.deps))} {shlex.quote(str(env.deps_mount))}"]
        mounts += [f"mount -t tmpfs tmpfs {shlex.quote(str(h))}" for h in hidden]
        worker = [str(env.python), "-m", "distributed.cli.dask_worker", address, "--nworkers", str(nworkers),
                  "--nthreads", "1", "--no-dashboard", "--local-directory", str(folder / "dask"),
                  "--name", folder.name]
        script = " && ".join(mounts + [f"cd {shlex.quote(str(home))}", "exec " + shlex.join(worker)])
        unshare = ["unshare", "--mount", "--propagation", "private"]
        if os.geteuid() != 0:
            unshare[1:1] = ["--user", "--map-root-user"]
        self.log = open(folder / "worker.log", "wb")
        self.proc = subprocess.Popen(unshare + ["sh", "-c", script], env=env.env(home), stdout=self.log,
                                     stderr=subprocess.STDOUT, start_new_session=True)

    def stop(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, 15)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, 9)
                self.proc.wait()
        self.log.close()

    def __enter__(self) -> "IsolatedWorker":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def worker_view(paths: Sequence[str]) -> Dict[str, object]:
    """Run on a worker (``client.run``): which of ``paths`` it sees (a non-empty folder or a
    file), where its immersim comes from, its cache folder."""
    import immersim.orchestrator
    from immersim.orchestrator.build import user_cache_dir

    seen = {p: os.path.isfile(p) or (os.path.isdir(p) and bool(os.listdir(p))) for p in paths}
    return {"sees": seen, "immersim": immersim.orchestrator.__file__, "cache": str(user_cache_dir()),
            "cwd": os.getcwd()}


def wait_for_workers(client, n: int, proc_checks: Sequence[IsolatedWorker], timeout: float = 120) -> None:
    """Wait until ``n`` workers joined; raise with the worker log if a worker process ended."""
    t_end = time.monotonic() + timeout
    while len(client.scheduler_info()["workers"]) < n:
        for w in proc_checks:
            if w.proc.poll() is not None:
                w.log.flush()
                raise RuntimeError(f"isolated worker ended ({w.proc.returncode}): "
                                   f"{(w.folder / 'worker.log').read_text()[-2000:]}")
        if time.monotonic() > t_end:
            raise TimeoutError(f"{n} workers did not join within {timeout} s")
        time.sleep(0.2)


#: the records that carry a log's content; chunks, message indexes, statistics and summary
#: offsets only say where they lie (MCAP spec), and the writer cuts chunks on wall-clock time
#: (observers.McapObserver: flushed every second), so two runs of one scenario differ there,
#: and in where a metadata record written between two chunks falls among the messages
CONTENT_RECORDS = ("Header", "Schema", "Channel", "Message", "Metadata", "Attachment")


def log_records(path: Path) -> Tuple[List[tuple], List[tuple]]:
    """The content of an MCAP file: its non-message content records in file order (header,
    schemas, channels, metadata, attachments) and its messages in file order, each as (record
    type, its fields): channel, sequence, log and publish time, data bytes."""
    from dataclasses import astuple

    from mcap.stream_reader import StreamReader

    with open(path, "rb") as fh:
        recs = [(type(r).__name__, astuple(r)) for r in StreamReader(fh, emit_chunks=False).records
                if type(r).__name__ in CONTENT_RECORDS]
    return [r for r in recs if r[0] != "Message"], [r for r in recs if r[0] == "Message"]


def scratch_dir(prefix: str) -> Path:
    """A fresh folder outside the checkout and outside the temporary folder (the isolated
    workers hide both), removed by :func:`remove`."""
    base = Path("/var/tmp") if Path("/var/tmp").is_dir() else Path.home()
    return Path(tempfile.mkdtemp(prefix=prefix, dir=base))


def remove(folder: Path) -> None:
    shutil.rmtree(folder, ignore_errors=True)

"""What a sweep run ships to a Dask worker: FMUs stored by content, a scenario rebuilt from
its text under the client's names."""
from __future__ import annotations

import hashlib
import shutil

import pytest

from immersim.orchestrator.sweep.runs import RunTask
from immersim.orchestrator.sweep.shipping import attach_inputs, shipped_scenario, store_fmus
from immersim.orchestrator.system import check_system

from .helpers import oscillator_scenario


def test_fmus_are_stored_once_under_their_hash_and_checked(tmp_path):
    data = b"not really an FMU"
    digest = hashlib.sha256(data).hexdigest()
    first = store_fmus({digest: data}, tmp_path)
    assert first == {digest: tmp_path / f"{digest}.fmu"} and first[digest].read_bytes() == data
    mtime = first[digest].stat().st_mtime_ns
    assert store_fmus({digest: data}, tmp_path) == first and first[digest].stat().st_mtime_ns == mtime
    bad = "0" * 64
    with pytest.raises(ValueError, match=r"^shipped FMU 000000000000: the bytes received hash to "
                                         + hashlib.sha256(data).hexdigest()[:12] + "$"):
        store_fmus({bad: data}, tmp_path)
    assert not (tmp_path / f"{bad}.fmu").exists() and not list(tmp_path.glob("*.part"))


def test_a_shipped_scenario_loads_local_copies_under_the_clients_names(tmp_path, test_fmus):
    fmu = shutil.copyfile(test_fmus["oscillator"], tmp_path / "osc.fmu")
    scenario = oscillator_scenario(tmp_path, fmu, stop=0.1)
    shutil.copyfile(fmu, tmp_path / "other.fmu")
    task = RunTask(str(scenario), {"m2:fmu": "other.fmu", "m1.x0": 2.0}, str(tmp_path / "x.mcap"), [])
    files, failed = attach_inputs([task], scenario)
    digest = hashlib.sha256(fmu.read_bytes()).hexdigest()
    assert failed == {} and list(files) == [digest]  # two files, one content: one to ship
    assert files[digest] in (fmu, tmp_path / "other.fmu")
    assert task.text == scenario.read_text()
    assert task.fmus == {"m1": (digest, str(fmu)), "m2": (digest, str(tmp_path / "other.fmu"))}

    elsewhere = store_fmus({digest: fmu.read_bytes()}, tmp_path / "worker")
    sc = shipped_scenario(task, elsewhere)
    assert sc.file == scenario and sc.text == task.text and sc.unit("m1").parameters["x0"] == 2.0
    system = check_system(sc)
    assert system.paths == {"m1": elsewhere[digest], "m2": elsewhere[digest]}
    assert (system.origin("m1"), system.origin("m2")) == (str(fmu), str(tmp_path / "other.fmu"))

    missing = RunTask(str(scenario), {"m1:fmu": str(tmp_path / "nowhere.fmu")}, "", [], index=3)
    _, failed = attach_inputs([missing], scenario)
    assert list(failed) == [3] and failed[3].startswith("FmuLoadError: unit m1: FMU ")

"""Corrupted copies of an FMU archive, one per way an FMU can fail to load, for the
boundary tests: each is refused at load with one line naming the unit and what is wrong."""
from __future__ import annotations

import re
import zipfile
from pathlib import Path
from typing import Callable, Dict

#: case -> (edit of {member name: bytes}, regex the error line must match)
Edit = Callable[[Dict[str, bytes]], Dict[str, bytes]]


def _model_identifier(files: Dict[str, bytes]) -> str:
    return re.search(rb'modelIdentifier="([^"]+)"', files["modelDescription.xml"]).group(1).decode()


def platform_folder(files: Dict[str, bytes]) -> str:
    """``binaries/`` folder of this platform for the archive's FMI version."""
    return "x86_64-linux" if b'fmiVersion="3' in files["modelDescription.xml"] else "linux64"


def _without(prefix: str) -> Edit:
    return lambda f: {k: v for k, v in f.items() if not k.startswith(prefix)}


def _without_platform(f: Dict[str, bytes]) -> Dict[str, bytes]:
    return _without(f"binaries/{platform_folder(f)}/")(f)


def _garbage_binary(f: Dict[str, bytes]) -> Dict[str, bytes]:
    f = dict(f)
    f[f"binaries/{platform_folder(f)}/{_model_identifier(f)}.so"] = b"\x7fELF" + bytes(range(256)) * 8
    return f


def _empty_binary(f: Dict[str, bytes]) -> Dict[str, bytes]:
    f = dict(f)
    f[f"binaries/{platform_folder(f)}/{_model_identifier(f)}.so"] = b""
    return f


def _text_binary(f: Dict[str, bytes]) -> Dict[str, bytes]:
    f = dict(f)
    f[f"binaries/{platform_folder(f)}/{_model_identifier(f)}.so"] = b"not a shared library\n"
    return f


def _rename_identifier(f: Dict[str, bytes]) -> Dict[str, bytes]:
    f = dict(f)
    mid = _model_identifier(f).encode()
    f["modelDescription.xml"] = f["modelDescription.xml"].replace(b'modelIdentifier="' + mid + b'"',
                                                                  b'modelIdentifier="no_such_binary"')
    return f


def _bad_xml(f: Dict[str, bytes]) -> Dict[str, bytes]:
    f = dict(f)
    f["modelDescription.xml"] = f["modelDescription.xml"][:200]
    return f


def _empty_slavemodule(f: Dict[str, bytes]) -> Dict[str, bytes]:
    f = dict(f)
    f["resources/slavemodule.txt"] = b""
    return f


def _wrong_slavemodule(f: Dict[str, bytes]) -> Dict[str, bytes]:
    f = dict(f)
    f["resources/slavemodule.txt"] = b"no_such_module"
    return f


def _without_slave_code(f: Dict[str, bytes]) -> Dict[str, bytes]:
    module = f["resources/slavemodule.txt"].decode().strip()
    return {k: v for k, v in f.items() if k != f"resources/{module}.py"}


#: every archive case: (edit, expected message); the pythonfmu ones apply to our FMUs only
CASES: Dict[str, tuple] = {
    "no binary for this platform": (_without_platform, r"has no binary for (linux64|x86_64-linux)"),
    "no binaries at all": (_without("binaries/"), r"has no binary for (linux64|x86_64-linux).*platforms: none"),
    "wrong modelIdentifier": (_rename_identifier, r"has no binary for .*no_such_binary"),
    "garbage binary": (_garbage_binary, r"cannot load the binary .*(ELF|invalid)"),
    "empty binary": (_empty_binary, r"cannot load the binary .*file too short"),
    "text binary": (_text_binary, r"cannot load the binary .*(invalid ELF header|file too short)"),
    "truncated modelDescription.xml": (_bad_xml, r"modelDescription.xml"),
    "no modelDescription.xml": (_without("modelDescription.xml"), r"modelDescription.xml"),
}
PYTHONFMU_CASES: Dict[str, tuple] = {
    "no slavemodule.txt": (_without("resources/slavemodule.txt"), r"resources/slavemodule.txt is missing"),
    "empty slavemodule.txt": (_empty_slavemodule, r"resources/slavemodule.txt names no module"),
    "slavemodule.txt names a missing module": (_wrong_slavemodule,
                                               r"resources/no_such_module.py is missing"),
    "slave code missing": (_without_slave_code, r"resources/.*\.py is missing"),
    "no resources": (_without("resources/"), r"resources/slavemodule.txt is missing"),
}


def corrupt(src: Path, dest: Path, edit: Edit) -> Path:
    """Write ``dest``: the archive ``src`` with ``edit`` applied to its members."""
    with zipfile.ZipFile(src) as z:
        files = {i.filename: z.read(i) for i in z.infolist() if not i.is_dir()}
    files = edit(files)
    with zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in files.items():
            z.writestr(name, data)
    return dest


def truncated(src: Path, dest: Path, keep: float = 0.5) -> Path:
    """The first ``keep`` of ``src``'s bytes (a download cut short)."""
    data = src.read_bytes()
    dest.write_bytes(data[:int(len(data) * keep)])
    return dest

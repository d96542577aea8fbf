"""Map the top-level folders onto the ``immersim`` namespace.

``models/`` installs as ``immersim.models``, ``orchestrator/`` as ``immersim.orchestrator``
and ``fmus/`` as ``immersim.fmus`` so that a user never gets a generic ``import models``.
Every folder below them is a package, also those without ``__init__.py`` (the unit folders
``fmus/<unit>/`` with their wrapper scripts), and ``scenarios/`` installs as
``immersim.scenarios`` (the example scenarios of ``immersim examples``): an installed wheel
builds and runs every built-in unit and shipped scenario. ``api/`` is the package ``immersim``
itself: the public Python API (``immersim.run``, ``immersim.read_log``).
"""
from pathlib import Path

from setuptools import setup

TOP = ("models", "orchestrator", "fmus", "scenarios")
HERE = Path(__file__).parent
DATA = ["*.md", "*.json", "*.csv", "*.toml", "*.txt", "*.c", "*.h"]

packages = ["immersim"]
for top in TOP:
    for folder in sorted([HERE / top] + [p for p in (HERE / top).rglob("*") if p.is_dir()]):
        rel = folder.relative_to(HERE)
        if not any(part.startswith((".", "__")) for part in rel.parts):
            packages.append("immersim." + ".".join(rel.parts))

setup(
    packages=packages,
    package_dir={"immersim": "api", **{f"immersim.{t}": t for t in TOP}},
    package_data={p: DATA for p in packages},
    include_package_data=True,
)

"""Map the top-level folders onto the ``immersim`` namespace.

``models/`` installs as ``immersim.models``, ``orchestrator/`` as ``immersim.orchestrator``
and ``fmus/`` as ``immersim.fmus`` so that a user never gets a generic ``import models``.
``api/`` is the package ``immersim`` itself: the public Python API (``immersim.run``,
``immersim.read_log``).
"""
from pathlib import Path

from setuptools import setup

TOP = ("models", "orchestrator", "fmus")
HERE = Path(__file__).parent

packages = ["immersim"]
for top in TOP:
    for init in sorted((HERE / top).rglob("__init__.py")):
        rel = init.parent.relative_to(HERE)
        packages.append("immersim." + ".".join(rel.parts))

setup(
    packages=packages,
    package_dir={"immersim": "api", **{f"immersim.{t}": t for t in TOP}},
    package_data={f"immersim.{t}": ["**/*.md", "**/*.json", "**/*.csv", "**/*.toml", "**/*.txt"] for t in TOP},
    include_package_data=True,
)

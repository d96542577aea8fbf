"""SSP 1.0 (System Structure and Parameterization): run an ``.ssp`` file, export a scenario as one.

* :func:`~.reader.load_ssp` reads an SSP archive into a
  :class:`~immersim.orchestrator.scenario.Scenario`: the SSD's components and connectors,
  connections with linear transformations, parameter bindings (``.ssv`` files or inline
  values), the ``DefaultExperiment`` (and OSP's fixed-step base step size); nested systems are
  flattened (a component ``c`` of subsystem ``s`` becomes unit ``s-c``); what it cannot run
  (signal dictionaries, parameter mappings, non-linear transformations, non-FMU components)
  is refused with one line naming the file and element.
* :func:`~.writer.export_ssp` writes a scenario as an SSP: each FMU once under
  ``resources/``, one ``.ssv`` per unit with parameters, the connections with their gain and
  offset as linear transformations, the default experiment with OSP's fixed-step algorithm
  annotation. What SSP cannot say (scenario inputs, faults, extrapolation, delayed
  connections, worker processes, the log selection, the 3D view) travels as the scenario file
  itself (``resources/immersim/scenario.toml``, named by an ``org.immersim.scenario``
  annotation), so ``immersim run`` of the export logs what the scenario logs, bit for bit; the
  scenario inputs also become a signal-source FMU (:mod:`.source`) connected to their targets,
  so another tool running the SSP gets them too.
"""
from .reader import load_ssp
from .writer import export_ssp

__all__ = ["export_ssp", "load_ssp"]

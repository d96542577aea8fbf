"""What the master algorithm needs of a unit instance, wherever it runs.

:class:`~immersim.orchestrator.fmu.FmuInstance` (an FMU loaded in this process) and
:class:`~immersim.orchestrator.transport.RemoteInstance` (one loaded by a worker process) both
implement :class:`Instance`; a worker instance also implements :class:`WorkerStepping`, the
calls that let its worker step it ahead of the master (``Master._ahead``).
"""
from __future__ import annotations

from typing import Any, Dict, List, Optional, Protocol, Sequence, runtime_checkable


@runtime_checkable
class Instance(Protocol):
    """One unit instance. Times in ns; values in the order of the names asked for.

    ``reader(names)`` returns an object whose ``read()`` gives the values of ``names``;
    ``real_setter(names)`` / ``discrete_setter(names)`` one whose ``set(values)`` sets them.
    ``remote`` says whether the unit runs in a worker process (:class:`WorkerStepping`).
    """

    name: str
    remote: bool
    t_ns: int

    def var(self, name: str) -> Any: ...

    def initialize(self, start_ns: int, stop_ns: Optional[int], parameters: Dict[str, Any],
                   tolerance: Optional[float] = None) -> None: ...

    def do_step(self, t_ns: int, h_ns: int) -> None: ...

    def set_values(self, values: Dict[str, Any]) -> None: ...

    def get_values(self, names: Sequence[str]) -> List[Any]: ...

    def reader(self, names: Sequence[str], check_finite: bool = False) -> Any: ...

    def real_setter(self, names: Sequence[str]) -> Any: ...

    def discrete_setter(self, names: Sequence[str]) -> Any: ...

    def terminate(self) -> None: ...


@runtime_checkable
class WorkerStepping(Instance, Protocol):
    """A unit in a worker process: its calls are queued and sent as one message (``post``,
    ``sync``); a unit its worker steps itself is set up once (``setup_stepping``), posted a
    step at a time (``post_step``, two in flight when it ``queues``) and caught up at the end
    (``finish_stepping``, returning the steps it skipped lazily)."""

    worker: Any
    queues: bool

    def post(self, read: bool = True, hold: bool = False) -> None: ...

    def sync(self) -> None: ...

    def post_step(self, t_ns: int, h_ns: int, inputs: Optional[tuple], hold: bool = False) -> None: ...

    def setup_stepping(self, spec: Dict[str, Any]) -> None: ...

    def finish_stepping(self) -> int: ...

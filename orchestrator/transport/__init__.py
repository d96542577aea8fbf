"""Units in worker processes: the processes, the pipes and shared memory to them, and the
:class:`RemoteInstance` through which the master steps such a unit.

pythonfmu FMUs run their Python code under the loading process's one GIL, so two of them step
at once only in two processes: a unit given ``process = N`` is loaded by worker process N.
"""
from .instance import RemoteInstance, RemoteReader, RemoteSetter
from .process import RemoteConfig, WorkerProcess

__all__ = ["RemoteConfig", "RemoteInstance", "RemoteReader", "RemoteSetter", "WorkerProcess"]

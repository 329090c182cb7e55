"""FMU instances kept between the runs of one process (a sweep's worker runs hundreds).

Loading an FMU's library through fmpy (``FMU2Slave``: ``dlopen`` and one ctypes prototype per FMI
function) and instantiating it costs about as much as a short run's stepping. A
:class:`SlavePool` keeps each instance when its run ends and hands it to the next run of the same
FMU after ``fmi2Reset`` (``fmi3Reset``), which the next run follows with its own start values and
initialisation: the standard way to run an FMU again with other parameters. A reset is only as
good as the FMU's: the pool keeps only the instances that ``reusable`` accepts (an FMU whose reset
is known to restore the state after instantiation); it closes the others, and any instance
whose run ended in a fatal status or an unexpected exception, as a run without a pool would.
"""
from __future__ import annotations

import threading

from .slave import CoSimulationError

__all__ = ["SlavePool"]


class SlavePool:
    """Idle instances by (class, FMU, instance name, unpacked folder).

    ``reusable(slave)``: whether ``slave``'s FMU resets completely. ``created`` and ``reused``
    count the instances made and the resets done."""

    def __init__(self, reusable):
        self.reusable = reusable
        self.created = self.reused = 0
        self._idle: dict = {}
        self._lock = threading.Lock()        # a dask worker with several threads shares it

    def acquire(self, unit, path, name: str, start_values: dict, unzipdir=None):
        """An instance of ``unit`` (:class:`~orchestration.cosim.slave.Slave` or a subclass) for
        the FMU at ``path``, ready for ``initialize`` with ``start_values``: an idle one reset,
        or a new one."""
        key = (unit, str(path), name, None if unzipdir is None else str(unzipdir))
        with self._lock:
            idle = self._idle.get(key)
            slave = idle.pop() if idle else None
        if slave is not None:
            try:
                slave.reset(start_values)
                self.reused += 1
                return slave
            except CoSimulationError:
                slave.close()
        slave = unit(path, name, start_values, unzipdir=unzipdir)
        slave.pool_key = key
        self.created += 1
        return slave

    def release(self, slave, reuse: bool = True):
        """Keep ``slave`` for the next run of its FMU (``reuse`` and its FMU resets completely),
        else close it."""
        key = getattr(slave, "pool_key", None)
        if not reuse or key is None or slave.fmu is None or not self.reusable(slave):
            slave.close()
            return
        with self._lock:
            self._idle.setdefault(key, []).append(slave)

    def close(self):
        """Close every idle instance (``freeInstance``, the library unloaded)."""
        with self._lock:
            idle, self._idle = self._idle, {}
        for slaves in idle.values():
            for s in slaves:
                s.close()

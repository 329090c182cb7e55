"""The dask worker plugin of :class:`~orchestration.sweeps.executor.DaskExecutor`, apart so that
dask is imported only where a dask executor opens (importing it costs about 0.6 s)."""
from __future__ import annotations

import os
import sys
from pathlib import Path

from distributed.diagnostics.plugin import WorkerPlugin

__all__ = ["Setup", "WORKER_FILES"]

#: name -> path of the files the plugin wrote into this worker process's folder
#: (:func:`orchestration.sweeps.executor.worker_file` reads it)
WORKER_FILES: dict[str, str] = {}


class Setup(WorkerPlugin):
    """Worker plugin: put ``paths`` first on ``sys.path``, write ``files`` (name -> bytes) into
    the worker's local folder (see :func:`~orchestration.sweeps.executor.worker_file`), and (a
    LocalCluster's workers) ignore Ctrl-C."""

    name = "flexpend-setup"

    def __init__(self, paths, files, ignore_sigint=False):
        self.paths, self.files = list(paths), dict(files)
        self.ignore_sigint = ignore_sigint

    def setup(self, worker):
        if self.ignore_sigint:
            # a LocalCluster's workers share the client's terminal: Ctrl-C is the client's to
            # handle (it keeps what finished and closes the cluster), not theirs to die of
            import signal
            try:
                signal.signal(signal.SIGINT, signal.SIG_IGN)
            except ValueError:              # not the main thread: leave it
                pass
        for p in reversed(self.paths):
            if p not in sys.path:
                sys.path.insert(0, p)
        folder = Path(worker.local_directory) / "flexpend-files"
        folder.mkdir(parents=True, exist_ok=True)
        for name, data in self.files.items():
            target = folder / name
            if not target.is_file():
                part = target.with_suffix(target.suffix + ".part")
                part.write_bytes(data)
                os.replace(part, target)
            WORKER_FILES[name] = str(target)

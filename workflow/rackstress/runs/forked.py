"""Work in a forked child process while this one goes on (the machine's other core): the VTK
series beside the pictures (:class:`rackstress.stress.export.VtkJob`), the plots beside the
sheet (:mod:`rackstress.render.pictures`).

The child hands its result back as JSON in a file and ends with ``os._exit`` (nothing of the
parent's — its atexit hooks, its run directory's lock — runs twice). Where fork is not
available, the work runs in this process at :meth:`ForkedJob.join`.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

from rackstress.errors import EXIT_STORAGE, StorageError
from rackstress.runs.rundir import in_forked_child


class ForkedError(Exception):
    """The child's error, handed to the parent: its message, whether it was a
    :class:`~rackstress.errors.StorageError`, its ``errno`` if any, and the child's exit code
    when it left no result (``EXIT_STORAGE``: it could not write one)."""

    def __init__(self, message: str, storage: bool = False, errno: int | None = None,
                 exitcode: int | None = None):
        super().__init__(message)
        self.message, self.storage, self.errno, self.exitcode = message, storage, errno, exitcode


class ForkedJob:
    """``work()`` (returning something JSON can hold) in a forked child; :meth:`join` returns
    it, or raises :class:`ForkedError`. Without fork, :meth:`join` runs ``work`` here (its
    errors as they are). After :meth:`join`, :attr:`cpu_s` is the CPU time the child took
    (a forked child's CPU clock starts at zero; None without fork), so that a run's timings
    say what each process cost, not only how long it was awaited.

    Example
    -------
    >>> import tempfile
    >>> job = ForkedJob(lambda: {"n": 2}, Path(tempfile.mkdtemp()) / "job.json")
    >>> job.join()
    {'n': 2}
    """

    def __init__(self, work, result):
        import multiprocessing as mp

        self.work, self.result = work, Path(result)
        self.proc, self.parent, self.cpu_s = None, os.getpid(), None
        if "fork" in mp.get_all_start_methods():
            import gc

            self.proc = mp.get_context("fork").Process(target=self._child, daemon=True)
            gc.freeze()                  # the objects so far: no collection walks them in the
            try:                         # child, whose pages then stay shared (copy on write)
                self.proc.start()
            finally:
                gc.unfreeze()

    def _child(self):
        import gc

        gc.disable()                     # a short life: no collection touches the parent's
        in_forked_child(self.parent)     # pages; the run directory's lock stays the parent's
        try:
            rec = {"value": self.work()}
        except BaseException as exc:  # noqa: BLE001 - handed to the parent
            rec = {"error": f"{type(exc).__name__}: {exc}",
                   "storage": isinstance(exc, StorageError),
                   "errno": getattr(exc, "errno", None)}
        import time

        rec["cpu_s"] = time.process_time()
        try:
            self.result.write_text(json.dumps(rec))
        except OSError:      # a full disk: the parent learns it from the exit status
            os._exit(EXIT_STORAGE)
        os._exit(0)

    def join(self):
        if self.proc is None:
            self.result.unlink(missing_ok=True)
            return self.work()
        self.proc.join()
        try:
            rec = json.loads(self.result.read_text())
        except (OSError, json.JSONDecodeError):
            self.result.unlink(missing_ok=True)
            raise ForkedError(f"ended with exit code {self.proc.exitcode}",
                              exitcode=self.proc.exitcode) from None
        self.result.unlink(missing_ok=True)
        self.cpu_s = rec.get("cpu_s")
        if "error" in rec:
            raise ForkedError(rec["error"], rec["storage"], rec["errno"])
        return rec["value"]

    def kill(self):
        if self.proc is not None and self.proc.is_alive():
            self.proc.kill()
            self.proc.join()
        self.result.unlink(missing_ok=True)

"""Work in a forked child process while this one goes on (the machine's other core): the VTK
series beside the pictures (:class:`rackstress.stress.export.VtkJob`), the plots beside the
sheet (:mod:`rackstress.render.pictures`).

The child hands its result back as JSON in a file and ends with ``os._exit`` (nothing of the
parent's — its atexit hooks, its run directory's lock — runs twice). Where fork is not
available, the work runs in this process at :meth:`ForkedJob.join`.
"""
from __future__ import annotations

import atexit
import json
import os
import signal
import sys
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


_LIVE: set[int] = set()            # forked children not yet reaped: killed at this one's exit


@atexit.register
def _kill_live() -> None:
    for pid in list(_LIVE):
        try:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        except OSError:
            pass
    _LIVE.clear()


class ForkedJob:
    """``work()`` (returning something JSON can hold) in a forked child; :meth:`join` returns
    it, or raises :class:`ForkedError`. Without fork, :meth:`join` runs ``work`` here (its
    errors as they are). After :meth:`join`, :attr:`cpu_s` is the CPU time the kernel charged
    the child, from ``wait4`` (its writing of the result and its exit included; None without
    fork), so that a run's timings say what each process cost, not only how long it was
    awaited. A child not joined is killed when this process exits.

    Example
    -------
    >>> import tempfile
    >>> tmp = tempfile.TemporaryDirectory()
    >>> job = ForkedJob(lambda: {"n": 2}, Path(tmp.name) / "job.json")
    >>> job.join()
    {'n': 2}
    >>> tmp.cleanup()
    """

    def __init__(self, work, result):
        self.work, self.result = work, Path(result)
        self.pid, self.parent, self.cpu_s = None, os.getpid(), None
        if hasattr(os, "fork") and hasattr(os, "wait4"):
            import gc

            gc.freeze()                  # the objects so far: no collection walks them in the
            try:                         # child, whose pages then stay shared (copy on write)
                pid = os.fork()
            finally:
                if os.getpid() == self.parent:
                    gc.unfreeze()
            if pid == 0:
                self._child()            # never returns
            self.pid = pid
            _LIVE.add(pid)

    def _child(self):
        code = 1                         # anything unforeseen: the parent sees exit code 1
        try:
            import gc

            gc.disable()                 # a short life: no collection touches the parent's
            in_forked_child(self.parent)  # pages; the run directory's lock stays the parent's
            try:
                rec = {"value": self.work()}
            except BaseException as exc:  # noqa: BLE001 - handed to the parent
                rec = {"error": f"{type(exc).__name__}: {exc}",
                       "storage": isinstance(exc, StorageError),
                       "errno": getattr(exc, "errno", None)}
            try:
                self.result.write_text(json.dumps(rec))
                code = 0
            except OSError:              # a full disk: the parent learns it from the exit status
                code = EXIT_STORAGE
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(code)

    def _reap(self) -> int | None:
        """Wait for the child; its exit code, and :attr:`cpu_s` from its resource usage (None
        for both if something else in this process reaped it: a ``waitpid(-1)``)."""
        try:
            _, status, usage = os.wait4(self.pid, 0)
        except ChildProcessError:
            return None
        finally:
            _LIVE.discard(self.pid)
        self.cpu_s = usage.ru_utime + usage.ru_stime
        return os.waitstatus_to_exitcode(status)

    def join(self):
        if self.pid is None:
            self.result.unlink(missing_ok=True)
            return self.work()
        exitcode = self._reap()
        try:
            rec = json.loads(self.result.read_text())
        except (OSError, json.JSONDecodeError):
            self.result.unlink(missing_ok=True)
            raise ForkedError(f"ended with exit code {exitcode}", exitcode=exitcode) from None
        self.result.unlink(missing_ok=True)
        if "error" in rec:
            raise ForkedError(rec["error"], rec["storage"], rec["errno"])
        return rec["value"]

    def kill(self):
        if self.pid is not None and self.pid in _LIVE:
            try:
                os.kill(self.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self._reap()
        self.result.unlink(missing_ok=True)

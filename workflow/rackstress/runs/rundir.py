"""One writer per run directory, and what a run directory may be reused for.

**The lock.** :func:`locked` takes an exclusive ``flock`` on ``RUNDIR/.lock`` before anything
else is written and holds it until the command is done (``rackstress run`` holds it through
post-processing and render; ``render`` and ``--resume`` take it too). The lock file records the
holder — pid, host, command line, start time — so a second command on the same directory exits
with status 2 naming it. The kernel releases an ``flock`` when its process dies, so a killed run
never blocks the next one; the lock file it leaves behind (a clean release removes it) is
recognized as stale — its process no longer exists — and reported.

**Reuse.** :func:`claim` decides what a new run may do with an existing directory: an empty or
new directory is used; a finished run (``summary.json``) or a run that did not finish (killed:
``scene.json`` without ``summary.json``) is refused unless ``--overwrite`` (or ``--resume`` for
the latter); a non-empty directory holding no run is refused always (``--overwrite`` deletes
only run directories). ``--overwrite`` starts clean: the old run directory is renamed aside in
one step (``os.replace``) and then deleted, so a kill at any moment leaves the old run whole or
nothing of it; leftovers of such a kill are removed by the next claim.
"""
from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import shutil
import socket
import sys
import time
from pathlib import Path

from rackstress.errors import RunDirError, storage_error

LOCK = ".lock"
#: Files whose presence makes a directory a run directory (written by ``rackstress run``).
MARKERS = ("scene.json", "summary.json", "progress.json")

_held: dict[str, list] = {}     # resolved path -> [fd, depth]: re-entrant within a process


def _command_line() -> str:
    return " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]) if sys.argv else "python"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def holder(rundir: Path) -> dict | None:
    """The holder record in ``RUNDIR/.lock`` (None if there is none or it is unreadable)."""
    try:
        text = (Path(rundir) / LOCK).read_text()
        return json.loads(text) if text.strip() else None
    except (OSError, ValueError):
        return None


def describe_holder(rec: dict | None) -> str:
    if not rec:
        return "another process"
    return (f"pid {rec.get('pid')} on {rec.get('host')} since {rec.get('started')} "
            f"('{rec.get('command')}')")


def stale_note(rec: dict | None) -> str | None:
    """A note on a holder record left by a process that died without releasing the lock."""
    if not rec or rec.get("host") != socket.gethostname():
        return None
    pid = int(rec.get("pid", 0) or 0)
    if pid and pid != os.getpid() and not _pid_alive(pid):
        return (f"the previous command on this directory, pid {pid} ('{rec.get('command')}', "
                f"started {rec.get('started')}), ended without releasing it (killed?)")
    return None


def in_forked_child(parent: int) -> None:
    """Call first in a process forked while a lock is held (the pictures' plot process): close
    its copies of the lock files, so the lock ends with the process that took it — a copy would
    keep the ``flock`` alive after that process is killed — and die with the parent (Linux:
    ``PR_SET_PDEATHSIG``), so nothing goes on writing into a run directory nobody holds."""
    for fd, _ in list(_held.values()):
        try:
            os.close(fd)            # never LOCK_UN: that would release the parent's lock too
        except OSError:
            pass
    _held.clear()
    try:
        import ctypes
        import signal

        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL), 0, 0, 0)  # PDEATHSIG
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:     # the parent (pid ``parent``) died before prctl took effect
        os._exit(1)


@contextlib.contextmanager
def locked(rundir, command: str | None = None, comm=None, create: bool = True, notes=None):
    """Hold the exclusive lock of a run directory for the duration of a ``with`` block.

    Parameters
    ----------
    rundir : path
        The run directory (created if missing and ``create``).
    command : str, optional
        What the holder does (default: this process's command line).
    comm : mpi4py communicator, optional
        Under MPI only its rank 0 takes the lock; every rank raises the same error.
    notes : list, optional
        Receives a note when a stale holder (a dead process) is found.

    Raises
    ------
    RunDirError
        The directory is held by another process (the message names it), or cannot be created.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp()) / "run"
    >>> with locked(d):
    ...     (d / "scene.json").write_text("{}")
    2
    """
    from rackstress.lib.mpi import on_root

    rundir = Path(rundir)
    check_out(rundir)
    key = str(rundir.resolve())

    def acquire():
        if key in _held:
            _held[key][1] += 1
            return
        if create:
            try:
                rundir.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise storage_error(exc, "create the run directory") from None
        elif not rundir.is_dir():     # a command on an existing run: bad input, not the disk
            raise RunDirError(f"{rundir} is not a run directory (it does not exist)")
        fd = _take(rundir)
        old = holder(rundir)
        note = stale_note(old)
        if note:
            if notes is not None:
                notes.append(note)
            else:
                sys.stderr.write(f"rackstress: note: {note}\n")
        rec = {"pid": os.getpid(), "host": socket.gethostname(),
               "command": command or _command_line(),
               "started": time.strftime("%Y-%m-%dT%H:%M:%S")}
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, (json.dumps(rec) + "\n").encode(), 0)
        except OSError:
            pass      # a full disk: the lock holds all the same, unnamed
        _held[key] = [fd, 1]

    def release():
        ent = _held.get(key)
        if ent is None:
            return
        ent[1] -= 1
        if ent[1] == 0:
            del _held[key]
            # a clean release leaves no lock file (a killed holder leaves its record behind);
            # unlinked while still held, so a waiter never locks a file that is gone (_take)
            with contextlib.suppress(OSError):
                os.unlink(rundir / LOCK)
            os.close(ent[0])

    on_root(acquire, comm)
    try:
        yield rundir
    finally:
        if comm is None or comm.Get_rank() == 0:
            release()


def _take(rundir: Path) -> int:
    """Open and ``flock`` ``RUNDIR/.lock``; retry if the file was replaced meanwhile (a holder
    that released it unlinks it: a lock on the unlinked file would exclude nobody)."""
    path = rundir / LOCK
    for _ in range(100):
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise storage_error(exc, "create the lock file", path) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise RunDirError(f"run directory {rundir} is in use by "
                                  f"{describe_holder(holder(rundir))}; wait for it to finish, "
                                  "or choose another --out") from None
            raise storage_error(exc, "lock", path) from None
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)
    raise RunDirError(f"could not lock {path}: it keeps being replaced")


def check_out(out) -> Path:
    """Refuse an empty or blank ``--out`` (it would write into the working directory)."""
    if out is None or not str(out).strip():
        raise RunDirError("--out is empty: give a run directory (e.g. --out runs/mine)")
    return Path(out)


def is_run(rundir: Path) -> bool:
    return any((Path(rundir) / m).exists() for m in MARKERS)


def contents(rundir: Path) -> list[str]:
    try:
        return sorted(p.name for p in Path(rundir).iterdir() if p.name != LOCK)
    except FileNotFoundError:
        return []


def unfinished_step(rundir: Path) -> str:
    """How far a run that did not finish got: its checkpoint and its last frame."""
    rundir = Path(rundir)
    facts = []
    try:
        facts.append(f"checkpoint at step {json.loads((rundir / 'progress.json').read_text())['step']}")
    except (OSError, ValueError, KeyError):
        facts.append("no checkpoint")
    return ", ".join(facts)


def claim(rundir, overwrite: bool = False) -> Path:
    """Make ``rundir`` ready for a new run (the caller holds :func:`locked`); see the module.

    Raises
    ------
    RunDirError
        It holds a finished or an unfinished run and ``overwrite`` is not given, or it holds
        files that are not a run.
    """
    rundir = check_out(rundir)
    if rundir.exists() and not rundir.is_dir():
        raise RunDirError(f"run directory {rundir} exists and is not a directory")
    _remove_leftovers(rundir)
    names = contents(rundir)
    if not names:
        return rundir
    if not is_run(rundir):
        raise RunDirError(f"{rundir} is not empty ({', '.join(names[:5])}"
                          f"{', ...' if len(names) > 5 else ''}) and holds no run: choose an "
                          "empty or new --out (--overwrite replaces only run directories)")
    if not overwrite:
        if (rundir / "summary.json").exists():
            raise RunDirError(f"run directory {rundir} already holds a finished run "
                              "(summary.json); choose another --out or pass --overwrite to "
                              "replace it")
        raise RunDirError(f"run directory {rundir} holds a run that did not finish (killed? "
                          f"{unfinished_step(rundir)}): continue it with 'rackstress run "
                          f"--resume {rundir}' or replace it with --overwrite")
    _start_clean(rundir)
    return rundir


def _trash_name(rundir: Path) -> Path:
    return rundir.parent / f".{rundir.name}.old-{os.getpid()}"


def _start_clean(rundir: Path) -> None:
    """Everything of the earlier run goes: moved aside in one rename, then deleted.

    The lock file moves with it (this process keeps holding the moved one), so a new lock file
    is taken on the fresh directory at once."""
    trash = _trash_name(rundir)
    key = str(rundir.resolve())
    try:
        os.replace(rundir, trash)
        rundir.mkdir()
    except OSError as exc:
        raise storage_error(exc, "move aside the earlier run") from None
    ent = _held.get(key)
    if ent is not None:
        fd = _take(rundir)
        old_fd = ent[0]
        with contextlib.suppress(OSError):
            os.pwrite(fd, os.pread(old_fd, 4096, 0), 0)
        ent[0] = fd
        os.close(old_fd)
    shutil.rmtree(trash, ignore_errors=True)


def _remove_leftovers(rundir: Path) -> None:
    """Earlier runs moved aside by an --overwrite that was killed before deleting them."""
    parent = rundir.parent if str(rundir.parent) else Path(".")
    if not parent.is_dir():
        return
    for old in parent.glob(f".{rundir.name}.old-*"):
        try:
            pid = int(old.name.rsplit("-", 1)[1])
        except ValueError:
            continue
        if pid == os.getpid() or not _pid_alive(pid):
            shutil.rmtree(old, ignore_errors=True)
    remove_temporaries(rundir)


def remove_temporaries(rundir: Path) -> list[str]:
    """Remove the temporary files and folders of writers killed midway (atomic writes, renders,
    post-processing: hidden names with ``.tmp``); the caller holds :func:`locked`, so no live
    writer owns them. Returns their names."""
    rundir = Path(rundir)
    gone = []
    if rundir.is_dir():
        for tmp in rundir.glob(".*.tmp*"):
            if tmp.is_dir():
                shutil.rmtree(tmp, ignore_errors=True)
            else:
                tmp.unlink(missing_ok=True)
            gone.append(tmp.name)
    return gone

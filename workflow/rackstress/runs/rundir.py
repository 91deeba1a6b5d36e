"""One writer per run directory, and what a run directory may be reused for.

**The lock.** :func:`locked` takes an exclusive ``flock`` on ``RUNDIR/.lock`` before anything
else is written and holds it until the command is done (``rackstress run`` holds it through
post-processing and render; ``render`` and ``--resume`` take it too). The lock file records the
holder — pid, host, command line, start time — so a second command on the same directory exits
with status 2 naming it. The kernel releases an ``flock`` when its process dies, so a killed run
never blocks the next one; the lock file it leaves behind (a clean release removes it) is
recognized as stale — its process no longer exists — and reported.

**What a run owns.** A directory may hold the user's own files beside a run (the scene and its
STL, notes): a run directory only ever loses what rackstress wrote there. The manifest
``RUNDIR/.rackstress-files.json`` lists the top-level names rackstress wrote (a folder it made,
``figures/``, ``vtk/``, ``restart/``, with what is in it). It is written atomically: a new run
records the names it may write (:data:`rackstress.lib.runfiles.RUN_FILES`) before writing them,
and every command that holds the lock adds, when it ends, the names that appeared meanwhile and
drops the names that were not written; the lock record keeps the names present when the command
began, so that the next command adopts what a killed one wrote. A run directory written before
runs kept a manifest owns the names of :data:`~rackstress.lib.runfiles.RUN_FILES` it holds, and
nothing else. Other folders rackstress writes into (``render --out``, ``stress --out``, ``deck
--out``) keep the same manifest (:func:`own`).

**Reuse.** :func:`claim` decides what a new run may do with an existing directory: a new
directory, or one holding only the user's files, is used (they stay as they are); one holding a
file of a name a run writes that no run wrote (the user's ``report.html``) is refused, naming
it; a finished run (``summary.json``) or a run that did not finish (killed: ``scene.json``
without ``summary.json``) is refused unless ``--overwrite`` (or ``--resume`` for the latter).
``--overwrite`` removes what the manifest lists and nothing else: it first marks those names as
being removed in the manifest (one atomic write), then removes the run's markers (so a kill
midway never leaves something that looks like a run) and the rest; the next claim finishes a
removal a kill interrupted.
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

from rackstress.errors import RackstressError, RunDirError, storage_error
from rackstress.lib.runfiles import RUN_FILES

LOCK = ".lock"
#: The manifest: the top-level names rackstress wrote into a directory (module doc).
MANIFEST = ".rackstress-files.json"
#: Files whose presence makes a directory a run directory (written by ``rackstress run``).
MARKERS = ("scene.json", "summary.json", "progress.json")

#: resolved path -> [fd, depth, names present when the command began]: re-entrant in a process
_held: dict[str, list] = {}


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
    for fd, *_ in list(_held.values()):
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
    >>> tmp = tempfile.TemporaryDirectory()
    >>> d = pathlib.Path(tmp.name) / "run"
    >>> with locked(d):
    ...     (d / "scene.json").write_text("{}")
    2
    >>> tmp.cleanup()
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
            if isinstance(old.get("present"), list):    # what the killed command wrote
                _adopt(rundir, present(rundir) - set(old["present"]))
        before = present(rundir)
        rec = {"pid": os.getpid(), "host": socket.gethostname(),
               "command": command or _command_line(),
               "started": time.strftime("%Y-%m-%dT%H:%M:%S"), "present": sorted(before)}
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, (json.dumps(rec) + "\n").encode(), 0)
        except OSError:
            pass      # a full disk: the lock holds all the same, unnamed
        _held[key] = [fd, 1, before]

    def release():
        ent = _held.get(key)
        if ent is None:
            return
        ent[1] -= 1
        if ent[1] == 0:
            del _held[key]
            with contextlib.suppress(OSError, RackstressError):
                _adopt(rundir, present(rundir) - ent[2], prune=True)
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
    """The names in a directory, but for the lock and the manifest."""
    try:
        return sorted(p.name for p in Path(rundir).iterdir() if p.name not in (LOCK, MANIFEST))
    except (FileNotFoundError, NotADirectoryError):
        return []


def present(rundir: Path) -> set[str]:
    """:func:`contents` without the temporaries of writers at work (``.NAME.tmp…``,
    ``.tmp-…``): the names a command may leave behind."""
    return {n for n in contents(rundir)
            if not (n.startswith(".") and (".tmp" in n or n.startswith(".tmp-")))}


def manifest(rundir: Path) -> dict | None:
    """The manifest of ``rundir`` (``{"files": [...], "removing": [...]}``), or None if there is
    none (or it cannot be read: then nothing is taken for rackstress's)."""
    try:
        data = json.loads((Path(rundir) / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and isinstance(data.get("files"), list) else None


def owned(rundir: Path) -> set[str]:
    """The top-level names of ``rundir`` that rackstress wrote: the manifest's, or in a run
    directory written before runs kept one, the names of :data:`RUN_FILES` it holds."""
    m = manifest(rundir)
    if m is not None:
        return set(m["files"]) | set(m.get("removing") or [])
    if is_run(rundir):
        return set(RUN_FILES) & present(rundir)
    return set()


def _write_manifest(rundir: Path, files, removing=None) -> None:
    from rackstress.lib.jsonio import write_json

    rec = {"files": sorted(set(files))}
    if removing:
        rec["removing"] = list(removing)
    write_json(Path(rundir) / MANIFEST, rec)


def _adopt(rundir: Path, names, prune: bool = False) -> None:
    """Add ``names`` (written by a command) to the manifest; ``prune``: drop the names that
    are not there (recorded before a write that did not happen)."""
    mine = owned(rundir)
    files = (mine | set(names)) & present(rundir) if prune else mine | set(names)
    m = manifest(rundir)
    if m is not None and set(m["files"]) == files and not m.get("removing"):
        return
    if m is None and not names:
        return
    _write_manifest(rundir, files)


def strangers(rundir: Path, names) -> list[str]:
    """Those of ``names`` that ``rundir`` holds and rackstress did not write (the user's)."""
    return sorted(set(names) & present(rundir) - owned(rundir))


def own(directory, names, doing: str) -> Path:
    """Before writing ``names`` into ``directory`` (created if missing): refuse if it holds a
    file of one of those names that rackstress did not write, else record them in its
    manifest (module doc). ``doing`` says what would be written, for the message.

    Raises
    ------
    RunDirError
        A file of the user's would be written over (exit 2); nothing is written.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> tmp = tempfile.TemporaryDirectory()
    >>> d = pathlib.Path(tmp.name)
    >>> (d / "stress.json").write_text("mine")
    4
    >>> own(d, ["stress.json"], "the stress files")
    Traceback (most recent call last):
    ...
    rackstress.errors.RunDirError: ...
    >>> tmp.cleanup()
    """
    directory = Path(directory)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise storage_error(exc, "create the directory") from None
    theirs = strangers(directory, names)
    if theirs:
        raise RunDirError(f"{directory} already holds {_names(theirs)}, which rackstress did "
                          f"not write there: writing {doing} would replace "
                          f"{'it' if len(theirs) == 1 else 'them'}; move "
                          f"{'it' if len(theirs) == 1 else 'them'} away, or choose another "
                          "--out")
    _adopt(directory, names)
    return directory


def _names(names, at_most: int = 6) -> str:
    shown = ", ".join(names[:at_most])
    return shown + (f" and {len(names) - at_most} more" if len(names) > at_most else "")


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

    The user's files in it stay as they are; what an earlier run wrote is removed with
    ``overwrite``; the names the new run may write are recorded in the manifest first.

    Raises
    ------
    RunDirError
        It holds a finished or an unfinished run (or other rackstress output) and
        ``overwrite`` is not given, or it holds a file of a name a run writes that no run
        wrote (the user's); nothing is removed then.
    """
    rundir = check_out(rundir)
    if rundir.exists() and not rundir.is_dir():
        raise RunDirError(f"run directory {rundir} exists and is not a directory")
    _remove_leftovers(rundir)
    m = manifest(rundir)
    if m is not None and m.get("removing"):      # an --overwrite killed midway: finish it
        _remove(rundir, m["removing"])
    here = present(rundir)
    mine = owned(rundir) & here
    theirs = sorted(here - mine)
    clash = [n for n in theirs if n in RUN_FILES]
    if clash:
        raise RunDirError(f"{rundir} holds {_names(clash)}, which no run wrote there, and a run "
                          f"writes {'that name' if len(clash) == 1 else 'those names'}: move "
                          f"{'it' if len(clash) == 1 else 'them'} away or choose another --out "
                          "(a run never writes over or removes files it did not write)")
    if mine and not overwrite:
        if "summary.json" in mine:
            raise RunDirError(f"run directory {rundir} already holds a finished run "
                              "(summary.json); choose another --out or pass --overwrite to "
                              "replace it")
        if is_run(rundir):
            raise RunDirError(f"run directory {rundir} holds a run that did not finish (killed? "
                              f"{unfinished_step(rundir)}): continue it with 'rackstress run "
                              f"--resume {rundir}' or replace it with --overwrite")
        raise RunDirError(f"{rundir} holds files rackstress wrote ({_names(sorted(mine))}); "
                          "choose another --out or pass --overwrite to replace them")
    if mine:
        _remove(rundir, mine)
    if theirs:
        sys.stderr.write(f"rackstress: note: {rundir} also holds {_names(theirs)}, not the "
                         "run's: left as they are (--overwrite never removes them)\n")
    _write_manifest(rundir, RUN_FILES)      # before writing them; the lock's release prunes
    ent = _held.get(str(rundir.resolve()))
    if ent is not None:
        ent[2] = present(rundir)
    return rundir


def _remove(rundir: Path, names) -> None:
    """Remove ``names`` (the run's) from ``rundir``: first marked as being removed in the
    manifest, then the run's markers, then the rest, then the manifest without them."""
    names = set(names)
    keep = owned(rundir) - names
    order = [n for n in MARKERS if n in names] + sorted(names - set(MARKERS))
    try:
        _write_manifest(rundir, keep, removing=order)
        for name in order:
            path = rundir / name
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)
            else:
                path.unlink(missing_ok=True)
        _write_manifest(rundir, keep)
    except OSError as exc:
        raise storage_error(exc, "remove the earlier run from", rundir) from None


def _remove_leftovers(rundir: Path) -> None:
    """Earlier runs moved aside whole (``.NAME.old-PID``, as ``--overwrite`` once did) by an
    --overwrite that was killed before deleting them; temporaries of killed writers."""
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

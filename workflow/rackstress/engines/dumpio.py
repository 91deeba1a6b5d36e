"""Trajectory frames in LAMMPS ``dump custom`` text format (``id type mol x y z``).

Both engines write this one format, so everything downstream (MDAnalysis, stress, pictures)
reads every run the same way. Frames are appended whole and flushed, so a run stopped by the
watchdog keeps every complete frame written before it.

A frame may hold only some particles: a LAMMPS deck with a resting (passive) group dumps the
particles of the moving group, which holds every particle displaced (:meth:`Deck.dump_commands
<rackstress.engines.lammps.deck.Deck.dump_commands>`); a particle a frame does not hold sits at
its original position, the data file's. :func:`read_frames` reads either kind into whole frames.

A run that has finished keeps its dump as ``trajectory.dump.gz``, one gzip member a frame
(:func:`compress_dump`, :class:`CompressJob`; docs/output.md): the text stays while the run can
still be resumed or cut (:func:`trim_after`, :func:`trim_nonfinite`, ``runs.resume``), and every
reader here takes either file (:func:`dump_path`).
"""
from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from rackstress.errors import storage_error

#: Columns every rackstress dump holds: what post-processing needs and nothing more.
COLUMNS = ("id", "type", "mol", "x", "y", "z")
#: Float format of positions in dumps (10 significant digits: far below any visible deformation).
FLOAT_FORMAT = "%.10g"


def frame_text(step: int, p: np.ndarray, columns, table: np.ndarray, fmt) -> str:
    """One ``dump custom`` frame: header (box = the particles' bounds, boundary ``mm``) and rows."""
    lo, hi = p.min(axis=0), p.max(axis=0)
    buf = io.StringIO()
    buf.write(f"ITEM: TIMESTEP\n{int(step)}\nITEM: NUMBER OF ATOMS\n{len(p)}\n"
              "ITEM: BOX BOUNDS mm mm mm\n")
    for k in range(3):
        buf.write(f"{lo[k]:.10g} {hi[k]:.10g}\n")
    buf.write("ITEM: ATOMS " + " ".join(columns) + "\n")
    np.savetxt(buf, table, fmt=fmt)
    return buf.getvalue()


def _reopen_at(path: Path, size: int):
    """Reopen ``path`` for appending after truncating it to ``size`` bytes (best effort)."""
    try:
        os.truncate(path, size)
    except OSError:
        pass
    return open(path, "a")


class DumpWriter:
    """Append frames of a whole scene to a LAMMPS-style dump file."""

    def __init__(self, path: Path, types: np.ndarray, mols: np.ndarray):
        self.path = Path(path)
        self.ids = np.arange(1, len(types) + 1)
        self.types, self.mols = np.asarray(types), np.asarray(mols)
        self._fh = open(self.path, "w")

    def write(self, step: int, p: np.ndarray) -> None:
        text = frame_text(step, p, COLUMNS, np.column_stack([self.ids, self.types, self.mols, p]),
                          ["%d", "%d", "%d"] + [FLOAT_FORMAT] * 3)
        start = self._fh.tell()
        try:
            self._fh.write(text)
            self._fh.flush()
        except OSError as exc:
            # a full disk: cut the torn frame off, so the file keeps only whole frames
            try:
                self._fh.close()
            except OSError:
                pass
            self._fh = _reopen_at(self.path, start)
            raise storage_error(exc, f"write frame {step} to", self.path) from None

    def close(self) -> None:
        try:
            self._fh.close()
        except OSError:
            pass       # the failed write was already reported and cut off

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _cut_at(path, first_cut, what: str):
    """Truncate the dump at the frame ``first_cut(mm, heads)`` picks, ``(offset, iteration)``
    or None (``heads``: each frame's offset and iteration, in file order); return that
    iteration, or None if nothing is cut (or there is no dump). One C-speed pass (mmap)."""
    import mmap
    import re

    path = Path(path)
    try:
        size = path.stat().st_size
    except OSError:
        return None
    if size == 0:
        return None
    head = re.compile(rb"ITEM: TIMESTEP\n(\d+)\n")
    with open(path, "r+b") as fh:
        with mmap.mmap(fh.fileno(), 0) as mm:
            heads = [(m.start(), int(m.group(1))) for m in head.finditer(mm)]
            cut = first_cut(mm, heads, size)
        if cut is None:
            return None
        try:
            fh.truncate(cut[0])
        except OSError as exc:
            raise storage_error(exc, what, path) from None
    return cut[1]


def trim_nonfinite(path) -> int | None:
    """Cut a dump before its first frame holding a non-finite value (``nan``, ``inf``); return
    that frame's iteration, or None if every frame is finite (or there is no dump).

    After a divergence: a check that noticed it only some steps later (the watchdog runs every
    few steps; LAMMPS writes its dump itself) must not leave NaN frames kept as if whole."""
    import re

    bad = re.compile(rb"(?i)(?<![a-z])(nan|inf)")

    def first_bad(mm, heads, size):
        for k, (start, step) in enumerate(heads):
            end = heads[k + 1][0] if k + 1 < len(heads) else size
            atoms = mm.find(b"ITEM: ATOMS", start, end)
            body = mm.find(b"\n", atoms, end) if atoms >= 0 else start
            if bad.search(mm, body, end):
                return start, step
        return None

    return _cut_at(path, first_bad, "trim the non-finite frames of")


def trim_after(path, step: int) -> int | None:
    """Cut a dump before its first frame of an iteration after ``step``; return that frame's
    iteration, or None if there is none (or no dump).

    After the plugin left a non-finite term out (a bound pair that coincides): the positions
    LAMMPS wrote after that step are finite but lack it, so they are not the run's."""
    return _cut_at(path, lambda mm, heads, size: next((h for h in heads if h[1] > step), None),
                   "trim the frames after the divergence of")


def read_frames(path, o: np.ndarray, want=None):
    """(step, positions of every particle in id order) of each complete frame of a rackstress
    dump (``id ... x y z`` columns, ids 1..n), text or gzip (:func:`compress_dump`); a particle a
    frame does not hold is at its original position ``o`` (n, 3). ``want``: the frame numbers to
    read (default all); a frame cut short at the end of the file (a killed run) is left out."""
    import mmap

    path = Path(path)
    o = np.asarray(o, dtype=np.float64)
    if not path.exists() or path.stat().st_size == 0:
        return
    if path.name.endswith(GZ):
        frame = 0
        for _, text in gzip_members(path):
            for step, p in _frames_in(text, o, want, frame):
                yield step, p
            frame += text.count(b"ITEM: TIMESTEP\n")
        return
    with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        yield from _frames_in(mm, o, want, 0)


def _frames_in(mm, o, want, frame):
    """The complete frames of the dump text ``mm`` (bytes or mmap), numbered from ``frame``."""
    pos = 0
    while True:
        at = mm.find(b"ITEM: TIMESTEP\n", pos)
        if at < 0:
            return
        lines = []
        q = at
        for _ in range(9):
            e = mm.find(b"\n", q)
            if e < 0:
                return
            lines.append(mm[q:e])
            q = e + 1
        step, n = int(lines[1]), int(lines[3])
        cols = lines[8].decode().split()[2:]
        # the frame's n lines end where the next frame starts (counted in C, not line by line)
        nxt = mm.find(b"ITEM: TIMESTEP\n", q)
        stop = len(mm) if nxt < 0 else nxt
        if mm[q:stop].count(b"\n") == n and (nxt >= 0 or stop == q or mm[stop - 1] in (10, b"\n")):
            end = stop
        else:
            end = q
            for _ in range(n):
                e = mm.find(b"\n", end)
                if e < 0:
                    return                   # cut short: not a complete frame
                end = e + 1
        pos = end
        if want is None or frame in want:
            p = o.copy()
            if n:
                from rackstress.lib.numtext import numbers

                t = numbers(mm[q:end])     # NumPy's values, compiled, if loaded
                if t is None or t.size != n * len(cols):
                    t = np.fromstring(mm[q:end].decode("ascii"), sep=" ")
                t = t.reshape(n, len(cols))
                ids = t[:, cols.index("id")].astype(np.int64) - 1
                p[ids] = t[:, [cols.index(c) for c in ("x", "y", "z")]]
            yield step, p
        frame += 1


# ----------------------------------------------------------------------------- the finished file
#: A finished run's trajectory: ``trajectory.dump`` gzip-compressed, one gzip member a frame
GZ = ".gz"
#: ISA-L level (0-3) of :func:`compress_dump`'s members, written by python-isal's
#: ``isal_zlib`` (Intel's ISA-L deflate: standard gzip members that zlib, gzip and every reader
#: open). magpod-small's 18.2 MB of text, a member a frame, CPU seconds (``time.process_time``,
#: 15 passes interleaved, load 1.2, AVX-512 x86-64): ISA-L 3 0.045 s, 8.31 MB; ISA-L 2 0.048 s,
#: 8.39 MB; ISA-L 1 0.049 s, 8.42 MB; zlib 1 (what it was) 0.146 s, 8.63 MB; zlib 6 0.8 s,
#: 8.1 MB. Level 3 is both the smallest and the fastest here; on 32 KiB blocks it takes 1.6
#: times level 1's time (the VTK frames', ``stress.export._Vtp``), which a 180 kB frame repays.
GZ_LEVEL = 3


def gz_member(text, level: int = GZ_LEVEL) -> bytes:
    """``text`` as one gzip member: ISA-L deflate at ``level``, no name, time 0, OS 255 (the
    same text gives the same bytes; ``isal.igzip.compress(text, level, mtime=0)`` byte for
    byte). ISA-L lets go of the GIL while it compresses."""
    from isal import isal_zlib

    return isal_zlib.compress(text, level, wbits=31)


def dump_path(rundir, name: str = "trajectory.dump") -> Path:
    """The run's trajectory: ``name`` while it is text (a running, killed or ``--dump-text``
    run), else ``name.gz`` (a finished run, :func:`compress_dump`); ``name`` if neither exists."""
    text = Path(rundir) / name
    gz = text.with_name(name + GZ)
    return gz if gz.is_file() and not text.is_file() else text


def compress_dump(path, level: int = GZ_LEVEL) -> Path:
    """Write ``path.gz`` from a finished text dump, one gzip member a frame (:func:`gz_member`:
    ISA-L level :data:`GZ_LEVEL`, no name, time 0: the same text gives the same bytes), then
    remove the text; return the ``.gz`` path.

    A multi-member gzip file is one stream to ``gzip -d``, OVITO's and MDAnalysis' readers; the
    members let :func:`gzip_members` (the stress reader, :func:`read_frames`) read a frame
    without the ones before it. Written to a temporary name and renamed, then the text removed:
    a kill leaves the text (or both, the ``.gz`` whole), never half a file.

    Example
    -------
    >>> compress_dump("runs/plane-rack/trajectory.dump")          # doctest: +SKIP
    PosixPath('runs/plane-rack/trajectory.dump.gz')
    """
    job = CompressJob(path, level, thread=False)
    return job.finish()


class CompressJob:
    """:func:`compress_dump` in a thread (ISA-L leaves the GIL while it compresses): the ``.gz``
    is written under a temporary name while the text is still read (the pictures); :meth:`finish`
    waits, renames it into place and removes the text; :meth:`cancel` leaves the text alone."""

    def __init__(self, path, level: int = GZ_LEVEL, thread: bool = True):
        import threading

        self.path = Path(path)
        self.out = self.path.with_name(self.path.name + GZ)
        self.tmp = self.out.with_name(f".{self.out.name}.tmp{os.getpid()}")
        self.level, self.error = level, None
        PENDING.add(str(self.path.resolve()))
        self._thread = threading.Thread(target=self._write, daemon=True) if thread else None
        if self._thread is not None:
            self._thread.start()
        else:
            self._write()

    def _write(self) -> None:
        import mmap
        import re

        from isal.isal_zlib import crc32

        head = re.compile(rb"ITEM: TIMESTEP\n")
        ahead = AHEAD.pop(str(self.path.resolve()), None)
        done = ahead.members if ahead is not None and ahead.level == self.level else {}
        try:
            with open(self.path, "rb") as fh, open(self.tmp, "wb") as dst:
                size = os.fstat(fh.fileno()).st_size
                if size:
                    with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mm:
                        starts = [m.start() for m in head.finditer(mm)] or [0]
                        starts[0] = 0
                        for a, b in zip(starts, starts[1:] + [size]):
                            got = done.get(a)         # compressed while the run ran: the
                            if got is not None and got[0] == b and got[1] == crc32(mm[a:b]):
                                dst.write(got[2])     # same bytes there, the same member
                            else:
                                dst.write(gz_member(mm[a:b], self.level))
        except OSError as exc:
            self.error = exc

    def finish(self) -> Path:
        """The ``.gz`` in place and the text removed; a write error (a full disk) raises
        :class:`~rackstress.errors.StorageError` naming the dump, which is then kept as text."""
        if self._thread is not None:
            self._thread.join()
        try:
            if self.error is not None:
                raise self.error
            os.replace(self.tmp, self.out)
            self.path.unlink()
        except OSError as exc:
            self.tmp.unlink(missing_ok=True)
            raise storage_error(exc, "compress", self.path) from None
        finally:
            PENDING.discard(str(self.path.resolve()))
        return self.out

    def cancel(self) -> None:
        if self._thread is not None:
            self._thread.join()
        self.tmp.unlink(missing_ok=True)
        PENDING.discard(str(self.path.resolve()))


#: text dumps a :class:`CompressJob` of this process is turning into ``.gz`` (the report, written
#: meanwhile, links the file the run directory will hold: :func:`final_name`)
PENDING: set = set()

#: dump path → its :class:`GzAhead` (filled while the run runs, taken by :class:`CompressJob`)
AHEAD: dict = {}


class GzAhead:
    """The gzip members of a dump's frames compressed while LAMMPS still writes it (``rackstress
    run``, on the core the simulation leaves idle): :meth:`step` compresses the next frame
    the file holds whole (the next one has begun), as :class:`CompressJob` would, and keeps it
    with its end and the CRC of its bytes; :class:`CompressJob` takes a member only where the
    finished dump holds the same bytes (a run cut after divergence or resumed compresses the
    changed frames anew). It holds at most :attr:`LIMIT` bytes of members (the rest is
    compressed at the end)."""

    LIMIT = 64 * 2 ** 20

    def __init__(self, path, level: int = GZ_LEVEL):
        self.path, self.level = Path(path), level
        self.members: dict = {}          # frame start → (end, crc32, gzip member)
        self.at = 0                      # where the next frame starts
        self.held = 0                    # bytes of members
        AHEAD[str(self.path.resolve())] = self

    def step(self) -> bool:
        """Compress the next whole frame; False if the file holds none yet (or
        :attr:`LIMIT` is reached)."""
        from isal.isal_zlib import crc32

        if self.held >= self.LIMIT:
            return False
        text, nxt = b"", -1
        try:
            with open(self.path, "rb") as fh:
                fh.seek(self.at)
                while nxt < 0:
                    more = fh.read(1 << 20)
                    if not more:
                        return False
                    nxt = (text + more).find(b"ITEM: TIMESTEP\n", max(1, len(text) - 16))
                    text += more
        except OSError:
            return False
        frame = text[:nxt]
        member = gz_member(frame, self.level)
        self.members[self.at] = (self.at + nxt, crc32(frame), member)
        self.held += len(member)
        self.at += nxt
        return True


def final_name(rundir, name: str = "trajectory.dump") -> str:
    """The name the run's trajectory has once this process is done: ``name.gz`` if it is, or is
    being, compressed, else ``name``."""
    text = Path(rundir) / name
    if str(text.resolve()) in PENDING:
        return name + GZ
    return dump_path(rundir, name).name


def gzip_members(path):
    """(byte offset, text) of each gzip member of ``path`` in turn, one member's text in memory
    at a time; the text of a member cut short (a torn file) is what could be decompressed.
    ISA-L inflates (``isal_zlib``, zlib's interface): the same text as zlib, in 0.55 of its
    CPU time (magpod-small's 8.3 MB: 0.034 s against 0.061 s)."""
    from isal import isal_zlib

    with open(path, "rb") as fh:
        pos, pending = 0, b""
        while True:
            d = isal_zlib.decompressobj(wbits=31)
            out = []
            start = pos
            while not d.eof:
                block = pending or fh.read(1 << 20)
                pending = b""
                if not block:
                    break
                try:
                    out.append(d.decompress(block))
                except isal_zlib.error:      # not gzip: the end of what can be read
                    return
                pos += len(block) - len(d.unused_data)
            if out or d.eof:
                yield start, b"".join(out)
            if not d.eof:
                return
            pending = d.unused_data
            if not pending:
                pending = fh.read(1 << 20)
                if not pending:
                    return


def gzip_member(path, offset: int) -> bytes:
    """The text of the gzip member of ``path`` at byte ``offset`` (:func:`gzip_members`)."""
    from isal import isal_zlib

    with open(path, "rb") as fh:
        fh.seek(offset)
        d = isal_zlib.decompressobj(wbits=31)
        out = []
        while not d.eof:
            block = fh.read(1 << 20)
            if not block:
                break
            out.append(d.decompress(block))
        return b"".join(out)

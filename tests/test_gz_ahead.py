"""GzAhead (engines/dumpio.py): the trajectory's frames compressed while LAMMPS writes them,
taken by CompressJob only where the finished dump holds the same bytes. The finished file is
checked against gzip itself: one member a frame, each gzip.compress of that frame's text."""
import gzip

from rackstress.engines.dumpio import AHEAD, CompressJob, GzAhead


def _frame(step: int, n: int, shift: float = 0.0) -> bytes:
    rows = "".join(f"{i + 1} 1 1 {i + shift} {2 * i} {step}\n" for i in range(n))
    return (f"ITEM: TIMESTEP\n{step}\nITEM: NUMBER OF ATOMS\n{n}\nITEM: BOX BOUNDS mm mm mm\n"
            f"0 1\n0 1\n0 1\nITEM: ATOMS id type mol x y z\n{rows}").encode()


def _members(path) -> list:
    """The gzip members of ``path``, each decompressed, by gzip's own reader."""
    data, out = path.read_bytes(), []
    while data:
        d = gzip.zlib.decompressobj(16 + 15)
        out.append(d.decompress(data))
        data = d.unused_data
    return out


def test_frames_compressed_while_written_make_the_same_file(tmp_path):
    frames = [_frame(10 * k, 50 + k) for k in range(6)]
    dump = tmp_path / "trajectory.dump"
    dump.write_bytes(frames[0] + frames[1][:40])           # the second frame half written
    ahead = GzAhead(dump)
    assert ahead.step() and not ahead.step()                # only the first is whole
    dump.write_bytes(b"".join(frames[:4]) + frames[4][:9])  # "ITEM: TIM": frame 3 not whole
    while ahead.step():
        pass
    assert sorted(ahead.members) == [sum(map(len, frames[:k])) for k in range(3)]
    # the run is cut and written again from frame 2 on: those frames differ from what was read
    frames[2] = _frame(20, 52, shift=0.5)
    text = b"".join(frames)
    dump.write_bytes(text)
    out = CompressJob(dump, thread=False).finish()
    assert not dump.exists() and str(dump.resolve()) not in AHEAD
    assert _members(out) == frames                          # a member a frame, as written
    assert gzip.decompress(out.read_bytes()) == text
    want = b"".join(gzip.compress(f, 1, mtime=0) for f in frames)
    assert out.read_bytes() == want                         # as compress_dump writes it

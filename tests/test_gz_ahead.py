"""GzAhead (engines/dumpio.py): the trajectory's frames compressed while LAMMPS writes them,
taken by CompressJob only where the finished dump holds the same bytes. The finished file is
checked against Python's gzip (one member a frame, each decompressing to that frame's text)
and python-isal's own gzip writer (``isal.igzip.compress``, mtime 0: the same bytes); a
compressed run reads, through load_run, read_frames and MDAnalysis' own LAMMPS dump reader,
as its text does."""
import gzip
import shutil

import numpy as np
from isal import igzip

from rackstress.engines.dumpio import AHEAD, GZ_LEVEL, CompressJob, GzAhead, compress_dump


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
    want = b"".join(igzip.compress(f, GZ_LEVEL, mtime=0) for f in frames)
    assert out.read_bytes() == want                         # as compress_dump writes it
    assert want != b"".join(gzip.compress(f, 1, mtime=0) for f in frames)   # not zlib's


def test_a_compressed_run_reads_as_its_text(tmp_path):
    """compress_dump's .gz: Python's gzip gives back the text byte for byte, and load_run,
    read_frames and MDAnalysis' LAMMPSDUMP reader give what they give from the text."""
    import MDAnalysis as mda

    from rackstress.engines.dumpio import read_frames
    from rackstress.stress import load_run
    from test_stress import BLOCK, SHEET, lattice, rigid, write_run

    bed = lattice(8, 1, 8, origin=(20, 0, 0))
    parts = [("block", "part", BLOCK), ("sheet", "part", SHEET), ("bed", "sediment", bed)]
    frames = [(10 * k, np.concatenate([rigid(BLOCK, [0, 0.05 * k, 0], [0.3 * k, 0, 0]),
                                       SHEET + [0, 0.01 * k, 0], bed])) for k in range(6)]
    text_dir, gz_dir = tmp_path / "text", tmp_path / "gz"
    write_run(text_dir, parts, frames)
    shutil.copytree(text_dir, gz_dir)
    text = (text_dir / "trajectory.dump").read_bytes()
    gz = compress_dump(gz_dir / "trajectory.dump")
    assert gz.name == "trajectory.dump.gz" and not (gz_dir / "trajectory.dump").exists()
    assert gzip.decompress(gz.read_bytes()) == text
    assert len(gz.read_bytes()) < len(text) / 2
    a, b = load_run(text_dir), load_run(gz_dir)
    assert list(a.steps) == list(b.steps) == [s for s, _ in frames]
    for k, (step, p) in enumerate(frames):
        got = b.trajectory[k].data["positions64"]
        np.testing.assert_array_equal(got, a.trajectory[k].data["positions64"])
        np.testing.assert_allclose(got, p, rtol=1e-9, atol=0)      # the dump's 10 digits
    o = np.concatenate([q for _, _, q in parts])
    for (sa, pa), (sb, pb) in zip(read_frames(text_dir / "trajectory.dump", o),
                                  read_frames(gz, o), strict=True):
        assert sa == sb and np.array_equal(pa, pb)
    u = [mda.Universe(str(d / "particles.data"), str(f), topology_format="DATA",
                      atom_style="id resid type x y z", format="LAMMPSDUMP")
         for d, f in ((text_dir, text_dir / "trajectory.dump"), (gz_dir, gz))]
    assert len(u[0].trajectory) == len(u[1].trajectory) == len(frames)
    for ta, tb in zip(u[0].trajectory, u[1].trajectory):
        assert ta.frame == tb.frame
        np.testing.assert_array_equal(u[0].atoms.positions, u[1].atoms.positions)

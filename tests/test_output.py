"""Output that follows what moves: the trajectory of a deck with a resting sediment
holds the displaced particles only, every reader puts the others at their original positions,
the measures of every frame at once equal the per-frame AnalysisBase classes, and the VTK files
open in their readers (pyvista, VTK's XML reader) in both variants.

Expected values come from independent paths: the same run dumped whole (``--dump-all``), the
per-frame MDAnalysis classes of :mod:`rackstress.stress.measures`, the NumPy strain path.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import HANG_S, dump_text, trajectory

from rackstress.stress import AccumulatedDistance, VonMisesStrain, load_run
from rackstress.stress.measures import (frame_positions, measure_frames, neighbourhoods,
                                        strain_frames)
from test_stress import BLOCK, SHEET, lattice, rigid, write_run

BIN = Path(sys.executable).parent
RACKSTRESS = str(BIN / "rackstress")
BED = lattice(8, 1, 8, origin=(20, 0, 0))      # a sediment: 64 particles, one layer


def _frames():
    """BLOCK turns and bends, SHEET rests then stretches, BED rests but for a dent."""
    out = []
    for k, step in enumerate((0, 10, 20, 30)):
        pb = rigid(BLOCK, [0.0, 0.05 * k, 0.0], [0.3 * k, 0.0, 0.0])
        pb[:6] += [0.0, 0.1 * k, 0.0]                       # a bent corner
        ps = SHEET.copy()
        if step == 30:
            ps[:, 0] = 10 + (SHEET[:, 0] - 10) * 1.1
        pe = BED.copy()
        if step >= 20:
            pe[9, 1] -= 0.25                                 # a dent, one particle
        out.append((step, np.concatenate([pb, ps, pe])))
    return out


PARTS = [("block", "part", BLOCK), ("sheet", "part", SHEET), ("bed", "sediment", BED)]


def test_measures_of_all_frames_equal_the_per_frame_classes(tmp_path):
    frames = _frames()
    write_run(tmp_path, PARTS, frames)
    run = load_run(tmp_path)
    got = measure_frames(run)
    acc = AccumulatedDistance(run).run().results
    st = VonMisesStrain(run).run().results
    bed = run.parts["bed"].index
    rest = np.setdiff1d(np.arange(run.n_atoms), bed)
    for name, ref in (("paper", acc.distance), ("accumulated", acc.per_particle),
                      ("strain", st.von_mises), ("d2min", st.d2min)):
        a, b = got[name][:, rest], ref[:, rest]
        assert np.array_equal(np.isnan(a), np.isnan(b)), name
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12, err_msg=name)
    # a sediment has no rest shape: its desired position is its original one
    o = run.o[bed]
    for k, (_, p) in enumerate(frames):
        np.testing.assert_array_equal(got["paper"][k, bed], np.linalg.norm(p[bed] - o, axis=1))
    assert got["paper"][3, bed[9]] == 0.25
    # resting neighbourhoods: exactly zero, not round-off (frame 0 everything, SHEET till 30)
    sheet = run.parts["sheet"].index
    assert (got["strain"][0][np.isfinite(got["strain"][0])] == 0).all()
    assert (got["strain"][1:3, sheet] == 0).all() and (got["d2min"][1:3, sheet] == 0).all()
    np.testing.assert_allclose(got["strain"][3, sheet], 0.5 * (1.1 ** 2 - 1) / np.sqrt(3),
                               atol=1e-12)                   # a uniform stretch (OVITO's η)


def test_compiled_strain_equals_the_numpy_path(tmp_path):
    write_run(tmp_path, PARTS, _frames())
    run = load_run(tmp_path)
    hood = neighbourhoods(run, list(run.parts.values()))
    P = frame_positions(run, range(run.index.n_frames))
    from rackstress.stress import kernels

    assert kernels.available()
    a = kernels.strain(hood, run.o, P)
    b = strain_frames(hood, run.o, P)
    for x, y in zip(a, b):
        assert np.array_equal(np.isnan(x), np.isnan(y))
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-13)


def test_compiled_robust_fit_equals_the_numpy_path():
    """The paper measure's robust fit compiled (stress/kernels.py) against its NumPy definition
    (lib/rigid.py) on parts that turn, bend locally and stretch, frame by frame: equal to
    round-off, and a local bump on a rigid motion shows exactly its own displacement."""
    from rackstress.lib import rigid as lib_rigid
    from rackstress.stress import kernels

    assert kernels.available()
    rng = np.random.default_rng(11)
    for part in (BLOCK, SHEET, lattice(12, 3, 9)):
        P = []
        for k in range(9):
            p = rigid(part, rng.normal(0, 0.4, 3), rng.normal(0, 2.0, 3))
            bump = rng.choice(len(part), 1 + k % 4, replace=False)
            p[bump] += rng.normal(0, 0.3, (len(bump), 3))           # a few particles bent away
            if k == 8:
                p += rng.normal(0, 0.02, p.shape)                   # deformed everywhere
            P.append(p)
        P = np.stack(P)
        np.testing.assert_allclose(kernels.robust_fit_frames(part, P),
                                   lib_rigid.robust_fit_frames(part, P), rtol=0, atol=1e-13)
    q = rigid(BLOCK, [0.0, 0.0, 0.3], [1.0, 2.0, 3.0])
    q[0] += [0.0, 0.5, 0.0]                  # the bump: 0.5 along y after the rigid motion
    d = kernels.robust_fit_frames(BLOCK, q[None])[0]
    assert abs(d[0] - 0.5) < 1e-12 and d[1:].max() < 1e-12


def test_partial_frames_read_through_mdanalysis(tmp_path):
    """A dump whose frames hold only some particles, as LAMMPS writes it for a deck with a
    resting sediment: load_run's Universe gives every particle, the others at rest."""
    frames = _frames()
    write_run(tmp_path / "whole", PARTS, frames)
    d = tmp_path / "part"
    write_run(d, PARTS, frames)
    o = np.concatenate([q for _, _, q in PARTS])
    types = np.concatenate([np.full(len(q), k + 1) for k, (_, _, q) in enumerate(PARTS)])
    lines = []
    for step, p in frames:
        moved = np.flatnonzero((p != o).any(axis=1))
        lines.append(f"ITEM: TIMESTEP\n{step}\nITEM: NUMBER OF ATOMS\n{len(moved)}\n"
                     "ITEM: BOX BOUNDS mm mm mm\n0 1\n0 1\n0 1\nITEM: ATOMS id type mol x y z\n")
        for i in moved:
            x, y, z = (repr(float(v)) for v in p[i])
            lines.append(f"{i + 1} {types[i]} {types[i]} {x} {y} {z}\n")
    (d / "trajectory.dump").write_text("".join(lines))
    whole, part = load_run(tmp_path / "whole"), load_run(d)
    assert part.index.partial and list(part.index.counts)[0] == 0
    for a, b in zip(whole.trajectory, part.trajectory):
        assert np.array_equal(a.data["positions64"], b.data["positions64"])
    for name, v in measure_frames(whole).items():
        np.testing.assert_array_equal(v, measure_frames(part)[name])


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    """magpod-small's first 600 iterations twice: the trajectory as it follows what moves, and
    every particle every frame (--dump-all)."""
    base = tmp_path_factory.mktemp("magpod")
    out = {}
    for name, extra in (("moving", []), ("all", ["--dump-all"])):
        r = subprocess.run([RACKSTRESS, "run", "magpod-small", "--steps", "600", "--dump-every",
                            "50", "--no-render", "--no-progress", "--out", str(base / name),
                            *extra], capture_output=True, text=True, timeout=900)
        assert r.returncode == 0, r.stderr[-2000:]
        out[name] = base / name
    return out


@pytest.mark.lammps
def test_moving_dump_holds_what_moved_and_reads_as_the_whole(two_runs):
    moving, whole = two_runs["moving"], two_runs["all"]
    assert json.loads((moving / "scene.json").read_text())["dump"] == "moving"
    assert json.loads((whole / "scene.json").read_text())["dump"] == "all"
    assert "dump rs_dump rs_move custom" in (moving / "in.lammps").read_text()
    a, b = load_run(whole), load_run(moving)
    assert list(a.steps) == list(b.steps) == list(range(0, 601, 50))
    n = a.n_atoms
    counts = b.index.counts
    sed = a.parts["sediment"].index
    assert counts[0] >= n - len(sed) and (counts < n).all()    # the robot and what it can reach
    assert counts[-1] > counts[0]
    assert (np.diff(counts) >= 0).all()          # a particle once moving stays in the frames
    for k, (ta, tb) in enumerate(zip(a.trajectory, b.trajectory)):
        pa, pb = ta.data["positions64"], tb.data["positions64"]
        assert np.array_equal(pa, pb)
        # the whole dump proves it: a particle a frame leaves out sits at its original position
        held = np.zeros(n, bool)
        held[counts_ids(moving, k) - 1] = True
        assert np.array_equal(pa[~held], a.o[~held])
        assert (~held[sed]).sum() > 0.5 * len(sed)          # most of the sediment rests
    size = {k: len(dump_text(trajectory(d))) for k, d in two_runs.items()}
    assert size["moving"] < 0.9 * size["all"]
    # the measures: the same numbers either way
    for name, v in measure_frames(a).items():
        np.testing.assert_array_equal(v, measure_frames(b)[name])


def counts_ids(rundir: Path, frame: int) -> np.ndarray:
    """The ids frame ``frame`` of a dump holds, by a plain parser."""
    text = dump_text(trajectory(rundir)).split("ITEM: TIMESTEP\n")[1 + frame]
    rows = text.split("ITEM: ATOMS id type mol x y z\n")[1].splitlines()
    return np.array([int(r.split()[0]) for r in rows], dtype=np.int64)


@pytest.mark.lammps
def test_vtk_variants_open_in_their_readers(two_runs, tmp_path):
    import pyvista as pv
    from vtkmodules.vtkIOXML import vtkXMLPolyDataReader

    rundir = two_runs["moving"]
    for fmt in ("paraview", "ovito"):
        out = tmp_path / fmt
        r = subprocess.run([RACKSTRESS, "stress", str(rundir), "--out", str(out), "--no-dump",
                            "--no-progress", "--vtk-format", fmt], capture_output=True, text=True,
                           timeout=HANG_S)
        assert r.returncode == 0, r.stderr[-2000:]
    summary = json.loads((tmp_path / "paraview" / "stress.json").read_text())
    pk = summary["peak"]
    run = load_run(rundir)
    for fmt in ("paraview", "ovito"):
        vtk = tmp_path / fmt / "vtk"
        head = (vtk / "frame_0000050.vtp").read_bytes()[:2000]
        if fmt == "paraview":
            assert b'compressor="vtkZLibDataCompressor"' in head and b'format="appended"' in head
        else:
            assert b"compressor" not in head and b'format="binary"' in head
        reader = pv.get_reader(str(vtk / "run.pvd"))
        assert list(reader.time_values) == list(run.steps)
        reader.set_active_time_value(pk["iteration"])
        blocks = reader.read()
        # paraview: the frame and the sediment's resting particles (rest.vtp, written once);
        # ovito: every particle in the frame
        assert len(blocks) == (2 if fmt == "paraview" else 1)
        mesh = whole(blocks)
        k = int(np.flatnonzero(run.steps == pk["iteration"])[0])
        p = run.trajectory[k].data["positions64"]
        assert len(mesh["id"]) == run.n_atoms
        np.testing.assert_array_equal(mesh["id"], run.data.ids)
        np.testing.assert_array_equal(mesh["points"], p.astype(np.float32))
        np.testing.assert_array_equal(mesh["displacement"], (p - run.o).astype(np.float32))
        paper = mesh["paper"]
        assert paper.dtype == np.float64 and paper[pk["particle"] - 1] == pk["value"]
        # VTK's own XML reader, as ParaView opens a frame (and the resting part)
        files = ["frame_0000050.vtp"] + (["rest.vtp"] if fmt == "paraview" else [])
        n = 0
        for f in files:
            x = vtkXMLPolyDataReader()
            x.SetFileName(str(vtk / f))
            x.Update()
            n += x.GetOutput().GetNumberOfPoints()
            assert x.GetOutput().GetPointData().GetArray("d2min") is not None
        assert n == run.n_atoms
    size = {f: sum(q.stat().st_size for q in (tmp_path / f / "vtk").iterdir())
            for f in ("paraview", "ovito")}
    assert size["paraview"] < 0.4 * size["ovito"]


def _appended_arrays(data: bytes) -> list:
    """Each array of a ``.vtp`` file's appended data (UInt32 headers, vtkZLibDataCompressor:
    block count, block size, last block's size, each block's compressed size, then the
    blocks), inflated by Python's zlib: (block size, last block's size, the raw bytes)."""
    import re
    import zlib

    start = data.index(b"   _") + 4
    out = []
    for m in re.finditer(rb'<DataArray [^>]*offset="(\d+)"', data[:start]):
        at = start + int(m.group(1))
        nb, bs, last = np.frombuffer(data, "<u4", 3, at)
        sizes = np.frombuffer(data, "<u4", int(nb), at + 12)
        at += 12 + 4 * int(nb)
        raw = []
        for k, n in enumerate(sizes):
            z = zlib.decompressobj()
            raw.append(z.decompress(data[at:at + int(n)]))
            assert z.eof and not z.unused_data      # one whole zlib stream a block
            assert len(raw[-1]) == (last if k == nb - 1 else bs)
            at += int(n)
        out.append((int(bs), int(last), b"".join(raw)))
    return out


@pytest.mark.lammps
def test_the_numpy_vtk_writer_writes_what_vtks_own_writer_writes(two_runs, tmp_path):
    """The ``paraview`` variant written by rackstress (export._Vtp, what 'rackstress run' and
    'rackstress stress' write) and by ``vtkXMLPolyDataWriter`` (the independent path): the
    same files, the same arrays through VTK's reader. With Python's zlib (``deflate="zlib"``)
    the same compressed bytes in each file's appended data (only VTK's optional range hints
    differ); with ISA-L (the default) the same blocks once inflated by Python's zlib."""
    import pyvista as pv

    from rackstress.stress import export
    from rackstress.stress.post import compute_fields

    run = load_run(two_runs["moving"])
    fields = compute_fields(run, cache=False)
    for measures in ("default", "all"):
        vtks = tmp_path / f"vtk-{measures}"
        export.write_vtk(run, fields, vtks, measures=measures, writer="vtk")
        for deflate in ("zlib", "isal"):
            ours = tmp_path / f"ours-{measures}-{deflate}"
            kw = {"deflate": deflate} if deflate == "zlib" else {}     # isal: the default
            export.write_vtk(run, fields, ours, measures=measures, **kw)
            names = sorted(p.name for p in ours.iterdir())
            assert names == sorted(p.name for p in vtks.iterdir()) and "rest.vtp" in names
            for name in names:
                a, b = (ours / name).read_bytes(), (vtks / name).read_bytes()
                if not name.endswith(".vtp"):
                    assert a == b
                    continue
                if deflate == "zlib":
                    assert a[a.index(b"   _"):] == b[b.index(b"   _"):], name
                else:
                    x, y = _appended_arrays(a), _appended_arrays(b)
                    assert len(x) == len(y) > 10 and x == y, name
                    assert a[a.index(b"   _"):] != b[b.index(b"   _"):], name   # not zlib's
                x, y = pv.read(ours / name), pv.read(vtks / name)
                assert x.n_points == y.n_points and np.array_equal(x.verts, y.verts)
                np.testing.assert_array_equal(x.points, y.points)
                assert list(x.point_data) == list(y.point_data)
                for k in x.point_data:
                    assert x.point_data[k].dtype == y.point_data[k].dtype, k
                    np.testing.assert_array_equal(x.point_data[k], y.point_data[k])


def whole(blocks) -> dict:
    """Every particle of a time of a PVD series (its parts joined), by id: points and arrays."""
    parts = [blocks[i] for i in range(len(blocks))]
    ids = np.concatenate([b.point_data["id"] for b in parts])
    order = np.argsort(ids, kind="stable")
    out = {"points": np.concatenate([b.points for b in parts])[order]}
    for name in parts[0].point_data.keys():
        out[name] = np.concatenate([b.point_data[name] for b in parts])[order]
    return out


@pytest.mark.lammps
def test_a_run_writes_the_leading_measure_once_a_frame_and_a_gzip_trajectory(two_runs, tmp_path):
    """What 'rackstress run' leaves: trajectory.dump.gz, a gzip member a frame, which
    gzip, MDAnalysis' own LAMMPSDUMP reader and load_run open as the text LAMMPS wrote; and the
    VTK series with the leading measure and displacement, its resting sediment written once,
    equal array for array to the full series 'rackstress stress RUNDIR' writes."""
    import gzip
    import zlib

    import MDAnalysis as mda
    import pyvista as pv

    for d in two_runs.values():
        gz = d / "trajectory.dump.gz"
        assert gz.is_file() and not (d / "trajectory.dump").exists()
        raw, members, text = gz.read_bytes(), 0, b""
        while raw:                                  # member by member, by zlib alone
            z = zlib.decompressobj(wbits=31)
            text += z.decompress(raw)
            assert z.eof
            raw, members = z.unused_data, members + 1
        assert text == gzip.decompress(gz.read_bytes())
        run = load_run(d)
        assert members == text.count(b"ITEM: TIMESTEP\n") == len(run.steps) == 13
    # MDAnalysis' stock reader opens the .gz (every particle every frame: --dump-all); it
    # shifts each frame by its box's lower corner and keeps float32
    d = two_runs["all"]
    run = load_run(d)
    u = mda.Universe(str(d / "particles.data"), str(d / "trajectory.dump.gz"),
                     topology_format="DATA", atom_style="id resid type x y z",
                     format="LAMMPSDUMP")
    assert len(u.trajectory) == len(run.steps)
    for k, ts in enumerate(u.trajectory):
        p = run.trajectory[k].data["positions64"] - run.index.box[k, :, 0]
        np.testing.assert_allclose(ts.positions, p, rtol=0, atol=4 * np.spacing(np.float32(200)))
    # the run's VTK series against the full one
    d = two_runs["moving"]
    run = load_run(d)
    full = tmp_path / "full"
    r = subprocess.run([RACKSTRESS, "stress", str(d), "--out", str(full), "--no-dump",
                        "--no-progress"], capture_output=True, text=True, timeout=HANG_S)
    assert r.returncode == 0, r.stderr[-2000:]
    lean, every = (pv.get_reader(str(x / "vtk" / "run.pvd")) for x in (d, full))
    assert list(lean.time_values) == list(every.time_values) == list(run.steps)
    sed = run.parts["sediment"].index
    for t in lean.time_values:
        lean.set_active_time_value(t)
        every.set_active_time_value(t)
        a, b = whole(lean.read()), whole(every.read())
        assert set(b) - set(a) == {"displacement_magnitude", "accumulated", "strain", "d2min"}
        assert set(a) <= set(b) and "paper" in a
        for name in a:
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)
        rest = lean.read()[1]
        assert 0 < rest.n_points < len(sed)          # resting sediment, the same at every time
        np.testing.assert_array_equal(rest.points, run.o[rest.point_data["id"] - 1]
                                      .astype(np.float32))
        assert (rest.point_data["paper"] == 0).all()
    files = sorted(q.name for q in (d / "vtk").iterdir())
    assert files.count("rest.vtp") == 1 and len(files) == len(run.steps) + 2


@pytest.mark.lammps
def test_bench_e2e_dump_cost_and_table():
    """The benchmark's own parts: a frame of the moving particles holds fewer atoms and bytes
    than one of every particle, and the table shows each run's phases and the ratio."""
    from rackstress.bench import e2e

    d = e2e.dump_cost("magpod-small", 300, reps=2)
    assert 0 < d["moving"]["atoms_per_frame"] < d["all"]["atoms_per_frame"] == d["n_particles"]
    assert d["moving"]["bytes_per_frame"] < d["all"]["bytes_per_frame"]
    run = {"scene": "magpod-small", "steps": None, "cold": False, "repeat": 0, "wall_s": 10.0,
           "exit": 0, "size_total": 30e6, "sizes": {"vtk/": 20e6, "trajectory.dump": 10e6},
           "load_at_start": 1.25, "frames": 101, "frames_measured_while_running": 96,
           "phases": {"simulation": 4.0, "measures": 1.0, "pictures": 2.0,
                      "start-up and the rest": 3.0, "vtk (beside the pictures)": 1.5}}
    md = e2e.markdown({"runs": [run], "dumps": [d]}, {"cores": 2, "load_avg_at_start": [1, 1, 1]})
    assert "| magpod-small | the scene's | warm | 1.2 | 4.00 s | 96 of 101 | 1.00 s | " \
           "2.00 s (1.50 s) | 3.00 s | 10.00 s | 2.50× |  | 30.0 MB |" in md
    assert "`vtk/` 20.00 MB" in md and "| magpod-small | 5,705 | 300 |" in md
    # the targets of README's first run, from the same run: 10 s over its 4 s simulation; 30 MB
    assert "| warm total / its simulation (beside the head start) | | 2.50× |" in md
    assert "the simulation's own time" not in md                  # no run without it
    assert "| run directory | ≤ 30 MB | 30.0 MB |" in md and "cold − warm" not in md
    # a run without the head start (RACKSTRESS_HEAD_START=0) beside it: its simulation time
    # is shown against the other's, and it takes no part in the ratio
    alone = dict(run, head_start=False, wall_s=8.0,
                 phases=dict(run["phases"], simulation=3.5))
    md = e2e.markdown({"runs": [run, alone], "dumps": [d]},
                      {"cores": 2, "load_avg_at_start": [1, 1, 1]})
    assert "| magpod-small | the scene's | warm, no head start | 1.2 | 3.50 s |" in md
    # the verdict: the total over the simulation's own time (10 s / 3.5 s), and over the
    # simulation beside the head start (10 s / 4 s) apart
    assert ("| warm total / the simulation's own time (the *no head start* run of the same "
            "round) | ≤ 2× | 2.86× |") in md
    assert "| warm total / its simulation (beside the head start) | | 2.50× |" in md
    assert "| 10.00 s | 2.50× | 2.86× | 30.0 MB |" in md and "| 8.00 s | 2.29× | 2.29× |" in md
    assert "| not slower | 4.00 / 3.50 s |" in md
    # CPU by process after the simulation, as the run recorded it
    busy = dict(run, cpu_s=7.25, cpu_after={"pictures": 0.61, "vtk": 0.32, "plots": 0.58,
                                            "view3d": 0.1},
                driver={"steps_s": 3.5, "checks_s": 0.2, "between_s": 0.3})
    md = e2e.markdown({"runs": [busy], "dumps": [d]}, {"cores": 2, "load_avg_at_start": [1, 1, 1]})
    assert ("| magpod-small | warm | 3.50 / 0.20 / 0.30 s | 0.61 s | 0.32 s | 0.58 s | 0.10 s "
            "| 3.00 s | 7.25 s |") in md


def test_forked_job_reports_the_childs_cpu(tmp_path):
    """A forked child's CPU time (what wait4 says the kernel charged that child: its work, its
    writing of the result and its exit) is what getrusage counts for the parent's waited
    children, within a clock tick or two, and none of the parent's CPU before the fork: 0.6 s
    of it, so that the child's own 0.2 s and its exit (0.04 s measured beside a large pytest
    worker, whose pages the child's exit unmaps) stay below 0.5, and the two together above."""
    import resource
    import time

    from rackstress.runs.forked import ForkedJob

    t = time.process_time()
    while time.process_time() - t < 0.6:        # the parent's CPU before the fork: not counted
        pass

    def work():
        t = time.process_time()
        while time.process_time() - t < 0.2:
            pass
        return 1

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    job = ForkedJob(work, tmp_path / "job.json")
    assert job.join() == 1
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    kernel = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    assert 0.2 <= job.cpu_s < 0.5
    assert abs(job.cpu_s - kernel) < 0.03


def test_bench_e2e_variants_table_shows_the_runs_formats_first():
    """bench e2e's formats table (bench.e2e.variants' record): the first row of each table is
    what 'rackstress run' writes, ISA-L's zlib streams and ISA-L's gzip members."""
    from rackstress.bench import e2e

    vtk = [{"measures": m, "format": "paraview", "compressor": c, "bytes": b, "s": 0.1}
           for m, c, b in (("all", "zlib streams by ISA-L 1", 25e6), ("default", "zlib 1", 14.6e6),
                           ("default", "zlib streams by ISA-L 1", 14.4e6))]
    dump = [{"kind": "text", "bytes": 18.2e6, "s": 0.0},
            {"kind": "gzip by ISA-L 3, a member a frame", "bytes": 8.3e6, "s": 0.05},
            {"kind": "gzip by zlib 1, a member a frame", "bytes": 8.6e6, "s": 0.15}]
    md = e2e.markdown({"runs": [], "dumps": [], "variants": [
        {"scene": "magpod-small", "frames": 102, "vtk": vtk, "dump": dump}]},
        {"cores": 2, "load_avg_at_start": [1, 1, 1]})
    rows = [line for line in md.splitlines() if line.startswith("| paraview")
            or line.startswith("| gzip") or line.startswith("| text")]
    assert rows[0] == ("| paraview | the leading one and displacement | zlib streams by ISA-L 1 "
                       "| 14.40 MB | 0.10 s |")
    assert rows[3] == "| gzip by ISA-L 3, a member a frame | 8.30 MB | 0.05 s |"
    assert rows[4] == "| text | 18.20 MB | 0.00 s |" and len(rows) == 6

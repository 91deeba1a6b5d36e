"""Measures kept over the particles that moved (sediment-large's stress).

Past the in-memory limit, a run whose sediment rests keeps its measures over the particles that
moved and their strain neighbours only (:func:`rackstress.stress.measures.measure_columns`);
every other particle's values are implied. Expected values come from the dense path
(:func:`measure_frames`, itself tested against the per-frame AnalysisBase classes in
test_output.py) and from hand: a resting particle has p = o, so |p − o| = 0, its integral 0, and
η = D²min = 0 where its neighbourhood fit is defined (F = I), NaN where it is not (a particle
with no neighbour).
"""
from __future__ import annotations

import numpy as np
import pytest

from rackstress.stress import load_run
from rackstress.stress import post
from rackstress.stress.dump import read_data_file
from rackstress.stress.measures import Columns, measure_columns, measure_frames
from conftest import HANG_S
from test_output import BED, _frames
from test_stress import BLOCK, SHEET, write_run

LONE = np.array([[40.0, 0.0, 40.0]])          # a sediment particle with no neighbour
PARTS = [("block", "part", BLOCK), ("sheet", "part", SHEET),
         ("bed", "sediment", np.concatenate([BED, LONE]))]
MEASURES = ("paper", "accumulated", "strain", "d2min")


def _run(tmp_path):
    frames = [(s, np.concatenate([p, LONE])) for s, p in _frames()]
    write_run(tmp_path, PARTS, frames)
    return load_run(tmp_path)


def test_resting_columns_are_implied_exactly_and_the_moving_ones_equal_the_dense(tmp_path):
    run = _run(tmp_path)
    dense = measure_frames(run)
    got = measure_columns(run)
    bed = run.parts["bed"].index
    cols = got["cols"]
    # kept: the two parts with a rest shape whole, of the bed the dented particle (9, at
    # (20, 0, 1) + (1, 0, 1)·…: row 9 of an 8 × 8 layer) and its neighbours within 1.5 spacings
    kept_bed = np.intersect1d(cols, bed) - bed[0]
    o9 = BED[9]
    near9 = np.flatnonzero(np.linalg.norm(BED - o9, axis=1) <= 1.5 * (1 + 1e-9))
    assert np.array_equal(kept_bed, near9)
    assert np.isin(run.parts["block"].index, cols).all()
    assert np.isin(run.parts["sheet"].index, cols).all()
    rest = np.setdiff1d(np.arange(run.n_atoms), cols)
    assert len(rest) == len(BED) + 1 - len(near9)
    for m in MEASURES:
        v = Columns(cols, got[m], got["rest"][m])
        full = np.asarray(v)
        # the resting particles: exactly the dense path's values, and by hand
        assert np.array_equal(full[:, rest], dense[m][:, rest], equal_nan=True), m
        by_hand = np.zeros((len(dense["steps"]), len(rest)))
        if m in ("strain", "d2min"):
            by_hand[:, rest == bed[-1]] = np.nan             # the lone particle: no fit
        assert np.array_equal(full[:, rest], by_hand, equal_nan=True), m
        # the moving ones: the dense path's to the order of summation
        assert np.array_equal(np.isnan(full), np.isnan(dense[m])), m
        np.testing.assert_allclose(full, dense[m], rtol=0, atol=1e-12, err_msg=m)
        # indexed as the dense array is
        idx = np.array([0, bed[9], bed[0], bed[-1], run.n_atoms - 2])
        for k in range(len(dense["steps"])):
            np.testing.assert_array_equal(v[k], full[k])
            np.testing.assert_array_equal(v[k, idx], full[k, idx])
        np.testing.assert_array_equal(v[:, idx], full[:, idx])
        np.testing.assert_array_equal(v[1:3][:, bed], full[1:3][:, bed])
        assert v.shape == dense[m].shape
    assert got["paper"][3, np.searchsorted(cols, bed[9])] == 0.25


def test_past_the_limit_a_resting_sediment_gets_its_peaks_and_vtk(tmp_path, monkeypatch):
    """postprocess past MAX_VALUES (here lowered to this small run's size) keeps the moving
    columns and finds the same peaks as the dense path below the limit; the VTK frames carry
    every particle's values."""
    import pyvista as pv

    dense_dir, cols_dir = tmp_path / "dense", tmp_path / "cols"
    _run(dense_dir)
    _run(cols_dir)
    want = post.postprocess(dense_dir, vtk=True)
    post._MEMO.clear()
    n_values = load_run(cols_dir).n_atoms * 4
    monkeypatch.setattr(post, "MAX_VALUES", n_values - 1)
    fields = post.compute_fields(load_run(cols_dir), cache=False)
    assert all(isinstance(v, Columns) for v in fields.values.values())
    got = post.postprocess(cols_dir, vtk=True)
    for name, rec in want["groups"].items():
        for m, pk in rec.items():
            q = got["groups"][name][m]
            assert (q["iteration"], q["particle"], q["position"]) == \
                (pk["iteration"], pk["particle"], pk["position"]), (name, m)
            assert q["value"] == pytest.approx(pk["value"], rel=0, abs=1e-12)
    for k in range(4):
        a = pv.read(sorted((dense_dir / "vtk").glob("*.vtp"))[k])
        b = pv.read(sorted((cols_dir / "vtk").glob("*.vtp"))[k])
        for m in MEASURES:
            x, y = np.asarray(a.point_data[m]), np.asarray(b.point_data[m])
            assert np.array_equal(np.isnan(x), np.isnan(y))
            np.testing.assert_allclose(y, x, rtol=0, atol=1e-12)


def test_past_the_limit_rackstress_run_writes_the_resting_bed_once(tmp_path, monkeypatch):
    """rackstress run's VTK series (background, the leading measure) of a run past the limit:
    the bed's resting particles go once into rest.vtp, the frames hold the others, and every
    particle's value there is the dense path's."""
    import pyvista as pv

    dense_dir, cols_dir = tmp_path / "dense", tmp_path / "cols"
    _run(dense_dir)
    run = _run(cols_dir)
    post.postprocess(dense_dir, vtk=True, vtk_measures="default", background=True)
    post.wait_files(dense_dir)
    post._MEMO.clear()
    monkeypatch.setattr(post, "MAX_VALUES", run.n_atoms * 4 - 1)
    post.postprocess(cols_dir, vtk=True, vtk_measures="default", background=True)
    assert post.wait_files(cols_dir) is not None
    names = sorted(p.name for p in (cols_dir / "vtk").iterdir())
    assert names == sorted(p.name for p in (dense_dir / "vtk").iterdir())
    assert "rest.vtp" in names
    for name in names:
        if not name.endswith(".vtp"):
            continue
        a, b = pv.read(dense_dir / "vtk" / name), pv.read(cols_dir / "vtk" / name)
        assert a.n_points == b.n_points < run.n_atoms or name == "rest.vtp"
        x, y = np.asarray(a.point_data["paper"]), np.asarray(b.point_data["paper"])
        assert np.array_equal(np.isnan(x), np.isnan(y))
        np.testing.assert_allclose(y, x, rtol=0, atol=1e-12)


def test_past_the_limit_even_the_moving_columns_is_a_clear_error(tmp_path, monkeypatch):
    run = _run(tmp_path)
    monkeypatch.setattr(post, "MAX_VALUES", 10)
    with pytest.raises(post.TooLargeError, match="particles that moved or whose neighbours "
                                                 "moved × 4 frames"):
        post.compute_fields(run, cache=False)


def test_data_file_with_comments_and_image_flags_reads_as_written(tmp_path):
    """The Atoms section read by NumPy: comments and LAMMPS' image flags ignored, rows sorted
    by id, every digit kept."""
    path = tmp_path / "particles.data"
    path.write_text("LAMMPS data file\n\n3 atoms\n1 atom types\n\n0 1 xlo xhi\n0 1 ylo yhi\n"
                    "0 1 zlo zhi\n\nMasses\n\n1 2.5  # part\n\nAtoms  # bond\n\n"
                    "2 1 1 0.1 0.2 0.30000000000000004 0 0 1  # moved\n"
                    "1 1 1 -1e-300 5 6\n"
                    "3 2 1 7 8 9\n")
    d = read_data_file(path)
    assert d.ids.tolist() == [1, 2, 3] and d.mols.tolist() == [1, 1, 2]
    assert d.masses == {1: 2.5}
    assert d.positions.tolist() == [[-1e-300, 5.0, 6.0], [0.1, 0.2, 0.30000000000000004],
                                    [7.0, 8.0, 9.0]]


# ----------------------------------------------------------------------------- while it runs
def _grow(path, frames, upto):
    """The dump as LAMMPS leaves it mid-run: frames 0..upto-1 whole, the next one cut."""
    from test_stress import frame_text

    o = np.concatenate([q for _, _, q in PARTS])
    types = np.concatenate([np.full(len(q), k + 1) for k, (_, _, q) in enumerate(PARTS)])
    text = "".join(frame_text(s, p, types, types) for s, p in frames[:upto])
    if upto < len(frames):
        text += frame_text(*frames[upto], types, types)[:700]       # a torn frame
    path.write_text(text)
    return o


def _follow_until(tmp_path, frames, upto, chunks):
    """post.follow in its thread over a dump of ``upto`` whole frames, stopped once it has
    measured ``chunks`` chunks."""
    import threading
    import time

    _grow(tmp_path / "trajectory.dump", frames, upto)
    stop = threading.Event()
    t = threading.Thread(target=post.follow, args=(tmp_path, stop, len(frames), 0.01))
    t.start()
    key = str(tmp_path.resolve())
    deadline = time.monotonic() + HANG_S
    while time.monotonic() < deadline:
        head = post._HEADS.get(key)
        if head is not None and len(head.done) >= chunks:
            break
        time.sleep(0.01)
    stop.set()
    t.join()
    return post._HEADS[key]


def test_frames_measured_while_the_dump_grows_are_the_measures_of_the_whole(tmp_path,
                                                                          monkeypatch):
    """follow measures whole chunks of the frames written so far (not the torn one); the
    finished run's measures take them and equal, bit for bit, those computed after the run."""
    from rackstress.stress import measures

    frames = [(s, np.concatenate([p, LONE])) for s, p in _frames()]
    frames = frames + [(40 + s, p) for s, p in frames]            # 8 frames
    monkeypatch.setattr(measures, "CHUNK_BYTES", 1)                 # a chunk a frame
    write_run(tmp_path, PARTS, frames)
    want = measure_frames(load_run(tmp_path))
    head = _follow_until(tmp_path, frames, 5, 5)
    assert sorted(head.done) == [(k, 1) for k in range(5)]          # not frame 5, torn
    kept = dict(head.tables)                    # the atom tables follow parsed
    assert sorted(kept) == list(range(5))
    write_run(tmp_path, PARTS, frames)                              # the run goes on and ends
    post._MEMO.clear()
    run = load_run(tmp_path)
    fields = post.compute_fields(run, cache=False)
    assert fields.timings["frames_measured_while_running"] == 5
    for m in MEASURES:
        assert np.array_equal(fields.values[m], want[m], equal_nan=True), m
    # the finished run's reader holds those tables (its forked writers read no text again;
    # frame 0 it read itself when the run was opened), and every frame reads as a run opened
    # anew parses it from the finished dump
    held = run.trajectory._tables
    assert all(held[k] is kept[k] for k in range(1, 5))
    fresh = load_run(tmp_path)
    for k in range(len(frames)):
        assert np.array_equal(run.trajectory[k].data["positions64"],
                              fresh.trajectory[k].data["positions64"]), k


def test_follow_keeps_no_table_the_finished_reader_would_not_hold(tmp_path, monkeypatch):
    """A run whose frames will not all fit the reader's cache (dump.CACHE_BYTES): follow's
    tables are not kept for it (the finished run's reader would not hold them either)."""
    from rackstress.stress import dump, measures

    frames = [(s, np.concatenate([p, LONE])) for s, p in _frames()]
    monkeypatch.setattr(measures, "CHUNK_BYTES", 1)
    write_run(tmp_path, PARTS, frames)
    table = load_run(tmp_path).trajectory._table(0).nbytes        # a frame's atom lines
    # the 2 frames written so far fit (follow's reader holds them), not the 4 the run writes
    monkeypatch.setattr(dump, "CACHE_BYTES", int(2.5 * table))
    post._HEADS.clear()
    head = _follow_until(tmp_path, frames, 2, 2)
    assert sorted(head.done) == [(0, 1), (1, 1)] and head.tables == {}


def test_a_frame_changed_after_it_was_measured_is_measured_again(tmp_path, monkeypatch):
    """A run cut after divergence, or written again, differs from what follow read: its chunk
    is measured anew from the finished dump."""
    from rackstress.stress import measures

    frames = [(s, np.concatenate([p, LONE])) for s, p in _frames()]
    monkeypatch.setattr(measures, "CHUNK_BYTES", 1)
    write_run(tmp_path, PARTS, frames)
    head = _follow_until(tmp_path, frames, 4, 4)
    kept = dict(head.tables)
    moved = [(s, p.copy()) for s, p in frames]
    moved[2][1][0, 0] += 0.5                                        # frame 2 is not as read
    write_run(tmp_path, PARTS, moved)
    want = measure_frames(load_run(tmp_path))
    post._MEMO.clear()
    run = load_run(tmp_path)
    fields = post.compute_fields(run, cache=False)
    assert fields.timings["frames_measured_while_running"] == 3
    for m in MEASURES:
        assert np.array_equal(fields.values[m], want[m], equal_nan=True), m
    # frame 2's table as follow read it is not the finished run's: that frame is read anew
    assert run.trajectory._tables[2] is not kept[2]
    assert run.trajectory[2].data["positions64"][0, 0] == moved[2][1][0, 0]

"""Smoke runs of ``rackstress bench stability | accuracy | perf`` at minimal sizes (real engines)."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from rackstress.bench import accuracy, perf, stability
from rackstress.cli import main


def test_bench_stability_smoke(tmp_path):
    runner = CliRunner()
    res = runner.invoke(main, ["bench", "stability", "--quick", "--out", str(tmp_path),
                               "--only", "plane-rack", "--only", "damping"])
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "stability.json").read_text())
    assert {c["family"] for c in data["cases"]} == {"rack bind", "damping", "verlet mode"}
    v = next(c for c in data["cases"] if c["family"] == "verlet mode")
    # the second-order mode's limit is 2/ω whatever the damping (leapfrog)
    assert v["t_pred"] == pytest.approx(2.0 / np.sqrt(v["limit"]["omega2"]), rel=1e-9)
    for c in data["cases"]:
        assert c["converged"] and c["within_2x"], c
        # the bracket: its lower end was stable, its upper end was not
        lo, hi = c["bracket"]
        assert hi / lo <= 1.0 + stability.REL_TOL + 1e-12
    damp = next(c for c in data["cases"] if c["family"] == "damping")
    # plane-bound d=2 with damping 50: t_max = 4/(γ + √(γ² + 4ω²)) with γ = 50
    assert damp["limit"]["gamma"] == pytest.approx(50.0)
    assert (tmp_path / "stability.md").read_text().count("|") > 10
    assert (tmp_path / "stability.png").stat().st_size > 1000
    assert "wrote" in res.output


@pytest.mark.slow
@pytest.mark.lammps
def test_bench_accuracy_smoke(tmp_path):
    data = accuracy.run_bench(tmp_path, quick=True, scenes_=("plane-rack",), echo=lambda s: None)
    rows = data["scenes"][0]["rows"]
    assert len(rows) == 4 * 5 and all(r["status"] == "ok" for r in rows)
    for r in rows:
        assert abs(r["T"] - 3.0) < 1e-12          # the same physical time at every t
        if (r["engine"], r["mode"]) == ("lammps", "exact"):
            assert r["vs_reference_same_t"] < 1e-10   # exact mode: the reference to round-off
    ref = [r["pos_max"] for r in rows if r["engine"] == "reference" and r["integrator"] == "euler"]
    assert all(a > b for a, b in zip(ref, ref[1:]))   # smaller t, smaller error
    assert data["scenes"][0]["observed_order_reference"][-1] > 0.8
    assert min(data["scenes"][0]["observed_order_verlet"]) >= 1.9   # the second-order mode
    # a verlet step costs an Eq. 5 step: at equal t (equal work) its error is >= 10x smaller
    err = {(r["integrator"], r["t"]): r["pos_max"] for r in rows
           if (r["engine"], r["mode"]) == ("lammps", "exact")}
    assert all(err[("euler", t)] >= 10 * err[("verlet", t)] for t in (0.01, 0.005, 0.0025))
    assert data["scenes"][0]["verlet_front"]["lammps"]["points"]
    assert (tmp_path / "accuracy.png").stat().st_size > 1000
    assert "lammps fast" in (tmp_path / "accuracy.md").read_text()
    ff = data["scenes"][0]["fast_front"]
    assert [p["t"] for p in ff["points"]] == [0.02, 0.01, 0.005, 0.0025]
    assert "the front" in (tmp_path / "accuracy.md").read_text()
    c = data["scenes"][0]["error_constants"]["lammps"]
    # e1 = A t and e2 = B t^2, so the ratio at equal t, A/(B t), is 10 at t* = A/(10 B)
    for t in (0.01, 0.005, 0.0025):
        assert err[("euler", t)] / err[("verlet", t)] == pytest.approx(c["A"] / (c["B"] * t),
                                                                       rel=0.15)
    assert c["t_star"] >= 0.01


@pytest.mark.lammps
@pytest.mark.mpi
def test_bench_perf_interleaves_the_plugin_on_one_and_two_ranks(tmp_path):
    """The plugin's 1- and 2-rank rows of a scene run as an interleaved pair (1, 2, 1, 2) with
    the PMPI shim in every rank: each row keeps its best wall time, every run's, and each rank's
    CPU time outside MPI calls; the verdict compares the two."""
    cfg = (("lammps", "exact", 1, "plugin", "magpod-small", 8),
           ("lammps", "exact", 2, "plugin", "magpod-small", 8))
    data = perf.run_bench(tmp_path, steps=8, profile_steps=0, scene_name="magpod-small",
                          configs=cfg, echo=lambda s: None, kernel_times=False, interleave=2)
    one, two = data["rows"]
    assert (one["status"], two["status"]) == ("ok", "ok"), (one.get("error"), two.get("error"))
    assert one["plugin"] and two["plugin"] and two["ranks"] == 2
    assert len(one["repeats"]) == len(two["repeats"]) == 2
    assert one["wall_s"] == min(g["wall_s"] for g in one["repeats"])
    assert one["work_outside_mpi"] and two["work_outside_mpi"]
    assert len(one["work_ms_per_it"]) == 1 and len(two["work_ms_per_it"]) == 2
    assert all(w > 0 for w in one["work_ms_per_it"] + two["work_ms_per_it"])
    assert "the plugin on 2 ranks against 1" in (tmp_path / "perf.md").read_text()


def test_error_constants_of_first_and_second_order_errors_by_hand():
    A, B = 4.0, 100.0
    rows = [{"engine": "reference", "mode": "exact", "integrator": integ, "t": t, "t_pred": 0.05,
             "pos_max": A * t if integ == "euler" else B * t * t}
            for t in (0.02, 0.01, 0.005) for integ in ("euler", "verlet")]
    c = accuracy.error_constants(rows, [2.0, 2.0])["reference"]
    assert c["A"] == pytest.approx(A) and c["B"] == pytest.approx(B)
    assert c["t_star"] == pytest.approx(0.004)            # A / (10 B): where A/(B t) = 10
    assert c["t_star_over_t_max"] == pytest.approx(0.08)
    assert c["steps_saved_at"]["0.001"] == pytest.approx(A / np.sqrt(1e-3 * B))   # t1/t2 at ε
    assert accuracy.error_constants(rows, [2.0, 1.1])["reference"] is None   # not second order


def test_equal_t_ratios_by_hand():
    """Eq. 5's error over the verlet mode's at each t, in both norms, paired by engine and t."""
    rows = [{"engine": "reference", "mode": "exact", "integrator": "euler", "t": 0.01,
             "pos_max": 0.04, "pos_rms": 0.03},
            {"engine": "reference", "mode": "exact", "integrator": "verlet", "t": 0.01,
             "pos_max": 0.01, "pos_rms": 0.002},
            {"engine": "lammps", "mode": "fast", "integrator": "euler", "t": 0.01,
             "pos_max": 1.0, "pos_rms": 1.0},      # fast mode: not Eq. 5 exactly, not paired
            {"engine": "reference", "mode": "exact", "integrator": "verlet", "t": 0.005,
             "pos_max": 0.001, "pos_rms": 0.001}]  # no Eq. 5 run at this t: no ratio
    got = accuracy.equal_t_ratios(rows)
    assert len(got) == 1
    assert got[0]["engine"] == "reference" and got[0]["t"] == 0.01
    assert got[0]["max"] == pytest.approx(4.0) and got[0]["rms"] == pytest.approx(15.0)


@pytest.mark.lammps
def test_bench_perf_smoke(tmp_path):
    data = perf.run_bench(tmp_path, steps=4, profile_steps=4, scene_name="magpod-small",
                          configs=(("reference", "exact", 1), ("lammps", "exact", 1),
                                   ("lammps", "fast", 2), ("lammps", "exact", 1, "numpy")),
                          echo=lambda s: None, kernel_times=False)
    rows = data["rows"]
    assert [r["status"] for r in rows] == ["ok"] * 4, [r.get("error") for r in rows]
    assert [r["kernels"] for r in rows] == ["—", "numba", "numba", "numpy"]
    assert rows[3]["cpu_ms_per_it"] > 0 and data["kernel_compile"] is None
    ex = rows[1]
    assert ex["x_lammps_exact_1"] == 1.0 and ex["maxrss_mb"] > 10
    assert ex["breakdown"]["_loop"]["steps"] == 4 and "Modify" in ex["breakdown"]
    assert 0.0 < ex["callback_share"] < 1.0 and ex["callback_calls"] >= 4
    assert rows[2]["ranks"] == 2 and len(rows[2]["callback_s_per_rank"]) == 2
    assert np.isclose(data["paper"]["particle_steps_per_s"], 33689 * 1200 / 142)
    md = (tmp_path / "perf.md").read_text()
    assert "paper" in md and "MPI" not in md.split("\n")[0]


def test_bench_e2e_writes_the_package_bytecode_its_runs_read(monkeypatch):
    """``bench e2e`` writes the package's bytecode before its runs (as pip's install does),
    also under ``PYTHONDONTWRITEBYTECODE``: a module's cached file is there afterwards and
    stamped with its source's modification time and size (PEP 552's header: flags 0, then
    mtime and size, little-endian)."""
    import importlib.util
    import struct
    from pathlib import Path

    from rackstress.bench import e2e

    monkeypatch.setenv("PYTHONDONTWRITEBYTECODE", "1")
    monkeypatch.setattr("sys.dont_write_bytecode", True)
    src = Path(e2e.__file__).parent.parent / "lib" / "vec.py"
    pyc = Path(importlib.util.cache_from_source(str(src)))
    pyc.unlink(missing_ok=True)
    assert e2e.bytecode() == src.parent.parent
    head = pyc.read_bytes()[:16]
    st = src.stat()
    assert head[:4] == importlib.util.MAGIC_NUMBER
    assert struct.unpack("<III", head[4:16]) == (0, int(st.st_mtime) & 0xFFFFFFFF,
                                                 st.st_size & 0xFFFFFFFF)


def test_bench_walls_quick_reads_a_wall_of_whole_cells_like_beam_theory(tmp_path):
    """``rackstress bench walls --quick``: a cantilever 4 spacings deep (face cells whole,
    φ = 1) deflects as Timoshenko's beam (F·L³/3EI + F·L/κGA, by hand from the bench's
    geometry) within 2 %, its particles' curvature gives M·c/I within 2 % and its face reads
    M·c/I within 3 %; the 4.29 deep one's face cells overhang (φ = 1.145, (4.29 − 3)/2 + ½).
    Bound by its bindings alone (``poisson = "lattice"``, the default), the 4-deep wall's top
    particles, edges included, read M·c/I within 3 % (its edges read 8.8 % high with the
    volumetric lattice's sample offsets)."""
    res = CliRunner().invoke(main, ["bench", "walls", "--quick", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    rows = json.loads((tmp_path / "walls-quick.json").read_text())["rows"]
    whole, over, bound = rows
    assert (whole["layers"], over["layers"], bound["layers"]) == (4, 4, 4)
    assert bound["poisson"] == "lattice" and bound["settled"]
    assert bound["beam_low"] == pytest.approx(1.0, abs=0.03)
    assert bound["beam_high"] == pytest.approx(1.0, abs=0.03)
    assert whole["phi"] == pytest.approx(1.0, abs=1e-6)
    assert over["phi"] == pytest.approx(1.145, abs=1e-3)
    assert whole["settled"] and over["settled"]
    assert whole["tip_ratio"] == pytest.approx(1.0, abs=0.02)
    assert whole["curvature_ratio"] == pytest.approx(1.0, abs=0.02)
    assert whole["face_ratio"] == pytest.approx(1.0, abs=0.03)
    assert "| material | 4.29 | 0.3 | 4 | 1.145 |" in (tmp_path / "walls-quick.md").read_text()

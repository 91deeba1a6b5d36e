"""Stress measures on synthetic run directories with analytic answers; bad dumps → clear errors.

Every run directory here is written by the test itself (scene.json, particles.data, a LAMMPS
dump custom file at full precision) and read back through MDAnalysis (RackDumpReader).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rackstress.errors import RackstressError
from rackstress.stress import (AccumulatedDistance, DataMismatchError, DesiredPositionDistance,
                               DumpColumnsError, DumpError, NonAffineD2min, PartMotion,
                               TruncatedDumpError, VirialStress, VonMisesStrain, load_run,
                               von_mises_strain)

COLUMNS = ("id", "type", "mol", "x", "y", "z")


# ----------------------------------------------------------------------------- writing runs
def lattice(nx, ny, nz, spacing=1.0, origin=(0.0, 0.0, 0.0)):
    g = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij"), -1)
    return g.reshape(-1, 3) * spacing + np.asarray(origin, float)


def _r(x) -> str:
    """A float at full precision (shortest round-trip repr)."""
    return repr(float(x))


def frame_text(step, p, types, mols, columns=COLUMNS, extra=None):
    n = len(p)
    lines = [f"ITEM: TIMESTEP\n{step}\nITEM: NUMBER OF ATOMS\n{n}\nITEM: BOX BOUNDS mm mm mm\n"]
    lo, hi = p.min(0), p.max(0)
    lines += [f"{_r(lo[k])} {_r(hi[k])}\n" for k in range(3)]
    lines.append("ITEM: ATOMS " + " ".join(columns) + "\n")
    for i in range(n):
        row = {"id": str(i + 1), "type": str(types[i]), "mol": str(mols[i]),
               "x": repr(float(p[i, 0])), "y": repr(float(p[i, 1])), "z": repr(float(p[i, 2]))}
        if extra is not None:
            row.update({k: repr(float(v[i])) for k, v in extra.items()})
        lines.append(" ".join(row[c] for c in columns) + "\n")
    return "".join(lines)


def write_run(d: Path, parts, frames, dt=0.01, columns=COLUMNS, extras=None, shuffle=False):
    """parts: [(name, kind, o)], frames: [(step, p)]. Returns (types, mols)."""
    d.mkdir(parents=True, exist_ok=True)
    o = np.concatenate([q for _, _, q in parts])
    types = np.concatenate([np.full(len(q), k + 1) for k, (_, _, q) in enumerate(parts)])
    mols = types.copy()
    groups, first = [], 1
    for k, (name, kind, q) in enumerate(parts):
        groups.append({"name": name, "kind": kind, "host": None, "n": len(q), "type": k + 1,
                       "mol": k + 1, "first_id": first})
        first += len(q)
    (d / "scene.json").write_text(json.dumps({"scene": "synthetic", "dt": dt, "groups": groups,
                                              "phases": []}))
    lo, hi = o.min(0) - 1, o.max(0) + 1
    text = [f"LAMMPS data file: synthetic\n\n{len(o)} atoms\n{len(parts)} atom types\n\n",
            "".join(f"{_r(lo[k])} {_r(hi[k])} {a}lo {a}hi\n" for k, a in enumerate("xyz")),
            "\nMasses\n\n" + "".join(f"{k + 1} 1.0  # {n}\n" for k, (n, _, _) in enumerate(parts)),
            "\nAtoms  # bond\n\n"]
    text += [f"{i + 1} {mols[i]} {types[i]} {_r(o[i, 0])} {_r(o[i, 1])} {_r(o[i, 2])}\n"
             for i in range(len(o))]
    (d / "particles.data").write_text("".join(text))
    with open(d / "trajectory.dump", "w") as fh:
        for k, (step, p) in enumerate(frames):
            extra = extras[k] if extras is not None else None
            fh.write(frame_text(step, p, types, mols, columns, extra))
    return types, mols


def rigid(o, rotvec, t):
    return o @ Rotation.from_rotvec(rotvec).as_matrix().T + np.asarray(t, float)


BLOCK = lattice(6, 5, 4)                       # 120 particles, 3D
SHEET = lattice(7, 1, 6, origin=(10, 0, 0))    # 42 particles, planar (x–z)


# ----------------------------------------------------------------------------- reading
def test_universe_reads_types_groups_and_full_precision(tmp_path):
    p1 = rigid(BLOCK, (0.1, 0.2, 0.3), (1e3 + 1 / 3, -2.5, 7.125))
    write_run(tmp_path, [("block", "body", BLOCK)], [(0, BLOCK), (40, p1)])
    run = load_run(tmp_path)
    u = run.universe
    assert len(u.atoms) == len(BLOCK) and set(u.atoms.types) == {"1"}
    assert u.trajectory.n_frames == 2 and list(run.steps) == [0, 40]
    ts = u.trajectory[1]
    assert ts.data["step"] == 40 and ts.data["time"] == pytest.approx(0.4)
    # float64, not shifted by the box: exactly what was written
    assert np.array_equal(ts.data["positions64"], p1)
    assert np.array_equal(run.o, BLOCK)
    assert run.parts["block"].n == len(BLOCK)


def test_dump_atoms_out_of_id_order_are_sorted(tmp_path):
    write_run(tmp_path, [("block", "body", BLOCK)], [(0, BLOCK)])
    text = (tmp_path / "trajectory.dump").read_text().splitlines(keepends=True)
    head, atoms = text[:9], text[9:]
    (tmp_path / "trajectory.dump").write_text("".join(head + atoms[::-1]))
    run = load_run(tmp_path)
    assert np.array_equal(run.universe.trajectory[0].data["positions64"], BLOCK)


# ----------------------------------------------------------------------------- the paper's measure
@pytest.mark.parametrize("fit", ["robust", "kabsch"])
def test_rigid_rotation_translation_gives_zero(tmp_path, fit):
    frames = [(10 * k, np.concatenate([rigid(BLOCK, (0.3 * k, -0.2 * k, 0.5), (k, 2 * k, -k)),
                                       rigid(SHEET, (0.0, 0.4 * k, 1.1), (5, -k, 3))]))
              for k in range(5)]
    write_run(tmp_path, [("block", "body", BLOCK), ("sheet", "leg", SHEET)], frames)
    run = load_run(tmp_path)
    paper = DesiredPositionDistance(run, fit=fit).run()
    assert paper.results.per_particle.shape == (5, len(BLOCK) + len(SHEET))
    assert np.nanmax(paper.results.per_particle) < 1e-12
    acc = AccumulatedDistance(run, fit=fit).run()
    assert np.nanmax(acc.results.per_particle) < 1e-12
    # a rigid motion has no strain either
    strain = VonMisesStrain(run).run()
    assert np.nanmax(strain.results.per_particle) < 1e-12
    assert np.nanmax(strain.results.d2min) < 1e-20


def test_local_bump_gives_exactly_its_displacement(tmp_path):
    o = lattice(8, 6, 5)                               # 240 particles
    centre = np.array([7.0, 5.0, 4.0])                 # a corner
    r2 = ((o - centre) ** 2).sum(1)
    bump = r2 <= 2.0                                   # 7 particles
    amp = 0.4 * np.exp(-r2 / 2.0)
    b = np.zeros_like(o)
    b[bump] = amp[bump, None] * np.array([0.6, 0.8, 0.0])   # in the part's own frame
    frames = [(0, o)]
    rot, t = (0.2, -0.7, 0.4), (3.0, -1.0, 12.0)
    frames.append((100, rigid(o + b, rot, t)))          # deform, then move rigidly
    write_run(tmp_path, [("body", "body", o)], frames)
    run = load_run(tmp_path)
    got = DesiredPositionDistance(run).run().results.per_particle[1]
    expected = np.linalg.norm(b, axis=1)
    assert bump.sum() == 7
    assert np.abs(got - expected).max() < 1e-12
    assert np.abs(got[~bump]).max() < 1e-12
    # the plain least-squares fit is dragged by the bump: not exact (why the robust fit)
    plain = DesiredPositionDistance(run, fit="kabsch").run().results.per_particle[1]
    assert np.abs(plain[~bump]).max() > 1e-3


def test_accumulated_is_the_time_integral(tmp_path):
    o = lattice(5, 4, 3)
    sel = np.zeros(len(o), bool)
    sel[0] = True
    frames = []
    steps = [0, 10, 30, 60]
    amps = [0.0, 0.2, 0.2, 0.5]
    for s, a in zip(steps, amps):
        p = o.copy()
        p[sel] += [0.0, a, 0.0]
        frames.append((s, p))
    write_run(tmp_path, [("body", "body", o)], frames, dt=0.5)
    run = load_run(tmp_path)
    acc = AccumulatedDistance(run).run().results
    t = np.array(steps) * 0.5
    expected = np.concatenate([[0.0], np.cumsum(0.5 * (np.array(amps[1:]) + amps[:-1])
                                                 * np.diff(t))])
    assert np.allclose(acc.per_particle[:, 0], expected, atol=1e-12, rtol=0)
    assert np.abs(acc.per_particle[:, 1:]).max() < 1e-12
    assert np.allclose(acc.distance[:, 0], amps, atol=1e-12, rtol=0)


# ----------------------------------------------------------------------------- strain
def shear_eta(g):
    return np.sqrt(g ** 2 / 4 + g ** 4 / 12)


def test_uniform_simple_shear_gives_analytic_von_mises_strain(tmp_path):
    o = lattice(6, 6, 5, spacing=1.0)
    frames = [(0, o)]
    gammas = [0.05, 0.2]
    Q = Rotation.from_rotvec((0.3, 0.1, -0.5)).as_matrix()
    for k, g in enumerate(gammas, start=1):
        F = np.eye(3)
        F[0, 1] = g                                   # x += γ y
        frames.append((k, o @ (Q @ F).T + [1.0, 2.0, 3.0]))
    write_run(tmp_path, [("block", "body", o)], frames)
    run = load_run(tmp_path)
    res = VonMisesStrain(run).run().results
    assert np.abs(res.per_particle[0]).max() < 1e-12
    for k, g in enumerate(gammas, start=1):
        assert np.abs(res.per_particle[k] - shear_eta(g)).max() < 1e-10, g
        assert np.nanmax(res.d2min[k]) < 1e-20       # affine: nothing non-affine
    # the D²min class is the same fit
    d2 = NonAffineD2min(run).run().results
    assert np.nanmax(d2.per_particle) < 1e-20
    assert np.abs(d2.von_mises[2] - shear_eta(0.2)).max() < 1e-10


def test_planar_sheet_uniaxial_stretch_membrane_strain(tmp_path):
    o = lattice(7, 1, 6)                               # planar: Σ d0 d0ᵀ is singular
    eps = 0.1
    F = np.diag([1 + eps, 1.0, 1.0])
    Q = Rotation.from_rotvec((0.7, 0.2, 0.1)).as_matrix()   # tilt the sheet out of its plane
    p = o @ (Q @ F).T + [0.0, 5.0, 0.0]
    write_run(tmp_path, [("sheet", "plane", o)], [(0, o), (1, p)])
    res = VonMisesStrain(load_run(tmp_path)).run().results
    exx = 0.5 * ((1 + eps) ** 2 - 1)
    assert np.abs(res.per_particle[1] - exx / np.sqrt(3)).max() < 1e-10
    assert np.nanmax(res.d2min[1]) < 1e-20


def test_von_mises_formula_matches_ovito_definition():
    E = np.array([[0.1, 0.02, 0.03], [0.02, -0.05, 0.04], [0.03, 0.04, 0.2]])
    expected = np.sqrt(0.02 ** 2 + 0.04 ** 2 + 0.03 ** 2
                       + ((0.1 + 0.05) ** 2 + (-0.05 - 0.2) ** 2 + (0.2 - 0.1) ** 2) / 6)
    assert von_mises_strain(E) == pytest.approx(expected, rel=1e-14)


def test_non_affine_bump_shows_in_d2min_not_far_away(tmp_path):
    o = lattice(8, 6, 5)
    p = o.copy()
    p[100] += [0.0, 0.3, 0.0]                         # one particle pushed out of place
    write_run(tmp_path, [("body", "body", o)], [(0, o), (1, p)])
    res = NonAffineD2min(load_run(tmp_path)).run().results
    d2 = res.per_particle[1]
    far = np.linalg.norm(o - o[100], axis=1) > 3.0
    assert d2[100] > 0.01 and np.nanmax(d2[far]) < 1e-20


# ----------------------------------------------------------------------------- virial
def test_virial_columns_give_von_mises_stress(tmp_path):
    o = lattice(3, 3, 3)
    n = len(o)
    s = {f"c_st[{k}]": np.zeros(n) for k in range(1, 7)}
    s["c_st[1]"][:] = 2.0                 # uniaxial σxx = 2 → σ_vm = 2
    s["c_st[4]"][5] = 1.5                 # plus shear σxy on one atom
    cols = COLUMNS + tuple(s)
    write_run(tmp_path, [("body", "body", o)], [(0, o)], columns=cols, extras=[s])
    res = VirialStress(load_run(tmp_path)).run().results
    expected = np.full(n, 2.0)
    expected[5] = np.sqrt(0.5 * (4 + 0 + 4) + 3 * 1.5 ** 2)
    assert np.allclose(res.per_particle[0], expected, rtol=1e-14)
    assert np.allclose(res.pressure[0], -2.0 / 3)


def test_virial_absent_is_a_clear_error(tmp_path):
    write_run(tmp_path, [("body", "body", BLOCK)], [(0, BLOCK)])
    with pytest.raises(DumpColumnsError, match="did not record per-atom virial stress"):
        VirialStress(load_run(tmp_path))


# ----------------------------------------------------------------------------- motion
def test_part_motion_centre_of_mass_and_footprints(tmp_path):
    sed = lattice(6, 1, 6, spacing=4.0, origin=(-10, -2, -10))
    p_sed = sed.copy()
    p_sed[7, 1] -= 1.5
    body = BLOCK
    write_run(tmp_path, [("body", "body", body), ("sediment", "sediment", sed)],
              [(0, np.concatenate([body, sed])),
               (5, np.concatenate([body + [4.0, 0.0, 0.0], p_sed])),
               (9, np.concatenate([body + [6.0, 0.0, 0.0], sed]))])
    res = PartMotion(load_run(tmp_path)).run().results
    assert np.allclose(res.com[:, 0, 0] - body[:, 0].mean(), [0.0, 4.0, 6.0])
    fp = res.footprints["sediment"]
    assert fp["min_dy"][7] == pytest.approx(-1.5) and np.abs(np.delete(fp["min_dy"], 7)).max() == 0
    assert np.abs(fp["final_dy"]).max() == 0


def test_part_motion_of_parts_given_out_of_order(tmp_path):
    """A part whose particles are not consecutive (its index read in another order) has the
    same centre of mass, box and footprints as the part in order: hand values of a block
    moved by (4, -1, 2) and a sediment with one particle pressed 1.5 down."""
    sed = lattice(6, 1, 6, spacing=4.0, origin=(-10, -2, -10))
    p_sed = sed.copy()
    p_sed[7, 1] -= 1.5
    write_run(tmp_path, [("body", "body", BLOCK), ("sediment", "sediment", sed)],
              [(0, np.concatenate([BLOCK, sed])),
               (5, np.concatenate([BLOCK + [4.0, -1.0, 2.0], p_sed]))])
    run = load_run(tmp_path)
    for part in run.parts.values():
        part.index = part.index[::-1].copy()
    res = PartMotion(run).run().results
    centre = BLOCK.mean(axis=0)
    assert np.allclose(res.com[:, 0], [centre, centre + [4.0, -1.0, 2.0]])
    assert np.array_equal(res.lo[1, 0], BLOCK.min(axis=0) + [4.0, -1.0, 2.0])
    assert np.array_equal(res.hi[1, 1], sed.max(axis=0))
    assert res.lo[1, 1, 1] == -3.5                     # the pressed particle: y -2 - 1.5
    fp = res.footprints["sediment"]                    # in the (reversed) index's order
    k = len(sed) - 1 - 7
    assert fp["min_dy"][k] == pytest.approx(-1.5) and np.abs(np.delete(fp["min_dy"], k)).max() == 0


# ----------------------------------------------------------------------------- bad input
def _good(tmp_path, n_frames=4):
    frames = [(10 * k, rigid(BLOCK, (0.0, 0.1 * k, 0.0), (k, 0, 0))) for k in range(n_frames)]
    write_run(tmp_path, [("block", "body", BLOCK)], frames)
    return tmp_path / "trajectory.dump"


def test_truncated_dump_names_file_step_and_atoms(tmp_path):
    dump = _good(tmp_path)
    text = dump.read_text()
    lines = text.splitlines(keepends=True)
    per = len(BLOCK) + 9
    cut = 3 * per + 9 + 50                    # frame 3 (step 30): header and 50 atom lines
    dump.write_text("".join(lines[:cut]))
    with pytest.raises(TruncatedDumpError) as err:
        load_run(tmp_path)
    msg = str(err.value)
    assert str(dump) in msg and "ends mid-frame at step 30 (frame 3)" in msg
    assert f"50 of {len(BLOCK)} atoms" in msg and "--allow-truncated" in msg
    assert err.value.step == 30 and err.value.atoms_read == 50
    # the complete frames are still there on request
    run = load_run(tmp_path, allow_truncated=True)
    assert list(run.steps) == [0, 10, 20] and "step 30" in run.truncation
    assert DesiredPositionDistance(run).run().results.per_particle.shape == (3, len(BLOCK))


def test_dump_cut_mid_line_is_truncated_too(tmp_path):
    dump = _good(tmp_path, 2)
    data = dump.read_bytes()
    dump.write_bytes(data[:-7])              # the last atom line loses its end
    with pytest.raises(TruncatedDumpError, match=rf"step 10 \(frame 1\): {len(BLOCK) - 1} of"):
        load_run(tmp_path)


def test_missing_columns_is_a_clear_error(tmp_path):
    frames = [(0, BLOCK)]
    write_run(tmp_path, [("block", "body", BLOCK)], frames)
    dump = tmp_path / "trajectory.dump"
    # rewrite without z
    rows = dump.read_text().splitlines()
    out = []
    for line in rows:
        if line.startswith("ITEM: ATOMS"):
            out.append("ITEM: ATOMS id type mol x y")
        elif len(line.split()) == 6:
            out.append(" ".join(line.split()[:5]))
        else:
            out.append(line)
    dump.write_text("\n".join(out) + "\n")
    with pytest.raises(DumpColumnsError) as err:
        load_run(tmp_path)
    assert str(dump) in str(err.value) and "x y z" in str(err.value)
    assert isinstance(err.value, RackstressError)


def test_data_file_atom_count_mismatch(tmp_path):
    _good(tmp_path)
    other = tmp_path / "other"
    write_run(other, [("block", "body", BLOCK[:-1])], [(0, BLOCK[:-1])])
    (tmp_path / "particles.data").write_bytes((other / "particles.data").read_bytes())
    with pytest.raises(DataMismatchError) as err:
        load_run(tmp_path)
    msg = str(err.value)
    assert "trajectory.dump" in msg and "particles.data" in msg
    assert f"{len(BLOCK)} atoms per frame" in msg and f"has {len(BLOCK) - 1}" in msg


def test_data_file_type_mismatch(tmp_path):
    dump = _good(tmp_path)
    lines = dump.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("17 "))
    f = lines[k].split()
    f[1] = "2"
    lines[k] = " ".join(f)
    dump.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataMismatchError, match="atom 17 has type 2 in .*trajectory.dump but "
                                                "type 1 in .*particles.data"):
        load_run(tmp_path)
    # and a scene.json whose groups do not match the data file
    _good(tmp_path)
    data = tmp_path / "particles.data"
    text = data.read_text().replace("\n17 1 1 ", "\n17 1 2 ")
    data.write_text(text)
    with pytest.raises(DataMismatchError, match="group 'block' has type 1 but its atoms in "):
        load_run(tmp_path)


def test_not_a_dump_is_a_clear_error(tmp_path):
    _good(tmp_path)
    (tmp_path / "trajectory.dump").write_text("hello\nworld\n" * 10)
    with pytest.raises(DumpError, match="expected 'ITEM: TIMESTEP'"):
        load_run(tmp_path)


def test_malformed_atom_line_is_a_clear_error(tmp_path):
    dump = _good(tmp_path, 2)
    text = dump.read_text().replace("\n5 1 1 ", "\n5 1 1 abc ", 1)
    dump.write_text(text)
    run_err = None
    try:
        load_run(tmp_path)
    except DumpError as err:
        run_err = err
    assert run_err is not None and "atom line 5" in str(run_err) and str(dump) in str(run_err)

"""The plugin's per-step work over the moving rows only (rs_common.h, "Resting
atoms"): ``rs/force``, ``rs/dampen`` (no contact) and ``rs/nve`` against LAMMPS' own ``fix
addforce``, ``fix viscous`` and ``fix nve`` (the independent path: LAMMPS' implementation of the same arithmetic, Eqs. 8–9)
in a deck whose resting atoms sit after ``atom_modify first``'s rows; the watchdog's prefix of
moving rows; the plugin check's version string.

Real LAMMPS with the compiled plugin; expected values from LAMMPS' own styles or by hand.
"""
from __future__ import annotations

import numpy as np
import pytest

from rackstress.engines.lammps import plugin
from rackstress.engines.lammps.runner import moving_prefix, plugin_library

pytestmark = pytest.mark.lammps

#: three moving atoms of two types and two resting ones (type 3), ids interleaved so that
#: ``atom_modify first`` has rows to reorder; each moving atom starts with its own velocity
DECK = """
units lj
dimension 3
boundary f f f
atom_style atomic
atom_modify map array sort 0 0.0 first moving
region box block -10 10 -10 10 -10 10
create_box 3 box
create_atoms 3 single 0 0 0
create_atoms 1 single 1 0 0
create_atoms 3 single 0 3 0
create_atoms 2 single 2 0 1
create_atoms 1 single 3 1 0
mass 1 2.0
mass 2 0.5
mass 3 4.0
group moving type 1 2
group two type 2
velocity moving set 0.3 -0.2 0.1 units box
set atom 4 vx -0.5 vy 0.25 vz 0.75
timestep 0.01
{fixes}
fix integrate moving {integrate}
run 50
"""


def _run(fixes: str, load: bool, integrate: str = "nve") -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities by atom id after the deck's 50 steps."""
    from rackstress.lib.mpi import lammps_module

    lmp = lammps_module().lammps(cmdargs=["-log", "none", "-screen", "none"])
    try:
        if load:
            lmp.command(f"plugin load {plugin_library()}")
        lmp.commands_string(DECK.format(fixes=fixes, integrate=integrate))
        ids = lmp.numpy.extract_atom("id")[:5].copy()
        order = np.argsort(ids)
        x = lmp.numpy.extract_atom("x")[:5][order].copy()
        v = lmp.numpy.extract_atom("v")[:5][order].copy()
        nfirst = lmp.numpy.extract_atom("mask")[:5]
        assert int(np.count_nonzero(nfirst & 2)) == 3      # the moving group (bit of group 1)
        return x, v
    finally:
        lmp.close()


def test_rs_force_and_dampen_equal_lammps_addforce_and_viscous_over_the_moving_rows():
    """Eq. 8's constant force and Eq. 9's damping (c per unit mass, per type: γ = c·m, as fix
    viscous takes it) over the moving rows only give LAMMPS' own styles' trajectory bit for
    bit, and the resting atoms stay where they were, with v = 0."""
    c1, c2 = 0.7, 1.5
    ours = _run("fix f1 moving rs/force 0.25 -1.0 0.5\n"
                "fix f2 two rs/force 0.0 0.125 0.0\n"
                f"fix d moving rs/dampen 0 type 1 {c1} type 2 {c2}\n"
                "fix d2 two rs/dampen 0.3", load=True)
    lammps = _run("fix f1 moving addforce 0.25 -1.0 0.5\n"
                  "fix f2 two addforce 0.0 0.125 0.0\n"
                  f"fix d moving viscous 1.0 scale 1 {c1 * 2.0!r} scale 2 {c2 * 0.5!r}\n"
                  f"fix d2 two viscous {0.3 * 0.5!r}", load=False)
    assert np.array_equal(ours[0], lammps[0]) and np.array_equal(ours[1], lammps[1])
    # the resting atoms (ids 1 and 3) never moved
    assert np.array_equal(ours[0][[0, 2]], [[0.0, 0.0, 0.0], [0.0, 3.0, 0.0]])
    assert not ours[1][[0, 2]].any()
    # and the moving ones did (the forces acted)
    assert np.abs(ours[0][[1, 3, 4]] - [[1, 0, 0], [2, 0, 1], [3, 1, 0]]).min() > 0


def test_rs_nve_equals_lammps_nve_over_the_moving_rows():
    """Eq. 5 as fix rs/nve integrates it (dt/2m once per type) gives LAMMPS' own fix nve's
    trajectory bit for bit, with constant forces and damping acting (the same fixes both
    times), and leaves the resting atoms where they were."""
    fixes = ("fix f1 moving rs/force 0.25 -1.0 0.5\n"
             "fix f2 two rs/force 0.0 0.125 0.0\n"
             "fix d moving rs/dampen 0 type 1 0.7 type 2 1.5")
    ours = _run(fixes, load=True, integrate="rs/nve")
    lammps = _run(fixes, load=True, integrate="nve")
    assert np.array_equal(ours[0], lammps[0]) and np.array_equal(ours[1], lammps[1])
    assert np.array_equal(ours[0][[0, 2]], [[0.0, 0.0, 0.0], [0.0, 3.0, 0.0]])
    assert not ours[1][[0, 2]].any()
    assert np.abs(ours[0][[1, 3, 4]] - [[1, 0, 0], [2, 0, 1], [3, 1, 0]]).min() > 0


def test_rs_dampen_alone_follows_eq_9_through_velocity_verlet():
    """Damping only, f = −c·m·v on each moving atom: LAMMPS' fix nve (half kick with the force
    of the last state, drift, force at the new half-step velocity, half kick) worked by hand
    per unit mass, v½ = v + h·a, a = −c·v½, v = v½ + h·a (h = dt/2); the resting atoms stay."""
    c, dt, steps = 0.7, 0.01, 50
    x, v = _run(f"fix d moving rs/dampen {c}", load=True)
    h = dt / 2
    want = np.array([[0.3, -0.2, 0.1], [-0.5, 0.25, 0.75], [0.3, -0.2, 0.1]])
    a = -c * want                     # the setup's force, at v0
    for _ in range(steps):
        half = want + h * a
        a = -c * half
        want = half + h * a
    assert np.allclose(v[[1, 3, 4]], want, rtol=1e-12, atol=0)
    assert not v[[0, 2]].any()


def test_moving_prefix_by_hand():
    """The watchdog's moving rows: the leading rows with the group's bit, from any hint."""
    bit = 4
    mask = np.array([5, 4, 6, 1, 4, 0, 0], np.int32)      # rows 0–2 move; row 4 activated late
    for hint in (0, 1, 3, 5, 7, 100):
        assert moving_prefix(mask, bit, hint) == 3
    assert moving_prefix(np.full(1000, bit, np.int32), bit, 10) == 1000
    assert moving_prefix(np.zeros(4, np.int32), bit, 2) == 0
    assert moving_prefix(np.zeros(0, np.int32), bit, 3) == 0


def test_check_accepts_a_version_string_after_any_non_printable_byte(tmp_path):
    """The linker may put the version string right after another constant (a double ending
    in 0x80 was seen, and every run fell back to the callback): the check accepts it, and
    still names a build for another LAMMPS placed the same way."""
    want = plugin.version_string(plugin.lammps_version()).encode()
    data = bytearray(open(plugin_library(), "rb").read())
    at = data.find(want + b"\0")
    assert at > 0 and not 32 <= data[at - 1] < 127
    data[at - 1] = 0x80
    lib = tmp_path / "this" / plugin.LIBRARY
    lib.parent.mkdir()
    lib.write_bytes(bytes(data))
    assert plugin.check(lib) == ""
    other = "29 Aug 2024".encode()[:len(want)].ljust(len(want), b" ")
    data[at:at + len(want)] = other
    lib = tmp_path / "other" / plugin.LIBRARY
    lib.parent.mkdir()
    lib.write_bytes(bytes(data))
    assert plugin.check(lib).startswith("was built for ")

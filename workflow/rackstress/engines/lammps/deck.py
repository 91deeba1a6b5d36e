"""The deck compiler: a scene becomes a LAMMPS data file and an input deck (docs/model.md, "On LAMMPS").

How each operator is realized (``mode='exact'`` unless said otherwise):

==========================  ================================================================
operator                    LAMMPS realization
==========================  ================================================================
force (phase-conditioned)   ``fix addforce`` on the selected atoms, F = m·â (Eq. 8); constant
                            forces with the same F share one fix (one pass over the atoms)
dampen                      one ``fix viscous`` for all groups, γ = c·m per type (Eq. 9)
dampen (phase-conditioned)  ``fix viscous`` on the group, γ = c·m, redefined at phase switches
dampen + contact extra      base as above; the extra term in the Python callback
collide, reciprocal         ``pair_style lepton`` E = K((r²−R²)/2 − R² ln(r/R)), cut R (Eq. 10)
collide, material contact   the plugin's ``rs/collide``, one fix a side (``[[contact]]``:
                            :func:`material_contacts`), when the deck uses the plugin
collide, one-way            Python callback (a Verlet list over local + ghost atoms)
collide, contact-searched   Python callback, when a contact condition (Eq. 28's damping)
                            already searches the same two groups: the pairs are found once, and
                            ``pair_style lepton`` (which re-parses its expression every step,
                            0.45 ms measured) is not needed
bind                        Python callback, exact per-pair L0 (Eq. 12)
bind, ``mode='fast'``       ``bond_style harmonic`` K = c·m, r0 = L0 (one bond type per
                            distinct L0): equal to Eq. 12 to first order in the strain
attract                     Python callback (Eq. 14), only in phases where it is active
integrate                   ``fix nve`` (the plugin's ``rs/nve`` in plugin decks: the same
                            bits), started with v = v0 + dt/2·a0 after ``run 0`` so its
                            positions are Eq. 5's exactly; the same restart at every phase switch;
                            only on the particles that can move (Active particles, below)
==========================  ================================================================

Directed coefficients: a reciprocal LAMMPS interaction of strength K gives accelerations K/m_i
and K/m_j, so a pair of operators c_ij (on i from j) and c_ji becomes one interaction when the
group masses satisfy m_i·c_ij = m_j·c_ji. Masses are solved over all such pairs (each
component's lightest group gets mass 1); a pair that would contradict earlier ones stays in
Python. Every other operator on a group is scaled by its mass, so accelerations are the paper's.

Skipped because it is exact to skip: no pair style when nothing is realized as a pair style;
``neigh_modify exclude`` for every type pair that does not collide; no bonds in exact mode; no
``fix external`` in a phase where no Python-realized operator is active.

Active particles: a *passive* group (:func:`passive_groups`: at rest, moved only by collisions
the callback evaluates, and damped — MagPod's sediment) is left out of the group ``rs_move``
that ``fix nve`` and ``fix viscous`` act on. A particle of it has zero velocity and zero force
until a collision partner comes within reach, and Eq. 5 does not move such a particle, so
skipping it is exact. ``atom_modify first rs_move`` makes LAMMPS keep the group's atoms first in
its arrays (it reorders them when it reneighbours) and ``fix nve`` loop over those rows only, so
the resting ones cost nothing there; in serial runs the runner adds ``neigh_modify include
rs_move`` (forces cleared, displacements checked and atoms binned over those rows only; a resting
row's force is zeroed once and nothing writes it); the callback adds forces only on the rows it
computed (never a resting one). The callback adds a passive particle to ``rs_move`` (its
group bit in LAMMPS' per-atom mask), for good, as soon as a partner comes within reach + 2 skins
when LAMMPS reneighbours: one reneighbouring before anything can touch it, so LAMMPS has reordered
it among the integrated rows by then. A particle touched at the start is reordered by a second
``run 0``; a force on a row LAMMPS does not integrate yet (a particle that moved more than a skin
between two reneighbourings) stops the run with an error rather than lose exactness. A run
resumed from a checkpoint re-adds every passive particle that is moving. Atom ids stay the
particles' ids (dumps, checkpoints and gathers go by id). In such a deck LAMMPS would still pass
over every atom each step in ``fix addforce``, ``fix viscous`` and fix external's add pass, so
the callback adds its forces into LAMMPS' force array itself (fix external's Napply is never
reached) and the static constant forces and damping too, on the moving rows, in the fixes' own
arithmetic and order (:attr:`Deck.callback_natives`); and LAMMPS' skin is ``PASSIVE_SKIN``, the
callback's contact lists keeping ``SKIN`` with a displacement check of their own.

Plugin (``compile_deck(..., plugin=True)``; ``None``: whenever the compiled plugin is there for
this LAMMPS, what ``rackstress run`` and ``rackstress deck`` ask for): every operator the table
gives to the Python callback becomes a fix of the compiled plugin instead (docs/plugin.md) —
collide ``rs/collide``, bind over every pair (the rack coupling, Eq. 23) ``rs/rack``, bind
within(d) ``rs/bind`` over the data file's bonds (one bond type per bind and its reverse,
``bond_style zero``, ``newton_bond off``), attract ``rs/attract`` (its region index named for the
phase), the contact-conditioned extra of dampen ``rs/dampen``. A phase-conditioned one is defined
while its phase holds (:meth:`Deck.phase_commands`). The styles read per-atom originals, radii
and region indices from ``fix property/atom`` (set right after read_data). Such a deck has no
Python operator and runs standalone; its ghost cutoff is the interaction range
(:func:`plugin_ghost_cutoff`). Active particles work as above, with ``rs/collide ... activate
rs_move`` in the callback's place (the same activation one reneighbouring early; each target's
partners summed in atom-id order, so the reordering changes no bit), a second ``run 0`` at each
setup for particles touched there, and the constant forces and damping as the plugin's
``rs/force`` and ``rs/dampen`` (the arithmetic of ``fix addforce`` and ``fix viscous``, over the
moving rows only: :attr:`Deck.moving_rows`). A scene with an operator the
plugin has no style for (a contact-conditioned force) keeps the callback, and one line says so.
"""
from __future__ import annotations

import math
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rackstress.model import topology
from rackstress.errors import SceneError
from rackstress.model.operators import (Attract, Bind, Collide, Const, Dampen, Force, Indent,
                                        Matched,
                                        contact_groups, phase_active, reverse_of)
from rackstress.model.scene import Phase, Scene
from rackstress.model.verlet import scaled_scene
from rackstress.model.volume import Volume

MODES = ("exact", "fast")
#: The fix external that carries every Python-realized operator.
PY_FIX = "rs_py"
#: A schedule of more phases than this is written with a LAMMPS loop over its identical cycles
#: (:meth:`Deck.schedule_commands`); ``LOOP_VAR`` is the loop's variable and label.
LOOP_AFTER, LOOP_VAR = 10_000, "rs_cycle"
#: fix external's Napply: how often its own pass adds its force array to every owned atom of
#: its group. Never after step 0 (LAMMPS' largest int): the callback adds its forces into
#: LAMMPS' force array itself, on the rows it computed; at step 0 the pass adds zeros.
PY_NAPPLY = 2**31 - 1
#: The group LAMMPS integrates and damps: every particle but the resting ones of passive groups
#: (module doc, "Active particles"); the callback adds a passive particle the moment it can move.
MOVE_GROUP = "rs_move"
#: Neighbour skin (distance units). 2 rather than 1 halves the rebuilds of a MagPod run (measured:
#: 52 against 99 in 300 iterations), each of which re-bins all the resting sediment.
SKIN = 2.0
#: LAMMPS' neighbour skin of a deck with passive groups (module doc, "Active particles"): each
#: reneighbouring there passes over every atom, resting or not (exchange, reordering, atom map,
#: box), ~15 ms for a million atoms, so LAMMPS reneighbours only for the moving rows' reordering
#: (9 rather than 57 times in the first 1200 iterations of sediment-large, measured) while the
#: callback keeps its contact lists with SKIN and its own displacement check (serial).
PASSIVE_SKIN = 8.0
#: LAMMPS' skin of a plugin deck with passive groups: the compiled styles search their contact
#: candidates with LAMMPS' skin (no list of their own), so a wider one costs every step what it
#: saves at each reneighbouring (every pass over all atoms). 4 measured: sediment-large 4.5 ->
#: 2.8 ms per iteration (1 M particles), MagPod unchanged, against 2.
PLUGIN_PASSIVE_SKIN = 4.0
#: How many resting particles a moving one (MOVE_GROUP) weighs in the weighted ``balance rcb`` of a
#: deck with passive groups (:func:`balance_commands`; a scene's ``robot_weight`` overrides it).
#: Measured (``rackstress bench scaling``, each rank's CPU time outside MPI): a moving particle
#: costs ~74 ns a step, a resting one ~3.6 ns, a ratio of ~21. With it the bisection cuts MagPod
#: through the robot (4 leaves it whole on one rank; 20 splits it 2173 / 1888). sediment-large
#: weighs its robot as much as its whole bed (scenes/large.py, at least ROBOT_WEIGHT): at 20 its
#: million resting particles outweighed the robot, which stayed whole on one rank.
MOVE_WEIGHT = 20.0
#: Distinct per-pair coefficients of one bind the plugin takes (a bond type and fix each); a
#: material solid's face compensation gives c·(1 + ¼k), k = 0 … 4: a handful
MAX_PAIR_TYPES = 16
#: Relative tolerance under which two original lengths count as one bond type (fast mode).
L0_DIGITS = 10
#: LAMMPS' skin of a plugin deck with passive groups (after PLUGIN_PASSIVE_SKIN) where the resting
#: particles outnumber the moving ones by ``LARGE_BED`` or more: each
#: of LAMMPS' reneighbourings still passes over every atom (exchange, atom map, box), while a
#: step's work follows the moving ones (the plugin's contact lists keep their own margin,
#: Contacts::refresh), so a wider skin pays. Measured (CPU ms per iteration, one run): MagPod
#: (8 resting per moving) 0.22 at 4 against 0.24 at 8; sediment-large (250) 0.68–0.75 at 4
#: against 0.55–0.58 at 8.
PLUGIN_LARGE_BED_SKIN, LARGE_BED = 8.0, 50


@dataclass
class Realized:
    """How one operator of the scene is carried out on LAMMPS.

    ``native`` is the LAMMPS style that carries it ('addforce', 'viscous', 'lepton',
    'harmonic') or None; ``python`` says whether (a part of) it is evaluated in the Python
    callback (``fix external``). Neither: an operator with a zero coefficient, skipped.
    """

    target: str
    op: object
    native: str | None = None
    python: bool = False
    partner: object = None   # the reverse operator folded into the same pair style / bond
    site: tuple = None       # (group, index in its operator sequence): where it sits in the scene
    plugin: str | None = None  # the compiled style carrying it (``rs/collide``, ...; plugin.py)
    #: rs/bind: the bond types of its pairs, each with its c (None: the operator's own c)
    btypes: list = field(default_factory=list)
    #: rs/volume: the bond types it also binds (Eq. 12), each with its c: its part's bind's
    #: pairs, whose rs/bind is then ``fused`` into it and writes no fix of its own
    bind: list = field(default_factory=list)
    fused: bool = False

    @property
    def how(self) -> str:
        """'addforce' | 'viscous' | 'viscous+python' | 'lepton' | 'harmonic' | 'python' | 'skip'."""
        if self.native and (self.python or self.plugin):
            return f"{self.native}+{self.plugin or 'python'}"
        return self.native or self.plugin or ("python" if self.python else "skip")


@dataclass
class Deck:
    scene: Scene
    mode: str
    masses: dict
    realized: list
    ghost_cutoff: float
    bonds: tuple | None = None            # (types, i, j) 1-based atom ids, fast mode only
    bond_types: list = field(default_factory=list)   # [(K, r0)]
    lepton: dict = field(default_factory=dict)       # (type_i, type_j) → (K, R)
    #: the callback's Verlet lists of contacts: candidates within reach + skin
    skin: float = SKIN
    #: LAMMPS' neighbour skin (``neighbor``), if not ``skin``: it reneighbours once an atom has
    #: moved half of it (PASSIVE_SKIN for decks with passive groups)
    neighbor_skin: float | None = None
    #: "euler" (Eq. 5) or "verlet": then ``scene`` is the scaled scene of
    #: :func:`rackstress.model.verlet.scaled_scene` and fix nve starts from v without Eq. 5's
    #: half-step shift (plain velocity Verlet, fix viscous at v_{n+1/2}).
    integrator: str = "euler"
    #: groups whose particles rest until touched (only python-realized collides and dampen act
    #: on them): LAMMPS integrates them only once the callback has activated them
    passive: tuple = ()
    #: the operators LAMMPS has no style for run as the compiled plugin's fixes (fix rs/...,
    #: module doc "Plugin"), not in the Python callback
    plugin: bool = False
    #: every particle in every frame of the trajectory, as a plain LAMMPS dump (``rackstress run
    #: --dump-all``), instead of the ones that moved (:meth:`dump_commands`)
    dump_all: bool = False
    #: the volumetric terms' boundary and held particles, once made (:meth:`_volume_cells`)
    _cells: tuple | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def dump_moving(self) -> bool:
        """Whether the trajectory's frames hold only the displaced particles."""
        return bool(self.passive) and not self.dump_all

    @property
    def lammps_skin(self) -> float:
        """LAMMPS' neighbour skin (``neighbor_skin``, else ``skin``)."""
        return self.skin if self.neighbor_skin is None else self.neighbor_skin

    @property
    def moving(self) -> str:
        """The group ``fix nve`` and ``fix viscous`` act on."""
        return MOVE_GROUP if self.passive else "all"

    # ------------------------------------------------------------------ pieces
    @property
    def python_ops(self) -> list:
        return [r for r in self.realized if r.python]

    # ------------------------------------------------------------------ data file
    def data_text(self) -> str:
        return data_text(self.scene, self.masses, self.bonds, len(self.bond_types))

    # ------------------------------------------------------------------ input deck
    def setup_commands(self, data_file: str = "particles.data", dump_file: str | None = "trajectory.dump",
                       dump_every: int = 100, volume_file: str | None = None) -> list[str]:
        """Everything before the first run: styles, groups, static fixes, dump. ``volume_file``:
        the word for ``volume.atoms`` when ``data_file`` is a variable (``${rs_pathN}``, whose
        name has no folder to put it beside); by default the file beside ``data_file``."""
        sc, types = self.scene, topology.group_types(self.scene)
        L = [f"# rackstress deck: scene '{sc.name}', mode '{self.mode}', "
             f"{sc.n_particles} particles, dt = {sc.dt:g}"]
        if self.python_ops:
            L += [f"# Generated by rackstress. {len(self.python_ops)} operator(s) run in a Python "
                  f"callback (fix external {PY_FIX}) that 'rackstress run' attaches:",
                  "# 'lmp -in in.lammps' alone stops at the first 'run 0' with \"Fix external "
                  "callback function not set\"."]
        else:
            L += ["# Generated by rackstress. No operator runs in Python: 'lmp -in in.lammps' runs "
                  "this deck standalone",
                  "# and writes the same atom positions in every frame as 'rackstress run'."]
        if self.plugin:
            L[-2:] = ["# Generated by rackstress. The operators LAMMPS has no style for are the "
                      "rackstress plugin's fixes (rs/...):",
                      "# the venv's 'lmp -in in.lammps' loads it (entry point lammps.plugins); "
                      "elsewhere 'plugin load rackstressplugin.so' (docs/plugin.md)."]
        L += ["units lj", "dimension 3", "boundary m m m"]
        L.append("atom_style bond")
        # passive groups: LAMMPS keeps the moving group's atoms first in its arrays and
        # fix nve integrates only those rows (module doc, "Active particles")
        first = f" first {MOVE_GROUP}" if self.passive else ""
        L.append(f"atom_modify map array sort 0 0.0{first}")
        if self.bonds is not None:
            # A rack bonded to thousands of hosts: keep LAMMPS from building 1-3/1-4 lists.
            L.append("special_bonds lj/coul 1.0 1.0 1.0")
        if self.plugin:
            L += plugin_setup_commands(self)
        L.append(f"read_data {data_file}")
        if self.plugin:
            L += plugin_property_commands(self.scene)
        L.append(f"comm_modify cutoff {self.ghost_cutoff:.6g}")
        if any(getattr(r.op, "mu", 0.0) > 0 for r in self.realized):
            # a contact's friction reads its partner's velocity, a ghost's under MPI
            L.append("comm_modify vel yes")
        L.append(f"neighbor {self.lammps_skin:g} bin")
        binsize = ""
        if self.lepton:
            # bins as wide as the cutoff: a flat sediment in a tall box otherwise makes millions
            # of near-empty bins that every rebuild sweeps (measured: 3x faster rebuilds)
            cut = max(R for _, R in self.lepton.values()) + self.lammps_skin
            binsize = f" binsize {_f(cut)}"
        # plugin decks: fix rs/nve checks the displacements itself, in the plugin's reduction of
        # the step's gathered positions (one collective a step instead of two: once yes turns
        # LAMMPS' own check off, rs/nve forces the reneighbouring when an atom moved half a skin)
        check = "check no once yes" if self.plugin else "check yes"
        L.append(f"neigh_modify delay 0 every 1 {check}{binsize}")
        L.append(f"timestep {_f(sc.dt)}")
        for name in sc.groups:
            L.append(f"group {name} type {types[name]}")
        L += self.volume_commands(data_file, volume_file)
        if self.passive:
            L.append(f"# {', '.join(self.passive)}: at rest until touched; integrated and damped "
                     f"only once the callback adds a particle to {MOVE_GROUP}")
            L.append(f"group {MOVE_GROUP} subtract all {' '.join(self.passive)}")
        L += self._pair_commands()
        if self.bonds is not None and self.plugin:
            L += ["bond_style zero nocoeff", "bond_coeff *"]
        elif self.bonds is not None:
            L.append("bond_style harmonic")
            for k, (K, r0) in enumerate(self.bond_types, start=1):
                L.append(f"bond_coeff {k} {_f(K)} {_f(r0)}")
        # composition, as comments a reader can hold against the paper
        L.append("# operators (paper order) and their realization:")
        for r in self.realized:
            L.append(f"#   {r.target} <- {r.op.label()}: {r.how}"
                     + (" (its pairs in the part's rs/volume)" if r.fused else ""))
        forces, gamma = self.static_natives()
        if self.callback_natives:
            L.append(f"# the constant forces and damping of the moving particles are added by the "
                     f"callback (fix external {PY_FIX}),")
            L.append("# f = F - gamma*v over the rows fix nve integrates (these fixes, which would "
                     "pass over every atom):")
            L += ["# " + c for cmds, _, _ in forces for c in cmds]
            if any(gamma.values()):
                L.append("# " + self._damp_command(gamma))
        else:
            L += [c for cmds, _, _ in forces for c in cmds]
            if any(gamma.values()):
                L.append(self._damp_command(gamma))
        L += [line for idx, r in enumerate(self.realized) if r.plugin and not r.op.when
              for line in self.plugin_command(idx, r, {}).split("\n") if line]
        held_cmds, nve_group = support_commands(sc)   # supports and v0 (scene-level)
        L += held_cmds
        # a scene with supports has no passive group (passive_groups), so the two never meet
        # the plugin's rs/nve is fix nve's arithmetic (the same bits) without its per-atom
        # division by the mass, over the moving rows
        integrate = "rs/nve" if self.plugin else "nve"
        L.append(f"fix rs_nve {self.moving if self.passive else nve_group} {integrate}")
        L.append("thermo_style custom step")
        L.append(f"thermo {max(1, dump_every)}")
        if dump_file:
            L += self.dump_commands(dump_file, dump_every)
        return L

    # ------------------------------------------------------------------ rs/volume's cells
    @property
    def volumes(self) -> list:
        """The realized volumetric terms of a plugin deck (``rs/volume``)."""
        return [r for r in self.realized if r.plugin == "rs/volume"]

    def _volume_cells(self) -> tuple:
        """(atom ids, columns φx φy φz held_x held_y held_z) of the volumetric terms' boundary
        and held particles (:meth:`volume_atoms_text`); none where every cell is whole and
        free (a part the spacing divides, unsupported). Made once a deck: the text and the
        deck's lines both ask."""
        if self._cells is None:
            self._cells = self._volume_cells_made()
        return self._cells

    def _volume_cells_made(self) -> tuple:
        ids, cols = [], []
        for r in self.volumes:
            g, solid = self.scene.groups[r.target], r.op.solid
            phi = (np.ones((g.n, 3)) if getattr(solid, "part", None) is None
                   else solid.fractions(g.o))
            held = np.asarray(g.fixed, bool)
            k = np.flatnonzero(np.any(phi != 1.0, axis=1) | held.any(axis=1))
            ids.append(k + self.scene.offset(r.target) + 1)
            cols.append(np.column_stack([phi[k], held[k].astype(float)]))
        return np.concatenate(ids), np.concatenate(cols)

    def volume_atoms_text(self) -> str | None:
        """``volume.atoms``: for ``rs/volume``, each boundary or held particle's cell extents φ
        (in spacings, along x, y, z; docs/calibration.md "Walls of any thickness") and the
        directions a support holds it in (0 or 1), six sets of LAMMPS' atomfile variable
        (``ID value``) after a set of ones naming them; every other particle has a whole cell
        (φ = 1) and is free. None when the deck has no such term, or no such particle (LAMMPS
        refuses an atomfile set of none: "could not read values")."""
        if not self.volumes:
            return None
        ids, cols = self._volume_cells()
        if not len(ids):
            return None
        out = ["# rackstress: for fix rs/volume, a set of 1 (which particles follow), then each "
               "boundary or held particle's cell extents (x, y, z) and held directions (x, y, z)"]
        cols = np.column_stack([np.ones(len(ids)), cols])
        for k in range(7):
            out.append(f"{len(ids)}")
            out += [f"{i} {v!r}" for i, v in zip(ids.tolist(), cols[:, k].tolist())]
        return "\n".join(out) + "\n"

    def volume_commands(self, data_file: str, volume_file: str | None = None) -> list[str]:
        """After read_data: every particle of a volumetric term's part gets a whole cell
        (φ = 1) and no held direction, the boundary and held ones theirs from
        ``volume.atoms`` beside the data file (:meth:`volume_atoms_text`, an atomfile
        variable: one set per column), where there are any."""
        if not self.volumes:
            return []
        path = volume_file or str(Path(data_file).with_name(VOLUME_ATOMS))
        L = [f"set group {r.target} d2_rsphi[{k}] {1.0 if k <= 3 else 0.0}"
             for r in self.volumes for k in range(1, 7)]
        if not len(self._volume_cells()[0]):
            return L
        L += [f"variable rs_phi atomfile {path}", "group rs_vphi variable rs_phi"]
        for k in range(1, 7):
            L += ["next rs_phi", f"set group rs_vphi d2_rsphi[{k}] v_rs_phi"]
        L += ["variable rs_phi delete", "group rs_vphi delete"]
        return L

    def write_data(self, path) -> None:
        """The data file at ``path`` and, for a volumetric term, ``volume.atoms`` beside it."""
        path = Path(path)
        path.write_text(self.data_text())
        text = self.volume_atoms_text()
        if text is not None:
            path.with_name(VOLUME_ATOMS).write_text(text)

    def dump_commands(self, dump_file: str, dump_every: int) -> list[str]:
        """The trajectory's ``dump``. In a deck with passive groups it follows what moves: each
        frame holds the atoms of the moving group ``rs_move`` (module doc, "Active particles":
        an atom outside it has never moved, so it sits exactly at its original position, the
        data file's, with v = 0; it joins for good one reneighbouring before anything can
        touch it, and a resumed run restores the group as the checkpoint recorded it). The
        readers (:func:`rackstress.engines.dumpio.read_frames`, the stress reader) put every
        other atom there. MagPod's resting sediment is then written once, in the data file,
        and a frame costs what the moving atoms cost (the dump skips the others by their group
        bit; no pass computes anything over them)."""
        L = []
        if self.dump_moving:
            L.append(f"# the dump follows what moves ({MOVE_GROUP}): a particle a frame does not "
                     "hold sits at its position in the data file")
        L.append(f"dump rs_dump {self.dump_group} custom {dump_every} {dump_file} "
                 "id type mol x y z")
        L.append("dump_modify rs_dump sort id format float %.10g")
        return L

    @property
    def dump_group(self) -> str:
        """The group the trajectory's frames hold (:meth:`dump_commands`)."""
        return MOVE_GROUP if self.dump_moving else "all"

    def write_dump_command(self, dump_file: str) -> str:
        """One frame of the current step in the trajectory's own format (:meth:`dump_commands`)."""
        return (f"write_dump {self.dump_group} custom {dump_file} id type mol x y z modify "
                "sort id format float %.10g append yes")

    @property
    def callback_natives(self) -> bool:
        """Whether the static ``fix addforce`` and ``fix viscous`` are evaluated by the callback
        instead (module doc, "Active particles"): a deck with passive groups, where those fixes
        would pass over every atom each step, resting or not, while the callback passes over
        the rows ``fix nve`` integrates. Only where nothing else adds to those forces before
        the callback (no pair style, no bonds, no phase-conditioned native fix), so each atom's
        force is summed in LAMMPS' own order and the trajectory is the same bit for bit."""
        return (bool(self.passive) and not self.plugin and not self.lepton and self.bonds is None
                and not any(r.op.when and not r.python and r.native in ("addforce", "viscous")
                            for r in self.realized))

    def static_natives(self) -> tuple[list, dict]:
        """The static constant forces and damping: ``([(commands, particles, F)], {type: γ})``,
        the ``fix addforce`` in LAMMPS' fix order (F = m·â on the particles, global indices)
        and γ = Σ c·m per atom type of the one ``fix viscous``."""
        sc, types = self.scene, topology.group_types(self.scene)
        out = []
        gamma = dict.fromkeys(range(1, len(sc.groups) + 1), 0.0)   # static damping per type
        # constant forces: groups whose one constant force is the same vector share one fix
        # addforce (MagPod's two legs: one pass over the atoms, not one per group; each atom
        # gets the same F = m·â). A group with several constant forces, or a force on part of a
        # group (where), keeps a fix of its own: a union would count an atom once, not twice
        static = [(idx, r) for idx, r in enumerate(self.realized)
                  if r.native == "addforce" and not r.op.when]
        per_group = Counter(r.target for _, r in static)
        same = defaultdict(list)
        for idx, r in static:
            cmds = self._addforce(idx, r)
            sl = sc.slice(r.target)
            parts = (np.arange(sl.start, sl.stop) if r.op.where is None
                     else np.flatnonzero(np.asarray(r.op.where, bool)) + sl.start)
            F = tuple(self.masses[r.target] * float(a) for a in r.op.accel)
            if r.op.where is None and per_group[r.target] == 1:
                same[cmds[-1].split(f" {self._force_style} ")[1]].append((idx, cmds, parts, F))
            else:
                out.append((cmds, parts, F))
        for idx, r in enumerate(self.realized):
            if r.native == "viscous" and (r.python or r.plugin or not r.op.when):
                gamma[types[r.target]] += r.op.c * self.masses[r.target]
        for Fs, fixes in same.items():
            if len(fixes) == 1:
                out.append(fixes[0][1:])
                continue
            sel = [cmds[-1].split()[2] for _, cmds, _, _ in fixes]
            idx = fixes[0][0]
            out.append(([f"group rs_fu{idx} union {' '.join(sel)}",
                         f"fix rs_force{idx} rs_fu{idx} {self._force_style} {Fs}"],
                        np.sort(np.concatenate([p for _, _, p, _ in fixes])), fixes[0][3]))
        return out, gamma

    def _damp_command(self, gamma: dict) -> str:
        # one fix for every group's constant damping: one pass over the atoms, not one per
        # group (gamma 1 times scale γ_type is γ_type exactly; an unnamed type would get 1)
        if self.moving_rows:
            # rs/dampen's c is Eq. 9's, per unit mass (γ = c·m per atom type, as below)
            types = topology.group_types(self.scene)
            c = dict.fromkeys(gamma, 0.0)
            for r in self.realized:
                if r.native == "viscous" and (r.python or r.plugin or not r.op.when):
                    c[types[r.target]] += r.op.c
            return (f"fix rs_damp {self.moving} rs/dampen 0 "
                    + " ".join(f"type {t} {_f(v)}" for t, v in c.items()))
        scale = " ".join(f"scale {t} {_f(g)}" for t, g in gamma.items())
        return f"fix rs_damp {self.moving} viscous 1.0 {scale}"

    def natives_per_particle(self) -> tuple[np.ndarray, np.ndarray]:
        """(F, γ) per particle of :meth:`static_natives`: F summed in fix order from 0, as
        LAMMPS adds the fixes to a cleared force, and γ of the particle's type."""
        sc, types = self.scene, topology.group_types(self.scene)
        forces, gamma = self.static_natives()
        F = np.zeros((sc.n_particles, 3))
        for _, parts, vec in forces:
            F[parts] += np.array(vec)
        g = np.zeros(sc.n_particles)
        for name in sc.groups:
            g[sc.slice(name)] = gamma[types[name]]
        return F, g

    def _pair_commands(self) -> list[str]:
        if not self.lepton:
            return []
        sc = self.scene
        rmax = max(R for _, R in self.lepton.values())
        L = [f"pair_style lepton {_f(rmax)}"]
        ntypes = len(sc.groups)
        for ti in range(1, ntypes + 1):
            for tj in range(ti, ntypes + 1):
                if (ti, tj) in self.lepton:
                    K, R = self.lepton[(ti, tj)]
                    L.append(f'pair_coeff {ti} {tj} "{_f(K)}*((r^2-{_f(R)}^2)/2-{_f(R)}^2*log(r/{_f(R)}))" '
                             f"{_f(R)}")
                else:
                    L.append(f'pair_coeff {ti} {tj} "0" {_f(rmax)}')
                    L.append(f"neigh_modify exclude type {ti} {tj}")
        return L

    def _addforce(self, idx, r) -> list[str]:
        m = self.masses[r.target]
        gname = f"rs_f{idx}"
        start = self.scene.offset(r.target)
        if r.op.where is None:
            sel = r.target
            L = []
        else:
            ids = np.flatnonzero(np.asarray(r.op.where, bool)) + start + 1
            L = [f"group {gname} id {' '.join(str(int(i)) for i in ids)}"]
            sel = gname
        fx, fy, fz = (m * float(a) for a in r.op.accel)
        L.append(f"fix rs_force{idx} {sel} {self._force_style} {_f(fx)} {_f(fy)} {_f(fz)}")
        return L

    @property
    def moving_rows(self) -> bool:
        """Whether constant forces and damping are the plugin's ``rs/force`` and ``rs/dampen``
        rather than LAMMPS' ``fix addforce`` and ``fix viscous`` (the same arithmetic): a plugin
        deck with passive groups, where those pass over the moving rows only, LAMMPS' over every
        atom, resting or not (module doc, "Active particles")."""
        return bool(self.plugin and self.passive)

    @property
    def _force_style(self) -> str:
        return "rs/force" if self.moving_rows else "addforce"

    def _viscous(self, idx, r, extra) -> str:
        if self.moving_rows:     # Eq. 9 per unit mass: the style multiplies by the mass
            return f"fix rs_damp{idx} {r.target} rs/dampen {_f(r.op.c + extra)}"
        gamma = (r.op.c + extra) * self.masses[r.target]
        return f"fix rs_damp{idx} {r.target} viscous {_f(gamma)}"

    def plugin_command(self, idx: int, r: Realized, phase_vars) -> str:
        """The plugin fix carrying ``r`` in the phase ``phase_vars`` (module doc, "Plugin")."""
        op, fid = r.op, f"{PLUGIN_FIX}{idx}"
        if r.plugin == "rs/dampen":
            return f"fix {fid} {r.target} rs/dampen {_f(op.extra)} contact {contact_groups(op.when)[0]}"
        if r.plugin == "rs/indent":       # the sphere, its travel's steps, d_rskN per atom
            name = next(n for n, _, o in _indent_props(self.scene) if o is op)
            return (f"fix {fid} {r.target} rs/indent "
                    + " ".join(_f(x) for x in (*op.centre, op.radius, *op.travel))
                    + f" {int(op.steps)} stiffness d_{name}")
        if r.plugin == "rs/volume":       # the moduli per unit density (the style × its mass)
            return (f"fix {fid} {r.target} rs/volume {_f(op.solid.spacing)} "
                    + " ".join(_f(x) for x in op.c) + " btype "
                    + " ".join(str(bt) for bt, _ in r.btypes)
                    + ("" if not r.bind else " bind " + " ".join(f"{bt} {_f(cv)}"
                                                                for bt, cv in r.bind)))
        c = _f(op.coeff.c)
        if r.plugin == "rs/bind" and r.fused:
            return ""
        if r.plugin == "rs/bind":          # one fix per bond type: rs_pN, rs_pN_2, …
            return "\n".join(
                f"fix {fid}{'' if k == 0 else f'_{k + 1}'} {r.target} rs/bind {op.source} "
                f"{c if cv is None else _f(cv)} btype {bt}"
                for k, (bt, cv) in enumerate(r.btypes))
        if r.plugin == "rs/attract":
            if isinstance(op.coeff, Matched):
                t = _prop_name(op.coeff.target.format(**phase_vars))
                s = _prop_name(op.coeff.source.format(**phase_vars))
                return f"fix {fid} {r.target} rs/attract {op.source} {c} {t} {s}"
            return f"fix {fid} {r.target} rs/attract {op.source} {c} all all"
        if r.plugin == "rs/collide":
            fric = f" friction {_f(op.mu)} {_f(op.eta)}" if op.mu > 0 else ""
            if r.target in self.passive:
                # a resting target joins the moving group one reneighbouring before it is
                # touched
                return (f"fix {fid} {r.target} rs/collide {op.source} {c}{fric} activate "
                        f"{MOVE_GROUP}")
            return f"fix {fid} {r.target} rs/collide {op.source} {c}{fric}"
        return f"fix {fid} {r.target} {r.plugin} {op.source} {c}"

    def phase_commands(self, phase_vars, previous=None) -> list[str]:
        """Commands that set the phase-conditioned native fixes for ``phase_vars``."""
        L = []
        for idx, r in enumerate(self.realized):
            if r.plugin and r.op.when:
                # defined while its phase conditions hold; redefined when its command changes
                # (an attraction region that follows the phase: breg{r})
                now = phase_active(r.op.when, phase_vars)
                before = previous is not None and phase_active(r.op.when, previous)
                cmd = self.plugin_command(idx, r, phase_vars) if now else None
                old = self.plugin_command(idx, r, previous) if before else None
                if cmd is not None and cmd != old:
                    L.append(cmd)
                elif cmd is None and old is not None:
                    L.append(f"unfix {PLUGIN_FIX}{idx}")
                continue
            if not r.op.when or r.python or r.native not in ("addforce", "viscous"):
                continue
            now = phase_active(r.op.when, phase_vars)
            before = previous is not None and phase_active(r.op.when, previous)
            if r.native == "viscous":
                extra = r.op.extra if now else 0.0
                if previous is None or now != before:
                    L.append(self._viscous(idx, r, extra))
            else:
                if now and not before:
                    L += self._addforce(idx, r)
                elif before and not now:
                    L.append(f"unfix rs_force{idx}")
        return L

    def velocity_variables(self) -> list[str]:
        """Atom variables for v + dt/2·f/m (into fix nve) and v − dt/2·f/m (back to Eq. 5's v)."""
        h = _f(0.5 * self.scene.dt)
        partial = partial_groups(self.scene)
        if self.scene.held().any() or partial:
            # held atoms keep v = 0 whatever force the callback leaves on them (× 1 is exact);
            # an atom fixed in one direction keeps that component 0
            def mask(c):
                m = [f"gmask({FREE})"] if self.scene.held().any() else []
                if c in partial:
                    m.append(f"(1-gmask(rs_fix{c}))")
                return "*".join(m) or "1"
            return [f"variable rs_vh{c} atom (v{c}+{h}*f{c}/mass)*{mask(c)}" for c in "xyz"] + \
                   [f"variable rs_vp{c} atom (v{c}-{h}*f{c}/mass)*{mask(c)}" for c in "xyz"]
        return [f"variable rs_vh{c} atom v{c}+{h}*f{c}/mass" for c in "xyz"] + \
               [f"variable rs_vp{c} atom v{c}-{h}*f{c}/mass" for c in "xyz"]

    def schedule_commands(self, loop_after: int = LOOP_AFTER) -> list[str]:
        """The whole schedule as plain LAMMPS commands (what the runner does, in one text).

        A schedule of more than ``loop_after`` phases (``--steps 1000000000000``: 8·10⁸ of them)
        is written as its first cycle, one cycle in a LAMMPS ``loop``/``jump SELF`` over the
        identical cycles after it, and the cut last cycle: the deck stays a few lines long."""
        sc = self.scene
        spc = sc.steps_per_cycle
        full = (sc.total_steps // spc) if spc else 0
        if full * len(sc.phases) > loop_after and full >= 3:
            return self._looped_schedule(full)
        L = self.velocity_variables()
        previous = None
        for first, phase, cycle in self.scene.schedule():
            L.append(f"# phase '{phase.name}' {dict(phase.vars)} (cycle {cycle + 1}), "
                     f"steps {first}..{first + phase.steps}")
            L += self.switch_commands(phase.vars, previous)
            L.append(f"run {phase.steps} pre no post no")
            previous = phase.vars
        return self._include_moving(L)

    def _looped_schedule(self, full: int) -> list[str]:
        sc = self.scene
        spc = sc.steps_per_cycle
        L = self.velocity_variables()

        def cycle(phases, previous, note):
            for phase in phases:
                L.append(f"# phase '{phase.name}' {dict(phase.vars)} ({note}), {phase.steps} steps")
                L.extend(self.switch_commands(phase.vars, previous))
                L.append(f"run {phase.steps} pre no post no")
                previous = phase.vars
            return previous

        previous = cycle(sc.phases, None, f"cycle 1, steps 0..{spc}")
        L += [f"# cycles 2..{full} are alike: a LAMMPS loop (steps {spc}..{full * spc})",
              f"variable {LOOP_VAR} loop {full - 1}", f"label {LOOP_VAR}"]
        previous = cycle(sc.phases, previous, f"cycles 2..{full}")
        L += [f"next {LOOP_VAR}", f"jump SELF {LOOP_VAR}"]
        rest, tail = sc.total_steps - full * spc, []
        for phase in sc.phases:
            take = min(phase.steps, rest)
            if take > 0:
                tail.append(Phase(phase.name, take, phase.vars))
                rest -= take
        cycle(tail, previous, f"cycle {full + 1}, cut short")
        return self._include_moving(L)

    def _include_moving(self, L: list[str]) -> list[str]:
        """A standalone plugin deck with passive groups does what the runner does before its
        first run (runner.LammpsRun): ``neigh_modify include rs_move``, so that LAMMPS clears
        forces (and would bin and check displacements) over the moving rows only
        (``atom_modify first``), not over every owned atom a step. It comes right after the first
        ``run 0``: that setup, with include still off, cleared every owned row's force (the
        runner zeroes them itself), and nothing writes a resting row's force later (the styles
        add forces to moving rows only; a resting particle touched at a setup has joined
        rs_move and is reordered among the first rows by the second ``run 0``, whose setup
        clears those). A resting row's force can still be stale under MPI (LAMMPS moves
        positions and velocities with an atom, not forces: a row that receives an atom by
        exchange, or that a departing moving atom left, keeps the force it held); nothing reads
        it while the atom rests, and rs/collide zeroes it when it activates the atom, so that a
        phase switch's velocity shift (v − dt/2·f/m over rs_move) before LAMMPS has put the
        atom among the first rows leaves it at rest (without that zeroing, magpod-small's
        standalone deck on 2 ranks left the reference trajectory at step 204). Among the first
        rows, its force is cleared each step before the styles add theirs."""
        if not (self.plugin and self.passive):
            return L
        k = L.index("run 0 post no")
        return L[:k + 1] + [f"neigh_modify include {MOVE_GROUP}"] + L[k + 1:]

    def switch_commands(self, phase_vars, previous) -> list[str]:
        """Enter a phase exactly: back to the paper's v_n, new coefficients, forces, v + dt/2·a.

        In the verlet mode the run starts from LAMMPS' own velocity (no half-step shift); a later
        switch, like Eq. 5's, recomputes the forces with v − dt/2·a (``fix viscous`` must see
        v_{n−½}, the velocity the scheme damps with, not the full-step one) and then restores v."""
        if self.integrator == "verlet" and previous is None:
            return self.phase_commands(phase_vars, previous) + ["run 0 post no"]
        # only the particles that can move: a resting one has v = 0 and f = 0 (Active
        # particles), which both settings leave as they are
        L = []
        if previous is not None:
            L.append(f"velocity {self.moving} set v_rs_vpx v_rs_vpy v_rs_vpz units box")
        L += self.phase_commands(phase_vars, previous)
        L.append("run 0 post no")
        if self.plugin and self.passive:
            # rs/collide may have activated resting particles there that it touches already:
            # LAMMPS puts them among its integrated rows at this second run 0 (same forces)
            L.append("run 0 post no")
        L.append(f"velocity {self.moving} set v_rs_vhx v_rs_vhy v_rs_vhz units box")
        return L

    def equilibrium_text(self, step: int) -> str:
        """The deck of a static run's equilibrium (``in.lammps`` once it settled): the scene's
        styles and supports as :meth:`setup_commands` writes them, the equilibrium's positions
        read from ``equilibrium.dump`` (the original ones stay in ``particles.data``: what the
        bindings' rest lengths come from), one ``run 0``, and every atom's force there into
        ``forces.dump`` — in LAMMPS' units (force = the deck's mass × the paper's acceleration:
        × the scene's particle mass / its type's mass for newtons, docs/tutorials/lammps-decks.md).
        Plain ``lmp -in in.lammps`` reproduces the engine's check of the equilibrium."""
        L = self.setup_commands(dump_file=None)
        L += ["# the equilibrium rackstress found (static analysis): its positions, then one "
              "force evaluation",
              f"read_dump equilibrium.dump {int(step)} x y z box no format native",
              "run 0 post no",
              "write_dump all custom forces.dump id fx fy fz modify sort id format float %.17g"]
        return "\n".join(L) + "\n"

    def input_text(self, dump_every: int = 100, loop_after: int = LOOP_AFTER) -> str:
        py = self.python_ops
        L = self.setup_commands(dump_every=dump_every)
        if py:
            L.append(f"fix {PY_FIX} {self.moving} external pf/callback 1 {PY_NAPPLY}")
            L += partial_support_commands(self.scene, redefine=True)
        bal = balance_commands(self)
        if bal:
            L.append("# under mpiexec: cut the domain by work, not by volume (one rank alone: "
                     "no effect)")
            L += bal
        L += self.schedule_commands(loop_after)
        return "\n".join(L) + "\n"


def balance_commands(deck: Deck) -> list[str]:
    """LAMMPS' load balancing of a deck under MPI (docs/benchmarks/scaling.md).

    LAMMPS splits the box evenly by volume; where particles rest until touched (passive groups),
    the work sits where the robot is, so one rank gets all of it (MagPod: 4061 moving particles
    on one rank, 0 on the other). A deck with passive groups therefore balances by weight:
    ``comm_style tiled`` and one recursive-coordinate-bisection ``balance`` in which a moving
    particle (:data:`MOVE_GROUP`) weighs ``robot_weight`` (:data:`MOVE_WEIGHT`) resting ones.
    A scene's ``balance`` parameter chooses otherwise: ``"shift"`` (``balance shift xz`` on
    particle counts) or ``"none"`` (LAMMPS' even split). Where atoms sit changes no trajectory
    beyond round-off in the order of the ranks' partial sums (plugin parity tests: 1e-10).

    Examples
    --------
    >>> from rackstress import scenes
    >>> balance_commands(compile_deck(scenes.build("magpod-small"), "exact", plugin=True))[-1]
    'balance 1.0 rcb weight group 1 rs_move 20.0'
    """
    params = deck.scene.params or {}
    # by default only on the plugin's decks, whose ghost cutoff is the real interaction range:
    # the callback's (rack couplings, fast mode's bonds) spans a body, beyond what a tiled
    # decomposition's ghost exchange reaches (LAMMPS aborted with a corrupted heap, fast mode)
    how = params.get("balance", "rcb" if deck.passive and deck.plugin else "none")
    if how in (None, "none"):
        return []
    ghosts = [f"comm_modify group {MOVE_GROUP}"] if moving_ghosts_suffice(deck) else []
    if how == "shift":
        return ghosts + ["balance 1.05 shift xz 20 1.05"]
    if how == "rcb":
        if not deck.passive:
            return ["comm_style tiled", "balance 1.0 rcb"]
        w = float(params.get("robot_weight", MOVE_WEIGHT))
        return ["comm_style tiled"] + ghosts + [
            f"balance 1.0 rcb weight group 1 {MOVE_GROUP} {w!r}"]
    raise SceneError(f"scene '{deck.scene.name}': unknown balance '{how}' (rcb, shift or none)")


def moving_ghosts_suffice(deck: Deck) -> bool:
    """Whether a plugin deck with passive groups may send only the moving group's atoms as
    ghosts (``comm_modify group rs_move``; LAMMPS requires it to be ``atom_modify first``'s
    group): a resting particle is then never a ghost, and neither LAMMPS' forward communication
    of every step nor its borders at each reneighbouring pass over the resting ones (the 4 M
    bed: 32,488 ghosts a rank, ~1,300 left). Exact when every operator that reads a passive
    group's particle across ranks is a contact (``rs/collide`` from it, ``rs/dampen``'s contact
    condition on it; reach r_p + r_u) on a group T for which the passive group has an
    unconditional ``rs/collide ... activate`` from T. A particle u of it within a contact's
    reach of a T particle p at some step was within r_p + r_u + skin of p at LAMMPS' last
    reneighbouring before it, and within r_p + r_u + 3/2 skin at the one before that (p
    moves less than half a skin between two, u not at all), where the activating fix on u's
    rank (p is a moving ghost there) put u into rs_move: from the last reneighbouring on, u is
    a ghost wherever p's rank needs it. A setup's contact (step 0, a phase switch) activates u
    there and is recomputed by the second ``run 0`` (runner._plugin_reorder), whose borders
    send u. A contact found later than that stops the run on u's rank ("... before LAMMPS
    integrated it"), as without this. Everything else a passive group can be a source of
    (racks, attraction) is gathered by reductions over owned atoms, not from ghosts; a bind
    over bonds is not (its partner is a ghost), nor is a passive target's passive source."""
    if not (deck.plugin and deck.passive) or deck.python_ops:
        return False
    passive = set(deck.passive)
    activating = {(r.target, r.op.source) for r in deck.realized
                  if r.plugin == "rs/collide" and r.target in passive and not r.op.when}
    for r in deck.realized:
        sources = set(contact_groups(r.op.when or ()))
        source = getattr(r.op, "source", None)
        if source is not None:
            sources.add(source)
        for s in sources & passive:
            if r.target in passive or r.plugin not in ("rs/collide", "rs/dampen"):
                return False
            if (s, r.target) not in activating:
                return False
    return True


# ---------------------------------------------------------------------------- supports, v0
#: LAMMPS groups of the held atoms (supports) and of the rest, which ``fix nve`` integrates.
HELD, FREE = "rs_held", "rs_free"


def id_ranges(ids) -> str:
    """1-based atom ids as LAMMPS ``group id`` ranges: ``1:4 7 9:10``."""
    ids = np.asarray(ids, dtype=np.int64)
    if not len(ids):
        return ""
    breaks = np.flatnonzero(np.diff(ids) != 1)
    starts = np.concatenate([[ids[0]], ids[breaks + 1]])
    ends = np.concatenate([ids[breaks], [ids[-1]]])
    return " ".join(f"{a}" if a == b else f"{a}:{b}" for a, b in zip(starts, ends))


def support_commands(scene: Scene) -> tuple[list[str], str]:
    """Commands for the scene's supports and initial velocities, and the group ``fix nve`` takes.

    Held atoms (``Group.held``) are left out of ``fix nve`` and get ``fix setforce 0 0 0``: they
    never move and keep v = 0 (the velocity variables mask them, :meth:`Deck.velocity_variables`),
    as on the reference engine. ``Group.v0`` is set with ``velocity … set`` before the first
    ``run 0``, so the paper's v at step 0 is v0 on both engines. Nothing for a scene with
    neither (the committed decks are unchanged).
    """
    L = []
    held = scene.held()
    if held.any():
        L.append(f"group {HELD} id {id_ranges(np.flatnonzero(held) + 1)}")
        L.append(f"group {FREE} subtract all {HELD}")
        L.append(f"fix rs_hold {HELD} setforce 0.0 0.0 0.0")
    L += partial_support_commands(scene)
    v0 = scene.initial_velocities()
    moving = np.flatnonzero(np.any(v0 != 0.0, axis=1))
    if len(moving):
        rows, inv = np.unique(v0[moving], axis=0, return_inverse=True)
        for k, row in enumerate(rows):
            ids = moving[inv.reshape(-1) == k] + 1
            L.append(f"group rs_v0 id {id_ranges(ids)}")
            L.append(f"velocity rs_v0 set {_f(row[0])} {_f(row[1])} {_f(row[2])} units box")
            L.append("group rs_v0 delete")
    return L, (FREE if held.any() else "all")


def partial_groups(scene: Scene) -> dict:
    """{axis letter: atom ids (1-based)} of the particles fixed in that direction only (a roller
    or symmetry plane: some directions fixed, not all three)."""
    fixed = scene.fixed()
    part = fixed & ~fixed.all(axis=1)[:, None]
    return {c: np.flatnonzero(part[:, k]) + 1 for k, c in enumerate("xyz") if part[:, k].any()}


def partial_support_commands(scene: Scene, redefine: bool = False) -> list[str]:
    """``fix setforce`` with NULL in the free directions, one per fixed axis (rollers, symmetry
    planes). These atoms stay in ``fix nve``: a zero force and a zero start velocity in the
    fixed direction keep them at their original coordinate there (the velocity variables mask
    that component, :meth:`Deck.velocity_variables`). ``redefine``: the fixes again (unfix, fix),
    so that they come after a ``fix external`` defined since (LAMMPS runs post_force in fix
    order, and the callback adds its forces in its own)."""
    L = []
    for c, ids in partial_groups(scene).items():
        comp = " ".join("0.0" if c == d else "NULL" for d in "xyz")
        if redefine:
            L.append(f"unfix rs_fix{c}")
        else:
            L.append(f"group rs_fix{c} id {id_ranges(ids)}")
        L.append(f"fix rs_fix{c} rs_fix{c} setforce {comp}")
    return L


# ---------------------------------------------------------------------------- compile
def _f(x) -> str:
    """A number as LAMMPS reads it back exactly (shortest round-trip repr of the float)."""
    return repr(float(x))


def _uniform_radius(g) -> float | None:
    return float(g.r[0]) if np.all(g.r == g.r[0]) else None


def contact_searched(scene: Scene) -> set:
    """Unordered group pairs {target, group} that a contact condition searches every step."""
    return {frozenset((target, g)) for target, seq in scene.operators.items()
            for op in seq for g in contact_groups(op.when)}


# ---------------------------------------------------------------------------- reciprocal pairs
# An operator class LAMMPS can carry as one reciprocal interaction (module doc: directed
# coefficients become masses): when it qualifies, the style it becomes, and how it is folded.
def _collide_foldable(scene: Scene, target: str, op, mode: str, searched: set) -> bool:
    """A collide folds into ``pair_style lepton`` (exact: Eq. 10 is its derivative) when it is
    unconditional, both groups have one radius each (one R per type pair), and no contact
    condition already searches the two groups (then it rides on that search in Python)."""
    return (frozenset((target, op.source)) not in searched
            and not op.mu > 0           # friction reads velocities: not a pair potential
            and _uniform_radius(scene.groups[target]) is not None
            and _uniform_radius(scene.groups[op.source]) is not None)


def _bind_foldable(scene: Scene, target: str, op, mode: str, searched: set) -> bool:
    """A bind folds into harmonic bonds only in fast mode (equal to Eq. 12 to first order)."""
    return mode == "fast"


def _fold_collide(build: dict, scene: Scene, types: dict, target: str, op, K: float) -> None:
    R = _uniform_radius(scene.groups[target]) + _uniform_radius(scene.groups[op.source])
    build["lepton"][tuple(sorted((types[target], types[op.source])))] = (K, R)


def _fold_bind(build: dict, scene: Scene, types: dict, target: str, op, K: float) -> None:
    build["bonds"].append(_bonds_of(scene, target, op, K))


#: operator class → (the LAMMPS style, may it fold?, fold it into the deck)
RECIPROCAL = {Collide: ("lepton", _collide_foldable, _fold_collide),
              Bind: ("harmonic", _bind_foldable, _fold_bind)}


def solve_masses(scene: Scene, mode: str, unfolded=frozenset()):
    """Group masses making every reciprocal-capable pair one LAMMPS interaction (module doc).

    Returns (masses, pairs) where pairs maps an operator's place (group, index) → the place of
    its reverse, for the pairs that fit. A collide between two groups a contact condition
    already searches stays in Python, as one between the pairs of groups ``unfolded`` (each a
    frozenset of two names: material contacts the plugin carries, :func:`material_contacts`).
    """
    ratio_edges = []  # (A, B, m_A/m_B, site, reverse site)
    searched = contact_searched(scene) | set(unfolded)
    ops = scene.operators
    for target, seq in ops.items():
        for k, op in enumerate(seq):
            spec = RECIPROCAL.get(type(op))
            if spec is None or op.when or op.coeff.c == 0:
                continue
            if not spec[1](scene, target, op, mode, searched):
                continue
            rev = reverse_of(ops, target, k)
            if rev is None or ops[rev[0]][rev[1]].coeff.c == 0:
                continue
            ratio_edges.append((target, op.source, ops[rev[0]][rev[1]].coeff.c / op.coeff.c,
                                (target, k), rev))
    mass = {}
    adj = defaultdict(list)
    pairs = {}
    for A, B, ratio, site, rev in ratio_edges:
        if A == B:
            if ratio == 1.0:
                pairs[site] = rev
            continue
        # accept if consistent with what is known (checked incrementally below)
        adj[A].append((B, ratio, site, rev))
    # BFS per component, rejecting contradicting edges
    for start in scene.groups:
        if start in mass:
            continue
        mass[start] = 1.0
        queue, comp = [start], [start]
        while queue:
            A = queue.pop()
            for B, ratio, site, rev in adj[A]:
                mB = mass[A] / ratio
                if B not in mass:
                    mass[B] = mB
                    queue.append(B)
                    comp.append(B)
                if math.isclose(mass[B], mB, rel_tol=1e-12):
                    pairs[site] = rev
        lo = min(mass[g] for g in comp)
        for g in comp:
            mass[g] /= lo
    # an op is folded only if its reverse is folded too (both directions consistent)
    pairs = {k: v for k, v in pairs.items() if v in pairs}
    return mass, pairs


# ---------------------------------------------------------------------------- realizations
def _realize_force(cx: dict, target: str, k: int, op) -> Realized:
    """fix addforce (F = m·â); a force conditioned on a contact goes to the callback."""
    if contact_groups(op.when):
        return Realized(target, op, None, True, site=(target, k))
    return Realized(target, op, "addforce", site=(target, k))


def _realize_dampen(cx: dict, target: str, k: int, op) -> Realized:
    """fix viscous (γ = c·m); a contact-conditioned extra (Eq. 28) goes to the callback."""
    return Realized(target, op, "viscous", bool(op.extra and contact_groups(op.when)),
                    site=(target, k))


def _realize_pair(cx: dict, target: str, k: int, op) -> Realized:
    """A reciprocal pair that fits the masses becomes one native interaction (folded once for
    both directions); every other pair operator goes to the callback; c = 0 is skipped."""
    site = (target, k)
    if op.coeff.c == 0:
        return Realized(target, op, site=site)
    rev = cx["pairs"].get(site)
    if rev is None:
        return Realized(target, op, None, True, site=site)
    native, _, fold = RECIPROCAL[type(op)]
    partner = cx["scene"].operators[rev[0]][rev[1]]
    if site not in cx["folded"]:
        cx["folded"].update({site, rev})
        fold(cx, cx["scene"], cx["types"], target, op, op.coeff.c * cx["masses"][target])
    return Realized(target, op, native, partner=partner, site=site)


def _realize_volume(cx: dict, target: str, k: int, op) -> Realized:
    """A material part's volumetric term: the plugin's ``rs/volume`` over its bind's bonds
    (:func:`_plugin_realize`), else the callback (it has no native LAMMPS style)."""
    return Realized(target, op, None, True, site=(target, k))


def _realize_indent(cx: dict, target: str, k: int, op) -> Realized:
    """A rigid sphere (``[[indenter]]``): the plugin's ``rs/indent``
    (:func:`_plugin_realize`); the Python callback does not model it (it refuses the run:
    engines/lammps/callback.py ``Forces``)."""
    return Realized(target, op, None, True, site=(target, k))


#: operator class → its realization on LAMMPS (adding an operator adds one entry)
REALIZE = {Force: _realize_force, Dampen: _realize_dampen, Collide: _realize_pair,
           Bind: _realize_pair, Attract: _realize_pair, Volume: _realize_volume,
           Indent: _realize_indent}


def _indent_props(scene: Scene) -> list[tuple[str, int, object]]:
    """(per-atom property, its group's first index, the operator) of each Indent: rs/indent's
    stiffness per unit mass, d_rsk1, d_rsk2, … in the operators' order."""
    out = []
    for target, seq in scene.operators.items():
        for op in seq:
            if isinstance(op, Indent):
                out.append((f"rsk{len(out) + 1}", scene.offset(target), op))
    return out


def plugin_passive_skin(scene: Scene, passive) -> float:
    """LAMMPS' skin of a plugin deck with the resting groups ``passive``
    (:data:`PLUGIN_PASSIVE_SKIN`, :data:`PLUGIN_LARGE_BED_SKIN`)."""
    resting = sum(scene.groups[g].n for g in passive)
    moving = max(1, scene.n_particles - resting)
    return PLUGIN_LARGE_BED_SKIN if resting >= LARGE_BED * moving else PLUGIN_PASSIVE_SKIN


def passive_groups(scene: Scene, realized: list) -> tuple:
    """Groups whose particles start at rest and are moved only by collisions the callback
    evaluates (and damped): a particle of one that no collision partner can reach has zero
    velocity and zero force, so Eq. 5 leaves it where it is, and LAMMPS need not pass over it
    until the callback finds a partner within reach + skin (module doc, "Active particles")."""
    if not any(r.python or r.plugin for r in realized) or scene.fixed().any():
        return ()     # nothing to activate, or supports (their own fix nve group)
    out = []
    for name, g in scene.groups.items():
        rs = [r for r in realized if r.target == name]
        v0 = getattr(g, "v0", None)
        contact_only = all(
            (r.op.pair and not r.op.fixed_pairs and not r.native     # collide: the callback's,
             and (r.python or r.plugin == "rs/collide"))             # or rs/collide ... activate
            or (r.native == "viscous" and not r.python and not r.op.when)        # dampen(c)
            for r in rs)
        if rs and contact_only and any(r.op.pair for r in rs) and (v0 is None or not np.any(v0)):
            out.append(name)
    return tuple(out)


# ---------------------------------------------------------------------------- plugin
#: the plugin fixes' ids (rs_p + the operator's place in Deck.realized)
PLUGIN_FIX = "rs_p"
#: the file beside the data file holding rs/volume's cells (Deck.volume_atoms_text)
VOLUME_ATOMS = "volume.atoms"
#: LAMMPS' own fix property/atom holding what the plugin's styles read per atom
PROP_FIX = "rs_prop"


def _prop_name(region: str) -> str:
    """The per-atom integer property of an attraction region index (Eqs. 27–28)."""
    return "rsreg_" + "".join(ch if ch.isalnum() else "_" for ch in region)


def _region_names(scene: Scene) -> list[str]:
    return sorted({name for g in scene.groups.values()
                   for name in (g.meta or {}).get("regions", {})})


def plugin_setup_commands(deck: Deck) -> list[str]:
    """Before read_data: ``newton`` and the per-atom properties the styles read: original
    position (Eq. 12's L0), radius (Eq. 10's R), attraction region indices (Eqs. 27–28); ghosts
    carry them.

    newton_bond is off for rs/bind (each rank lists every bond of its atoms). newton_pair is off
    too unless a collide folds into ``pair_style lepton``: the plugin's styles add forces to
    owned atoms only (whole-body sums are reductions), so a ghost never holds a force and
    LAMMPS' reverse communication after every step's forces (``newton on``) sent zeros — one
    exchange between ranks a step (docs/benchmarks/scaling.md).
    """
    if not deck.lepton:
        L = ["newton off off"]
    else:
        L = ["newton on off"] if deck.bonds is not None else []
    regions = " ".join(f"i_{_prop_name(n)}" for n in _region_names(deck.scene))
    if deck.volumes:              # rs/volume's cells (Deck.volume_commands)
        regions = (regions + " d2_rsphi 6").strip()
    regions = (regions + " " + " ".join(f"d_{n}" for n, _, _ in _indent_props(deck.scene))).strip()
    L.append(f"fix {PROP_FIX} all property/atom d2_rso 3 d_rsr {regions} ghost yes".replace("  ", " "))
    return L


def _id_runs(values: np.ndarray, offset: int = 0):
    """(first id, last id, value) for each run of equal values in id order (atom ids 1-based)."""
    values = np.asarray(values)
    if not len(values):
        return []
    cut = np.flatnonzero(values[1:] != values[:-1]) + 1
    starts = np.concatenate([[0], cut])
    ends = np.concatenate([cut, [len(values)]]) - 1
    return [(int(a) + offset + 1, int(b) + offset + 1, values[a]) for a, b in zip(starts, ends)]


def plugin_property_commands(scene: Scene) -> list[str]:
    """After read_data: fill :func:`plugin_setup_commands`' properties. The original position is
    where read_data put each atom (the data file is the original state), copied exactly through
    atom-style variables; radii and region indices by runs of atom ids (a data file section would
    do it in one pass, but MDAnalysis and OVITO, which read ``particles.data``, reject unknown
    sections)."""
    L = [f"variable rs_o{k} atom {c}" for k, c in enumerate("xyz", start=1)]
    L += [f"set group all d2_rso[{k}] v_rs_o{k}" for k in (1, 2, 3)]
    L += [f"variable rs_o{k} delete" for k in (1, 2, 3)]
    L += [f"set atom {a}*{b} d_rsr {_f(v)}" for a, b, v in _id_runs(scene.radii())]
    for name, start, op in _indent_props(scene):         # rs/indent's stiffness per atom
        L += [f"set atom {a}*{b} d_{name} {_f(v)}"
              for a, b, v in _id_runs(np.asarray(op.k, float), start) if v != 0]
    for name in _region_names(scene):
        for g_name, g in scene.groups.items():
            regions = (g.meta or {}).get("regions", {})
            if name in regions:
                L += [f"set atom {a}*{b} i_{_prop_name(name)} {int(v)}"
                      for a, b, v in _id_runs(regions[name], scene.offset(g_name)) if v != 0]
    return L


def _plugin_realize(scene: Scene, realized: list) -> tuple | None:
    """Hand every Python-realized operator to a plugin style (module doc, "Plugin"); the bonds
    of the rs/bind pairs (types, i, j: one bond per unordered pair, a type per bind and its
    reverse). None, with the reason, if one has no style (a contact-conditioned force)."""
    btypes, bonds, n_types = {}, [], 0
    for r in realized:
        if not r.python:
            continue
        op = r.op
        if isinstance(op, Force):
            return None, f"{r.target} <- {op.label()} (a contact-conditioned force) has no plugin style"
        if isinstance(op, Dampen):
            if len(contact_groups(op.when)) != 1:
                return None, f"{r.target} <- {op.label()}: the plugin's dampen takes one contact"
            r.plugin = "rs/dampen"
        elif isinstance(op, Collide):
            r.plugin = "rs/collide"
        elif isinstance(op, Indent):
            r.plugin = "rs/indent"
        elif isinstance(op, Attract):
            r.plugin = "rs/attract"
        elif isinstance(op, Volume):
            # over the bonds of the part's own bind (realized before it: it comes first)
            carrier = [b for b in realized if b.plugin == "rs/bind" and b.target == r.target
                       and b.op.source == r.target and b.op.coeff is op.solid]
            if op.when or not carrier:
                return None, (f"{r.target} <- {op.label()}: the volumetric term needs its "
                              "part's unconditional bind as rs/bind bonds")
            r.plugin, r.btypes = "rs/volume", list(carrier[0].btypes)
            if not carrier[0].op.when:
                # its part's bindings in the same pass (docs/plugin.md "rs/volume"): the bonds
                # stay the bind's, rs/volume binds them, no rs/bind fix is written
                c = float(carrier[0].op.coeff.c)
                r.bind = [(bt, c if cv is None else cv) for bt, cv in carrier[0].btypes]
                carrier[0].fused = True
        elif isinstance(op, Bind) and type(op.coeff) is Const:
            r.plugin = "rs/rack"
        elif isinstance(op, Bind):
            # a material solid's c differs per pair (its face compensation, model/solid.py:
            # c·(1 + ¼k), a few values): a bond type and an rs/bind fix per distinct value
            weighted = getattr(op.coeff, "weights", None) is not None
            if weighted and op.when:
                return None, (f"{r.target} <- {op.label()}: a phase-conditioned bind with a "
                              "coefficient per pair has no plugin style")
            rev = reverse_of(scene.operators, r.target, r.site[1])
            key = frozenset({r.site, rev}) if rev is not None else frozenset({r.site})
            if key not in btypes:
                pl = op.pairs(scene.groups[r.target], scene.groups[op.source])
                I = pl.i + scene.offset(r.target) + 1
                J = pl.j + scene.offset(op.source) + 1
                c = np.asarray(pl.c, float) if weighted else np.zeros(len(I))
                if r.target == op.source:
                    keep = I < J
                    I, J, c = I[keep], J[keep], c[keep]
                values, which = np.unique(c, return_inverse=True)
                if len(values) > MAX_PAIR_TYPES:
                    return None, (f"{r.target} <- {op.label()} has {len(values)} distinct "
                                  f"coefficients (the plugin takes up to {MAX_PAIR_TYPES}, one "
                                  "bond type each)")
                first = n_types + 1
                n_types += len(values)
                btypes[key] = [(first + k, float(v) if weighted else None)
                               for k, v in enumerate(values)]
                bonds.append((first + which.reshape(-1), I, J))
            r.plugin, r.btypes = "rs/bind", btypes[key]
        else:
            return None, f"{r.target} <- {op.label()} has no plugin style"
        r.python = False
    if not bonds:
        return (None, 0), ""
    return ((np.concatenate([b[0] for b in bonds]), np.concatenate([b[1] for b in bonds]),
             np.concatenate([b[2] for b in bonds])), n_types), ""


def plugin_ghost_cutoff(scene: Scene, bonds, skin: float, activate: bool = False) -> float:
    """The ghost cutoff of a plugin deck: the real interaction range, no more.

    - A collision's candidates reach r_p + r_max + skin (+ one more skin where rs/collide
      activates resting particles, ``activate``: it looks r_p + r_u + 2·skin far), + 1 spare.
    - A bound pair (rs/bind) needs its partner as a ghost only when LAMMPS reneighbours (it
      builds the bond list then): the longest bond L0 plus half a skin, or plus a quarter of
      itself if that is more (long binds of large-spacing scenes). A bond stretched beyond
      that at a reneighbouring stops LAMMPS with "Bond atoms missing", which rackstress
      reports as a divergence (exit 3); within(1.5) on a unit lattice: 2.41, not 2·L0 + 3.
    - Rack couplings and attraction are reductions, not ghosts."""
    contact = any((op.pair and not op.fixed_pairs) or contact_groups(op.when)   # collide, a
                  for seq in scene.operators.values() for op in seq)           # contact
    reach = 0.0
    if contact:
        reach = 2.0 * float(scene.radii().max()) + skin + 1.0 + (skin if activate else 0.0)
    if bonds is not None and len(bonds[1]):
        o = scene.original_positions()
        L0 = float(np.sqrt(((o[bonds[2] - 1] - o[bonds[1] - 1]) ** 2).sum(axis=1)).max())
        reach = max(reach, L0 + max(0.5 * skin, 0.25 * L0))
    return reach if reach > 0.0 else 2.0 * float(scene.radii().max()) + skin


_WARNED = set()


def _say_once(line: str) -> None:
    """One line on stderr, once per process and only on the first rank of an MPI run."""
    import os
    import sys

    rank = os.environ.get("PMI_RANK") or os.environ.get("OMPI_COMM_WORLD_RANK") or "0"
    if line not in _WARNED and rank == "0":
        _WARNED.add(line)
        sys.stderr.write(line + "\n")


def material_contacts(scene: Scene) -> frozenset:
    """The pairs of groups (frozensets of two names) whose collides are a contact between two
    material parts (``[[contact]]``: :func:`rackstress.engines.static.is_contact`)."""
    from rackstress.engines.static import is_contact

    return frozenset(frozenset((target, op.source)) for target, seq in scene.operators.items()
                     for op in seq if is_contact(scene, target, op))


def use_plugin(requested: bool | None = None) -> bool:
    """Whether decks use the compiled plugin: ``requested``, else not when the callback's
    kernels are asked for (``RACKSTRESS_KERNELS=numba|numpy``), else whenever the plugin is
    there for this LAMMPS (built at first use if need be). When it is not, one line says why."""
    import os

    from rackstress.engines.lammps import plugin

    if requested is not None:
        return requested      # a deck is text: running it is where the library must be there
    if os.environ.get("RACKSTRESS_PLUGIN", "1") in ("0", "no", "off"):
        return False
    if requested is None and os.environ.get("RACKSTRESS_KERNELS") in ("numba", "numpy"):
        return False
    lib, why = plugin.locate()
    if lib is None:
        _say_once(f"rackstress: using the Python callback for the exact operators: {why}")
        return False
    return True


def compile_deck(scene: Scene, mode: str = "exact", measure_fast: bool = False,
                 native: bool = True, active_only: bool = True,
                 plugin: bool | None = False) -> Deck:
    """Realize every operator of ``scene`` (module doc).

    Fast mode is offered only where it takes every operator out of the Python callback (the
    plane scenes): there it is on the work-precision front, 1.6-9x faster than the cheapest
    exact run at least as accurate. Where the callback stays (MagPod's attraction, one-way
    collisions and contact damping), it was measured at best 1.06x faster at 4-6x exact mode's
    error (``rackstress bench accuracy``), off the front, so it is refused; ``measure_fast``
    lets the benchmarks keep measuring it. ``native=False`` keeps every pair operator in the
    callback (no pair style, no bonds, unit masses): the tests check both paths against the
    same accelerations. ``active_only=False`` integrates every particle, resting or not.

    Examples
    --------
    >>> from rackstress import scenes
    >>> deck = compile_deck(scenes.build("plane-rack"), "fast")
    >>> sorted({r.how for r in deck.realized}), deck.masses
    (['addforce', 'harmonic', 'viscous'], {'plane': 1.0, 'planerack': 200.0})
    """
    if mode not in MODES:
        raise SceneError(f"unknown mode '{mode}'; modes: {', '.join(MODES)}")
    integrator = scene.integrator
    if integrator == "verlet":
        scene = scaled_scene(scene)
    if native:
        # two material parts in contact ([[contact]]): the plugin's rs/collide, one fix a
        # side — the same forces to round-off as pair_style lepton, without lepton's parsing
        # of its expression every step (rackstress bench dynamics: what contact costs a step)
        unfolded = material_contacts(scene) if mode == "exact" else frozenset()
        if unfolded and not (plugin or plugin is None and use_plugin(None)):
            unfolded = frozenset()
        masses, pairs = solve_masses(scene, mode, unfolded)
    else:
        masses, pairs = {name: 1.0 for name in scene.groups}, {}
    cx = {"scene": scene, "masses": masses, "pairs": pairs, "types": topology.group_types(scene),
          "folded": set(), "lepton": {}, "bonds": []}   # bonds: (i, j, K, r0), 1-based, i < j
    realized = [REALIZE[type(op)](cx, target, k, op)
                for target, seq in scene.operators.items() for k, op in enumerate(seq)]
    if (mode == "exact" and (plugin or plugin is None) and any(r.python for r in realized)
            and use_plugin(plugin)):
        got, why = _plugin_realize(scene, realized)
        if got is None:
            _say_once(f"rackstress: using the Python callback for scene '{scene.name}': {why}")
            for r in realized:
                r.plugin, r.python = None, r.python or r.plugin is not None
        else:
            pbonds, n_btypes = got
            # active-only: the resting groups are activated by rs/collide (module doc)
            passive = passive_groups(scene, realized) if active_only else ()
            skin = plugin_passive_skin(scene, passive) if passive else SKIN
            return Deck(scene, mode, masses, realized,
                        plugin_ghost_cutoff(scene, pbonds, skin, bool(passive)),
                        pbonds, [(0.0, 0.0)] * n_btypes, cx["lepton"], integrator=integrator,
                        plugin=True, passive=passive,
                        neighbor_skin=skin if skin != SKIN else None)
    bond_list, lepton = cx["bonds"], cx["lepton"]
    bonds, bond_types = None, []
    if bond_list:
        i = np.concatenate([b[0] for b in bond_list])
        j = np.concatenate([b[1] for b in bond_list])
        K = np.concatenate([b[2] for b in bond_list])
        r0 = np.concatenate([b[3] for b in bond_list])
        keys = np.round(np.column_stack([K, r0]), L0_DIGITS)
        uniq, inv = np.unique(keys, axis=0, return_inverse=True)
        # the exact K, r0 of the first bond of each type
        first = np.zeros(len(uniq), dtype=np.int64)
        first[inv[::-1]] = np.arange(len(inv))[::-1]
        bond_types = [(float(K[f]), float(r0[f])) for f in first]
        bonds = (inv.reshape(-1) + 1, i, j)
    passive = passive_groups(scene, realized) if active_only else ()
    skin = PASSIVE_SKIN if passive else SKIN
    deck = Deck(scene, mode, masses, realized, ghost_cutoff(scene, skin), bonds, bond_types,
                lepton, integrator=integrator, passive=passive,
                neighbor_skin=skin if skin != SKIN else None)
    if mode == "fast" and deck.python_ops and not measure_fast:
        kept = sorted({f"{r.target} <- {r.op.kind}" for r in deck.python_ops})
        raise SceneError(
            f"mode 'fast' is not offered for scene '{scene.name}': it only replaces bind by "
            f"harmonic bonds, and {len(deck.python_ops)} operators ({', '.join(kept[:4])}"
            f"{', ...' if len(kept) > 4 else ''}) stay in the Python callback either way. For "
            "such a scene fast mode was measured no faster than exact mode and about 4x less "
            "accurate (README 'Accuracy and speed'); use --mode exact.")
    return deck


def _bonds_of(scene: Scene, target: str, op: Bind, K: float):
    """One bond per unordered pair of a reciprocal bind: 1-based ids i < j, K, r0 = L0."""
    g_t, g_s = scene.groups[target], scene.groups[op.source]
    pl = op.pairs(g_t, g_s)
    I, J, L0sq = pl.i + scene.offset(target) + 1, pl.j + scene.offset(op.source) + 1, pl.q
    # per-pair c (a material solid's face compensation) scales K pair by pair
    scale = pl.c / float(op.coeff.c)
    if target == op.source:
        keep = I < J
        I, J, L0sq, scale = I[keep], J[keep], L0sq[keep], scale[keep]
    lo, hi = np.minimum(I, J), np.maximum(I, J)
    return lo, hi, K * scale, np.sqrt(L0sq)


def ghost_cutoff(scene: Scene, skin: float = SKIN) -> float:
    """Ghost-atom cutoff covering every bind/attract partner with room to deform (MPI runs);
    ``skin``: LAMMPS' neighbour skin."""
    o = scene.original_positions()
    reach = 0.0
    for target, seq in scene.operators.items():
        for op in seq:
            if op.fixed_pairs:     # bind, attract: partners anywhere in the two groups
                a, b = scene.slice(target), scene.slice(op.source)
                lo = np.minimum(o[a].min(0), o[b].min(0))
                hi = np.maximum(o[a].max(0), o[b].max(0))
                reach = max(reach, float(np.linalg.norm(hi - lo)))
    rmax = float(scene.radii().max())
    return 1.5 * reach + 2 * rmax + skin + 1.0


# ---------------------------------------------------------------------------- data file
def data_text(scene: Scene, masses: dict, bonds=None, n_bond_types: int = 0) -> str:
    """A LAMMPS data file (atom_style bond: id mol type x y z) of the scene's original state."""
    o = scene.original_positions()
    types = topology.per_particle(scene, topology.group_types(scene))
    mols = topology.per_particle(scene, topology.group_mols(scene))
    r = scene.radii()
    lo, hi = (o - r[:, None]).min(0) - 1.0, (o + r[:, None]).max(0) + 1.0
    n_types = len(scene.groups)
    out = [f"LAMMPS data file: rackstress scene '{scene.name}' "
           f"(groups: {', '.join(scene.groups)})", "",
           f"{len(o)} atoms", f"{n_types} atom types"]
    if bonds is not None:
        out += [f"{len(bonds[0])} bonds", f"{n_bond_types} bond types"]
    out += ["", f"{_f(lo[0])} {_f(hi[0])} xlo xhi", f"{_f(lo[1])} {_f(hi[1])} ylo yhi",
            f"{_f(lo[2])} {_f(hi[2])} zlo zhi", "", "Masses", ""]
    for k, name in enumerate(scene.groups, start=1):
        out.append(f"{k} {_f(masses.get(name, 1.0))}  # {name}")
    out += ["", "Atoms  # bond", ""]
    text = "\n".join(out) + "\n"
    # one str.format a row, floats by repr (as _f): a million rows in a few seconds, not 16
    x, y, z = np.asarray(o, dtype=np.float64).T.tolist()
    rows = "\n".join(map("{} {} {} {!r} {!r} {!r}".format, range(1, len(o) + 1),
                         np.asarray(mols).tolist(), np.asarray(types).tolist(), x, y, z))
    text += rows + "\n"
    if bonds is not None:
        btype, bi, bj = bonds
        text += "\nBonds\n\n" + "\n".join(
            f"{k} {t} {a} {b}" for k, (t, a, b) in enumerate(zip(btype, bi, bj), start=1)) + "\n"
    return text


def write_deck(scene: Scene, out: Path, mode: str = "exact", dump_every: int = 100,
               plugin: bool | None = None) -> Deck:
    """Write ``particles.data`` and ``in.lammps`` into ``out``; return the compiled deck.

    By default the operators LAMMPS has no style for are the plugin's fixes whenever the plugin
    is there (``plugin=None``), so the deck runs standalone: ``lmp -in in.lammps``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    deck = compile_deck(scene, mode, plugin=plugin)
    deck.write_data(out / "particles.data")
    (out / "in.lammps").write_text(deck.input_text(dump_every))
    return deck


def _global_int(lmp, name: str):
    """A pointer to one of LAMMPS' global ints (``lammps_extract_global``): read each step
    in a fraction of a microsecond, where ``lmp.extract_global`` takes a few."""
    import ctypes

    fn = lmp.lib.lammps_extract_global
    fn.restype = ctypes.POINTER(ctypes.c_int32)   # lmp.extract_global sets it on each call
    ptr = fn(lmp.lmp, name.encode())
    if not ptr:
        raise RuntimeError(f"LAMMPS has no global '{name}'")
    return ptr

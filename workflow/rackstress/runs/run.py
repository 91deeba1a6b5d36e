"""Running a scene: the run directory, the engine, the driver, and ``summary.json``.

A run directory holds ``scene.json`` (how the scene was built, and the fingerprint of what
determines its trajectory), ``particles.data`` (particles, types, molecules), ``trajectory.dump``
(frames every ``dump_every`` steps and the last step) and, once the run has ended either way,
``summary.json``. A run that diverged — stopped by the watchdog, by LAMMPS losing atoms, or by
the operator callback losing a partner — keeps its frames and records ``status: "diverged"``
with the step, particle and group. One process writes a run directory at a time
(:func:`rackstress.runs.rundir.locked`); a run and its resumption share one ending
(:func:`execute`).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from rackstress.lib import rigid
from rackstress.model import topology
from rackstress.errors import DivergenceError, RunDirError
from rackstress.lib.jsonio import write_json
from rackstress.lib.mpi import on_root, world
from rackstress.lib.progress import progress_bar
from rackstress.lib.resources import require_memory
from rackstress.model.operators import forget_pairs
from rackstress.model.scene import PhaseEnd, Scene

ENGINES = ("lammps", "reference")


#: LAMMPS reads the intervals of ``dump`` and ``thermo`` as a C int.
LAMMPS_MAX_INT = 2**31 - 1


def default_dump_every(scene: Scene) -> int:
    """About 100 frames a run, never fewer than every step, nor more steps apart than LAMMPS
    can count in a ``dump`` interval (a run of 10¹² steps gets more frames)."""
    return min(max(1, scene.total_steps // 100), LAMMPS_MAX_INT)


#: Bytes a particle costs, measured (peak RSS over particles, ``scripts/bench_large.py``:
#: 536 MB for 1,004,689 particles on LAMMPS, one rank), with room for the dump buffers.
BYTES_PER_PARTICLE = {"lammps": 700, "reference": 900}
#: Bytes a bind pair costs (index pairs, coefficients, L0²: 4 float64/int64 arrays, twice).
BYTES_PER_PAIR = 64
#: Bytes the volumetric term costs a particle of a material part (model/volume.py: its six
#: nearest pairs' i, j, L and one term's owner, κ and six coefficients with their columns,
#: twice for the engines' copies)
VOLUME_BYTES_PER_PARTICLE = 600


def check_memory(scene: Scene, engine: str, ranks: int = 1) -> int:
    """Refuse a run whose estimated memory exceeds what the machine has; return the estimate.

    The estimate: particles × :data:`BYTES_PER_PARTICLE` plus bind pairs × :data:`BYTES_PER_PAIR`
    (counted without building them: within(d) pairs by cells, :mod:`rackstress.lib.cells`), on
    every rank.
    """
    from rackstress.lib.cells import count_within
    from rackstress.model.operators import Bind, Within
    from rackstress.model.volume import Volume

    pairs, extra = 0, 0
    for target, seq in scene.operators.items():
        for op in seq:
            if isinstance(op, Volume):
                extra += scene.groups[target].n * VOLUME_BYTES_PER_PARTICLE
            if not isinstance(op, Bind):
                continue
            t, u = scene.groups[target], scene.groups[op.source]
            if isinstance(op.coeff, Within):      # only pairs closer than d (Eq. 16): count them
                pairs += count_within(t.o, u.o, float(op.coeff.d))
            else:
                pairs += t.n * u.n
    need = (scene.n_particles * BYTES_PER_PARTICLE.get(engine, 900) + pairs * BYTES_PER_PAIR
            + extra) * max(1, ranks)
    require_memory(need, f"scene '{scene.name}' ({scene.n_particles:,} particles, up to "
                         f"{pairs:,} bind pairs, {ranks} rank(s), {engine} engine)")
    return need


def scene_record(scene: Scene) -> dict:
    """What post-processing needs to know of a scene: its groups as atom types and id ranges."""
    types, mols = topology.group_types(scene), topology.group_mols(scene)
    rec = {"scene": scene.name, "params": scene.params, "dt": scene.dt,
           "source": scene_source(scene),
           "steps": scene.total_steps,
           "phases": [{"name": p.name, "steps": p.steps, "vars": dict(p.vars)}
                      for p in scene.phases],
           "cycles": scene.cycles,
           "groups": [{"name": name, "kind": g.kind, "host": g.host, "n": g.n,
                       "type": types[name], "mol": mols[name],
                       "first_id": scene.offset(name) + 1, **material_record(scene, g),
                       **surface_record(g)}
                      for name, g in scene.groups.items()],
           "units": units_record(scene.units)}
    if scene.analysis == "static":
        rec["analysis"] = "static"
    return rec


def surface_record(g) -> dict:
    """A part's own surface and lattice spacing, where the scene knows them: ``mesh`` (the
    file, absolute, and its placement: scale, rotate, translate) and ``spacing``; the static
    report paints the stress on that surface (:mod:`rackstress.render.surface`)."""
    meta = g.meta if isinstance(g.meta, dict) else {}
    out = {}
    if meta.get("mesh"):
        out["mesh"] = {k: list(v) if isinstance(v, tuple) else v
                       for k, v in meta["mesh"].items()}
    if meta.get("spacing"):
        out["spacing"] = float(meta["spacing"])
    return out


def units_record(u) -> dict:
    """The scene's unit system as ``scene.json`` keeps it (what the stress is reported in)."""
    return {"name": u.name, "length": u.length, "time": u.time, "mass": u.mass,
            "force": u.force, "stress": u.stress, "density": u.density}


def material_record(scene: Scene, g) -> dict:
    """A group's material in the scene's units, its volume and mass per particle (post-processing
    turns the bindings' forces into stress with them); nothing for a group without one."""
    if g.material is None:
        return {}
    rec = {"material": {"name": g.material.name, **g.material.in_units(scene.units)},
           "mass": g.mass(scene.units)}
    if g.volume is not None:
        rec["volume"] = float(g.volume)
    return rec


def write_bindings(scene: Scene, path: Path) -> int:
    """``bindings.npz``: every unconditional bind on a group with a material and a volume, in
    global particle order — ``i`` (the bound particle), ``j`` (its partner), ``k`` = m_i·c (the
    binding's force per length, Eq. 12 times the mass) and ``L0sq`` — so that post-processing
    finds the stress from the bindings' forces (:mod:`rackstress.stress.tensor`) without the
    scene. With a volumetric term (a material's Poisson's ratio, :mod:`rackstress.model.volume`)
    its terms too — ``vi``, ``vj``, ``vL`` (their pairs), ``vowner``, ``vK`` = m·κ (energies)
    and the sparse ``C`` as ``vC_indptr``, ``vC_indices``, ``vC_data`` — whose virial the
    stress adds (:meth:`rackstress.model.volume.Volume.virial`). With material parts in contact
    (``[[contact]]``) each side of each contact — ``ct`` (its target's and source's first and
    end particle), ``ck`` (the pair's force per length m·c) — and every particle's radius
    ``r``, so that the contact's force enters the stress of the layers that touch and the
    contact pressure is read (:func:`rackstress.stress.measures.read_contacts`). Returns the
    number of bindings (0: no file written)."""
    b = bindings_of(scene)
    if b is None:
        return 0
    idx = np.int32 if scene.n_particles < 2 ** 31 else np.int64
    tmp = path.with_name(f".{path.name}.tmp.npz")
    extra = {}
    vol = volume_of(scene)
    if vol is not None:
        m = scene.masses()
        extra = {"vi": vol.i.astype(idx), "vj": vol.j.astype(idx), "vL": vol.L,
                 "vowner": vol.owner.astype(idx), "vK": m[vol.owner] * vol.kappa,
                 "vC_indptr": vol.C.indptr.astype(np.int64),
                 "vC_indices": vol.C.indices.astype(np.int64), "vC_data": vol.C.data}
    from rackstress.engines.static import material_contacts

    contacts = material_contacts(scene)
    if contacts:
        m = scene.masses()
        extra.update(ct=np.array([[t.start, t.stop, s.start, s.stop]
                                  for t, s, *_ in contacts], np.int64),
                     ck=np.array([m[t.start] * c for t, _, c, *_ in contacts]),
                     r=np.concatenate([g.r for g in scene.groups.values()]))
    np.savez(tmp, i=b[0].astype(idx), j=b[1].astype(idx), k=b[2], L0sq=b[3],
             V=volumes_of(scene), **fractions_of(scene), **extra)
    tmp.replace(path)
    return len(b[0])


def volume_of(scene: Scene):
    """The volumetric terms of the material parts (:func:`rackstress.model.volume.volume_terms`:
    unconditional ones on groups with a material and a volume), or None."""
    from rackstress.model.volume import volume_terms

    if not any(g.material is not None and g.volume is not None for g in scene.groups.values()):
        return None
    return volume_terms(scene)


def volumes_of(scene: Scene) -> np.ndarray:
    """Each particle's volume in global order: a material part's cell share of the part
    (``Group.volume`` × its boundary fraction, docs/calibration.md), NaN elsewhere."""
    V = np.full(scene.n_particles, np.nan)
    for name, g in scene.groups.items():
        if g.material is None or g.volume is None:
            continue
        f = g.meta.get("fraction") if isinstance(g.meta, dict) else None
        k = scene.offset(name)
        V[k:k + g.n] = g.volume * (1.0 if f is None else np.asarray(f))
    return V


def fractions_of(scene: Scene) -> dict:
    """``{"phi": n×3}`` of a static scene: each particle's cell extent along x, y and z in
    spacings, in global order — a material part's :func:`rackstress.model.solid.axis_fractions`
    (1: a whole cell), NaN elsewhere — where a support's face lies (the stress measure adds
    the supports' forces there; a dynamic run's loads at a frame are not in its files, so its
    held particles' forces are not known there: ``{}``)."""
    if scene.analysis != "static":
        return {}
    phi = np.full((scene.n_particles, 3), np.nan)
    for name, g in scene.groups.items():
        if g.material is None or g.volume is None:
            continue
        f = g.meta.get("fractions") if isinstance(g.meta, dict) else None
        k = scene.offset(name)
        phi[k:k + g.n] = 1.0 if f is None else np.asarray(f)
    return {"phi": phi}


def bindings_of(scene: Scene):
    """(i, j, k, L0²) of :func:`write_bindings` as arrays, or None when there are none."""
    from rackstress.model.operators import Bind

    I, J, K, Q = [], [], [], []
    for target, seq in scene.operators.items():
        g = scene.groups[target]
        if g.material is None or g.volume is None:
            continue
        m = g.mass(scene.units)
        for op in seq:
            if not isinstance(op, Bind) or op.when:
                continue
            pl = op.pairs(g, scene.groups[op.source]).shifted(scene.offset(target),
                                                             scene.offset(op.source))
            I.append(pl.i)
            J.append(pl.j)
            K.append(m * pl.c)
            Q.append(pl.q)
    if not I:
        return None
    return (np.concatenate(I).astype(np.int64), np.concatenate(J).astype(np.int64),
            np.concatenate(K), np.concatenate(Q))


def scene_source(scene: Scene) -> str | None:
    """The scene file a TOML scene was read from (absolute), for --resume to find it again."""
    src = (scene.params or {}).get("file") or getattr(scene, "source", None)
    return str(Path(src).resolve()) if src else None


def group_figures(scene: Scene, p_start: np.ndarray, p_end: np.ndarray) -> dict:
    """Per group: n, centre of mass at start and end, and max_deformation.

    A moving part's ``max_deformation`` is the paper's: the largest distance from the desired
    position, after its best-fit rigid motion (docs/model.md, "Desired position"). A static
    analysis's parts are held by their supports, so their displacement is their deformation:
    there ``max_deformation`` is the largest displacement |p − o| (the rigid fit would take
    the bending out of a cantilever: 0.39 mm where its tip moved 0.92 mm), with the particle
    (``max_deformation_particle``, LAMMPS atom id) and where it sits in the part
    (``max_deformation_at``, undeformed)."""
    static = scene.analysis == "static"
    out = {}
    for name, g in scene.groups.items():
        sl = scene.slice(name)
        end = p_end[sl]
        ok = bool(np.isfinite(end).all())
        out[name] = {
            "n": g.n,
            "kind": g.kind,
            "com_start": p_start[sl].mean(axis=0).tolist(),
            "com_end": end.mean(axis=0).tolist() if ok else None,
            "max_deformation": rigid.max_deformation(g.o, end) if ok and not static else None,
        }
        if static and ok and g.n:
            u = np.linalg.norm(end - g.o, axis=1)
            k = int(np.argmax(u))
            out[name].update({"max_deformation": float(u[k]),
                              "max_deformation_particle": scene.offset(name) + k + 1,
                              "max_deformation_at": [float(x) for x in g.o[k]]})
    return out


def summarize(scene: Scene, engine: str, mode: str, p_end: np.ndarray, steps_done: int,
              wall_s: float, status: str, error: DivergenceError | None = None,
              extra: dict | None = None) -> dict:
    s = {
        "scene": scene.name,
        "engine": engine,
        "mode": mode,
        "status": status,
        "n_particles": scene.n_particles,
        "steps": int(steps_done),
        "steps_requested": scene.total_steps,
        "dt": scene.dt,
        "wall_s": wall_s,
        "params": scene.params,
        "groups": group_figures(scene, scene.original_positions(), p_end),
    }
    if error is not None:
        s["error"] = {"message": str(error), "step": error.step, "group": error.group,
                      "particle": error.local, "index": error.index,
                      "atom_id": None if error.index is None else error.index + 1}
    s["units"] = scene.units.name
    for name, g in scene.groups.items():        # a mesh part: its spacing and thin walls
        sizing = mesh_sizing(g)
        if sizing is not None:
            s["groups"][name]["sizing"] = sizing
    if scene.units.physical:
        for name, g in scene.groups.items():
            if g.material is not None:
                s["groups"][name]["material"] = {"name": g.material.name,
                                                 **g.material.in_units(scene.units)}
    if extra:
        s.update(extra)
    return s


def mesh_sizing(g) -> dict | None:
    """A mesh part's spacing, how it was chosen (None: given) and its walls thinner than three
    spacings (:mod:`rackstress.scenes.features`), or None for another group."""
    geo = (g.meta or {}).get("part") if isinstance(g.meta, dict) else None
    if geo is None:
        return None
    return {"spacing": geo.spacing, "chosen": getattr(geo, "choice", None),
            "thin_walls": list(getattr(geo, "thin", []) or [])}


def sizing_lines(scene: Scene) -> tuple[list, list]:
    """What ``rackstress run`` says of its mesh parts: (lines for stdout: a spacing chosen and
    why; warnings: walls thinner than three spacings, where and near which feature)."""
    say, warn = [], []
    for name, g in scene.groups.items():
        sz = mesh_sizing(g)
        if sz is None:
            continue
        if sz["chosen"]:
            say.append(f"  {name}: spacing {sz['spacing']:g} chosen: {sz['chosen']['reason']} "
                       "(set spacing = ... in the group, or --set spacing=...)")
        for t in sz["thin_walls"][:3]:
            where = ", ".join(f"{x:.4g}" for x in t["position"])
            warn.append(f"'{name}': a wall {t['thickness']:.3g} thick at [{where}]"
                        + (f" (near {t['near']})" if t.get("near") else "")
                        + f" has fewer than 3 particles across at spacing {sz['spacing']:g}: "
                        "its stress there is coarse; a smaller spacing resolves it")
        if len(sz["thin_walls"]) > 3:
            warn.append(f"'{name}': {len(sz['thin_walls']) - 3} more place(s) with walls "
                        "thinner than 3 spacings (summary.json: groups.NAME.sizing)")
    return say, warn


def write_boundary(scene: Scene, out) -> None:
    """``boundary.npz`` (docs/scenes.md): the supports (held atom ids and their fixed
    directions), the loads (atom ids and the external force on each at full load, gravity
    included, in the scene's force unit) and the normal stress a pressure puts on each pressed
    face of a part with the material's ν (``face_ids``, ``face_stress`` k×3 along x, y, z, in
    the scene's stress unit, at full load)."""
    from rackstress.engines.static import external_forces
    from rackstress.errors import storage_error

    fixed = scene.fixed()
    held = np.flatnonzero(fixed.any(axis=1))
    F = external_forces(scene)
    loaded = np.flatnonzero(np.any(F != 0.0, axis=1))
    face = np.zeros((scene.n_particles, 3))
    for name, g in scene.groups.items():
        if "face_stress" in g.meta:
            off = scene.offset(name)
            face[off:off + g.n] = g.meta["face_stress"]
    pressed = np.flatnonzero(np.any(face != 0.0, axis=1))
    path = Path(out) / "boundary.npz"
    tmp = Path(out) / ".boundary.tmp.npz"
    try:
        from rackstress.model.constraints import supported

        constrained = np.flatnonzero(supported(scene) & ~fixed.any(axis=1))
        np.savez(tmp, held_ids=(held + 1).astype(np.int64), held_mask=fixed[held],
                 load_ids=(loaded + 1).astype(np.int64), load_force=F[loaded].astype(np.float64),
                 units=np.str_(scene.units.name),
                 constrained_ids=(constrained + 1).astype(np.int64),
                 face_ids=(pressed + 1).astype(np.int64), face_stress=face[pressed])
        tmp.replace(path)
    except OSError as exc:
        raise storage_error(exc, "write", path) from None
    write_singular(scene, out, fixed, F)


def singular_of(scene: Scene, fixed=None, F=None) -> dict:
    """Per part with a material: (spacing, wall thickness, singular points) — the spacing they
    were found at, the part's wall thickness (:func:`rackstress.model.singular.wall_thickness`,
    its boundary cells' shares counted) and :func:`rackstress.model.singular.find`'s points
    (re-entrant edges from its shape, the boundary of its supports, its point loads)."""
    from rackstress.engines.static import external_forces
    from rackstress.model import singular

    fixed = scene.fixed() if fixed is None else fixed
    F = external_forces(scene) if F is None else F
    out = {}
    for name, g in scene.groups.items():
        if g.material is None:
            continue
        sl = scene.slice(name)
        spacing, shape = singular.part_geometry(scene, name)
        meta = g.meta if isinstance(g.meta, dict) else {}
        wall = singular.wall_thickness(g.o, spacing, phi=meta.get("fractions"))
        out[name] = (spacing, wall, singular.find(g.o, spacing, shape, _bores_held(g, fixed[sl]),
                                                  F[sl]))
    return out


def _bores_held(g, fixed: np.ndarray) -> np.ndarray:
    """``fixed`` (the part's held axes) with a pinned hole's ring and a cylindrical support's
    bore counted as held in every direction: their edge on the bore is a support's edge, as a
    fixed hole's is; a roller or symmetry plane (one direction) is not, as a held axis is not."""
    from rackstress.model.constraints import Ring

    out = np.array(fixed, dtype=bool, copy=True)
    for con in getattr(g, "constraints", ()):
        if isinstance(con, Ring):
            out[con.ids] = True
        else:                        # Normals: held in two directions or more (a bore)
            ids, counts = np.unique(con.ids, return_counts=True)
            out[ids[counts >= 2]] = True
    return out


def write_singular(scene: Scene, out, fixed=None, F=None) -> None:
    """``singular.npz`` (:data:`rackstress.lib.runfiles.SINGULAR`): :func:`singular_of` as
    arrays — ``points`` (k×3, the parts' undeformed coordinates), ``kind`` (index into
    :data:`rackstress.model.singular.KINDS`), ``angle`` (an edge's turning in degrees),
    ``part`` (index into ``parts``), and per part ``parts``, ``spacing``, ``wall``, ``source`` and its
    surface (``surface_K_vertices``, ``surface_K_faces``: the named features) — for
    post-processing's governing stress (:mod:`rackstress.stress.governing`). Nothing is
    written for a scene without a material part."""
    from rackstress.errors import storage_error
    from rackstress.lib.runfiles import SINGULAR

    found = singular_of(scene, fixed, F)
    if not found:
        return
    names = list(found)
    pts = [found[n][2] for n in names]
    path = Path(out) / SINGULAR
    tmp = Path(out) / f".{SINGULAR}.tmp.npz"
    try:
        np.savez(tmp, points=np.concatenate([s.points for s in pts]).reshape(-1, 3),
                 kind=np.concatenate([s.kind for s in pts]).astype(np.int64),
                 angle=np.concatenate([s.angle for s in pts]).astype(float),
                 part=np.repeat(np.arange(len(names)), [len(s) for s in pts]).astype(np.int64),
                 parts=np.array(names), spacing=np.array([found[n][0] for n in names]),
                 wall=np.array([found[n][1] for n in names]),
                 source=np.array([s.source for s in pts]),
                 notes=np.array(["; ".join(s.notes) for s in pts]),
                 **{f"surface_{k}_{what}": np.asarray(x) for k, s in enumerate(pts)
                    if s.surface is not None
                    for what, x in zip(("vertices", "faces"), s.surface)})
        tmp.replace(path)
    except OSError as exc:
        raise storage_error(exc, "write", path) from None


def load_path_warnings(scene: Scene) -> list[dict]:
    """A load that never reaches a support: loaded particles with no chain of bindings to a
    fixed particle: a static analysis of it cannot settle. One warning per group so affected,
    naming a particle; and the loads partly on held particles (scenes.physical)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    from rackstress.engines.static import _bind_pairs, external_forces
    from rackstress.model.constraints import supported
    from rackstress.scenes.physical import held_load_warnings

    fixed = supported(scene)          # a fixed direction, a pin, a roller on any face
    F = external_forces(scene)
    loaded = np.any(F != 0.0, axis=1)
    if not loaded.any():
        return held_load_warnings(scene)
    I, J, _, _ = _bind_pairs(scene)
    n = scene.n_particles
    graph = sp.coo_matrix((np.ones(len(I)), (I, J)), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    supported = np.zeros(label.max() + 1, dtype=bool)
    supported[label[fixed]] = True
    lost = loaded & ~supported[label] & ~fixed
    out = []
    for name in scene.groups:
        sl = scene.slice(name)
        k = np.flatnonzero(lost[sl])
        if len(k):
            out.append({"kind": "load_path", "groups": [name],
                        "message": f"{len(k)} loaded particle(s) of '{name}' (particle "
                                   f"{int(k[0])} first) are bound to no support: their load "
                                   "never reaches one (no chain of bindings to a held or "
                                   "fixed particle)"})
    return out + held_load_warnings(scene)


def execute_static(scene: Scene, out: Path, engine: str, mode: str, *, progress: bool = True,
                   comm=None, deck=None, extra: dict | None = None) -> dict:
    """A static analysis into the prepared run directory ``out``: the equilibrium
    (:func:`rackstress.engines.static.solve`), proven on the run's engine (its own forces at
    that state), written as two frames (the original state at step 0 and the equilibrium at
    step = Newton iterations), then ``summary.json`` with ``analysis``, ``settled``,
    ``iterations``, ``residual`` and ``status`` ("settled" or "not settled")."""
    import sys

    from rackstress.engines.static import (TOLERANCE, engine_residual, release, rounding_floor,
                                           solve, support_reactions)

    comm = comm or world()
    root = comm.Get_rank() == 0
    t0 = time.perf_counter()
    # a line per Newton step, on a terminal and in a batch job's log alike (the SO-100 base at
    # 93,236 particles: a minute and more of solve, nothing said before)
    show = bool(progress and root)
    if not root:
        release(scene)          # the part check's factorization: the solve is rank 0's
    res = solve(scene, progress=show) if root else None
    if comm.Get_size() > 1:
        res = comm.bcast(res, root=0)
    eng = open_engine(scene, out, engine, mode, 1, comm, deck)
    try:
        eng.enter_phase({})                     # frame 0: the original state
        if engine == "reference":
            engine_rel = engine_residual(scene, eng, res.p, res.load)
            eng.step_count = res.iterations
            if eng._dump is not None:
                eng._dump.write(res.iterations, res.p)
        else:
            if eng._dump_id is not None:      # LAMMPS resets no timestep under a dump
                eng.command(f"undump {eng._dump_id}")
            eng.command(f"reset_timestep {max(1, res.iterations)}")
            eng.step = max(1, res.iterations)
            engine_rel = engine_residual(scene, eng, res.p, res.load)
            if eng._dump_id is not None:
                eng.command(f"write_dump all custom {eng._dump_file} id type mol x y z modify "
                            "sort id format float %.10g append yes")
            if out is not None and not eng.deck.python_ops:
                # plain lmp reproduces the check: in.lammps becomes the equilibrium's deck
                from rackstress.lib.runfiles import EQUILIBRIUM

                word = eng.path_word(Path(out) / EQUILIBRIUM, dump=True)
                eng.command(f"write_dump all custom {word} id x y z modify sort id "
                            "format float %.17g")
                if root:
                    (Path(out) / "in.lammps").write_text(
                        eng.deck.equilibrium_text(max(1, res.iterations)))
        extra = dict(extra or {}, dump_every=1)
        if engine == "lammps":
            extra.update({"ranks": eng.comm.Get_size(), "lammps_version": eng.lmp.version(),
                          "masses": eng.deck.masses})
    finally:
        eng.close()
    settled = bool(res.settled and engine_rel <= TOLERANCE)
    wall = time.perf_counter() - t0
    extra.update({"analysis": "static", "settled": settled, "iterations": res.iterations,
                  "residual": max(res.residual, engine_rel), "residual_solver": res.residual,
                  "residual_engine": engine_rel, "tolerance": TOLERANCE,
                  "applied_load_total": res.load, "solve_s": res.wall_s,
                  "residual_history": res.history, "solver": res.solver,
                  "factorizations": res.factorizations,
                  "contact_sets": res.contact_sets})
    if root:
        extra.update(support_reactions(scene, res))
    if not settled and res.unbalanced:
        extra["unbalanced_at"] = res.unbalanced
    if not settled and res.load > 0:
        # relative to the load: the unbalanced force rounding alone leaves (the hint of exit 6)
        extra["rounding_floor"] = rounding_floor(scene, scene.original_positions()) / res.load
    if root:
        warnings = load_path_warnings(scene) + list(res.warnings)
        for w in warnings:
            print(f"rackstress: warning: {scene.name}: {w['message']}", file=sys.stderr)
        extra["warnings"] = warnings
    status = "settled" if settled else "not settled"
    summary = summarize(scene, engine, mode, res.p, res.iterations, wall, status, None, extra)
    on_root(lambda: write_json(Path(out) / "summary.json", summary), comm)
    return summary


def open_engine(scene: Scene, out: Path | None, engine: str, mode: str, dump_every: int,
                comm=None, deck=None, append: bool = False):
    """The engine for a run: the reference engine (one rank) or a LAMMPS runner on ``comm``."""
    if engine == "reference":
        from rackstress.engines.reference import Reference

        if (comm or world()).Get_size() > 1:
            raise RunDirError("the reference engine runs on one rank; run it without mpiexec")
        ref = Reference(scene)
        if out is not None:
            ref.open_dump(Path(out) / "trajectory.dump", dump_every)
        return ref
    from rackstress.engines.lammps.deck import compile_deck
    from rackstress.engines.lammps.runner import LammpsRun

    deck = deck or compile_deck(scene, mode)
    return LammpsRun(deck, out, comm=comm, dump_every=dump_every, append=append)


def execute(scene: Scene, out: Path, engine: str, mode: str, dump_every: int, *,
            progress: bool = True, comm=None, restart_every: int | None = None, deck=None,
            resume=None, records=None, wall_before: float = 0.0, extra: dict | None = None,
            fingerprint: dict | None = None, keep_checkpoints: bool = True,
            head_start=None, guards: bool = True) -> dict:
    """Drive ``scene`` on ``engine`` into the prepared run directory ``out``, then write
    ``summary.json`` — the one ending of a run and of its resumption.

    Parameters
    ----------
    resume : rackstress.runs.checkpoint.Checkpoint, optional
        Continue from this checkpoint (LAMMPS); ``records`` are the phase ends before it.
    wall_before : float
        Wall time of the earlier part(s) of a resumed run.
    head_start : callable, optional
        Called once, as soon as the steps left look to take under :data:`HEAD_START_S` seconds
        at the pace so far, or a quarter of the steps are done (``rackstress run`` then loads
        post-processing's modules and measures the frames written on the other core: a short
        run from its first steps, a long one not holding them from its start); a callable it
        returns is called once the steps are done, before the guard rails.
    guards : bool
        Check the guard rails of a run that ended well (:func:`rackstress.engines.guards.
        check_run`) into ``summary.json``'s ``warnings``; False: ``warnings`` is left empty
        for the caller to fill (``rackstress run``'s head start checks them beside this
        process). A run that diverged is always checked here.

    Returns
    -------
    dict
        The summary. Raises :class:`DivergenceError` after writing it when the run diverged.
    """
    from rackstress.engines.driver import drive

    comm = comm or world()
    root = comm.Get_rank() == 0
    if root:
        write_boundary(scene, out)
    if scene.analysis == "static":
        try:
            return execute_static(scene, out, engine, mode, progress=progress, comm=comm,
                                  deck=deck, extra=extra)
        finally:
            forget_pairs()               # the bindings are in the run directory now
    extra = dict(extra or {}, dump_every=dump_every)
    if records is None:
        records = [PhaseEnd(0, None, {}, 0, scene.original_positions())]
    on_phase_end = records.append if scene.report is not None else None
    t0 = time.perf_counter()
    eng = open_engine(scene, out, engine, mode, dump_every, comm, deck, append=resume is not None)
    forget_pairs()                       # the engine holds what it steps with
    try:
        ckpt = None
        if restart_every and engine == "lammps":
            from rackstress.runs.checkpoint import Checkpointer

            ckpt = Checkpointer(out, eng.comm, restart_every, mode=mode, dump_every=dump_every,
                                resumed=resume, fingerprint=fingerprint, keep=keep_checkpoints)
            on_phase_end = ckpt.wrap_phase_end(on_phase_end)
        status, error, ended = "ok", None, None
        try:
            with progress_bar(scene.total_steps, progress,
                              f"{scene.name} ({engine})") as bar:
                bar.update(resume.step if resume is not None else 0)
                if head_start is not None:
                    def begin():
                        nonlocal ended
                        ended = head_start()
                    bar = _Trigger(bar, scene.total_steps, begin)
                outcome = drive(eng, progress=bar, on_phase_end=on_phase_end,
                                checkpoint=ckpt, resume=resume)
            p_end, steps = outcome.positions, outcome.steps
            extra["driver_s"] = outcome.timings
        except DivergenceError as err:
            status, error = "diverged", err
            p_end = getattr(err, "p_end", None)
            if p_end is None:
                p_end = np.full((scene.n_particles, 3), np.nan)
            steps = getattr(err, "steps_done", err.step)
        if engine == "lammps":
            extra.update({"ranks": eng.comm.Get_size(), "lammps_version": eng.lmp.version(),
                          "python_operators": [f"{r.target} <- {r.op.kind}"
                                               for r in eng.deck.python_ops],
                          "masses": eng.deck.masses})
    finally:
        eng.close()
        if callable(ended):
            ended()
    if error is not None and root and engine == "lammps":
        from rackstress.engines.dumpio import trim_after, trim_nonfinite

        # LAMMPS writes the dump itself: frames of non-finite positions written before the
        # check that noticed them are cut, and the step named is the first bad one seen
        after = getattr(error, "trim_after", None)
        if after is not None:       # the plugin left a non-finite term out: later frames are wrong
            cut = trim_after(Path(out) / "trajectory.dump", after)
            if cut is not None:
                extra["trimmed_from_step"] = cut
            steps = min(steps, after)
        bad = trim_nonfinite(Path(out) / "trajectory.dump")
        if bad is not None:
            extra["trimmed_from_step"] = bad
            if bad < error.step:
                error.args = (f"{error} (its positions were non-finite at step {bad} already: "
                              f"the frames from step {bad} on were removed from the dump)",)
                error.step, steps = bad, min(steps, bad)
    wall = wall_before + time.perf_counter() - t0
    if scene.report is not None and root:
        extra["report"] = scene.report(scene, records)
    if root:   # guard rails: pass-through, force on racks (engines/guards.py)
        from rackstress.engines.guards import check_run

        extra["warnings"] = (check_run(scene, out, engine=engine)
                             if guards or error is not None else [])
    summary = summarize(scene, engine, mode, p_end, steps, wall, status, error, extra)
    on_root(lambda: write_json(Path(out) / "summary.json", summary), comm)
    if error is not None:
        raise error
    return summary


#: :func:`execute`'s ``head_start`` is called once the steps left look to take under this
#: many seconds (or a quarter of the steps are done)
HEAD_START_S = 10.0


class _Trigger:
    """A progress bar's ``update`` that also calls ``fn`` once, when the ``total`` steps'
    remainder looks to take under :data:`HEAD_START_S` at the pace of the steps so far, or a
    quarter of them are done."""

    def __init__(self, bar, total: int, fn):
        self.bar, self.total, self.fn, self.done = bar, total, fn, 0
        self.t0 = time.perf_counter()

    def update(self, n: int) -> None:
        self.bar.update(n)
        self.done += n
        if self.fn is None or self.done <= 0:
            return
        pace = (time.perf_counter() - self.t0) / self.done
        if self.done >= self.total // 4 or pace * (self.total - self.done) < HEAD_START_S:
            fn, self.fn = self.fn, None
            fn()


def plan(scene: Scene, engine: str = "lammps", mode: str = "exact",
         dump_every: int | None = None, comm=None, allow_unstable: bool = False) -> dict:
    """Check everything about a run that can be checked before its directory is touched: the
    engine, the dump interval, the predicted stability limit of Eq. 5
    (:mod:`rackstress.model.stability`, unless ``allow_unstable``), the memory it needs, and
    the deck; return what :func:`run` needs (``engine``, ``mode``, ``dump_every``, ``deck``,
    ``fingerprint``)."""
    from rackstress.engines.lammps.deck import compile_deck
    from rackstress.model.stability import check_dt
    from rackstress.runs.fingerprint import fingerprint

    if scene.analysis == "static" and mode == "fast" and engine == "lammps":
        raise RunDirError(f"scene '{scene.name}' is a static analysis: its equilibrium is that "
                          "of Eq. 12 exactly, which --mode fast replaces by harmonic bonds "
                          "(equal only to first order); run it in --mode exact")
    if engine not in ENGINES:
        raise RunDirError(f"unknown engine '{engine}'; choose one of {', '.join(ENGINES)}")
    dump_every = 1 if scene.analysis == "static" else (dump_every or default_dump_every(scene))
    if dump_every < 1:
        raise RunDirError(f"--dump-every must be >= 1, got {dump_every}")
    if engine == "lammps" and dump_every > LAMMPS_MAX_INT:
        raise RunDirError(f"--dump-every {dump_every} is more than LAMMPS can take in a dump "
                          f"interval ({LAMMPS_MAX_INT}); give a smaller one")
    comm = comm or world()
    if engine == "reference":
        mode = "exact"
        if comm.Get_size() > 1:
            raise RunDirError("the reference engine runs on one rank; run it without mpiexec")
    fp = fingerprint(scene, engine=engine, mode=mode, dump_every=dump_every)
    pred = None
    if scene.analysis != "static":      # a static run has no time step to check (Eq. 5)
        pred = check_dt(scene, allow=allow_unstable, pred=_cached_prediction(fp))
        _cache_prediction(fp, pred)
    check_memory(scene, engine, comm.Get_size())
    if scene.analysis == "static":
        # the part check (rigid-body modes, mechanisms) before the directory is touched; its
        # first factorization is kept on the scene for the solve (engines/static.py)
        from rackstress.engines.static import check_part

        check_part(scene)
    # LAMMPS runs the exact operators in the compiled plugin when it is there for this LAMMPS
    # (docs/plugin.md), else in the Python callback (one line says why); a resumed run keeps it
    deck = compile_deck(scene, mode, plugin=None if engine == "lammps" else False)
    if engine == "lammps":
        fp["operators"] = operators_path(deck)
    return {"engine": engine, "mode": mode, "dump_every": int(dump_every),
            "deck": deck, "stability": pred, "fingerprint": fp}


def operators_path(deck) -> str:
    """Where a LAMMPS deck evaluates the operators LAMMPS has no style for: 'plugin' (the
    compiled styles) or 'callback' (Python); a run's fingerprint records it for its resumption."""
    return "plugin" if deck.plugin else "callback"


def _prediction_path(fp: dict) -> Path:
    """Where Eq. 5's predicted limit of a scene is kept between runs: the user's cache, by a
    hash of everything the prediction depends on (the scene's parts, operators, schedule, dt)."""
    import hashlib
    import json
    import os

    key = {k: v for k, v in fp.items() if k not in ("engine", "mode", "dump_every")}
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:32]
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "rackstress" / "stability" / f"{digest}.json"


def _cached_prediction(fp: dict) -> dict | None:
    """The prediction of an earlier run of the same scene (the dense eigenproblem of
    :func:`rackstress.model.stability.predict` is a second of every start), or None."""
    import json

    try:
        pred = json.loads(_prediction_path(fp).read_text())
    except (OSError, ValueError):
        return None
    return pred if isinstance(pred, dict) and "t_max" in pred else None


def _cache_prediction(fp: dict, pred: dict) -> None:
    import json
    import os

    path = _prediction_path(fp)
    if path.exists():
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}")
        tmp.write_text(json.dumps(pred))
        os.replace(tmp, path)
    except (OSError, TypeError, ValueError):
        pass                    # a cache that cannot be written is only a cache


def run(scene: Scene, out: Path, engine: str = "lammps", mode: str = "exact",
        dump_every: int | None = None, progress: bool = True, overwrite: bool = False,
        comm=None, restart_every: int | None = None, allow_unstable: bool = False,
        planned: dict | None = None, keep_checkpoints: bool = True, head_start=None,
        guards: bool = True) -> dict:
    """Run ``scene`` on ``engine`` into the run directory ``out``; return the summary.

    Parameters
    ----------
    scene : Scene
        Built in (:func:`rackstress.scenes.build`) or from TOML (:func:`rackstress.scenes.load`).
    out : path
        The run directory: new or empty, or (with ``overwrite``) holding an earlier run, which
        is removed first. Held locked (:func:`rackstress.runs.rundir.locked`) while running.
    engine, mode : str
        ``lammps`` (``exact`` or ``fast``) or ``reference``.
    dump_every : int, optional
        Steps between trajectory frames (default: about 100 frames); the last step is always
        written.
    comm : mpi4py communicator, optional
        The ranks running this one job (default COMM_WORLD).
    restart_every : int, optional
        Write a checkpoint (LAMMPS restart + exact state, :mod:`rackstress.runs.resume`) every so
        many steps; None: none.
    keep_checkpoints : bool
        False: the checkpoints are only for surviving a kill, and the caller removes them once
        the run has finished (:func:`rackstress.runs.checkpoint.discard_finished`).
    head_start : callable, optional
        Called once the steps left look short, or a quarter are done; what it returns, if
        callable, once the steps are done (:func:`execute`).
    guards : bool
        False: the guard rails of a run that ended well are left to the caller (:func:`execute`).
    planned : dict, optional
        The result of :func:`plan` for these arguments (checked already).

    Returns
    -------
    dict
        The summary (also in ``out/summary.json``).

    Raises
    ------
    DivergenceError
        After writing the summary, when the run diverged.
    RunDirError, SceneError, StorageError
        Before anything of an earlier run is touched, where possible.

    Examples
    --------
    >>> import tempfile
    >>> from rackstress import scenes
    >>> sc = scenes.build("plane-rack").with_steps(20)
    >>> tmp = tempfile.TemporaryDirectory()
    >>> run(sc, tmp.name + "/pr", engine="reference", progress=False)["status"]
    'ok'
    >>> tmp.cleanup()
    """
    from rackstress.runs.rundir import check_out, claim, locked

    check_out(out)
    comm = comm or world()
    p = planned or plan(scene, engine, mode, dump_every, comm, allow_unstable)
    engine, mode, dump_every, deck, fp = (p["engine"], p["mode"], p["dump_every"], p["deck"],
                                          p["fingerprint"])
    if engine == "lammps":      # a path LAMMPS cannot be given: refused before writing
        from rackstress.engines.lammps.runner import check_paths

        check_paths(out)
    out = Path(out)

    def start():
        from rackstress.errors import storage_error
        from rackstress.lib.runfiles import BINDINGS

        claim(out, overwrite)
        dump = "moving" if (deck is not None and deck.dump_moving) else "all"
        write_json(out / "scene.json", {**scene_record(scene), "engine": engine, "mode": mode,
                                        "dump_every": dump_every, "dump": dump,
                                        "fingerprint": fp})
        if p.get("stability") is not None:      # the report's stability margin, predicted once
            from rackstress.lib.runfiles import STABILITY
            from rackstress.model.stability import describe_limit

            pred = p["stability"]
            write_json(out / STABILITY, {"t_max": pred["t_max"], "dt": scene.dt,
                                         "ratio": pred["ratio"], "set_by": describe_limit(pred),
                                         "scene": scene.name, "params": scene.params})
        try:
            deck.write_data(out / "particles.data")
            write_bindings(scene, out / BINDINGS)
            if engine == "lammps":
                (out / "in.lammps").write_text(deck.input_text(dump_every))
        except OSError as exc:
            raise storage_error(exc, "write") from None

    with locked(out, comm=comm):
        on_root(start, comm)
        return execute(scene, out, engine, mode, dump_every, progress=progress, comm=comm,
                       restart_every=restart_every,
                       deck=deck if engine == "lammps" else None, fingerprint=fp,
                       keep_checkpoints=keep_checkpoints, head_start=head_start,
                       guards=guards)

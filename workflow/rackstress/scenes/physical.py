"""The engineer's keys of a scene file: units, materials, loads in newtons, supports.

Everything here becomes the paper's model (docs/scenes.md "Physical scenes", docs/units.md):

* ``units = "mm-N-s"`` or ``"SI"`` (:mod:`rackstress.model.units`); the paper's dimensionless
  units stay the default.
* a part's ``material`` (a preset or a table in SI) makes it the elastic solid of
  :mod:`rackstress.model.solid`: particle mass ρ·a³ and a bind within 1.5·a inside the part
  with c = E/(5·ρ·a²) (``solid = false`` leaves the binding to the scene's own operators);
* ``[[load]]`` tables become ``force`` operators (Eq. 8) whose acceleration is the particle's
  share of the load divided by its mass: a total force F spread over the k selected particles
  is F/(k·m) each, so it does not change with the spacing; a pressure p on the exposed face
  of a region is p·a² per exposed particle; gravity is an acceleration; a prescribed
  displacement fixes the particles' directions at o + u (static analysis); ``ramp`` raises a
  load in ten equal stairs over the given time (dynamic runs, as phases);
* ``[[support]]`` tables hold the selected particles by ``type``: ``fixed`` (all or the
  listed directions: held, rollers and symmetry planes along axes), ``roller`` and
  ``symmetry`` along any normal, ``cylindrical`` and ``pinned`` about a hole's axis (the last
  three, off the axes, as :mod:`rackstress.model.constraints`: static analysis only).
"""
from __future__ import annotations

import math

import numpy as np

from rackstress.errors import SceneError
from rackstress.model.constraints import Normals, Ring, axis_of
from rackstress.model.operators import Bind, Collide, Attract, Force, PhaseIn
from rackstress.model.scene import Phase, steps_for
from rackstress.model.units import PAPER, units as unit_named

_LOAD_KINDS = ("force", "pressure", "gravity", "displacement")
#: The largest load component accepted (force, pressure, gravity): beyond, squares overflow.
HUGE_LOAD = 1e150
_LOAD_KEYS = ("on", "where", "normal", "ramp") + _LOAD_KINDS
_SUPPORT_KEYS = ("on", "where", "fix", "type", "normal", "axis", "plane")
#: stairs of a load ramp (each 1/RAMP_STAIRS of the full load, one phase each)
RAMP_STAIRS = 10


def scene_units(ctx, data: dict):
    """The scene's unit system from ``units`` (default: the paper's)."""
    if "units" not in data:
        return PAPER
    name = data["units"]
    if not isinstance(name, str):
        raise ctx.error(f"must be a unit system's name (\"mm-N-s\", \"SI\"), got {name!r}",
                        "units")
    try:
        return unit_named(name)
    except SceneError as exc:
        raise ctx.error(str(exc), "units") from None


def check_materials(ctx, groups: dict, u) -> None:
    """Materials need a physical unit system (E in GPa means nothing in the paper's units)."""
    for name, g in groups.items():
        if g.material is not None and not u.physical:
            raise ctx.error(f"group '{name}' has material '{g.material.name}', given in SI; "
                            "the scene's numbers must then have units too: declare units = "
                            "\"mm-N-s\" (mm, N, MPa, t/mm³) or \"SI\" at the top level",
                            "units")


def _group_of(c, t: dict, groups: dict):
    from rackstress.scenes.fields import _require, _string

    on = _string(c, _require(c, t, "on"), "on")
    if on not in groups:
        raise c.error(f"unknown group '{on}' (groups: {', '.join(groups)})", "on")
    return on, groups[on]


def _selection(c, t: dict, g, select) -> np.ndarray:
    """The particles ``where`` selects (default all); ``select(c, table, field, o, group)``
    is the scene reader's region → mask."""
    if "where" not in t:
        return np.ones(g.n, dtype=bool)
    mask = select(c, t["where"], "where", g.o, g)
    if not mask.any():
        raise c.error("selects no particle of the group (check the region against the "
                      "part's positions and the scene's length unit)", "where")
    return mask


def supports(ctx, tables, groups: dict, select, region_of=None) -> None:
    """``[[support]]``: hold the selected particles as its ``type`` says (module doc):
    ``fixed`` in the listed directions (default all: held), ``roller`` and ``symmetry`` along
    a normal, ``cylindrical`` radially and axially about an axis, ``pinned`` as a rigid ring
    turning about it. ``region_of(c, table, field, group)`` is the scene reader's region of a
    table (a named hole or face brings its axis or normal)."""
    from rackstress.scenes.fields import _array_of_tables, _check_keys, _string

    for k, t in enumerate(_array_of_tables(ctx, tables, "support"), 1):
        c = ctx.at(f"[[support]] #{k}")
        _check_keys(c, t, _SUPPORT_KEYS)
        name, g = _group_of(c, t, groups)
        kind = _string(c, t.get("type", "fixed"), "type")
        if kind not in SUPPORT_TYPES:
            from rackstress.scenes.fields import _hint

            raise c.error(f"unknown support type '{kind}'{_hint(kind, SUPPORT_TYPES)}; types: "
                          + "; ".join(f"{a} ({b})" for a, b in SUPPORT_TYPES.items()), "type")
        c = ctx.at(f"[[support]] #{k} (on '{name}', {kind})")
        for key, owner in (("fix", "fixed"), ("normal", "roller"), ("axis", "pinned"),
                           ("plane", "symmetry")):
            if key in t and kind not in (owner,) + (("cylindrical",) if key == "axis" else ()):
                raise c.error(f"'{key}' belongs to a {owner} support"
                              + (" or a cylindrical one" if key == "axis" else "")
                              + f", not a {kind} one", key)
        region = None
        if "where" in t:
            if region_of is not None:
                region = region_of(c, t["where"], "where", g)
                try:
                    mask = region.mask(g.o)
                except SceneError as exc:
                    raise c.error(str(exc), "where") from None
            else:
                mask = select(c, t["where"], "where", g.o)
            if not mask.any():
                raise c.error("selects no particle of the group (check the region against the "
                              "part's positions and the scene's length unit)", "where")
        elif kind == "symmetry":
            mask = None
        else:
            mask = np.ones(g.n, dtype=bool)
        if mask is not None:     # which [[support]] holds each particle (the last named)
            g.meta.setdefault("supported_by", np.zeros(g.n, dtype=np.int32))[mask] = k
        feature = getattr(region, "feature", None)
        label = f"[[support]] #{k} ({kind})"
        if kind == "fixed":
            dirs = _fix_axes(c, t, g, mask)
            # which particles and directions this support holds: its reaction (engines/static)
            g.meta.setdefault("supports", []).append((f"[[support]] #{k}", mask, dirs))
            continue
        if kind in ("roller", "symmetry"):
            point, n = _support_plane(c, t, kind, feature)
            if mask is None:         # the particles on the plane: within half a spacing
                a = (g.meta.get("spacing") or (g.meta.get("solid") or {}).get("spacing")
                     or getattr(g.meta.get("part"), "spacing", None))
                if a is None:
                    raise c.error("a symmetry plane without 'where' takes the particles within "
                                  "half a spacing of it; this group has no lattice spacing: "
                                  "give where = { ... }", "plane")
                mask = np.abs((g.o - point) @ n) <= 0.5 * a * (1.0 + 1e-9)
                if not mask.any():
                    raise c.error(f"no particle of '{name}' lies within half a spacing "
                                  f"({0.5 * a:g}) of the plane through {point.tolist()} normal "
                                  f"to {n.tolist()}", "plane")
            axis = axis_of(n)
            if axis is not None:     # an axis: the engines' fixed directions (also dynamic)
                g.fixed[mask, axis] = True
                _refix(g)
                g.meta.setdefault("supports", []).append((label, mask, np.eye(3, dtype=bool)[axis]))
            else:
                ids = np.flatnonzero(mask)
                g.constraints.append(Normals(ids, np.tile(n, (len(ids), 1)), label))
                g.meta.setdefault("supports", []).append((label, mask, None))
            continue
        point, axis = _support_axis(c, t, kind, feature)
        ids = np.flatnonzero(mask)
        g.meta.setdefault("supports", []).append((label, mask, None))   # its whole reaction
        if kind == "pinned":
            try:
                g.constraints.append(Ring(ids, point, axis, label))
            except SceneError as exc:
                raise c.error(str(exc)) from None
            continue
        # cylindrical: radial and axial fixed, the turn about the axis free
        rel = g.o[ids] - point
        radial = rel - np.outer(rel @ axis, axis)
        rho = np.linalg.norm(radial, axis=1)
        on_axis = rho <= 1e-9 * max(float(rho.max()), 1e-300)
        radial[~on_axis] /= rho[~on_axis, None]
        normals = [radial[~on_axis], np.tile(axis, (len(ids), 1))]
        pid = [ids[~on_axis], ids]
        if on_axis.any():                # a particle on the axis has no turn: held
            from rackstress.scenes.features import _basis

            u, v = _basis(axis)
            normals += [np.tile(u, (int(on_axis.sum()), 1)), np.tile(v, (int(on_axis.sum()), 1))]
            pid += [ids[on_axis]] * 2
        g.constraints.append(Normals(np.concatenate(pid), np.concatenate(normals), label,
                                     (np.asarray(point, float), np.asarray(axis, float))))


#: a [[support]]'s ``type`` and what it holds
SUPPORT_TYPES = {
    "fixed": "the directions of 'fix', default all three: held",
    "pinned": "a bolt: the bore turns as one rigid ring about the hole's axis",
    "cylindrical": "radial and axial held, the turn about the axis free",
    "roller": "the face's normal direction held, the face free to slide",
    "symmetry": "a symmetry plane: its normal direction held",
}


def _fix_axes(c, t: dict, g, mask) -> None:
    fix = t.get("fix", ["x", "y", "z"])
    if (not isinstance(fix, list) or not fix
            or not all(isinstance(a, str) and a in ("x", "y", "z") for a in fix)):
        raise c.error(f"must be a non-empty array of directions among \"x\", \"y\", \"z\" "
                      f"(a roller on a floor: [\"z\"]), got {fix!r}", "fix")
    twice = sorted({a for a in fix if fix.count(a) > 1})
    if twice:      # ["x", "x"] for ["x", "y"]: the part would be a mechanism (exit 6)
        raise c.error(f"lists {', '.join(repr(a) for a in twice)} more than once "
                      f"({fix!r}); name each direction to fix once: [\"x\", \"y\", "
                      "\"z\"] (the default) holds, one or two directions make a roller or "
                      "a symmetry plane", "fix")
    dirs = np.zeros(3, dtype=bool)
    for a in fix:
        g.fixed[mask, "xyz".index(a)] = True
        dirs["xyz".index(a)] = True
    _refix(g)
    return dirs


def _unit(c, value, field: str) -> np.ndarray:
    from rackstress.scenes.fields import _vec3

    n = np.asarray(_vec3(c, value, field))
    if not np.linalg.norm(n) > 0:
        raise c.error("must not be zero", field)
    return n / np.linalg.norm(n)


def _support_plane(c, t: dict, kind: str, feature):
    """(point, unit normal) of a roller or symmetry support: its ``normal`` / ``plane``, else
    the named face's."""
    from rackstress.scenes.fields import _check_keys, _require, _table, _vec3

    if kind == "symmetry" and "plane" in t:
        b = _table(c, t["plane"], "plane")
        _check_keys(c.at(f"{c.where}: plane"), b, ("point", "normal"))
        return (np.asarray(_vec3(c, _require(c.at(f"{c.where}: plane"), b, "point"),
                                 "plane.point")),
                _unit(c, _require(c.at(f"{c.where}: plane"), b, "normal"), "plane.normal"))
    if "normal" in t:
        n = _unit(c, t["normal"], "normal")
        return (np.asarray(feature.centre) if feature is not None else np.zeros(3)), n
    if feature is not None and getattr(feature, "kind", "") == "face":
        return np.asarray(feature.centre, float), np.asarray(feature.normal, float)
    need = "plane = { point = [x, y, z], normal = [nx, ny, nz] }" if kind == "symmetry" else \
        "normal = [nx, ny, nz]"
    raise c.error(f"a {kind} support holds the direction normal to a face: give {need}, or "
                  "select a named face (where = { face = \"F3\" }: its normal)")


def _support_axis(c, t: dict, kind: str, feature):
    """(point, unit direction) of a pinned or cylindrical support: its ``axis``, else the
    named hole's."""
    from rackstress.scenes.fields import _check_keys, _require, _table, _vec3

    if "axis" in t:
        b = _table(c, t["axis"], "axis")
        _check_keys(c.at(f"{c.where}: axis"), b, ("point", "direction"))
        req = c.at(f"{c.where}: axis")
        return (np.asarray(_vec3(c, _require(req, b, "point"), "axis.point")),
                _unit(c, _require(req, b, "direction"), "axis.direction"))
    if feature is not None and getattr(feature, "kind", "") == "hole":
        return np.asarray(feature.centre, float), np.asarray(feature.axis, float)
    raise c.error(f"a {kind} support turns about an axis: select a named hole (where = {{ hole "
                  "= \"H1\" }: its axis), or give axis = { point = [x, y, z], direction = "
                  "[dx, dy, dz] }")


def check_constraints(ctx, groups: dict, analysis: str) -> None:
    """Supports that fix no axis (rollers off the axes, symmetry planes at an angle, pinned
    and cylindrical supports) are solved by the static analysis only: LAMMPS' time stepping
    holds whole axes (``fix setforce``)."""
    if analysis == "static":
        return
    for name, g in groups.items():
        for con in g.constraints:
            raise ctx.error(f"{con.label} on '{name}' holds directions that are not x, y or z "
                            "(a roller or symmetry plane at an angle, a pinned or cylindrical "
                            "hole); time stepping holds whole axes only (LAMMPS' fix setforce): "
                            "solve the part with analysis = \"static\", or hold axes "
                            "(type = \"fixed\" with fix = [\"x\", ...])", "analysis")


def _refix(g) -> None:
    g.held = np.ascontiguousarray(g.fixed.all(axis=1))
    g.v0 = np.ascontiguousarray(np.where(g.fixed, 0.0, g.v0))


def solids(ctx, groups: dict, operators: dict, u) -> dict:
    """A material part's bind (the elastic lattice, :mod:`rackstress.model.solid`) and, with
    ``poisson = "material"``, its volumetric term (:mod:`rackstress.model.volume`: the
    material's ν instead of the bindings' own 1/4), put first among the part's operators."""
    from rackstress.model.regions import Box, Cylinder, Sphere
    from rackstress.model.solid import REACH, Solid, bind_coefficient
    from rackstress.model.volume import Volume, coefficients

    out = {name: list(seq) for name, seq in operators.items()}
    for name, g in groups.items():
        info = g.meta.get("solid")
        if not info or not info["bind"]:
            continue
        a = info["spacing"]
        shape = info["shape"]
        if isinstance(shape, (Box, Sphere, Cylinder)):
            shape = None          # convex: no binding between two inside points leaves it
        volumetric = info.get("poisson", "lattice") == "material"
        try:
            c, cv = coefficients(g.material, u, a) if volumetric else (
                bind_coefficient(g.material, u, a), (0.0,))
        except SceneError as exc:
            raise ctx.error(str(exc), f"group '{name}' material") from None
        solid = Solid(REACH * a, c, shape, spacing=a, material=g.material.name,
                      part=info["shape"])
        seq = out.setdefault(name, [])
        if any(cv):             # ν = 0, ... (every ν: the free faces' sub-cells)
            seq.insert(0, Volume(name, solid, cv))
        seq.insert(0, Bind(name, solid))
        if info["shape"] is not None:       # each cell's share of the part (stress volume)
            g.meta["fractions"] = solid.fractions(g.o)
            g.meta["fraction"] = g.meta["fractions"].prod(axis=1)
        g.meta.pop("solid")
        g.meta["spacing"] = a
    return {name: out[name] for name in groups if name in out}


#: ``[[contact]]`` keys
_CONTACT_KEYS = ("between", "stiffness", "friction")


def contact_stiffness(m1, m2, a: float, factor: float = 1.0) -> float:
    """k = factor·E*·a: the stiffness of one particle pair in contact, E* = 1/((1 − ν₁²)/E₁ +
    (1 − ν₂²)/E₂) the pair's contact modulus (Hertz's) and ``a`` the spacing (the mean of the
    two parts'). A contact pair per a² of face makes the interface as compliant as a layer
    of thickness a/factor of modulus E*: about one lattice layer of either part at factor 1,
    so contact neither softens the parts much nor stiffens the scene beyond its bindings (a
    binding of the calibrated lattice is 0.4·E·a), and the time step the stability
    prediction gives stays the lattice's (docs/calibration.md "Contact").

    ``m1``, ``m2`` are the two materials in the scene's units (``Material.in_units``).

    Example
    -------
    >>> al = {"E": 70000.0, "nu": 0.33}
    >>> round(contact_stiffness(al, al, 2.0), 1)                  # E* = E/(2(1 − ν²))
    78554.6
    """
    e_star = 1.0 / ((1 - m1["nu"] ** 2) / m1["E"] + (1 - m2["nu"] ** 2) / m2["E"])
    return float(factor * e_star * a)


def friction_damping(k: float, m1: float, m2: float) -> float:
    """ζ = γ_t·m_eff, the tangential damping (force per relative tangential speed) of a contact
    pair's regularized Coulomb friction below its Coulomb limit, with γ_t = ω_c = √(k/m_eff):
    half the normal contact's critical damping rate 2·ω_c (LAMMPS' usual γ_t = γ_n/2 with γ_n
    critical). A particle's own tangential damping rate is ζ/m ≤ ω_c, about half the lattice's
    highest frequency for two parts of one material (k = E*·a against its bindings' 0.4·E·a),
    so Eq. 5 stays stable at the lattice's step (λt² < 4 − 2γt: docs/calibration.md
    "Friction"); and as large as that allows, so that a part held by friction creeps slowest.

    >>> round(friction_damping(2.0, 1.0, 1.0), 6)       # √(k·m_eff) = √(2·0.5)
    1.0
    """
    m_eff = m1 * m2 / (m1 + m2)
    return float(math.sqrt(k * m_eff))


def contacts(ctx, tables, groups: dict, operators: dict, u) -> dict:
    """``[[contact]]``: two material parts that may touch, each pushed off the other by the
    paper's ``collide`` (Eq. 10, c·(u − p)·min(0, 1 − R²/d²), R the sum of the radii: zero at
    first touch, 2·c·m per unit of overlap there) with c from the materials instead of a paper
    acceleration: each side's c = k/(2·m) with k = :func:`contact_stiffness`, so that the two
    forces of a pair are equal and opposite whatever the particles weigh."""
    from rackstress.model.operators import Collide, Const
    from rackstress.scenes.fields import _array_of_tables, _check_keys, _number, _string

    out = {name: list(seq) for name, seq in operators.items()}
    for k, t in enumerate(_array_of_tables(ctx, tables, "contact"), 1):
        c = ctx.at(f"[[contact]] #{k}")
        _check_keys(c, t, _CONTACT_KEYS)
        mu = _number(c, t.get("friction", 0.0), "friction")
        if mu < 0:
            raise c.error(f"the friction coefficient must be >= 0 (0: frictionless), got {mu!r}",
                          "friction")
        pair = t.get("between")
        if not (isinstance(pair, list) and len(pair) == 2):
            raise c.error("'between' must name two groups, e.g. between = [\"bracket\", "
                          "\"floor\"]", "between")
        names = [_string(c, x, "between") for x in pair]
        if names[0] == names[1]:
            raise c.error(f"a part in contact with itself ('{names[0]}') is not modelled: "
                          "name two different groups", "between")
        parts = []
        for name in names:
            if name not in groups:
                raise c.error(f"unknown group '{name}' (groups: {', '.join(groups)})",
                              "between")
            g = groups[name]
            if g.material is None or "spacing" not in g.meta:
                raise c.error(f"group '{name}' is not a material part (a [[group]] with a "
                              "material, filled at a spacing): contact is derived from the "
                              "two materials; between paper groups use [[operator]] op = "
                              "\"collide\" with its own c", "between")
            parts.append(g)
        factor = _number(c, t.get("stiffness", 1.0), "stiffness", positive=True)
        mats = [g.material.in_units(u) for g in parts]
        a = 0.5 * (float(parts[0].meta["spacing"]) + float(parts[1].meta["spacing"]))
        kc = contact_stiffness(mats[0], mats[1], a, factor)
        zeta = friction_damping(kc, parts[0].mass(u), parts[1].mass(u)) if mu > 0 else 0.0
        for me, other in ((0, 1), (1, 0)):
            m = parts[me].mass(u)
            out.setdefault(names[me], []).append(
                Collide(names[other], Const(kc / (2.0 * m)), mu=mu, eta=zeta / m))
    return {name: out[name] for name in groups if name in out}


#: ``[[indenter]]`` keys, and its ``sphere`` table's
_INDENTER_KEYS = ("on", "sphere", "travel", "stiffness", "ramp")
_SPHERE_KEYS = ("centre", "radius")
#: the indenter's default stiffness factor (on E*·a per particle of the part's face):
#: docs/calibration.md "Contact" (the Hertz bench: p0 5.6 % low at factor 1)
INDENTER_STIFFNESS = 10.0


def indenters(ctx, tables, groups: dict, operators: dict, u, ramp, dt: float,
              analysis: str = "static") -> dict:
    """``[[indenter]]``: a rigid sphere (``sphere = { centre, radius }``) pressed on a material
    part (``on``) by moving its centre by ``travel``: at once in a static analysis (the
    equilibrium with the sphere there), over the scene's load ramp in a dynamic one (linearly,
    then held). Each particle the sphere's surface reaches is pushed radially out by a linear
    penalty k·g (:class:`rackstress.model.operators.Indent`), g its overlap with the particle
    (of radius half a spacing: the part's face is half a spacing above its top row), k =
    ``stiffness``·E*·a·A/a² with E* = E/(1 − ν²) the part's contact modulus against a rigid
    body (ν the lattice's 1/4 unless ``poisson = "material"``) and A/a² the particle's share of
    a face across the travel (its cell's fractions: ½ on a symmetry plane, ¼ on an axis)."""
    from rackstress.model.operators import Indent
    from rackstress.model.scene import steps_for
    from rackstress.model.volume import Volume
    from rackstress.scenes.fields import (_array_of_tables, _check_keys, _number, _require,
                                          _table, _vec3)

    out = {name: list(seq) for name, seq in operators.items()}
    for k, t in enumerate(_array_of_tables(ctx, tables, "indenter"), 1):
        c = ctx.at(f"[[indenter]] #{k}")
        _check_keys(c, t, _INDENTER_KEYS)
        name, g = _group_of(c, t, groups)
        if g.material is None:
            raise c.error(f"group '{name}' has no material: the indenter's stiffness comes "
                          "from the part's E and ν; give the part a material", "on")
        if analysis == "dynamic" and ramp is None:
            raise c.error("a dynamic analysis moves the indenter over the scene's load ramp: "
                          "give 'ramp' (a time), or analysis = \"static\" for the "
                          "equilibrium with the sphere at its travel's end", "ramp")
        sphere = _table(c, _require(c, t, "sphere"), "sphere")
        cs = c.at(f"[[indenter]] #{k} sphere")
        _check_keys(cs, sphere, _SPHERE_KEYS)
        centre = np.array(_vec3(cs, _require(cs, sphere, "centre"), "centre"))
        radius = _number(cs, _require(cs, sphere, "radius"), "radius", positive=True)
        travel = np.array(_vec3(c, _require(c, t, "travel"), "travel"))
        if not np.any(travel != 0):
            raise c.error("the sphere's centre must move (the indentation): give a nonzero "
                          "travel, e.g. travel = [0, 0, -0.1]", "travel")
        factor = _number(c, t.get("stiffness", INDENTER_STIFFNESS), "stiffness", positive=True)
        a = _spacing(c, g)
        mat = g.material.in_units(u)
        has_volume = any(isinstance(op, Volume) for op in out.get(name, []))
        nu = float(mat["nu"]) if has_volume else 0.25
        e_star = float(mat["E"]) / (1.0 - nu ** 2)
        # the particle's share of a face across the travel's main axis: its cell's fractions
        # along the two others (model/solid.py axis_fractions), whole cells without a solid
        solid = next((op.coeff for op in out.get(name, [])
                      if hasattr(getattr(op, "coeff", None), "fractions")), None)
        phi = solid.fractions(g.o) if solid is not None else np.ones((g.n, 3))
        ax = int(np.argmax(np.abs(travel)))
        share = np.prod(np.delete(phi, ax, axis=1), axis=1)
        kk = factor * e_star * a * share / g.mass(u)
        end = centre + travel
        d = np.linalg.norm(g.o - end[None, :], axis=1)
        if not np.any(d < radius + np.asarray(g.r, float)):
            raise c.error(f"the sphere at its end, centre {end.tolist()} and radius {radius:g}, "
                          f"reaches no particle of '{name}': check the centre, radius and "
                          "travel against the part's positions and the scene's length unit",
                          "travel")
        if np.any(d < 0.5 * radius):
            raise c.error(f"the sphere's centre ends inside '{name}' (its particles within "
                          "half a radius of it): place the sphere outside the part, touching "
                          "its face", "sphere")
        # the centre moves over the ramp's phases (ramp_phases: RAMP_STAIRS stairs), then stays
        steps = max(1, RAMP_STAIRS * steps_for(ramp / RAMP_STAIRS, dt, "the indenter's ramp")) \
            if ramp is not None else 0
        out.setdefault(name, []).append(
            Indent(tuple(float(x) for x in centre), float(radius),
                   tuple(float(x) for x in kk), tuple(float(x) for x in travel), steps,
                   ramp=None if ramp is None else float(ramp), stairs=RAMP_STAIRS))
    return {name: out[name] for name in groups if name in out}


def ramp_of(ctx, tables):
    """The ramp time shared by the scene's loads (one ramp per scene), or None."""
    ramps = {float(t["ramp"]) for t in tables if isinstance(t, dict) and "ramp" in t
             and isinstance(t["ramp"], (int, float)) and not isinstance(t["ramp"], bool)}
    bad = [t["ramp"] for t in tables if isinstance(t, dict) and "ramp" in t
           and (isinstance(t["ramp"], bool) or not isinstance(t["ramp"], (int, float))
                or not t["ramp"] > 0)]
    if bad:
        raise ctx.error(f"must be a positive time, got {bad[0]!r}", "[[load]] ramp")
    if len(ramps) > 1:
        raise ctx.error(f"the loads' ramps differ ({sorted(ramps)}); one ramp time per scene",
                        "[[load]] ramp")
    return ramps.pop() if ramps else None


def ramp_phases(ctx, data: dict, ramp: float, length, dt: float) -> list:
    """Ten stairs of ramp/10 each (phase variable ``ramp`` = 1 … 10), then the full load for
    the rest of the run's duration."""
    if "phase" in data:
        raise ctx.error("a load ramp makes the run's phases itself; it cannot be combined with "
                        "[[phase]] tables", "[[load]] ramp")
    if data.get("analysis") == "static":
        raise ctx.error("a ramp raises a load over time: it is for analysis = \"dynamic\"; a "
                        "static analysis finds the equilibrium under the full load",
                        "[[load]] ramp")
    stair = ramp / RAMP_STAIRS
    phases = [Phase(f"ramp{k}", steps_for(stair, dt), {"ramp": k}, stair)
              for k in range(1, RAMP_STAIRS + 1)]
    if length is not None and length[0] == "duration":
        rest = max(0.0, length[1] - ramp)
        phases.append(Phase("full", steps_for(rest, dt), {"ramp": RAMP_STAIRS}, rest))
    elif length is not None:
        done = sum(p.steps for p in phases)
        phases.append(Phase("full", max(0, int(length[1]) - done), {"ramp": RAMP_STAIRS}))
    return phases


def _spacing(c, g) -> float:
    a = g.meta.get("spacing")
    if a is None:
        raise c.error(f"group '{g.name}' has no material: a load in physical units needs the "
                      "particles' mass (density × spacing³); give the part a material", "on")
    return float(a)


def loads(ctx, tables, groups: dict, operators: dict, u, select, ramp) -> dict:
    """``[[load]]`` tables as force operators (module doc) and prescribed displacements."""
    from rackstress.scenes.fields import _array_of_tables, _check_keys, _number, _vec3

    out = {name: list(seq) for name, seq in operators.items()}
    for k, t in enumerate(_array_of_tables(ctx, tables, "load"), 1):
        c = ctx.at(f"[[load]] #{k}")
        _check_keys(c, t, _LOAD_KEYS)
        name, g = _group_of(c, t, groups)
        c = ctx.at(f"[[load]] #{k} (on '{name}')")
        kinds = [x for x in _LOAD_KINDS if x in t]
        if len(kinds) != 1:
            raise c.error(f"needs exactly one of {', '.join(_LOAD_KINDS)}"
                          + (f" (got {' and '.join(kinds)})" if kinds else ""))
        kind = kinds[0]
        if not u.physical and kind != "gravity":
            raise c.error(f"a {kind} in physical units needs the scene's units: declare units = "
                          "\"mm-N-s\" or \"SI\" (the paper's own loads are force operators)",
                          kind)
        if "normal" in t and kind != "pressure":
            raise c.error("'normal' belongs to a pressure", "normal")
        mask = _selection(c, t, g, select)
        m = g.mass(u)
        value = np.asarray(t[kind], dtype=object).ravel() if kind != "pressure" else [t[kind]]
        if kind != "displacement" and any(isinstance(x, (int, float)) and abs(x) > HUGE_LOAD
                                          for x in value):
            # the static solver and the stress measures square forces: 1e300² overflows
            raise c.error(f"{t[kind]!r} has a value beyond {HUGE_LOAD:g} in the scene's units: its square "
                          "overflows a double; check the units (docs/units.md)", kind)
        if kind == "force":
            F = np.asarray(_vec3(c, t["force"], "force"))
            accel = F / (mask.sum() * m)
            where = mask
        elif kind == "gravity":
            accel = np.asarray(_vec3(c, t["gravity"], "gravity"))
            where = mask
            if "fraction" in g.meta:    # the part's own weight ρ·g·ΣV: its cells' shares
                accel = accel * float(g.meta["fraction"][mask].mean())
        elif kind == "pressure":
            pr = _number(c, t["pressure"], "pressure")
            if "normal" not in t:
                raise c.error("a pressure needs 'normal': the outward normal of the loaded face "
                              "(the pressure pushes against it)", "normal")
            n = np.asarray(_vec3(c, t["normal"], "normal"))
            if not np.linalg.norm(n) > 0:
                raise c.error("must not be zero", "normal")
            n = n / np.linalg.norm(n)
            a = _spacing(c, g)
            where = mask & exposed(g.o, n, a)
            if not where.any():
                raise c.error(f"no particle of the region is on a face looking along {n.tolist()}"
                              " (the outward normal of the loaded face)", "normal")
            area = a * a / float(np.abs(n).max())     # a particle's share of the face
            if "fractions" in g.meta:   # the face's own area: its cells' in-face extents
                phi = np.delete(g.meta["fractions"][where], int(np.argmax(np.abs(n))), axis=1)
                area *= float(phi.prod(axis=1).mean())
            accel = -pr * area * n / m
            extra = _overhang_push(out.get(name, []), g, where, n, pr, u)
            if extra is not None:       # the pressed cells' overhang (model/volume.py)
                for vec, sel in extra:
                    out.setdefault(name, []).extend(_forces(vec / m, sel, ramp))
                # the normal stress on each pressed face (boundary.npz → face_stress: the
                # stress measure counts the face's push and the overhang's prestress)
                fs = g.meta.setdefault("face_stress", np.zeros((g.n, 3)))
                fs[where, int(np.argmax(np.abs(n)))] -= pr
        else:       # displacement
            uvec = np.asarray(_vec3(c, t["displacement"], "displacement"))
            if ramp is not None:
                raise c.error("a prescribed displacement is for static analysis", "displacement")
            if g.u0 is None:
                g.u0 = np.zeros((g.n, 3))
            clash = g.fixed[mask] & (g.u0[mask] != uvec[None, :])
            if clash.any():
                dirs = ", ".join(a for a, c_ in zip("xyz", clash.any(axis=0)) if c_)
                raise c.error(f"{int(clash.any(axis=1).sum())} particle(s) of its region are "
                              f"already held in {dirs} by a [[support]] (or another "
                              "displacement) at another position: a particle cannot be held "
                              "at o and at o + u; narrow 'where' or leave the support out there",
                              "displacement")
            g.fixed[mask] = True
            g.u0[mask] = uvec
            g.meta.setdefault("supports", []).append((f"[[load]] #{k} (displacement)", mask,
                                                      np.ones(3, dtype=bool)))
            _refix(g)
            continue
        if kind != "gravity":
            _spacing(c, g)
            _held_share(c, k, name, g, where, accel * m, t[kind], kind)
        where_t = None if where.all() else tuple(bool(x) for x in where)
        if ramp is None:
            out.setdefault(name, []).append(Force(tuple(float(x) for x in accel), where=where_t))
        else:
            for s in range(1, RAMP_STAIRS + 1):     # stair s adds 1/10 from phase ramp{s} on
                out.setdefault(name, []).append(Force(
                    tuple(float(x) / RAMP_STAIRS for x in accel), where=where_t,
                    when=(PhaseIn("ramp", tuple(range(s, RAMP_STAIRS + 1))),)))
    return {name: out[name] for name in groups if name in out}


def _held_part(g, idx: np.ndarray, f: np.ndarray) -> np.ndarray:
    """The part of the force ``f`` on each particle ``idx`` of ``g`` that its supports take
    before it deforms anything (rows, len(idx) × 3): on fixed axes and on a roller's, symmetry
    plane's or cylindrical bore's normals (:class:`~rackstress.model.constraints.Normals`) its
    projection on the directions held; on a pinned hole's ring (:class:`~rackstress.model.
    constraints.Ring`, one rigid body turning about its axis) all of it but the share its
    moment about the axis carries — φ = |Σ f·(â × r_i)| / Σ |f|·|â × r_i| over the loaded
    particles of the ring: a push through the pin (φ = 0) goes into it whole, a turn
    (φ = 1) reaches the part whole."""
    from rackstress.model.constraints import Normals, Ring

    pos = {int(i): k for k, i in enumerate(idx)}
    vecs = [[np.eye(3)[a] for a in range(3) if g.fixed[i, a]] for i in idx]
    out = np.zeros((len(idx), 3))
    ringed = np.zeros(len(idx), dtype=bool)
    for con in getattr(g, "constraints", None) or []:
        if isinstance(con, Normals):
            for i, n in zip(con.ids, con.normals):
                if int(i) in pos:
                    vecs[pos[int(i)]].append(n)
        elif isinstance(con, Ring):
            ks = [pos[int(i)] for i in con.ids if int(i) in pos]
            if not ks:
                continue
            t = np.cross(con.axis, g.o[idx[ks]] - con.point)       # each one's lever
            reach = float((np.linalg.norm(t, axis=1) * np.linalg.norm(f)).sum())
            phi = abs(float((t @ f).sum())) / reach if reach > 0 else 0.0
            out[ks] = (1.0 - phi) * f
            ringed[ks] = True
    for k, v in enumerate(vecs):
        if v and not ringed[k]:                # an orthonormal basis of their span
            u, sv, _ = np.linalg.svd(np.asarray(v, float).T, full_matrices=False)
            q = u[:, sv > 1e-9 * sv.max()]
            out[k] = q @ (q.T @ f)
    return out


def _held_share(c, k: int, name: str, g, where: np.ndarray, f: np.ndarray, given, kind):
    """A force or pressure on particles a ``[[support]]`` holds goes straight into the
    support: the engines zero a held direction's force, so it deforms nothing. All of it: the
    load is refused (it would settle in 0 iterations at 0 MPa); part of it: a warning on the
    part (``g.meta["held_load"]``, :func:`held_load_warnings`) naming the share, the force and
    the support. ``f``: the force on each loaded particle (the same on each)."""
    if not np.linalg.norm(f) > 0:
        return
    held = np.linalg.norm(_held_part(g, np.flatnonzero(where), f), axis=1)
    share = float(held.sum() / (len(held) * np.linalg.norm(f)))
    if share <= 1e-12:
        return
    by = g.meta.get("supported_by")
    nums = sorted({int(x) for x in by[where][held > 0]}) if by is not None else []
    sup = ", ".join(f"[[support]] #{n}" for n in nums if n) or "a [[support]]"
    n_held = int((held > 0).sum())
    what = f"its {kind} {given!r}"
    if share >= 1.0 - 1e-12:
        raise c.error(f"every one of its {len(held)} particle(s) is held by {sup} in the "
                      f"direction of {what}: the load goes straight into the support and "
                      "deforms nothing (the part would settle at once, at 0 stress); move the "
                      "load's region off the support, or the support off the load", "where")
    total = float(np.linalg.norm(f)) * len(held)
    g.meta.setdefault("held_load", []).append({
        "kind": "load_on_support", "groups": [name], "load": k, "share": share,
        "message": f"[[load]] #{k} (on '{name}'): {n_held} of its {len(held)} particles are "
                   f"held by {sup}: {share:.0%} of {what} ({share * total:.4g} of "
                   f"{total:.4g} in the scene's force unit) goes straight into the support "
                   "and deforms nothing"})


def held_load_warnings(scene) -> list[dict]:
    """The warnings of loads partly on particles a support holds (:func:`_held_share`) and of
    parts in contact drawn overlapping (``contact_overlap``), as ``summary.json`` records them
    (``kind``, ``groups``, ``share`` or ``sites``, ``message``)."""
    return [dict(w) for g in scene.groups.values() if isinstance(g.meta, dict)
            for w in g.meta.get("held_load", []) + g.meta.get("warnings", [])]


def _forces(accel, where, ramp) -> list:
    """The force operators of one load: constant, or ten stairs of a ramp."""
    where_t = None if where is None or np.all(where) else tuple(bool(x) for x in where)
    if ramp is None:
        return [Force(tuple(float(x) for x in accel), where=where_t)]
    return [Force(tuple(float(x) / RAMP_STAIRS for x in accel), where=where_t,
                  when=(PhaseIn("ramp", tuple(range(s, RAMP_STAIRS + 1))),))
            for s in range(1, RAMP_STAIRS + 1)]


def _overhang_push(ops, g, where, n, pr, u):
    """A pressure's push through the pressed cells' overhang (model.volume.loaded_overhang),
    as (force, particles) of each distinct force vector; None without a volumetric term."""
    from rackstress.model.volume import Volume, loaded_overhang

    vol = [op for op in ops if isinstance(op, Volume)]
    if not vol or float(np.abs(n).max()) < 1.0 - 1e-9:
        return None      # (a pressure along no lattice axis: its faces are staircases)
    F = loaded_overhang(vol[0], g, where, int(np.argmax(np.abs(n))), pr,
                        float(g.material.in_units(u)["nu"]))
    moved = np.flatnonzero(np.any(F != 0.0, axis=1))
    if not len(moved):
        return None
    rows, inv = np.unique(np.round(F[moved], 12), axis=0, return_inverse=True)
    out = []
    for r in range(len(rows)):
        sel = np.zeros(g.n, bool)
        sel[moved[inv.reshape(-1) == r]] = True
        out.append((rows[r], sel))
    return out


def exposed(o: np.ndarray, n: np.ndarray, a: float) -> np.ndarray:
    """Particles on a face looking along the unit vector ``n``: no particle within a/4 of
    o + a·n̂ (n̂: n snapped to its largest axis, the lattice's own faces)."""
    from scipy.spatial import cKDTree

    axis = int(np.argmax(np.abs(n)))
    step = np.zeros(3)
    step[axis] = math.copysign(a, n[axis])
    d, _ = cKDTree(o).query(o + step, distance_upper_bound=0.25 * a)
    return ~np.isfinite(d)


def analysis_of(ctx, data: dict, groups: dict, operators: dict, ramp) -> str:
    """``analysis`` as given, else static for a scene with a material and no motion (no
    initial velocity, no collisions or attractions but two material parts' contact, no
    phases, no ramp)."""
    if "analysis" in data:
        a = data["analysis"]
        if a not in ("static", "dynamic"):
            raise ctx.error(f"must be \"static\" (find the equilibrium) or \"dynamic\" (time "
                            f"stepping), got {a!r}", "analysis")
        return a
    if not any(g.material is not None for g in groups.values()):
        return "dynamic"
    moving = any(np.any(g.v0) for g in groups.values())
    # two material parts' contact ([[contact]]) is no motion: parts pressed together settle
    contact = any((isinstance(op, (Collide, Attract)) and not (
                       isinstance(op, Collide) and groups[t].material is not None
                       and getattr(groups.get(op.source), "material", None) is not None))
                  or op.when for t, seq in operators.items() for op in seq)
    return "dynamic" if (moving or contact or ramp is not None or "phase" in data) else "static"

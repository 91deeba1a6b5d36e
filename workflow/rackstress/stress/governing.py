"""The governing stress: the largest von Mises stress away from the part's singular points.

At a sharp re-entrant edge, at the edge of a support and under a point load the continuum's
stress is unbounded (:mod:`rackstress.model.singular`): the particles' peak there grows as the
spacing shrinks and measures the spacing, not the part. The number an engineer acts on is the
**governing stress** — the largest von Mises stress at least :func:`zone` away from every
singular point, read where the lattice converges — with the singular peak beside it, marked as
spacing-dependent, and what to do about it (docs/stress.md "The governing stress").

* :func:`singular_set` — a run's singular points per part (``singular.npz``, written when the
  run started; for an older run, the lattice's concave edges and ``boundary.npz``'s supports
  and loads);
* :func:`governing` — (index, value) of the largest value at least ``zone`` from every
  singular point; :func:`singular_peak` — the largest within it;
* :func:`record` — both, per part and overall, for ``summary.json["stress"]``;
* :func:`richardson`, :func:`observed_order`, :func:`error_bar` — the error bar of
  ``rackstress run --refine`` (two spacings; three give the order) and :func:`default_error`,
  what a single run may be off by, from the lattice's measured convergence.

Example
-------
>>> import numpy as np
>>> from rackstress.model.singular import Singular
>>> s = Singular(np.array([[0.0, 0, 0]]), np.array([0]), np.array([90.0]))
>>> x = np.array([[0.5, 0, 0], [3.0, 0, 0], [6.0, 0, 0]])
>>> governing(np.array([9.0, 5.0, 4.0]), x, s, zone=2.0)     # the 9 is within 2 of the edge
(1, 5.0)
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from rackstress.model.singular import KINDS, Singular
from rackstress.stress.rundata import boundary_rows, face_supports, lattice_nu

#: The zone: particles nearer than this many spacings to a singular point are left out of the
#: governing stress. Measured (``rackstress bench governing``, docs/stress.md): beyond two
#: spacings the particles read what converged FEA reads at the same points.
ZONE_SPACINGS = 2.0
#: ... and never less than this fraction of the part's wall thickness t: two spacings at the
#: spacing that puts five particles across the wall, the distance from a notch at which a
#: finite-element hot-spot reading starts (0.4 t), the same at every spacing finer than t/5,
#: so runs at those spacings read the same points.
ZONE_WALLS = 0.4
#: The refinement of ``rackstress run --refine``: the spacing divided by √2 (2.8× the
#: particles; halving it would take 8×).
REFINE_RATIO = math.sqrt(2.0)
#: The order of the governing stress's convergence on the lattice, for a two-spacing
#: Richardson estimate: a particle reads the stress at its centre, half a spacing inside the
#: surface, an error of order 1 in the spacing (hand calculation); ``rackstress bench
#: governing`` measures each part's own order from three spacings (docs/benchmarks/governing.md).
LATTICE_ORDER = 1.0
#: The last two spacings' governing stresses within this fraction of each other: the bar is
#: a convergence's; beyond it the run says the value is not converged there (a hole or a
#: curved face the lattice resolves as steps, a zone too near a concentration).
CONVERGING = 0.10
#: Roache's safety factors of the grid convergence index: 3 with an assumed order (two
#: spacings), 1.25 with an order measured on the part (three).
SAFETY_ASSUMED, SAFETY_MEASURED = 3.0, 1.25

RULE = ("the largest von Mises stress at least {zone:.3g} {unit} ({n:.3g} spacings) from every "
        "sharp re-entrant edge, support boundary, point load and contact edge of the part, "
        "where the continuum's stress is unbounded and a peak measures the spacing")
ADVICE = {
    "re-entrant edge": ("a sharp re-entrant edge: its stress is unbounded in the continuum and "
                        "this value grows as the spacing shrinks. Round the edge with a fillet "
                        "(of radius r ≥ 1.5 spacings the lattice resolves it; the real part's "
                        "radius sets its real peak), refine the spacing to see the trend, or "
                        "take the corner to a local FE submodel"),
    "support boundary": ("the edge of a rigid support: singular in the model, where the real "
                         "clamp, bolt or washer is compliant. Model the support as it bears "
                         "(a pin in a hole, a washer's area) or read the governing stress"),
    "point load": ("a load on a few particles (a point or line load): its stress grows as the "
                   "spacing shrinks. Spread the load over the real contact area"),
    "unresolved fillet": ("a fillet of radius under 1.43 spacings (its face turns through 20° "
                          "or more within half a spacing), which this spacing does not "
                          "resolve: the lattice reads it as a sharp edge and the governing "
                          "stress leaves it out, but the part's peak there is bounded and its "
                          "own. Refine the spacing below the radius / 1.43 (rackstress run "
                          "--refine says what the finer run reads there), or check it by FE "
                          "(rackstress fea)"),
    "contact edge": ("where a contact reaches the edge of a face (a pin bearing on a hole's "
                     "rim, a punch's edge): singular like a rigid support's edge, the pressure "
                     "and stress there grow as the spacing shrinks. A chamfer or radius on the "
                     "rim, or a longer bearing, spreads it in the real part; read the governing "
                     "stress beside it"),
}


#: What a singular peak is, by its kind: the continuum's unbounded stress, or (a fillet the
#: spacing does not resolve) a bounded peak of the part this lattice cannot read.
SINGULAR_NOTE = {None: "spacing-dependent: unbounded in the continuum",
                 "unresolved fillet": ("spacing-dependent: a fillet this spacing does not "
                                       "resolve; its peak is bounded and the part's own")}
#: ... and said in a line (:func:`describe`; the report sets the first part in bold).
SINGULAR_SAID = {None: ("spacing-dependent", ", not a property of the part"),
                 "unresolved fillet": ("not resolved at this spacing",
                                       ": the fillet's own peak is bounded and a property of "
                                       "the part, read only finer")}


def zone(spacing: float, wall: float | None = None) -> float:
    """The distance from singular points within which the governing stress is not read:
    max(:data:`ZONE_SPACINGS` × spacing, :data:`ZONE_WALLS` × wall thickness).

    >>> zone(1.0, 10.0), zone(1.0, 3.0), zone(0.5, 5.0)     # 0.4 t, 2 spacings, 0.4 t
    (4.0, 2.0, 2.0)
    """
    z = ZONE_SPACINGS * float(spacing)
    if wall is not None and np.isfinite(wall):
        z = max(z, ZONE_WALLS * float(wall))
    return float(z)


# --------------------------------------------------------------------------- singular points
def read_singular(rundir) -> dict | None:
    """``singular.npz`` of a run: ``{part: (spacing, wall, Singular)}``, or None when absent."""
    from rackstress.lib.runfiles import SINGULAR

    path = Path(rundir) / SINGULAR
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as z:
        names = [str(x) for x in z["parts"]]
        out = {}
        for k, name in enumerate(names):
            sel = z["part"] == k
            notes = [n for n in str(z["notes"][k]).split("; ") if n] if "notes" in z else []
            wall = float(z["wall"][k]) if "wall" in z else None
            out[name] = (float(z["spacing"][k]), wall,
                         Singular(z["points"][sel], z["kind"][sel], z["angle"][sel],
                                  str(z["source"][k]), notes))
    return out


def singular_set(run) -> dict:
    """Every part's singular points: ``{part: (spacing, wall, Singular)}`` for the parts with
    a material (:func:`rackstress.stress.measures.material_parts`).

    From ``singular.npz`` (written when the run started, from the part's shape); for a run
    without it, from its record: re-entrant edges from the lattice
    (:func:`rackstress.model.singular.lattice_edges`), supports and loads from
    ``boundary.npz``.

    Parameters
    ----------
    run : RunData
        :func:`rackstress.stress.load_run`.

    Example
    -------
    >>> sing = singular_set(load_run("runs/bracket"))         # doctest: +SKIP
    >>> spacing, wall, points = sing["bracket"]               # doctest: +SKIP
    >>> points.counts()                                       # doctest: +SKIP
    {'re-entrant edge': 65, 'support boundary': 84}
    """
    from rackstress.model import singular
    from rackstress.stress.measures import material_parts

    got = read_singular(run.rundir)
    names = list(material_parts(run)) or [p.name for p in run.displayed()]
    if got is not None:
        return {n: got[n] for n in names if n in got}
    held, loads = boundary_rows(run)
    out = {}
    for name in names:
        part = run.parts[name]
        o = run.o[part.index]
        spacing = singular.nearest_spacing(o)
        s = singular.find(o, spacing, None, held[part.index], loads[part.index])
        s.notes.append("singular.npz missing (a run of an older rackstress): re-entrant "
                       "edges from the lattice")
        out[name] = (spacing, singular.wall_thickness(o, spacing), s)
    return out


def contact_edges(run, fields) -> dict:
    """Per part in contact (``[[contact]]``): its particles pressed in some frame
    (``contact_pressure`` > 0) that have a free face — a lattice neighbour's site one spacing
    along an axis that no particle of any part occupies (within half a spacing) and no support
    holds across (a symmetry plane's mirror is there) — the points where a contact reaches the
    edge of a face (a pin on a hole's rim). ``{part: (k, 3) original positions}``, the points
    given to the part and to every part it touches."""
    pc = fields.values.get("contact_pressure")
    if pc is None:
        return {}
    from scipy.spatial import cKDTree

    from rackstress.stress.measures import contact_parts, read_contacts

    pressed = (np.nan_to_num(np.asarray(pc, float)) > 0).any(axis=0)
    if not pressed.any():
        return {}
    o = run.o
    held, _ = boundary_rows(run)
    tree = cKDTree(o)
    sides, r = read_contacts(run)
    partners: dict = {}
    for _m, a, b in contact_parts(run, sides):
        partners.setdefault(a, set()).add(b)
    out: dict = {}
    for name in partners:
        idx = run.parts[name].index
        idx = idx[pressed[idx]]
        if not len(idx):
            continue
        a = 2.0 * float(np.median(r[idx]))          # the spacing: two radii
        rim = np.zeros(len(idx), bool)
        for axis in range(3):
            for sign in (-1.0, 1.0):
                site = o[idx].copy()
                site[:, axis] += sign * a
                d, _ = tree.query(site)
                rim |= (d > 0.5 * a) & ~held[idx, axis]
        pts = o[idx[rim]]
        for part in (name, *partners[name]):
            out.setdefault(part, []).append(pts)
    return {k: np.concatenate(v) for k, v in out.items() if sum(len(x) for x in v)}


def with_contact_edges(run, fields, sing: dict) -> dict:
    """``sing`` (:func:`singular_set`) with each part's contact edges (:func:`contact_edges`)
    among its singular points, kind ``"contact edge"``."""
    from rackstress.model import singular

    edges = contact_edges(run, fields)
    if not edges:
        return sing
    kind = singular.KINDS.index("contact edge")
    out = dict(sing)
    for name, pts in edges.items():
        if name not in out:
            continue
        spacing, wall, s = out[name]
        add = Singular(pts, np.full(len(pts), kind, np.int64), np.full(len(pts), np.nan))
        both = singular.concat([s, add], s.source)
        both.notes, both.surface = list(s.notes), s.surface
        out[name] = (spacing, wall, both)
    return out


# --------------------------------------------------------------------------- the rule
def governing(values, positions, singular: Singular, zone: float):
    """(index, value) of the largest finite ``values`` at least ``zone`` from every point of
    ``singular``; (None, None) when every value is within it.

    Parameters
    ----------
    values : (n,) array
    positions : (n, 3) array
        Where each value is (undeformed positions: the zone is the part's, not its motion's).
    singular : Singular
    zone : float
    """
    v = np.asarray(values, float).reshape(-1)
    d, _ = singular.distance(positions)
    ok = np.isfinite(v) & (d >= zone)
    if not ok.any():
        return None, None
    k = int(np.flatnonzero(ok)[np.argmax(v[ok])])
    return k, float(v[k])


def singular_peak(values, positions, singular: Singular, zone: float):
    """(index, value, kind, distance) of the largest finite value within ``zone`` of a
    singular point (kind: that nearest point's, :data:`KINDS`); Nones when there is none."""
    v = np.asarray(values, float).reshape(-1)
    d, near = singular.distance(positions)
    ok = np.isfinite(v) & (d < zone)
    if not ok.any():
        return None, None, None, None
    k = int(np.flatnonzero(ok)[np.argmax(v[ok])])
    return k, float(v[k]), KINDS[int(singular.kind[near[k]])], float(d[k])


def _largest_away(vm: np.ndarray, away: np.ndarray):
    """Per frame of a (frames × n) array, the largest finite value among the particles
    ``away`` and the first particle holding it: (values, indices), −inf where none is (a
    frame at a time: no second frames × n array)."""
    values, where = np.full(len(vm), -np.inf), np.zeros(len(vm), dtype=np.int64)
    for k, row in enumerate(vm):
        a = np.isfinite(row) & away
        if a.any():
            j = int(np.flatnonzero(a)[np.argmax(row[a])])
            values[k], where[k] = row[j], j
    return values, where


def _frames_governing(vm: np.ndarray, o: np.ndarray, singular: Singular, z: float):
    """Over a (frames × n) array: (frame, index, value) of the governing stress, and of the
    singular peak (frame, index, value, kind, distance)."""
    d, near = singular.distance(o)
    away = d >= z
    values, where = _largest_away(vm, away)
    best, sbest = None, None
    if np.isfinite(values).any():
        k = int(np.argmax(values))
        best = (k, int(where[k]), float(values[k]))
    for k in range(vm.shape[0]):
        row = vm[k]
        fin = np.isfinite(row)
        s = fin & ~away
        if s.any():
            j = int(np.flatnonzero(s)[np.argmax(row[s])])
            if sbest is None or row[j] > sbest[2]:
                sbest = (k, j, float(row[j]), KINDS[int(singular.kind[near[j]])], float(d[j]))
    return best, sbest


def over_time(run, vm: np.ndarray) -> dict:
    """The governing stress of each material part frame by frame: the largest of ``vm``
    (frames × particles, von Mises) at least the part's zone away from its singular points,
    read where the measure reads it — :func:`record`'s rule, so its largest over the frames
    is the run's governing stress. ``{part: (frames,) array}`` (NaN where no particle is
    finite); what the stress-over-time plot draws beside the plain maximum."""
    from rackstress.stress.measures import recovery_points_of

    out = {}
    for name, (spacing, wall, s) in singular_set(run).items():
        if name not in run.parts:
            continue
        idx = run.parts[name].index
        d, _ = s.distance(recovery_points_of(run, run.parts[name]))
        best, _ = _largest_away(np.asarray(vm[:, idx], float), d >= zone(spacing, wall))
        out[name] = np.where(np.isfinite(best), best, np.nan)
    return out


def _near(features, x):
    if features is None:
        return None
    try:
        return features.nearest(x)
    except Exception:  # noqa: BLE001 - a name is a help, not a result
        return None


def part_features(rundir, name: str):
    """The named features of a part's surface (``rackstress.scenes.features`` when it exists),
    from the surface kept in ``singular.npz``; None otherwise."""
    try:
        from rackstress.scenes import features as feat
    except ImportError:
        return None
    from rackstress.stress.measures import read_surface

    try:
        surf = read_surface(rundir, name)
        return None if surf is None else feat.part_features(surf)
    except Exception:  # noqa: BLE001 - a name is a help, not a result
        return None


def record(run, fields, zone_override: float | None = None, singular: dict | None = None):
    """The governing stress and the singular peak, per part with a material and overall.

    Parameters
    ----------
    run : RunData
    fields : Fields
        :func:`rackstress.stress.post.compute_fields` (``von_mises``, ``safety``).
    zone_override : float, optional
        The zone to use instead of :func:`zone` of each part's spacing (``--refine`` reads the
        refined run at the coarse run's zone).
    singular : dict, optional
        ``{part: (spacing, Singular)}`` to use instead of the run's own (the coarse run's, for
        a refined run: the same points left out).

    Returns
    -------
    dict
        ``{"governing": {...}, "singular": {...}, "parts": {part: {"governing", "singular"}}}``
        or ``{}`` without a ``von_mises`` measure; records as ``summary.json["stress"]`` keeps
        them (docs/output.md).
    """
    from rackstress.stress.measures import material_parts, recovery_points_of

    vm = fields.values.get("von_mises")
    if vm is None:
        return {}
    sing = singular if singular is not None else with_contact_edges(run, fields,
                                                                     singular_set(run))
    unit = fields.unit("von_mises")
    length = ((run.scene or {}).get("units") or {}).get("length") or "length units"
    mats = material_parts(run)
    parts = {}
    for name, (spacing, wall, s) in sing.items():
        if name not in run.parts:
            continue
        part = run.parts[name]
        o = run.o[part.index]
        z = float(zone_override) if zone_override is not None else zone(spacing, wall)
        if singular is not None:              # another run's points (--refine): its own spacing
            from rackstress.model.singular import nearest_spacing

            spacing = nearest_spacing(o)
        # distances from where each particle's stress is read — its recovery point (patch
        # recovery, the von_mises route: a surface particle at its cell's surface point) —
        # as the FE check measures them (validity.solid), so both apply one rule
        read = recovery_points_of(run, part)      # as the measure reads it
        best, sbest = _frames_governing(vm[:, part.index], read, s, z)
        curved = None
        if best is not None:                  # the concave curved faces' own peak, same frame
            row = vm[best[0], part.index]
            m = curved_near(run.rundir, name, read, spacing) & (s.distance(read)[0] >= z) \
                & np.isfinite(row)
            if m.any():
                j = int(np.flatnonzero(m)[np.argmax(row[m])])
                curved = {"value": float(row[j]), "index": j,
                          "position": [float(x) for x in o[j]],
                          "read_at": [float(x) for x in read[j]]}
        y = ((mats.get(name) or {}).get("material") or {}).get("yield")
        feats = part_features(run.rundir, name)
        gov = None
        if best is not None:
            k, j, v = best
            gov = {"value": v, "units": unit, "group": name, "length_units": length,
                   "particle": int(run.data.ids[part.index[j]]), "index": int(j),
                   "iteration": int(fields.steps[k]), "frame": int(k),
                   "position": [float(x) for x in o[j]],
                   "read_at": [float(x) for x in read[j]],
                   "near": _near(feats, o[j]),
                   "safety": (float(y) / v) if (y and v > 0) else None,
                   "zone": z, "spacing": float(spacing),
                   "contact_edges": "contact edge" in s.counts(),
                   "unresolved_fillets": "unresolved fillet" in s.counts(),
                   "curved_face": curved,
                   "rule": RULE.format(zone=z, unit=length, n=z / spacing)}
            if (run.scene or {}).get("analysis") == "static":
                _with_notch(gov, notch_peak(run, name, spacing, s, z, k), o,
                            run.data.ids[part.index], feats, y)
            gov["zone_edge"] = zone_edge(gov["read_at"], s, z, float(spacing), feats,
                                         read, vm[gov["frame"], part.index])
        sp = None
        if sbest is not None:
            k, j, v, kind, dist = sbest
            sp = {"value": v, "units": unit, "group": name, "kind": kind,
                  "particle": int(run.data.ids[part.index[j]]), "index": int(j),
                  "iteration": int(fields.steps[k]), "frame": int(k),
                  "position": [float(x) for x in o[j]], "distance": dist,
                  "near": _near(feats, o[j]),
                  "spacing_dependent": True,
                  "note": SINGULAR_NOTE.get(kind, SINGULAR_NOTE[None]),
                  "advice": ADVICE[kind]}
        parts[name] = {"governing": gov, "singular": sp, "zone": z, "spacing": float(spacing),
                       "wall": wall,
                       "singular_points": s.counts(), "source": s.source,
                       "notes": list(s.notes)}
    if not parts:
        return {}
    govs = [p["governing"] for p in parts.values() if p["governing"]]
    sings = [p["singular"] for p in parts.values() if p["singular"]]
    top = max(govs, key=lambda g: g["value"]) if govs else None
    out = {"governing": top,
           "singular": max(sings, key=lambda g: g["value"]) if sings else None,
           "parts": parts}
    if top is not None:
        out["error"] = default_error(run, top)
    return out


#: ``read`` of another lattice's governing stress taken at the first run's governing point
FIRST_POINT = "first point"


def with_first_point(run, fields, g: dict | None, first: dict) -> dict | None:
    """Another lattice's governing stress (``--refine``'s finer one, ``--offsets``' moved
    ones) under the first run's rule — ``g``, :func:`record`'s, None where every particle lies
    within the zone — or, where it is the larger, this lattice's stress field at the first
    run's governing point ``first["read_at"]`` (``"read": "first point"``).

    The governing stress is the largest stress in the region at least the zone from the
    singular points; each lattice samples that region at its own points. Where the stress
    rises toward a singular point the largest lies at the zone's edge, and a lattice whose
    points there all fall just inside it reads the region's largest a spacing farther out:
    the SO-100 shoulder bracket's first run read 0.325 MPa 0.04 mm beyond its 5.73 mm zone,
    its refined run's particles there 5.4–5.5 mm from the edge, and its largest beyond the
    zone was 0.222 (the FE check: 0.356 at that point). The first run's governing point lies
    in the region, so this lattice's field there (:func:`rackstress.stress.surface.interpolate`,
    the moving-least-squares fit the report's surface takes) is a reading of the same
    quantity: 0.344 MPa there. ``g``'s own reading is kept as ``rule_value``.

    Examples
    --------
    >>> with_first_point(None, None, {"value": 2.0}, {})["value"]     # no first point: g
    2.0
    """
    from rackstress.model.singular import nearest_spacing
    from rackstress.stress.measures import recovery_points_of
    from rackstress.stress.surface import interpolate

    at = (first or {}).get("read_at")
    name = (first or {}).get("group")
    if at is None or name not in getattr(run, "parts", {}):
        return g
    vm = fields.values.get("von_mises")
    if vm is None:
        return g
    part = run.parts[name]
    frame = int(g["frame"]) if g else len(vm) - 1
    row = vm[frame, part.index]
    read = recovery_points_of(run, part)
    o = run.o[part.index]
    ok = np.isfinite(row)
    if not ok.any():
        return g
    p = np.asarray(at, float).reshape(1, 3)
    h = float(nearest_spacing(o))
    v = max(float(interpolate(read[ok], row[ok], p, h)[0]), 0.0)
    if g is not None and not v > g["value"]:
        return g
    j = int(np.argmin(np.einsum("ij,ij->i", read - p, read - p)))
    out = dict(g or {"units": first.get("units"), "group": name,
                     "length_units": first.get("length_units"), "zone": first.get("zone"),
                     "iteration": int(fields.steps[frame]), "frame": frame})
    y = (first.get("value") * first["safety"]) if first.get("safety") else None
    out.update(value=v, rule_value=None if g is None else g["value"], index=j,
               particle=int(run.data.ids[part.index[j]]), position=[float(x) for x in o[j]],
               read_at=[float(x) for x in p[0]], near=first.get("near"), read=FIRST_POINT,
               safety=(y / v) if (y and v > 0) else None, spacing=h)
    for k in ("notch", "patch_value", "zone_edge"):     # the rule reading's, not this point's
        out.pop(k, None)
    return out


#: The governing stress is said to lie at the zone's edge where it is read within this many
#: spacings beyond the zone ...
ZONE_EDGE = 0.5
#: ... and the particles' stress rises toward the singular point nearest it: within
#: :data:`ZONE_EDGE_NEAR` spacings of the read point, those a spacing farther out than the
#: zone's first spacing read more than this share less than those in it (not those inside
#: the zone: next to a sharp edge the recovered stress is not the edge's). Its value is then
#: set by where the zone ends, not by a peak of the part: on 5 of the corpus' 12 parts at the
#: default spacing (``rackstress bench parts``, docs/benchmarks/parts.md).
ZONE_EDGE_FALL = 0.05
ZONE_EDGE_NEAR = 2.0
#: ... and what an engineer does about the singular point it rises toward, by its kind
ZONE_EDGE_ADVICE = {
    "re-entrant edge": "model the edge's real fillet, or check that edge by FE (rackstress fea)",
    "support boundary": "model the support as it bears (a pin in a hole, a washer's area)",
    "point load": "spread the load over its real area",
    "unresolved fillet": ("refine below the fillet's radius / 1.43 (rackstress run --refine), "
                          "or check it by FE (rackstress fea)"),
    "contact edge": "a chamfer or radius on the rim, or a longer bearing, spreads it",
}


def zone_edge(at, singular: Singular, zone_: float, spacing: float, feats=None,
              read=None, values=None) -> dict | None:
    """Whether the governing stress, read at ``at``, is the zone's rather than the part's: it
    lies within :data:`ZONE_EDGE` spacings beyond the zone, and the particles' ``values``
    (read at ``read``, k×3) within :data:`ZONE_EDGE_NEAR` spacings of ``at`` fall away from
    the zone: 1 − the largest a spacing farther out over the largest in its first spacing
    beyond it (``fall``), more than :data:`ZONE_EDGE_FALL`. Returns the singular point
    nearest ``at`` (``position``, ``kind``, ``near``: the nearest named face or hole), its
    ``distance``, how far ``beyond`` the zone it is read and the ``fall``; None otherwise (a
    peak of the part).

    >>> from rackstress.model.singular import Singular
    >>> s = Singular(np.array([[0.0, 0.0, 0.0]]), np.array([0]), np.array([90.0]), "test")
    >>> x = np.array([[1.5, 0, 0], [2.1, 0, 0], [3.2, 0, 0]])     # stress rising toward 0
    >>> zone_edge([2.1, 0, 0], s, 2.0, 1.0, None, x, np.array([5.0, 10.0, 8.0]))["fall"]
    0.2
    >>> zone_edge([2.1, 0, 0], s, 2.0, 1.0, None, x, np.array([5.0, 10.0, 9.9]))  # flat
    >>> zone_edge([3.0, 0, 0], s, 2.0, 1.0, None, x, np.array([5.0, 10.0, 8.0]))  # beyond
    """
    a = float(spacing)
    d, k = singular.distance(np.asarray(at, float)[None])
    d, k = float(d[0]), int(k[0])
    if k < 0 or d - float(zone_) > ZONE_EDGE * a or read is None:
        return None
    read = np.asarray(read, float).reshape(-1, 3)
    v = np.asarray(values, float)
    near = np.linalg.norm(read - np.asarray(at, float), axis=1) <= ZONE_EDGE_NEAR * a
    ds = singular.distance(read[near])[0]
    z, ok = float(zone_), np.isfinite(v[near])
    first = ok & (ds >= z) & (ds < z + a)
    farther = ok & (ds >= z + a)
    if not first.any() or not farther.any():
        return None
    top = float(v[near][first].max())
    fall = 1.0 - float(v[near][farther].max()) / top if top > 0 else 0.0
    if not fall > ZONE_EDGE_FALL:
        return None
    x = singular.points[k]
    return {"distance": d, "beyond": d - float(zone_), "fall": round(fall, 12),
            "position": [float(c) for c in x], "kind": KINDS[int(singular.kind[k])],
            "near": _near(feats, x) if feats else None}


def zone_edge_sentence(gov: dict) -> str:
    """What :func:`zone_edge` found, in a sentence for the terminal and the report.

    >>> zone_edge_sentence({"zone_edge": {"distance": 5.77, "beyond": 0.04, "kind":
    ...     "re-entrant edge", "position": [10.0, 50.2, 9.0], "near": "face F43", "fall": 0.3},
    ...     "zone": 5.73, "length_units": "mm"})[:72]
    "at the zone's edge: 0.04 mm beyond it, 5.77 mm from a re-entrant edge at"
    """
    ze, u = gov["zone_edge"], gov.get("length_units", "")
    pos = ", ".join(f"{x:.4g}" for x in ze["position"])
    near = f", {ze['near']}" if ze.get("near") else ""
    return (f"at the zone's edge: {ze['beyond']:.2g} {u} beyond it, {ze['distance']:.3g} {u} "
            f"from {a_kind(ze['kind'])} at ({pos}){near}, toward which the stress rises (the "
            f"particles a spacing farther out read {100 * ze['fall']:.2g} % less): this value is "
            f"set by where the zone ends ({gov['zone']:.3g} {u}); "
            + ZONE_EDGE_ADVICE.get(ze["kind"], "check it by FE (rackstress fea)"))


def _with_notch(gov: dict, nk: dict | None, o: np.ndarray, ids, feats, y) -> None:
    """Put the notch reading ``nk`` (:func:`notch_peak`) in ``gov``, and make it the governing
    stress where it is the larger: the concave face's peak that the particles' patch fit
    flattens (``"read": "notch"``, the patch's own value kept as ``patch_value``)."""
    gov["notch"] = nk
    gov["read"] = "patch"
    if nk is None or not nk["value"] > gov["value"]:
        return
    j = int(nk["index"])
    gov["patch_value"] = gov["value"]
    gov.update(value=nk["value"], index=j, particle=int(ids[j]),
               position=[float(x) for x in o[j]], read_at=list(nk["position"]),
               near=_near(feats, np.asarray(nk["position"])),
               safety=(float(y) / nk["value"]) if (y and nk["value"] > 0) else None,
               read="notch")


# --------------------------------------------------------------------------- the error bar
def richardson(coarse: float, fine: float, ratio: float = REFINE_RATIO,
               order: float = LATTICE_ORDER) -> float:
    """Richardson's extrapolation of a value converging as h^order: from the values at h
    (``coarse``) and h/ratio (``fine``), fine + (fine − coarse)/(ratio^order − 1).

    >>> richardson(90.0, 95.0, ratio=2.0, order=1.0)     # errors 10 and 5: the limit 100
    100.0
    """
    return float(fine + (fine - coarse) / (ratio ** order - 1.0))


def observed_order(g1: float, g2: float, g3: float, ratio: float = REFINE_RATIO,
                   spacings=None):
    """The order p of convergence from three values at h, h/r, h/r² (``ratio`` r):
    p = ln((g1 − g2)/(g2 − g3)) / ln r; at any three ``spacings`` (h1 > h2 > h3) the p solving
    (g1 − g2)/(g2 − g3) = (h1^p − h2^p)/(h2^p − h3^p) (bisection). None when the differences
    change sign (not in the asymptotic range) or vanish, or p is outside 0.05 … 8.

    >>> round(observed_order(80.0, 90.0, 95.0, ratio=2.0), 6)   # errors 20, 10, 5: order 1
    1.0
    >>> round(observed_order(91.0, 96.0, 99.0, spacings=(3, 2, 1)), 6)   # 100 − h²: order 2
    2.0
    """
    d1, d2 = g1 - g2, g2 - g3
    if d1 == 0 or d2 == 0 or (d1 > 0) != (d2 > 0):
        return None
    q = d1 / d2
    if spacings is None:
        p = math.log(q) / math.log(ratio)
        return float(p) if 0.05 <= p <= 8.0 else None
    h1, h2, h3 = (float(x) for x in spacings)

    def f(p):
        return (h1 ** p - h2 ** p) / (h2 ** p - h3 ** p) - q

    lo, hi = 0.05, 8.0
    if f(lo) * f(hi) > 0:
        return None
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if f(lo) * f(mid) <= 0:
            hi = mid
        else:
            lo = mid
    return float(0.5 * (lo + hi))


def error_bar(values: list, spacings: list, order: float | None = None) -> dict:
    """The error bar of the governing stress from its values at two or three spacings
    (coarsest first, each the previous over one ratio).

    Richardson's extrapolation with the order measured from three values
    (:func:`observed_order`) when it can be, else :data:`LATTICE_ORDER` (the lattice's, from
    ``rackstress bench governing``); the error band is Roache's grid convergence index: the
    safety factor (:data:`SAFETY_MEASURED` with a measured order, :data:`SAFETY_ASSUMED` with
    an assumed one) times the distance from the finest value to the extrapolation. Returns
    ``{"values", "spacings", "ratio", "order", "order_from", "extrapolated", "value" (what
    the refinement reports: the finest value, the centre of the band), "estimate" (the
    half-width of the band about it), "relative" (of the coarsest value against the
    extrapolation), "low", "high", "method"}``.

    The reported value is the finest run's, not the extrapolation: the grid convergence index
    is a band about the finest grid's value (Roache, *Verification and Validation in
    Computational Science and Engineering*, 1998, §5.9), and the lattice's governing stress
    does not converge at a steady order (``rackstress bench governing`` measures none on its
    parts: the values move with where the layers fall and a notch reading scatters by several
    per cent), so the extrapolation carries 1/(r^p − 1) = 2.4 times that scatter at r = √2
    (docs/stress.md "The error bar").

    >>> e = error_bar([90.0, 95.0], [1.0, 0.5], order=1.0)
    >>> e["value"], e["extrapolated"], e["estimate"], round(e["relative"], 3)
    (95.0, 100.0, 15.0, -0.1)
    """
    v = [float(x) for x in values]
    h = [float(x) for x in spacings]
    if len(v) < 2:
        raise ValueError("an error bar needs the governing stress at two spacings at least")
    ratio = h[-2] / h[-1]
    p, src = order, "given"
    if len(v) >= 3 and p is None:
        p = observed_order(v[-3], v[-2], v[-1], spacings=h[-3:])
        src = "measured on this part (three spacings)"
        if p is not None and not (0.3 <= p <= 4.0):
            p = None
    if p is None:
        p, src = LATTICE_ORDER, "the lattice's, measured by rackstress bench governing"
    fs = SAFETY_MEASURED if src.startswith("measured") else SAFETY_ASSUMED
    ext = richardson(v[-2], v[-1], ratio, p)
    est = fs * abs(v[-1] - ext)
    change = abs(v[-1] - v[-2]) / abs(v[-1]) if v[-1] else None
    return {"values": v, "spacings": h, "ratio": ratio, "order": float(p), "order_from": src,
            "extrapolated": ext, "value": v[-1], "estimate": est,
            "relative": (v[0] - ext) / ext if ext else None,
            "relative_fine": (v[-1] - ext) / ext if ext else None,
            "low": max(0.0, v[-1] - est), "high": v[-1] + est, "safety_factor": fs,
            "change": change,
            "converging": bool(change is not None and change <= CONVERGING),
            "method": f"the finest spacing's value with Roache's grid convergence index "
                      f"(safety factor {fs:g}) about it, from Richardson's extrapolation (order "
                      f"{p:.3g}, {src}) over spacings " + ", ".join(f"{x:.4g}" for x in h)}


#: What a single run's governing stress may be off by, per s/t (s the spacing, t the shortest
#: chord through the part at the governing particle): the largest |governing / FEA − 1| per
#: s/t that ``rackstress bench governing`` measured over its parts and spacings
#: (docs/benchmarks/governing.md: "A single run's error per s/t"), where the governing
#: particle lies on flat faces ...
DEFAULT_ERROR_SLOPE = 0.79
#: ... and where it lies within :data:`CURVED_SPACINGS` of a concave curved face (a fillet or
#: a hole the lattice resolves as steps), at least this fraction whatever the spacing; also
#: how far the lattice under-reads the peak of such a face (:func:`curved_bound`): the plate
#: with a hole of ``rackstress bench validity --concentrations`` (radius 4 spacings: the
#: default patch route reads 0.52 of converged FEA and of Peterson's Kt there,
#: docs/benchmarks/validity-concentrations.md), a part apart from ``bench governing``'s, whose
#: filleted C frame then checks it (docs/benchmarks/governing.md). The linear fit of the
#: particles' values cannot reach a peak that rises by more than half in the last half
#: spacing (docs/stress.md "Patch recovery")
CURVED_ERROR = 0.48
CURVED_SPACINGS = 2.0
#: What the notch reading (:func:`notch_peak`), where it is the governing stress, may be off
#: by itself (:func:`default_error` adds the particles' field's error to it): the largest
#: |reading / converged FEA − 1| that ``rackstress bench validity
#: --concentrations`` measured on its parts with fillets and holes of radius at least
#: :data:`NOTCH_MIN_RADIUS` spacings (docs/benchmarks/validity-concentrations.md); the
#: filleted C frame of ``rackstress bench governing`` checks it.
NOTCH_ERROR = 0.18
#: ... and where the notch reading is its submodel's (:func:`notch_peak`, ``by`` "submodel"):
#: the largest |reading / converged FEA − 1| of the submodel's readings measured on the
#: plate with a hole, the notched and the filleted bars at eight spacings 0.35–0.6 mm (0.060,
#: the plate at 0.55 mm; measured while sizing its ball, notch.SUBMODEL_RHO); the same
#: bench's own runs, refined ones included, read within 0.037 of FEA; ``rackstress bench
#: governing``'s filleted C frame at 0.71 mm read 1.061 of FEA once the submodel was graded
#: no finer than the facets (notch.submodel_fine; 1.054 before), 1.063 read at its ball's
#: surface peak (notch.surface_peak): rounded up to that. All of them parts many particles
#: thick: a single run's band adds the particles' field's own error to it
#: (:func:`default_error`), which on thin-walled parts is not small (the SO-100 wrist housing
#: at 1.2 mm: its ball read 4.30 MPa driven by the particles, 3.81 driven by the FE check's
#: displacements; the particles' own stress in the ball 1.13 × the FE's; measured while
#: building this)
NOTCH_SUBMODEL_ERROR = 0.065


def curved_near(rundir, name: str, points, spacing: float) -> np.ndarray:
    """Per point (n, 3), whether it lies within :data:`CURVED_SPACINGS` spacings of a concave
    edge of the part's surface (``singular.npz``'s: fillets, holes, sharp edges alike); all
    False where the run has no surface for the part."""
    from scipy.spatial import cKDTree

    from rackstress.model.singular import concave_points
    from rackstress.stress.measures import read_surface

    x = np.asarray(points, float).reshape(-1, 3)
    surf = read_surface(rundir, name)
    if surf is None:
        return np.zeros(len(x), bool)
    V, F = surf
    pts = concave_points(V, F, spacing)
    if not len(pts):
        return np.zeros(len(x), bool)
    d, _ = cKDTree(pts).query(x)
    return d <= CURVED_SPACINGS * spacing


def near_curved(rundir, name: str, position, spacing: float) -> bool:
    """Whether ``position`` lies within :data:`CURVED_SPACINGS` of a concave edge of the part's
    surface (:func:`curved_near` of one point)."""
    return bool(curved_near(rundir, name, position, spacing)[0])


#: The notch reading (:mod:`rackstress.stress.notch`) reads a concave curved face whose radius
#: is at least this many spacings: below it the face is two or three particles across, its
#: staircase steps one particle each, and the tube's samples are the steps' (the filleted C
#: frame at 1 mm, radius 2 spacings: 1.16 of FEA's peak, measured while building this).
NOTCH_MIN_RADIUS = 2.5
#: ... each face point's reading the median of those within this many spacings of it.
NOTCH_SMOOTH = 0.5
#: ... and no face point within this many spacings of a particle clamped, loaded or pressed
#: by a contact: the face bears a load there, it is no free notch.
NOTCH_CLEAR = 2.0


def notch_peak(run, name: str, spacing: float, singular: Singular, zone_: float,
               frame: int) -> dict | None:
    """The largest notch reading (:mod:`rackstress.stress.notch`) of the part's concave curved
    faces of radius at least :data:`NOTCH_MIN_RADIUS` spacings, at least ``zone_`` from every
    singular point and :data:`NOTCH_CLEAR` spacings from whatever bears on the part (a clamp,
    a load, a contact's pressure), in ``frame``: each face point's reading the median of those
    within :data:`NOTCH_SMOOTH` spacings of it (one tube's samples fall on the staircase's
    steps); None
    where the part has no such face or no reading. The particles' ``continuum`` stress
    (at their centres, :class:`~rackstress.stress.measures.ParticleStress`) of that frame is
    what is fitted; the largest reading's face is then read by the submodel
    (:func:`_notch_submodel`, ``by``: "submodel"), or stays the fit's (``by``: "fit", with
    ``submodel_note`` saying why)."""
    from scipy.spatial import cKDTree

    from rackstress.stress import notch
    from rackstress.stress.measures import ParticleStress, read_surface

    surf = read_surface(run.rundir, name)
    if surf is None:
        return None
    a = float(spacing)
    pts, rho, nrm, chord = notch.faces(surf[0], surf[1], a)
    keep = (rho >= NOTCH_MIN_RADIUS * a) & (singular.distance(pts)[0] >= zone_) \
        if len(pts) else np.zeros(0, bool)
    if not keep.any():
        return None
    pts, rho, nrm, chord = pts[keep], rho[keep], nrm[keep], chord[keep]
    part = run.parts[name]
    st = ParticleStress(run, parts=[name], method="continuum")
    st.run(frames=[int(frame)])
    vm = np.asarray(st.results.von_mises[0])[part.index]
    o = run.o[part.index]
    # a face that something bears on is no free notch: not read within NOTCH_CLEAR of a
    # particle clamped (held in every direction), loaded or pressed by a contact
    held, loads = boundary_rows(run)
    engaged = held.all(axis=1) | np.any(loads != 0.0, axis=1)
    if "contact_pressure" in st.results:
        engaged |= np.nan_to_num(np.asarray(st.results.contact_pressure[0])) > 0.0
    engaged = engaged[part.index]
    # ... and a submodel's ball holds, as its cut, every particle something bears on, in the
    # directions it is held: a roller or a symmetry plane too (its face is no free surface
    # either); not a direction held on every particle of the part (face_supports)
    ways = face_supports(held[part.index]) | engaged[:, None]
    on = ways.any(axis=1)
    bears = (o[on], ways[on])
    reach = np.full(len(pts), np.inf)
    if engaged.any():
        d, _ = cKDTree(o[engaged]).query(pts)
        free = d > NOTCH_CLEAR * a
        pts, rho, nrm, reach, chord = pts[free], rho[free], nrm[free], d[free], chord[free]
    r = notch.readings(o, vm, pts, rho, nrm, a)
    ok = np.isfinite(r)
    if not ok.any():
        return None
    pts, rho, r, reach, chord = pts[ok], rho[ok], r[ok], reach[ok], chord[ok]
    smooth = np.array([np.median(r[n]) for n in
                       cKDTree(pts).query_ball_point(pts, NOTCH_SMOOTH * a * (1 + 1e-9))])
    k = int(np.argmax(smooth))
    fit = float(smooth[k])
    inner = notch.clear_of_edges(surf[0], surf[1], pts, a)
    point = None
    if inner.any():
        start = int(np.flatnonzero(inner)[int(np.argmax(smooth[inner]))])
        clear = cKDTree(o[engaged]) if engaged.any() else None

        def keep(X):          # the submodel's surface read as the face points are chosen
            ok = singular.distance(X)[0] >= zone_
            if clear is not None:
                ok &= clear.query(X)[0] > NOTCH_CLEAR * a
            return ok

        sk, value, why, point = _notch_submodel(run, part, o, surf, pts, rho, start, a,
                                                int(frame), inner, st.volume, reach, bears,
                                                chord, keep)
        k = k if value is None else sk
    else:
        value, why = None, (f"every point of the face lies within {notch.SUBMODEL_CLEAR:g} "
                            "spacings of the part's sharp outer edges")
    at = pts[k] if point is None else np.asarray(point, float)
    j = int(np.argmin(np.einsum("ij,ij->i", o - at, o - at)))    # nearest particle
    out = {"value": fit if value is None else float(value),
           "position": [float(x) for x in at], "radius": float(rho[k]), "index": j,
           "faces_read": int(len(r)), "fit": fit,
           "by": "fit" if value is None else "submodel"}
    if why:
        out["submodel_note"] = why
    return out


#: the most seconds the notch submodel's balls may take (:func:`_notch_submodel`): gmsh's
#: classification of a piece's surface does not end on some, and cannot be interrupted in
#: its process (rackstress.lib.forked)
NOTCH_SUBMODEL_TIMEOUT_S = 60.0


def _notch_submodel(run, part, o, surf, pts, rho, k: int, a: float, frame: int,
                    allowed: np.ndarray, volume, reach=None, bears=None, chord=None,
                    keep=None):
    """:func:`_notch_submodel_here` in a forked child process, stopped after
    :data:`NOTCH_SUBMODEL_TIMEOUT_S` (the fit's reading then stands, and the note says why)."""
    from rackstress.lib import forked

    try:
        return forked.call(lambda: _notch_submodel_here(run, part, o, surf, pts, rho, k, a,
                                                        frame, allowed, volume, reach,
                                                        bears, chord, keep),
                           NOTCH_SUBMODEL_TIMEOUT_S)
    except forked.Timeout:
        return k, None, (f"gmsh had not meshed the submodel's ball after "
                         f"{NOTCH_SUBMODEL_TIMEOUT_S:.0f} s (its surface classification does "
                         "not end on some pieces of a file's facets)"), None


def _notch_submodel_here(run, part, o, surf, pts, rho, k: int, a: float, frame: int,
                         allowed: np.ndarray, volume, reach=None, bears=None, chord=None,
                         keep=None):
    """The face's peak about face point ``k`` by the submodel (:func:`rackstress.stress.notch.
    submodel`: the part's true shape in a ball about the face point, its cut displaced as the
    particles are): the ball moves to the face point of the largest von Mises within a third
    of its radius until that is its centre (at most :data:`NOTCH_BALLS` balls), among the
    ``allowed`` face points (those clear of the part's sharp outer edges,
    :func:`rackstress.stress.notch.clear_of_edges`), and the last ball is read as the FE
    check reads its own (:func:`rackstress.stress.notch.surface_peak`: the largest on the
    part's surface within a third of its radius, where ``keep`` allows: the zone away from
    the singular points, clear of what bears on the part). ``volume``: the run's volumetric
    terms (or None); ``reach`` the face points' distances to the nearest particle something
    bears on (:func:`rackstress.stress.notch.submodel_radius`), ``bears`` (positions,
    directions) the particles held, loaded or pressed (held by the submodel in those
    directions where its ball reaches them), ``chord`` the facets' spacing across the face
    at each point (:func:`rackstress.stress.notch.submodel_fine`); the reading checked by a
    smaller ball at the same point (:func:`rackstress.stress.notch.cut_check`). Returns (face
    point, value, None, the point read), or (k, None, why, None) where no submodel can be
    made (gmsh or manifold3d not installed: the ``fem`` extra; their own error) or its two
    balls disagree."""
    from rackstress.stress import notch
    from rackstress.stress.measures import material_parts, positions

    mat = (material_parts(run).get(part.name) or {}).get("material") or {}
    if not mat.get("E"):
        return k, None, "the part has no Young's modulus in scene.json", None
    u = positions(run.trajectory[frame])[part.index] - o
    nu = lattice_nu(volume, part, mat)    # the cut's displacements are its own material's
    reach = np.full(len(pts), np.inf) if reach is None else np.asarray(reach, float)
    held = None if bears is None else (np.asarray(bears[0], float), bears[1], a)
    chord = np.zeros(len(pts)) if chord is None else np.asarray(chord, float)
    seen, at, value = [], k, None
    for _ in range(NOTCH_BALLS):
        seen.append(k)
        R = notch.submodel_radius(a, float(rho[k]), float(reach[k]))
        try:
            sol = notch.submodel(surf[0], surf[1], pts[k], o, u, a, float(rho[k]),
                                 float(mat["E"]), nu, radius=R, bears=held,
                                 fine=notch.submodel_fine(a, rho[k], chord[k]))
        except ImportError as exc:
            return k, None, (f"{exc.name or exc} is not installed: the notch submodel needs "
                             "the fem extra (pip install 'rackstress[fem]')"), None
        except Exception as exc:  # noqa: BLE001 - gmsh's or manifold3d's own words, kept
            if value is None:
                return k, None, (f"no submodel at ({', '.join(f'{x:.4g}' for x in pts[k])}): "
                                 f"{exc}"), None
            break             # the last ball's reading stands
        near = np.flatnonzero((np.linalg.norm(pts - pts[k], axis=1) <= R / 3) & allowed)
        vm = sol.at(pts[near])["von_mises"]
        value, at, R_at, last = float(sol.at(pts[k][None])["von_mises"][0]), k, R, sol
        best = int(near[int(np.argmax(vm))])
        if best in seen:
            break
        k = best
    # read on the surface about the last ball's centre, as the FE check reads its own ball
    peak, point = notch.surface_peak(last, pts[at], R_at, keep)
    if peak is None:                   # no surface node clear: the centre's reading stands
        point = pts[at]
    else:
        value = peak
    # the classical submodel's own check: its reading may not depend on where its cut lies
    try:
        other, R2, agree = notch.cut_check(surf[0], surf[1], pts[at], o, u, a, float(rho[at]),
                                           float(mat["E"]), nu, R_at, value, bears=held,
                                           fine=notch.submodel_fine(a, rho[at], chord[at]),
                                           peak=peak is not None, keep=keep)
    except Exception as exc:  # noqa: BLE001 - gmsh's own words: the reading stands, unchecked
        return at, value, f"its check ball could not be made ({exc}): unchecked", point
    if not agree:
        return at, None, (f"its reading depends on where its cut lies ({value:.4g} with a ball "
                          f"of {R_at:.3g}, {other:.4g} with one of {R2:.3g}: more than "
                          f"{notch.CHECK_AGREE * 100:.0f} % apart), so the cut's displacement "
                          "does not carry the notch's field there"), None
    return at, value, None, point


#: the most submodel balls :func:`_notch_submodel` moves through
NOTCH_BALLS = 4


def read_label(read: str | None, by: str | None = None) -> str:
    """How a governing stress was read, in a table's words: ``patch``, or ``notch`` with how
    the notch reading read it (``notch (submodel)``).

    >>> read_label("notch", "submodel"), read_label("patch", "fit"), read_label(None)
    ('notch (submodel)', 'patch', '—')
    """
    if read != "notch":
        return read or "—"
    return f"notch ({by})" if by else "notch"


def notch_how(nk: dict) -> str:
    """How the notch reading ``nk`` (:func:`notch_peak`) was read, in words for the terminal
    and the report.

    >>> notch_how({"by": "fit", "submodel_note": "gmsh is not installed"})[:44]
    "by the notch reading's fit of the particles "
    """
    from rackstress.stress import notch

    if nk.get("by") == "submodel":
        return ("by the notch reading: a finite-element submodel of the face's true shape in "
                f"a ball of {notch.SUBMODEL_RADIUS:g} spacings or {notch.SUBMODEL_RHO:g} × its "
                "radius, the larger, about it, its cut displaced as "
                "the particles are "
                f"(the fit of the particles beneath the face reads {nk['fit']:.4g})")
    note = f"; no submodel: {nk['submodel_note']}" if nk.get("submodel_note") else ""
    return ("by the notch reading's fit of the particles beneath it to a notch's field"
            + note)


def band(value: float, relative: float) -> tuple[float, float]:
    """The values the converged one may take when a reading ``value`` is off by at most
    ``relative`` of it: |value / converged − 1| ≤ e gives converged within value / (1 + e) …
    value / (1 − e) (the bench measures e as that ratio's distance from 1, so a reading
    e low needs value / (1 − e), more than value·(1 + e), to reach the converged value).

    >>> [round(x, 4) for x in band(58.0, 0.42)]          # 42 % low at most: up to 100
    [40.8451, 100.0]
    """
    v, e = float(value), abs(float(relative))
    return v / (1.0 + e), (v / (1.0 - e) if e < 1.0 else math.inf)


def curved_bound(gov: dict) -> float | None:
    """The most a concave curved face (a fillet, a hole) away from the singular points may
    truly carry, from the particles' largest value there (``gov["curved_face"]``,
    :func:`record`): that value / (1 − :data:`CURVED_ERROR`), the lattice's measured
    under-reading of such a face's peak; None where the part has none. The governing stress
    may sit elsewhere while the face's real peak, which the lattice does not resolve, is the
    larger."""
    c = gov.get("curved_face") if gov else None
    if not c:
        return None
    return band(c["value"], CURVED_ERROR)[1]


def with_single_run(err: dict, single: dict | None) -> dict:
    """``--refine``'s error bar (:func:`error_bar`) made never narrower than the refined run's
    own single-run band (:func:`default_error` of its governing stress, the curved faces'
    bound included): Richardson sees two values that may agree by chance (where the lattice's
    layers fall in the walls) or while both miss a fillet's peak the lattice does not
    resolve."""
    if not single:
        return err
    err["single_run"] = {k: single.get(k) for k in ("low", "high", "relative",
                                                    "curved_face_bound")}
    if single["low"] < err["low"] or single["high"] > err["high"]:
        err["low"], err["high"] = min(err["low"], single["low"]), max(err["high"],
                                                                       single["high"])
        err["method"] += ("; never narrower than the refined run's own single-run band "
                          f"({single['low']:.4g} … {single['high']:.4g})")
    return err


def default_error(run, gov: dict) -> dict:
    """What a single run's governing stress may be off by, without ``--refine``: ±
    :data:`DEFAULT_ERROR_SLOPE` × s/t, the lattice's measured convergence. Why s/t: a particle
    reads the stress at its centre, half a spacing inside the surface, which in bending across
    a member t thick is s/t below the surface's value (hand calculation); particles on a convex
    edge read a few per cent high. ``relative`` is the half-width of that band."""
    from rackstress.model.singular import chords

    part = run.parts[gov["group"]]
    o = run.o[part.index]
    s = float(gov["spacing"])
    t = float(chords(o, s)[int(gov["index"])])
    curved = near_curved(run.rundir, gov["group"], gov["position"], s)
    rel = DEFAULT_ERROR_SLOPE * s / t
    how = f"± {DEFAULT_ERROR_SLOPE:g} × s/t = ± {100 * rel:.2g} %"
    if gov.get("read") == "notch":
        # two errors, each of its own source, added: the notch reading's own (its submodel's
        # ball, mesh and cut, or its fit) and that of the particles' field it reads, which
        # is a particle's own (± DEFAULT_ERROR_SLOPE × s/t); the larger of the two alone
        # left readings of the corpus' parts outside their bands (docs/stress.md "The error
        # bar")
        sub = gov["notch"].get("by") == "submodel"
        own = NOTCH_SUBMODEL_ERROR if sub else NOTCH_ERROR
        field = rel
        rel = own + field
        how = (f"± {100 * rel:.2g} %: the notch reading's own error ("
               + ("its submodel" if sub else "its fit of the particles") +
               f", ± {100 * own:.2g} % at a concave curved face, rackstress bench validity "
               f"--concentrations; radius {gov['notch']['radius']:.3g} here) plus that of the "
               f"particles' field it reads, ± {DEFAULT_ERROR_SLOPE:g} × s/t = "
               f"± {100 * field:.2g} %")
    elif curved and CURVED_ERROR > rel:
        rel = CURVED_ERROR
        how = (f"± {100 * rel:.2g} %, the lattice's error at a concave curved face (a fillet or "
               "hole it resolves as steps), whatever the spacing")
    low, high = band(gov["value"], rel)
    cb = curved_bound(gov)
    face = ""
    if cb is not None and cb > high:
        high = cb
        c = gov["curved_face"]
        at = ", ".join(f"{x:.4g}" for x in c["read_at"])
        face = (f"; a concave curved face (fillet or hole) at ({at}) reads {c['value']:.4g}, "
                "and the lattice under-reads such a face's peak by up to "
                f"{100 * CURVED_ERROR:.2g} %: up to {cb:.4g} there")
    return {"estimate": rel * gov["value"], "relative": rel, "thickness": t, "curved": curved,
            "low": low, "high": high, "curved_face_bound": cb,
            "method": f"a single spacing: {how} (s = {s:.4g}, t = {t:.3g} the part's thickness "
                      "at the governing particle), the lattice's convergence measured by "
                      f"rackstress bench governing{face}; run with --refine for this part's "
                      "own error bar",
            "source": "docs/benchmarks/governing.md"}


def _where(rec: dict) -> str:
    pos = ", ".join(f"{x:.4g}" for x in rec["position"])
    near = f", {rec['near']}" if rec.get("near") else ""
    return f"particle {rec['particle']} at ({pos}){near}"


def a_kind(kind: str) -> str:
    """A singular point's kind with its article: 'a re-entrant edge', 'an unresolved fillet'."""
    return ("an " if kind[:1] in "aeiou" else "a ") + kind


def first_point_sentence(fine: dict, unit: str) -> str | None:
    """Where ``--refine``'s refined value was read at the first run's governing point
    (``summary.json["stress"]["error"]["governing_fine"]``, :func:`with_first_point`), what
    it says; None where it was read by the rule alone.

    >>> print(first_point_sentence({"read": "first point", "read_at": [10.67, 53.37, 10.89],
    ...                             "value": 0.3445, "rule_value": 0.222}, "MPa"))
    ... # doctest: +NORMALIZE_WHITESPACE
    the refined value is the finer run's stress at the first run's governing point
    (10.67, 53.37, 10.89), more than its own points beyond the zone read (at most 0.222 MPa;
    docs/stress.md "The first run's governing point")
    """
    if not fine or fine.get("read") != FIRST_POINT:
        return None
    at = ", ".join(f"{x:.4g}" for x in fine["read_at"])
    rule = ("it has no points beyond the zone" if fine.get("rule_value") is None else
            f"more than its own points beyond the zone read (at most "
            f"{fine['rule_value']:.4g} {unit}")
    return ("the refined value is the finer run's stress at the first run's governing point "
            f"({at}), {rule}; docs/stress.md \"The first run's governing point\")")


def fine_alone_sentence(own: dict, unit: str, length: str = "") -> str:
    """What ``--refine``'s refined run reads on its own where it reads more than the error
    bar's same-rule value (``summary.json["stress"]["error"]["fine_own"]``,
    :func:`rackstress.stress.refine.fine_alone`), and why it differs.

    >>> fine_alone_sentence({"value": 0.332, "position": [-10.3, 53.4, 11.6],
    ...                      "near": "face F43", "zone": 5.73, "why": "singular points"}, "MPa", "mm")
    'the refined run alone reads 0.332 MPa at (-10.3, 53.4, 11.6) near face F43: by its own singular points — at the finer spacing a concave edge there turns gently enough to be a fillet, not a sharp edge; check that place by FE (rackstress fea)'
    >>> fine_alone_sentence({"value": 12.0, "position": [1, 2, 3], "zone": 1.4, "why": "zone"},
    ...                     "MPa", "mm")
    'the refined run alone reads 12 MPa at (1, 2, 3): within its own zone of 1.4 mm, nearer a singular point, where the stress grows with refinement'
    """
    at = ", ".join(f"{x:.4g}" for x in own["position"])
    near = f" near {own['near']}" if own.get("near") else ""
    head = f"the refined run alone reads {own['value']:.4g} {unit} at ({at}){near}"
    if own.get("why") == "zone":
        return (f"{head}: within its own zone of {own['zone']:.3g} {length}, nearer a singular "
                "point, where the stress grows with refinement")
    return (f"{head}: by its own singular points — at the finer spacing a concave edge there "
            "turns gently enough to be a fillet, not a sharp edge; check that place by FE "
            "(rackstress fea)")


def describe(gov: dict | None, sing: dict | None, error: dict | None,
             headline: bool = True, static: bool = True) -> list:
    """Terminal lines: the governing stress as the headline (``headline`` False: left to the
    caller), its safety factor and zone, the error bar, and the singular peak beside it
    (spacing-dependent, with advice). ``static`` False (a run in time): ``--refine``, which
    refines static parts only, is not offered."""
    lines = []
    if gov:
        u = gov["units"]
        sf = f", factor of safety {gov['safety']:.3g}" if gov.get("safety") else ""
        if headline:
            lines.append(f"  governing von Mises stress {gov['value']:.4g} {u} in "
                         f"{gov['group']}{sf}: {_where(gov)}")
        if gov.get("read") == "notch":
            lines.append(f"    read on a concave curved face of radius "
                         f"{gov['notch']['radius']:.3g} {gov.get('length_units', '')} "
                         f"{notch_how(gov['notch'])} (docs/stress.md); the patch fit of the "
                         f"particles reads {gov['patch_value']:.4g} {u}")
        kinds = ["sharp re-entrant edges"] + (["fillets it does not resolve"]
                                               if gov.get("unresolved_fillets") else []) \
            + ["support boundaries", "point loads"] \
            + (["contact edges"] if gov.get("contact_edges") else [])
        kinds = ", ".join(kinds[:-1]) + " and " + kinds[-1]
        lines.append(f"    (the largest at least {gov['zone']:.3g} {gov.get('length_units', '')}"
                     f" from {kinds})")
        if gov.get("zone_edge"):
            lines.append("    " + zone_edge_sentence(gov))
        if error and error.get("extrapolated") is not None:
            lines.append(f"    error bar: {gov['value']:.4g} {u} at spacing "
                         f"{error['spacings'][0]:.4g}, {error['values'][-1]:.4g} at "
                         f"{error['spacings'][-1]:.4g}: refined {error['values'][-1]:.4g} {u}, "
                         f"converged value within {error['low']:.4g} … {error['high']:.4g} {u}"
                         f" (Richardson's extrapolation {error['extrapolated']:.4g}, order "
                         f"{error['order']:.2g}, sets the band's width)")
            if error.get("converging") is False:
                lines.append(f"    not converged: the governing stress moved by "
                             f"{100 * error['change']:.2g} % between the two spacings (more "
                             f"than {100 * CONVERGING:g} %); refine further, or check it by "
                             "FE (rackstress fea)")
            fp = first_point_sentence(error.get("governing_fine"), u)
            if fp:
                lines.append("    " + fp)
            if error.get("fine_own"):
                lines.append("    " + fine_alone_sentence(error["fine_own"], u,
                                                          gov.get("length_units", "")))
        elif error:
            lines.append(f"    may be off by about ±{100 * abs(error['relative']):.2g} % at this "
                         f"spacing (the part is {error['thickness']:.3g} "
                         f"{gov.get('length_units', '')} thick there; "
                         "rackstress bench governing)"
                         + ("; rackstress run --refine measures it" if static else ""))
    if sing:
        lines.append(f"  singular peak {sing['value']:.4g} {sing['units']} at "
                     f"{a_kind(sing['kind'])}, {_where(sing)}: "
                     f"{''.join(SINGULAR_SAID.get(sing['kind'], SINGULAR_SAID[None]))}; "
                     f"{sing['advice'].split(':')[0]}")
    return lines

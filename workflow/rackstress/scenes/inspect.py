"""``rackstress inspect``: what a part is, before any scene is written.

One look at a mesh file (STL, OBJ, PLY, VTK, or STEP through gmsh): its size, bodies, volume
and watertightness; its named holes and faces (:mod:`rackstress.scenes.features`) to hold and
load it by name; its thinnest walls; and the spacing a scene without ``spacing`` would get
(:func:`rackstress.scenes.features.choose_spacing`). :func:`inspect_part` returns it as a
dict (``--json``), :func:`text` as the table the command prints, :func:`picture` as a PNG
with the names written on the part (pyvista off-screen).

Example
-------
>>> from rackstress.scenes.inspect import inspect_part, text      # doctest: +SKIP
>>> info = inspect_part("examples/bracket/bracket.stl")            # doctest: +SKIP
>>> print(text(info))                                              # doctest: +SKIP
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from rackstress.scenes import features as ft

#: faces listed by ``text`` unless all are asked for
FACES_SHOWN = 12


def inspect_part(path, scale=None, budget: int = ft.BUDGET, bodies: str = "one") -> dict:
    """Size, bodies, volume, watertightness, holes, faces, walls and the chosen spacing of
    the part in ``path`` (its coordinates × ``scale``: one factor, or one per axis);
    ``bodies = "united"``: of the union of its bodies, as a scene with that key fills it and
    names its features (:func:`rackstress.scenes.mesh.united_triangles`)."""
    import trimesh

    from rackstress.scenes.mesh import placement

    place = placement(scale)
    V, T = _triangles(path, bodies)
    V = place.apply(V)
    tm = trimesh.Trimesh(V, T, process=True)
    edges, counts = np.unique(tm.edges_sorted, axis=0, return_counts=True)
    open_edges = int((counts == 1).sum())
    shared = int((counts > 2).sum())
    watertight = open_edges == 0 and shared == 0 and bool(tm.is_winding_consistent)
    f = ft.part_features(tm)
    walls = ft.wall_thickness(tm)
    lo, hi = tm.bounds
    size = hi - lo
    volume = abs(float(tm.volume)) if watertight else None
    spacing = ft.choose_spacing(volume, walls, budget) if volume else None
    thin = walls.thinner_than(ft.ACROSS * spacing["spacing"], f)[:5] if spacing else []
    scale_used = list(place.scale)
    return {
        "file": str(path), "scale": scale_used[0] if len(set(scale_used)) == 1 else scale_used,
        "triangles": int(len(tm.faces)), "bodies": f.bodies, "united": bodies == "united",
        "watertight": watertight,
        "open_edges": open_edges, "shared_edges": shared,
        "volume": volume, "bounds": [lo.tolist(), hi.tolist()], "size": size.tolist(),
        "units_hint": _units_hint(float(size.max())),
        "holes": [h.to_dict() for h in f.holes], "faces": [x.to_dict() for x in f.faces],
        "fillets": f.fillets,
        "walls": {"thinnest": _finite(np.nanmin(walls.thickness)) if np.isfinite(
            walls.thickness).any() else None,
            f"p{ft.WALL_PERCENTILE:g}": _finite(walls.percentile(ft.WALL_PERCENTILE)),
            "median": _finite(walls.percentile(50.0)),
            "samples": int(np.isfinite(walls.thickness).sum()),
            "thin": thin},
        "spacing": spacing,
    }


def _finite(x):
    return float(x) if x is not None and math.isfinite(x) else None


def _units_hint(largest: float) -> str | None:
    """A sentence when the part's size says its file is not in millimetres."""
    if largest < 2.0:
        return (f"the part is {largest:.3g} units across: if its file is in metres, give "
                "scale = 1000 (--scale 1000) to work in millimetres")
    if largest < 20.0:
        return (f"the part is {largest:.3g} units across: if its file is in inches, give "
                "scale = 25.4 (--scale 25.4) to work in millimetres")
    return None


def _v(x, digits: int = 4) -> str:
    big = max((abs(float(c)) for c in x), default=0.0)
    return "[" + ", ".join(_g(0.0 if abs(float(c)) < 1e-6 * big else c, digits)
                           for c in x) + "]"


def _g(x, digits: int = 4) -> str:
    if x is None:
        return "-"
    x = float(x)
    if abs(x) < 1e-12:
        x = 0.0
    return f"{x:.{digits}g}"


def text(info: dict, all_faces: bool = False) -> str:
    """The table ``rackstress inspect`` prints."""
    out = []
    sz = info["size"]
    out.append(f"{info['file']}: {info['triangles']:,} triangles, {info['bodies']} "
               f"bod{'y' if info['bodies'] == 1 else 'ies'}, "
               + ("watertight" if info["watertight"] else
                  f"NOT watertight ({info['open_edges']} open edge(s), {info['shared_edges']} "
                  "edge(s) shared by more than two triangles)"))
    out.append(f"  size {_g(sz[0])} x {_g(sz[1])} x {_g(sz[2])} (x, y, z), from "
               f"{_v(info['bounds'][0])} to {_v(info['bounds'][1])}"
               + (f", scale {info['scale']}" if info["scale"] != 1.0 else ""))
    if info["volume"] is not None:
        out.append(f"  volume {_g(info['volume'], 5)}")
    if info["units_hint"]:
        out.append(f"  note: {info['units_hint']}")
    if info["bodies"] > 1 and not info.get("united"):
        out.append(f"  note: {info['bodies']} bodies: a scene fills their union as one part with "
                   "bodies = \"united\" beside mesh; --bodies united names the union's holes "
                   "and faces (the names below are of the file as it is)")
    out.append("")
    holes = info["holes"]
    out.append(f"holes ({len(holes)}): hold one with where = {{ hole = \"H1\" }}" if holes
               else "holes (0): none found; hold or load the part by its faces, or by a box, "
                    "sphere or cylinder region")
    if holes:
        out.append(f"  {'name':5s} {'diameter':>9s} {'depth':>8s} {'':7s} {'axis':24s} "
                   f"{'centre (mid-depth)':28s} segments")
        for h in holes:
            out.append(f"  {h['name']:5s} {_g(h['diameter']):>9s} {_g(h['depth']):>8s} "
                       f"{'through' if h['through'] else 'blind':7s} {_v(h['axis'], 3):24s} "
                       f"{_v(h['centre']):28s} {h['segments']}")
    faces = info["faces"]
    shown = faces if all_faces else faces[:FACES_SHOWN]
    more = "" if len(shown) == len(faces) else f", the {len(shown)} largest shown (--all)"
    out.append("")
    out.append(f"flat faces ({len(faces)}{more}): load one with where = {{ face = \"F1\" }}"
               if faces else "flat faces (0): none found; load the part by a box, sphere or "
                             "cylinder region")
    if shown:
        out.append(f"  {'name':5s} {'area':>10s} {'normal':24s} {'centre':28s} extent")
        for x in shown:
            out.append(f"  {x['name']:5s} {_g(x['area']):>10s} {_v(x['normal'], 3):24s} "
                       f"{_v(x['centre']):28s} {_g(x['extent'][0])} x {_g(x['extent'][1])}")
    if info["fillets"]:
        out.append(f"  ({info['fillets']} fillet(s), round(s) and partial cylinder(s): "
                   "neither holes nor faces)")
    w = info["walls"]
    out.append("")
    if w["thinnest"] is None:
        out.append("walls: not measured (no ray met an opposite face)")
    else:
        out.append(f"walls: thinnest {_g(w['thinnest'], 3)}, "
                   f"{_g(w[f'p{ft.WALL_PERCENTILE:g}'], 3)} or thinner on "
                   f"{ft.WALL_PERCENTILE:g} % of the surface, median {_g(w['median'], 3)} "
                   f"({w['samples']:,} rays)")
    sp = info["spacing"]
    if sp:
        out.append(f"spacing: {_g(sp['spacing'], 3)} for a scene without one: {sp['reason']}")
        for t in w["thin"]:
            out.append(f"  thinner than {ft.ACROSS} particles: {_g(t['thickness'], 3)} at "
                       f"{_v(t['position'])}" + (f", near {t['near']}" if t["near"] else "")
                       + f" ({100 * t['share']:.1f} % of the surface)")
    else:
        out.append("spacing: none chosen (the part is not watertight: it has no inside to "
                   "fill)")
    return "\n".join(out)


def _triangles(path, bodies: str):
    """The file's triangles as read, or (``bodies = "united"``) their bodies' union."""
    from rackstress.scenes.mesh import is_united, read_triangles, united_triangles

    united = is_united(bodies)
    V, T = read_triangles(path)
    return united_triangles(V, T, str(path)) if united else (V, T)


def picture(path, out, scale=None, size=(1200, 900), bodies: str = "one") -> Path:
    """A PNG of the part from its isometric side with each hole's and face's name written
    at it (pyvista off-screen): what an engineer looks at to pick them."""
    import os

    if not os.environ.get("DISPLAY"):     # EGL without X, as render.draw.offscreen does
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    import pyvista as pv

    from rackstress.scenes.mesh import placement

    place = placement(scale)
    V, T = _triangles(path, bodies)
    V = place.apply(V)
    f = ft.part_features((V, T))
    poly = pv.PolyData.from_regular_faces(V, T)
    pl = pv.Plotter(off_screen=True, window_size=list(size))
    try:
        pl.set_background("white")
        pl.add_mesh(poly, color="#d9d4c7", smooth_shading=False, specular=0.2)
        for x in f.faces:
            pl.add_mesh(pv.PolyData.from_regular_faces(V, T[x.triangles]), color="#9ecae1",
                        opacity=0.6)
        for h in f.holes:
            pl.add_mesh(pv.PolyData.from_regular_faces(V, T[h.triangles]), color="#e6550d")
        pts = [h.centre for h in f.holes] + [x.centre for x in f.faces]
        names = [h.name for h in f.holes] + [x.name for x in f.faces]
        if pts:
            pl.add_point_labels(np.asarray(pts), names, font_size=14, point_size=6,
                                shape_opacity=0.7, always_visible=True, text_color="black")
        pl.view_isometric()
        pl.add_axes()
        out = Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        pl.screenshot(str(out))
    finally:
        pl.close()
    return out

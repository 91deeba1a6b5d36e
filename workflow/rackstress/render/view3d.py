"""``RUNDIR/view3d.html``: the peak frame as an interactive 3D view, offline (vtk.js).

The page is trame-vtk's standalone vtk.js viewer (``trame_vtk/tools/static_viewer.html``, the
one pyvista's HTML export writes; about 1 MB of JavaScript, no network) with the scene inlined:
a VTK render window serialized by trame-vtk's own serializers (the format its ``OfflineLocalView``
loads), zipped and base64-encoded. ``report.html`` embeds it in an ``<iframe>``.

What it shows:

* every particle of the coloured parts as a sphere of the part's radius (vtk.js
  ``vtkGlyph3DMapper``: one sphere instanced per particle, so MagPod's robot costs 12 bytes a
  particle, not a mesh), coloured by the pictures' measure with the pictures' colour map and
  scale (0 to the peak; opaque: the translucency of the still pictures is left out so that the
  view can be turned freely);
* the context parts (a sediment) as light sand spheres, at most :data:`MAX_CONTEXT` of them:
  beyond that only those nearest the coloured parts (the page says how many are shown);
* the peak particle inside a black wire sphere three radii wide;
* a slider over up to :data:`MAX_FRAMES` dumped frames (evenly spread, the peak frame
  included; fewer if their positions and colours would exceed :data:`FRAME_BUDGET` bytes), which
  moves the coloured parts and the marker to that frame and recolours them.

Mouse: left drag rotates, wheel or right drag zooms, shift + left drag (or middle drag) pans.
"""
from __future__ import annotations

import base64
import io
import json
import os
import zipfile
from pathlib import Path

import numpy as np

VIEW = "view3d.html"
#: Context particles shown at most (the rest of a large sediment is left out).
MAX_CONTEXT = 20000
#: Frames on the slider at most, and the raw bytes their positions and colours may take.
MAX_FRAMES = 40
FRAME_BUDGET = 1_500_000
#: Sphere resolution of a drawn particle (vtkSphereSource theta, phi).
SPHERE_RES = (10, 8)
SAND = (0.85, 0.80, 0.70)
MARKER_RGB = (0.0, 0.25, 1.0)


def _viewer_html() -> Path:
    from importlib.util import find_spec

    spec = find_spec("trame_vtk")
    return Path(spec.origin).parent / "tools" / "static_viewer.html"


def _glyph_serializer(parent, mapper, mapper_id, context, depth):
    """trame-vtk serializes plain mappers only (through a surface filter, which drops points
    without cells); a ``vtkGlyph3DMapper`` is its points (input port 0) and its glyph (port 1),
    which vtk.js's ``vtkGlyph3DMapper`` takes as they are."""
    from trame_vtk.modules.vtk.serializers.serialize import serialize
    from trame_vtk.modules.vtk.serializers.utils import reference_id, wrap_id

    calls, deps = [], []
    for port, suffix in ((0, "dataset"), (1, "glyph")):
        data = mapper.GetInputDataObject(port, 0)
        did = f"{mapper_id}-{suffix}"
        inst = serialize(mapper, data, did, context, depth + 1)
        if inst is None:
            return None
        deps.append(inst)
        calls.append(["setInputData", [wrap_id(did), port]])
    return {"parent": reference_id(parent), "id": mapper_id, "type": "vtkGlyph3DMapper",
            "properties": {"scalarVisibility": mapper.GetScalarVisibility(), "colorMode": 0,
                           "scalarMode": 0, "scaling": 0, "orient": 0, "scaleFactor": 1.0},
            "calls": calls, "dependencies": deps}


def _points(q: np.ndarray, rgb: np.ndarray | None = None):
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonCore import vtkPoints
    from vtkmodules.vtkCommonDataModel import vtkPolyData

    poly = vtkPolyData()
    pts = vtkPoints()
    pts.SetData(numpy_to_vtk(np.ascontiguousarray(q, dtype=np.float32), deep=True))
    poly.SetPoints(pts)
    if rgb is not None:
        arr = numpy_to_vtk(np.ascontiguousarray(rgb, dtype=np.uint8), deep=True)
        arr.SetName("rgb")
        poly.GetPointData().SetScalars(arr)
    return poly


def _sphere(radius: float, res=SPHERE_RES):
    from vtkmodules.vtkFiltersSources import vtkSphereSource

    s = vtkSphereSource()
    s.SetRadius(float(radius))
    s.SetThetaResolution(res[0])
    s.SetPhiResolution(res[1])
    s.Update()
    return s.GetOutput()


def _marker(radius: float, height: float):
    """The peak's marker round the origin: a wire sphere of ``radius`` and a pin rising
    ``height`` above it (visible however the peak particle is hidden among the others)."""
    from vtkmodules.vtkFiltersCore import vtkAppendPolyData
    from vtkmodules.vtkFiltersSources import vtkLineSource

    line = vtkLineSource()
    line.SetPoint1(0.0, radius, 0.0)
    line.SetPoint2(0.0, radius + height, 0.0)
    line.Update()
    app = vtkAppendPolyData()
    app.AddInputData(_sphere(radius, (24, 16)))
    app.AddInputData(line.GetOutput())
    app.AddInputData(_sphere(0.3 * radius, (12, 8)))
    app.Update()
    out = app.GetOutput()
    # the small ball on top of the pin
    from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy

    q = vtk_to_numpy(out.GetPoints().GetData()).copy()
    n_top = _sphere(0.3 * radius, (12, 8)).GetNumberOfPoints()
    q[-n_top:, 1] += radius + height
    out.GetPoints().SetData(numpy_to_vtk(q, deep=True))
    return out


def _view_direction(centre, peak_position) -> np.ndarray:
    """From the parts' centre towards the camera: from the side of the peak particle, raised
    by 30° (the peak faces the viewer when it is on the parts' surface); iso without a peak."""
    d = np.array([1.0, 0.0, 1.0]) if peak_position is None else \
        np.asarray(peak_position, float) - np.asarray(centre, float)
    h = np.array([d[0], 0.0, d[2]])
    if np.linalg.norm(h) < 1e-9 * (1.0 + np.linalg.norm(d)):
        h = np.array([1.0, 0.0, 1.0])
    h /= np.linalg.norm(h)
    out = h * np.cos(np.radians(30.0)) + np.array([0.0, np.sin(np.radians(30.0)), 0.0])
    return out / np.linalg.norm(out)


def _frame(run, k: int) -> np.ndarray:
    """Positions (float64, atom-id order) of dumped frame ``k``."""
    return run.trajectory[k].data["positions64"].copy()


def _peak(rundir: Path, run, values, parts, measure: str) -> dict | None:
    """The run's peak of ``measure`` over ``parts``: summary.json's record (the number every
    other page shows), with ``row``, the particle's place in the run's arrays; straight from
    ``values`` if the summary lacks it."""
    best = None
    try:
        groups = json.loads((Path(rundir) / "summary.json").read_text()).get("groups") or {}
    except (OSError, json.JSONDecodeError):
        groups = {}
    for part in parts:
        rec = ((groups.get(part.name) or {}).get("peak") or {}).get(measure)
        if rec and (best is None or rec["value"] > best["value"]):
            best = {**rec, "group": part.name, "row": int(part.index[rec["index"]])}
    if best is not None:
        return best
    idx = np.concatenate([q.index for q in parts])
    sub = np.where(np.isfinite(values[:, idx]), values[:, idx], -np.inf)
    if not np.isfinite(sub).any():
        return None
    k, j = np.unravel_index(int(np.argmax(sub)), sub.shape)
    row = int(idx[j])
    part = next(q for q in parts if row in set(q.index.tolist()))
    return {"value": float(sub[k, j]), "frame": int(k), "iteration": int(run.steps[k]),
            "group": part.name, "row": row, "particle": int(run.data.ids[row])}


def _frames(run, peak_frame: int, per_frame: int) -> list[int]:
    """Frame indices for the slider: evenly spread, the peak frame and the last included."""
    n = len(run.steps)
    k = int(max(1, min(MAX_FRAMES, n, FRAME_BUDGET // max(per_frame, 1))))
    ks = {int(round(x)) for x in np.linspace(0, n - 1, k)} if k > 1 else set()
    ks.add(int(peak_frame))
    while len(ks) > k:                       # the peak replaced one of the spread frames
        ks.remove(min((x for x in ks if x != peak_frame and x != n - 1),
                      key=lambda x: abs(x - peak_frame)))
    return sorted(ks)


def _rgb(values, vmax: float, cmap: str) -> np.ndarray:
    from rackstress.render.draw import colour_table

    s = np.clip(np.nan_to_num(np.asarray(values, float), nan=0.0) / vmax, 0.0, 1.0)
    table = colour_table(cmap)
    return np.round(table[np.round(s * 255).astype(int)] * 255).astype(np.uint8)


def _context_subset(q: np.ndarray, box_lo, box_hi) -> np.ndarray:
    """Indices of at most MAX_CONTEXT context particles, nearest the coloured parts' box."""
    if len(q) <= MAX_CONTEXT:
        return np.arange(len(q))
    d = np.linalg.norm(np.maximum(0.0, np.maximum(box_lo - q, q - box_hi)), axis=1)
    return np.sort(np.argsort(d, kind="stable")[:MAX_CONTEXT])


def _plain(cls):
    """``cls()`` as VTK defines it, not its OpenGL override: the render window here is only
    serialized (the viewer's own window draws it, whatever type it names), and the override's
    (EGL's, off-screen) opens its device as it is made: 13-30 ms of CPU. (The renderer then
    takes the camera's near-plane tolerance from no depth buffer: it is set.)"""
    from vtkmodules.vtkCommonCore import vtkObjectFactory

    name = cls.__name__
    vtkObjectFactory.SetAllEnableFlags(False, name)
    try:
        return cls()
    finally:
        vtkObjectFactory.SetAllEnableFlags(True, name)


def build_view(rundir, measure: str | None = None, cmap: str | None = None,
               vmax: float | None = None) -> dict:
    """Write ``RUNDIR/view3d.html`` (the peak frame in 3D, offline); return what it shows.

    The measure, colour map and colour scale are those of the default pictures
    (``figures/render.json``) when they exist, else the paper measure from 0 to its peak.

    Parameters
    ----------
    rundir : path
        A run directory with a trajectory (``rackstress run``).
    measure, cmap : str, optional
        Override the pictures' measure and colour map.
    vmax : float, optional
        Override the top of the colour scale (a render not yet moved in gives its own).

    Returns
    -------
    dict
        ``file``, ``bytes``, ``measure``, ``label``, ``vmax``, ``peak`` (value, iteration,
        particle, group), ``shown`` (coloured particles), ``context`` (shown, of), ``frames``
        (the slider's iterations), ``cmap``.

    Example
    -------
    >>> rec = build_view("runs/magpod-small")                     # doctest: +SKIP
    >>> rec["shown"], rec["context"], len(rec["frames"])          # doctest: +SKIP
    (3671, (2016, 2016), 40)
    """
    from rackstress.render.draw import offscreen, part_radius
    from rackstress.stress import load_run
    from rackstress.stress.post import compute_fields

    rundir = Path(rundir)
    manifest = {}
    try:
        manifest = json.loads((rundir / "figures" / "render.json").read_text())
    except (OSError, json.JSONDecodeError):
        pass
    from rackstress.stress.headline import is_static

    if is_static(rundir):
        return build_static_view(rundir, measure=measure, cmap=cmap, vmax=vmax,
                                 manifest=manifest)
    measure = measure or manifest.get("measure") or "paper"
    cmap = cmap or manifest.get("cmap") or "paper"
    run = load_run(rundir)
    fields = compute_fields(run, cache=True)
    values = fields.values[measure]
    coloured, context = run.displayed(), run.context()      # the pictures' default parts
    if not coloured:
        raise ValueError(f"{rundir}: no part to colour (every group is a rack or sediment)")
    peak = _peak(rundir, run, values, coloured, measure)
    if vmax is None:
        vmax = float(manifest.get("vmax") or 0.0) if manifest.get("measure") == measure else 0.0
    if not vmax > 0:
        vmax = peak["value"] if peak and peak["value"] > 0 else 1.0
    kpk = run.nearest_frames([peak["iteration"]])[0][1] if peak else len(run.steps) - 1
    p = _frame(run, kpk)

    offscreen()
    import vtkmodules.vtkRenderingOpenGL2  # noqa: F401 - registers the OpenGL classes
    from vtkmodules.vtkRenderingCore import (vtkActor, vtkGlyph3DMapper, vtkPolyDataMapper,
                                             vtkRenderer, vtkRenderWindow)

    ren = vtkRenderer()
    ren.SetBackground(1.0, 1.0, 1.0)
    rw = _plain(vtkRenderWindow)
    rw.AddRenderer(ren)
    keep = []                               # the VTK objects live until serialized

    def glyphs(q, radius, rgb=None, colour=None):
        mapper = vtkGlyph3DMapper()
        poly = _points(q, rgb)
        mapper.SetInputData(poly)
        mapper.SetSourceData(_sphere(radius))
        mapper.ScalingOff()
        mapper.OrientOff()
        if rgb is None:
            mapper.ScalarVisibilityOff()
        else:
            mapper.ScalarVisibilityOn()
            mapper.SetColorModeToDefault()
            mapper.SetScalarModeToUsePointData()
        actor = vtkActor()
        actor.SetMapper(mapper)
        if colour is not None:
            actor.GetProperty().SetColor(*colour)
        ren.AddActor(actor)
        keep.extend([mapper, poly, actor])
        return actor

    parts = []
    for part in coloured:
        glyphs(p[part.index], part_radius(run, part), _rgb(values[kpk, part.index], vmax, cmap))
        parts.append(part)
    allq = np.concatenate([p[q.index] for q in coloured])
    lo, hi = allq.min(axis=0), allq.max(axis=0)
    ctx_total = ctx_shown = 0
    for part in context:
        q = p[part.index]
        sub = _context_subset(q, lo, hi)
        ctx_total += len(q)
        ctx_shown += len(sub)
        glyphs(q[sub], part_radius(run, part), colour=SAND)
    marker_r = 3.0 * max(part_radius(run, q) for q in coloured)
    pin = 0.6 * float(np.max(hi - lo)) + marker_r
    if peak:
        m = vtkPolyDataMapper()
        m.SetInputData(_marker(marker_r, pin))
        m.ScalarVisibilityOff()
        marker = vtkActor()
        marker.SetMapper(m)
        pr = marker.GetProperty()
        pr.SetRepresentationToWireframe()
        pr.SetColor(*MARKER_RGB)
        pr.SetLighting(False)
        marker.SetPosition(*map(float, p[peak["row"]]))
        ren.AddActor(marker)
        keep.extend([m, marker])
    cam = ren.GetActiveCamera()
    centre = 0.5 * (lo + hi)
    size = float(np.linalg.norm(hi - lo)) or 1.0
    cam.SetFocalPoint(*map(float, centre))
    cam.SetPosition(*map(float, centre + _view_direction(centre, p[peak["row"]] if peak else None)
                         * 2.0 * size))
    cam.SetViewUp(0.0, 1.0, 0.0)
    ren.SetNearClippingPlaneTolerance(0.001)    # what VTK takes for a 24-bit depth buffer
    ren.ResetCameraClippingRange()

    buf = _serialized(rw, cam)

    # the slider's frames: positions (float32) and colours (uint8) of the coloured parts
    n_col = sum(q.n for q in parts)
    ks = _frames(run, kpk, n_col * 15)
    frames = []
    for k in ks:
        pk = _frame(run, k)
        pos = np.concatenate([pk[q.index] for q in parts]).astype(np.float32)
        rgb = np.concatenate([_rgb(values[k, q.index], vmax, cmap) for q in parts])
        frames.append({"iteration": int(run.steps[k]), "peak": k == kpk,
                       "pos": base64.b64encode(pos.tobytes()).decode(),
                       "rgb": base64.b64encode(rgb.tobytes()).decode(),
                       "marker": [float(x) for x in pk[peak["row"]]] if peak else None})
    label = fields.label(measure)
    stops = _rgb(np.linspace(0.0, vmax, 9), vmax, cmap)
    info = {"parts": [q.n for q in parts], "frames": frames,
            "peak_frame": ks.index(kpk), "label": label, "vmax": f"{vmax:.4g}",
            "gradient": ", ".join("#%02x%02x%02x" % tuple(int(c) for c in rgb) for rgb in stops),
            "note": f"{label}; blue: the peak particle"}
    rec = {"file": VIEW, "measure": measure, "label": label, "vmax": vmax, "cmap": cmap,
           "peak": {k: peak[k] for k in ("value", "iteration", "particle", "group")}
           if peak else None,
           "shown": n_col, "context": (ctx_shown, ctx_total),
           "frames": [f["iteration"] for f in frames], "marker_radius": marker_r}
    _write(rundir / VIEW, buf, info, rec)
    rec["bytes"] = (rundir / VIEW).stat().st_size
    return rec


def _serialized(rw, cam) -> bytes:
    """The render window as trame-vtk's offline viewer loads it: its scene and arrays, zipped;
    the window finalized."""
    from trame_vtk.modules.vtk.serializers import (SynchronizationContext, extract_array_hash,
                                                   initialize_serializers, reference_id,
                                                   serialize)
    from trame_vtk.modules.vtk.serializers.registry import register_instance_serializer

    initialize_serializers()
    register_instance_serializer("vtkGlyph3DMapper", _glyph_serializer)
    register_instance_serializer("vtkOpenGLGlyph3DMapper", _glyph_serializer)
    ctx = SynchronizationContext()
    scene = serialize(None, rw, "rackstress-view", ctx, 1)
    scene["extra"] = {"vtkRefId": reference_id(rw), "centerOfRotation": cam.GetFocalPoint(),
                      "camera": reference_id(cam)}
    hashes = {e["hash"]: {**e, "content": ctx.get_cached_data_array(e["hash"], False)}
              for e in extract_array_hash(scene)}
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("index.json", json.dumps({"hashes": hashes, "scene": scene}),
                    compress_type=zipfile.ZIP_DEFLATED)
    rw.Finalize()
    return buf.getvalue()


def _surface_poly(points: np.ndarray, faces: np.ndarray, rgb: np.ndarray | None = None):
    """A triangle surface (float32 points) with optional uint8 RGB point colours."""
    from vtkmodules.util.numpy_support import numpy_to_vtk

    from rackstress.render.static import _poly

    poly = _poly(np.asarray(points, np.float32).astype(np.float64), faces)
    if rgb is not None:
        arr = numpy_to_vtk(np.ascontiguousarray(rgb, dtype=np.uint8), deep=True)
        arr.SetName("rgb")
        poly.GetPointData().SetScalars(arr)
    return poly


#: a static view's surfaces beyond this many triangles are decimated for the page
MAX_TRIANGLES = 150_000


def build_static_view(rundir, measure: str | None = None, cmap: str | None = None,
                      vmax: float | None = None, manifest: dict | None = None) -> dict:
    """``RUNDIR/view3d.html`` of a static run: the part's surface, deformed by the pictures'
    magnification and coloured by their measure and scale (:mod:`rackstress.render.static`);
    the undeformed shape as a faint ghost with its sharp edges; the particles (hidden until
    asked: a check box) at the same magnification; the headline's point marked. Returns what
    it shows, as :func:`build_view` (``frames`` holds the equilibrium's iteration only).
    """
    from rackstress.render.draw import offscreen, part_radius
    from rackstress.render.static import magnification, surface_rgb
    from rackstress.stress.headline import headline
    from rackstress.stress import load_run
    from rackstress.stress.post import compute_fields
    from rackstress.stress.surface import interpolate, surfaces_for

    rundir = Path(rundir)
    manifest = manifest or {}
    run = load_run(rundir)
    fields = compute_fields(run, cache=True)
    measure = measure or manifest.get("measure") or fields.default
    cmap = cmap or manifest.get("cmap") or "paper"
    values = fields.values[measure]
    coloured = run.displayed() or list(run.parts.values())
    k = len(run.steps) - 1
    o = run.o
    p = _frame(run, k)
    p = np.where(np.isfinite(p), p, o)          # a state that did not settle may hold anything
    try:
        summary = json.loads((rundir / "summary.json").read_text())
    except (OSError, json.JSONDecodeError):
        summary = {}
    head = headline(summary, run.scene) if measure == fields.default else None
    surfaces = [s for s in surfaces_for(run, fields) if s.group in {q.name for q in coloured}]
    idx = np.concatenate([q.index for q in coloured])
    if vmax is None:
        vmax = float(manifest.get("vmax") or 0.0) if manifest.get("measure") == measure else 0.0
    if not vmax > 0:
        vmax = float(head["value"]) if head and head.get("value") else float(
            np.nanmax(values[k, idx]) if np.isfinite(values[k, idx]).any() else 1.0)
    if not vmax > 0:
        vmax = 1.0
    scale = manifest.get("magnification") if manifest.get("static") else None
    allpts = np.concatenate([s.points for s in surfaces]) if surfaces else o[idx]
    size = float(np.max(allpts.max(axis=0) - allpts.min(axis=0))) or 1.0
    if scale is None:
        umax = float(np.linalg.norm(p[idx] - o[idx], axis=1).max())
        scale = magnification(umax, size)
        scale = 0.0 if scale * umax > size else scale   # come apart: drawn undeformed
    scale = float(scale)

    offscreen()
    import vtkmodules.vtkRenderingOpenGL2  # noqa: F401 - registers the OpenGL classes
    from vtkmodules.vtkFiltersCore import vtkDecimatePro, vtkFeatureEdges, vtkPolyDataNormals
    from vtkmodules.vtkRenderingCore import (vtkActor, vtkGlyph3DMapper, vtkPolyDataMapper,
                                             vtkRenderer, vtkRenderWindow)

    ren = vtkRenderer()
    ren.SetBackground(1.0, 1.0, 1.0)
    rw = _plain(vtkRenderWindow)
    rw.AddRenderer(ren)
    keep = []
    roles = {"surface": [], "undeformed": [], "particles": [], "marker": []}

    def add(mapper, role, colour=None, opacity=1.0, lines=False):
        actor = vtkActor()
        actor.SetMapper(mapper)
        prop = actor.GetProperty()
        if colour is not None:
            prop.SetColor(*colour)
        prop.SetOpacity(opacity)
        if lines:
            prop.SetLighting(False)
            prop.SetLineWidth(1.5)
        ren.AddActor(actor)
        roles[role].append(ren.GetActors().GetNumberOfItems() - 1)
        keep.extend([mapper, actor])

    shown_tri = 0
    for s in surfaces:
        pts, faces = s.points, s.faces
        if len(faces) > MAX_TRIANGLES:          # the page's size: the pictures keep them all
            # vtkDecimatePro, its topology kept: vtkQuadricDecimation's time grew as the square
            # of the triangles on flat and thin parts (a public 1.2 mm slot cover's 481,779:
            # 20 s at 60,000 and 73 s at 120,000, the whole not done in 10 min; 2.5 s here)
            dec = vtkDecimatePro()
            dec.SetInputData(_surface_poly(pts, faces))
            dec.SetTargetReduction(1.0 - MAX_TRIANGLES / len(faces))
            dec.PreserveTopologyOn()
            dec.Update()
            from vtkmodules.util.numpy_support import vtk_to_numpy

            out = dec.GetOutput()
            pts = vtk_to_numpy(out.GetPoints().GetData()).astype(np.float64)
            faces = vtk_to_numpy(out.GetPolys().GetConnectivityArray()).reshape(-1, 3)
            part = run.parts[s.group]
            vals = interpolate(o[part.index], np.column_stack(
                [p[part.index] - o[part.index],
                 np.nan_to_num(values[k, part.index])]), pts, s.spacing)
            disp, col = vals[:, :3], np.maximum(vals[:, 3], 0.0)
        else:
            disp = np.nan_to_num(s.values["displacement"], nan=0.0, posinf=0.0, neginf=0.0)
            col = s.values.get(measure)
            if col is None:
                part = run.parts[s.group]
                col = interpolate(o[part.index], np.nan_to_num(values[k, part.index]), pts,
                                  s.spacing)
        shown_tri += len(faces)
        normals = vtkPolyDataNormals()      # smooth shading, sharp edges kept (split at 40°)
        normals.SetInputData(_surface_poly(pts + scale * disp, faces,
                                           surface_rgb(col, vmax, cmap)))
        normals.SetFeatureAngle(40.0)
        normals.SplittingOn()
        normals.Update()
        keep.append(normals)
        m = vtkPolyDataMapper()
        m.SetInputData(normals.GetOutput())
        m.ScalarVisibilityOn()
        m.SetColorModeToDefault()
        m.SetScalarModeToUsePointData()
        add(m, "surface")
        ghost = _surface_poly(*(s.shape or (pts, faces)))
        m = vtkPolyDataMapper()
        m.SetInputData(ghost)
        m.ScalarVisibilityOff()
        add(m, "undeformed", (0.55, 0.55, 0.55), 0.18)
        edges = vtkFeatureEdges()
        edges.SetInputData(ghost)
        edges.BoundaryEdgesOn()
        edges.FeatureEdgesOn()
        edges.SetFeatureAngle(60.0)
        edges.NonManifoldEdgesOff()
        edges.ManifoldEdgesOff()
        edges.ColoringOff()
        edges.Update()
        if edges.GetOutput().GetNumberOfPoints():       # a smooth lattice surface has none
            m = vtkPolyDataMapper()
            m.SetInputData(edges.GetOutput())
            m.ScalarVisibilityOff()
            add(m, "undeformed", (0.2, 0.2, 0.2), 1.0, lines=True)
        keep.extend([ghost, edges])
    shown = o.copy()
    shown[idx] = o[idx] + scale * (p[idx] - o[idx])
    for part in coloured:
        mapper = vtkGlyph3DMapper()
        poly = _points(shown[part.index], _rgb(values[k, part.index], vmax, cmap))
        mapper.SetInputData(poly)
        mapper.SetSourceData(_sphere(part_radius(run, part)))
        mapper.ScalingOff()
        mapper.OrientOff()
        mapper.ScalarVisibilityOn()
        mapper.SetColorModeToDefault()
        mapper.SetScalarModeToUsePointData()
        add(mapper, "particles")
        keep.append(poly)
    lo, hi = allpts.min(axis=0), allpts.max(axis=0)
    marker_r = 3.0 * max(part_radius(run, q) for q in coloured)
    where = None
    if head and head.get("particle") is not None and summary.get("settled") is not False:
        row = int(np.searchsorted(run.data.ids, int(head["particle"])))
        if row < run.n_atoms and run.data.ids[row] == int(head["particle"]):
            where = shown[row]
    if where is not None:
        m = vtkPolyDataMapper()
        m.SetInputData(_marker(marker_r, 0.25 * float(np.max(hi - lo)) + marker_r))
        m.ScalarVisibilityOff()
        marker = vtkActor()
        marker.SetMapper(m)
        pr = marker.GetProperty()
        pr.SetRepresentationToWireframe()
        pr.SetColor(*MARKER_RGB)
        pr.SetLighting(False)
        marker.SetPosition(*map(float, where))
        ren.AddActor(marker)
        roles["marker"].append(ren.GetActors().GetNumberOfItems() - 1)
        keep.extend([m, marker])
    cam = ren.GetActiveCamera()
    centre = 0.5 * (lo + hi)
    cam.SetFocalPoint(*map(float, centre))
    # from the iso side, as the pictures' first view (from the headline's side, the view ran
    # along the cantilever from its clamp)
    cam.SetPosition(*map(float, centre + _view_direction(centre, None)
                         * 2.0 * (float(np.linalg.norm(hi - lo)) or 1.0)))
    cam.SetViewUp(0.0, 1.0, 0.0)
    ren.SetNearClippingPlaneTolerance(0.001)
    ren.ResetCameraClippingRange()
    data = _serialized(rw, cam)
    label = fields.label(measure)
    stops = _rgb(np.linspace(0.0, vmax, 9), vmax, cmap)
    settled = summary.get("settled", True) is not False
    info = {"roles": roles, "label": label, "vmax": f"{vmax:.4g}",
            "gradient": ", ".join("#%02x%02x%02x" % tuple(int(c) for c in rgb) for rgb in stops),
            "scale": scale, "settled": settled,
            "note": (f"deformed × {scale:g}; grey: undeformed" if scale > 1 else
                     "deformation to scale; grey: undeformed" if scale == 1 else
                     "drawn undeformed (the displacements exceed the part's size)")
            + ("; NOT SETTLED: do not use these numbers" if not settled else
               "; blue: the headline's point" if where is not None else "")}
    rec = {"file": VIEW, "static": True, "measure": measure, "label": label, "vmax": vmax,
           "cmap": cmap, "magnification": scale, "settled": settled,
           "peak": {k_: head[k_] for k_ in ("value", "particle", "group", "position")}
           if head else None,
           "shown": int(len(idx)), "context": (0, 0), "triangles": int(shown_tri),
           "frames": [int(run.steps[k])], "marker_radius": marker_r}
    _write(rundir / VIEW, data, info, rec, STATIC_CONTROLS)
    rec["bytes"] = (rundir / VIEW).stat().st_size
    return rec


STATIC_CONTROLS = r"""
<div id="rs-controls" style="position:fixed;left:0;right:0;bottom:0;z-index:10;background:
rgba(255,255,255,.9);font:13px DejaVu Sans,Helvetica,Arial,sans-serif;padding:6px 10px;
border-top:1px solid #ccc">
<label><input type="checkbox" id="rs-surface" checked> surface</label>
<label><input type="checkbox" id="rs-undeformed" checked> undeformed</label>
<label><input type="checkbox" id="rs-particles"> particles</label>
<span id="rs-scale" style="white-space:nowrap;margin-left:1em">0 <span id="rs-bar"
style="display:inline-block;width:120px;height:10px;vertical-align:middle;border:1px solid
#999"></span> <span id="rs-vmax"></span></span> <span id="rs-note"></span></div>
<script>
(function () {
  const info = JSON.parse(document.getElementById("rs-frames").textContent);
  function actors() {
    const rw = window.global && window.global.renderWindow;
    if (!rw) return null;
    const a = rw.getRenderers().map(function (r) { return r.getActors(); })
      .reduce(function (x, y) { return y.length > x.length ? y : x; }, []);
    let n = 0;
    Object.keys(info.roles).forEach(function (k) { n += info.roles[k].length; });
    if (a.length < n) return null;
    // the scene's arrays arrive after it, and with them its own visibility: wait for them
    for (const role of ["surface", "undeformed", "particles"]) {
      for (const i of info.roles[role]) {
        const m = a[i].getMapper(), pd = m && m.getInputData(0);
        if (!pd || !pd.getPoints() || pd.getPoints().getNumberOfPoints() === 0) return null;
      }
    }
    return [rw, a];
  }
  function apply() {
    const got = actors();
    if (!got) return false;
    const rw = got[0], a = got[1];
    ["surface", "undeformed", "particles"].forEach(function (role) {
      const on = document.getElementById("rs-" + role).checked;
      info.roles[role].forEach(function (i) { a[i].setVisibility(on); });
    });
    rw.render();
    return true;
  }
  ["surface", "undeformed", "particles"].forEach(function (role) {
    document.getElementById("rs-" + role).addEventListener("change", apply);
  });
  // view3d.html#particles: the particles, not the skin; #show=surface,undeformed: those only
  const want = /show=([a-z,]*)/.exec(location.hash) ||
    (/particles/.test(location.hash) ? [null, "particles,undeformed"] : null);
  if (want) {
    const on = want[1].split(",");
    ["surface", "undeformed", "particles"].forEach(function (role) {
      document.getElementById("rs-" + role).checked = on.indexOf(role) >= 0;
    });
  }
  (function retry() { if (!apply()) setTimeout(retry, 100); })();
  document.getElementById("rs-note").textContent = info.note;
  if (!info.settled) document.getElementById("rs-note").style.color = "#b00";
  document.getElementById("rs-vmax").textContent = info.vmax + " " + info.label;
  document.getElementById("rs-bar").style.background =
    "linear-gradient(to right, " + info.gradient + ")";
})();
</script>
"""


CONTROLS = r"""
<div id="rs-controls" style="position:fixed;left:0;right:0;bottom:0;z-index:10;background:
rgba(255,255,255,.9);font:13px DejaVu Sans,Helvetica,Arial,sans-serif;padding:6px 10px;
border-top:1px solid #ccc">
<label for="rs-frame">iteration <b id="rs-iteration"></b></label>
<input id="rs-frame" type="range" min="0" step="1" style="width:40%;vertical-align:middle">
<span id="rs-scale" style="white-space:nowrap">0 <span id="rs-bar" style="display:inline-block;
width:120px;height:10px;vertical-align:middle;border:1px solid #999"></span>
<span id="rs-vmax"></span></span> <span id="rs-note"></span></div>
<script>
(function () {
  const info = JSON.parse(document.getElementById("rs-frames").textContent);
  const slider = document.getElementById("rs-frame");
  slider.max = info.frames.length - 1;
  slider.value = info.peak_frame;
  function bytes(b64) {
    const s = atob(b64), out = new Uint8Array(s.length);
    for (let i = 0; i < s.length; i++) out[i] = s.charCodeAt(i);
    return out;
  }
  function show(i) {
    const f = info.frames[i];
    document.getElementById("rs-iteration").textContent = f.iteration + (f.peak ? " (peak)" : "");
    const rw = window.global && window.global.renderWindow;
    if (!rw) return false;
    // the synchronized window has a renderer of its own besides the scene's
    const actors = rw.getRenderers().map(function (r) { return r.getActors(); })
      .reduce(function (a, b) { return b.length > a.length ? b : a; }, []);
    if (actors.length < info.parts.length + 1) return false;
    for (let j = 0; j < info.parts.length; j++) {      // the scene's arrays arrive after it
      const pd = actors[j].getMapper() && actors[j].getMapper().getInputData(0);
      if (!pd || !pd.getPoints() || pd.getPoints().getNumberOfPoints() !== info.parts[j]
          || !pd.getPointData().getScalars()) return false;
    }
    const pos = new Float32Array(bytes(f.pos).buffer), rgb = bytes(f.rgb);
    let off = 0;
    info.parts.forEach(function (n, j) {
      const pd = actors[j].getMapper().getInputData(0);
      pd.getPoints().setData(pos.slice(3 * off, 3 * (off + n)), 3);
      pd.getPointData().getScalars().setData(rgb.slice(3 * off, 3 * (off + n)), 3);
      pd.getPoints().modified(); pd.getPointData().getScalars().modified(); pd.modified();
      off += n;
    });
    if (f.marker) actors[actors.length - 1].setPosition(f.marker[0], f.marker[1], f.marker[2]);
    rw.render();
    return true;
  }
  slider.addEventListener("input", function () { show(+slider.value); });
  const m = /frame=(\d+)/.exec(location.hash);
  if (m) {                      // view3d.html#frame=K opens on the slider's frame K
    slider.value = Math.min(+m[1], info.frames.length - 1);
    (function retry() { if (!show(+slider.value)) setTimeout(retry, 100); })();
  }
  document.getElementById("rs-iteration").textContent =
    info.frames[info.peak_frame].iteration + " (peak)";
  document.getElementById("rs-note").textContent = info.note;
  document.getElementById("rs-vmax").textContent = info.vmax;
  document.getElementById("rs-bar").style.background =
    "linear-gradient(to right, " + info.gradient + ")";
})();
</script>
"""


def _write(path: Path, data: bytes, info: dict, rec: dict, controls: str | None = None) -> None:
    """The viewer page with the scene and the slider's frames (a static view: which actors
    are which) inlined; written atomically."""
    b64 = base64.b64encode(data).decode()
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    with open(_viewer_html(), encoding="utf-8") as src, open(tmp, "w", encoding="utf-8") as out:
        for line in src:
            if "<title>" in line:
                line = f"    <title>rackstress 3D view: {rec['label']}</title>\n"
            if "</body>" in line:
                out.write('<div class="content" style="position:absolute;left:0;right:0;'
                          'top:0;bottom:34px"></div>\n')
                out.write('<script type="application/json" id="rs-frames">')
                out.write(json.dumps(info).replace("</", "<\\/"))
                out.write("</script>\n")
                out.write(controls or CONTROLS)
                out.write("<script>\nfunction loadDataSet() {\n"
                          "  const container = document.querySelector('.content') || "
                          "document.querySelector('body');\n"
                          f'  const base64Str = "{b64}";\n'
                          "  OfflineLocalView.load(container, { base64Str });\n}\n</script>\n")
            out.write(line)
    os.replace(tmp, path)


def section(rundir, built: dict | None = None) -> str:
    """``report.html``'s 3D section: the view in an ``<iframe>`` and what it shows (or why
    there is none). Builds ``view3d.html`` first, unless ``built`` holds what
    :func:`build_view` returned (``{"rec": ...}``) or raised (``{"error": ...}``)."""
    import html

    def e(x):
        return html.escape(str(x), quote=True)

    from rackstress.stress.headline import is_static

    static = is_static(rundir)
    out = ['<h2 id="view3d">' + ("The part in 3D" if static else "The peak frame in 3D")
           + "</h2>"]
    try:
        if built and "error" in built:
            raise built["error"]
        rec = built["rec"] if built and "rec" in built else build_view(rundir)
    except Exception as exc:  # noqa: BLE001 - the report shows everything else
        out.append(f'<p class="note" id="view3d-missing">No 3D view: {e(type(exc).__name__)}: '
                   f"{e(exc)}</p>")
        return "\n".join(out)
    if rec.get("static"):
        pk = rec["peak"]
        mag = rec["magnification"]
        out.append(
            f'<iframe id="view3d-frame" src="{e(rec["file"])}" title="3D view of the part" '
            'style="width:100%;height:620px;border:1px solid #ddd"></iframe>')
        out.append(
            f'<p class="note" id="view3d-what" data-shown="{rec["shown"]}" '
            f'data-triangles="{rec["triangles"]}" data-magnification="{mag:g}" '
            f'data-bytes="{rec["bytes"]}">'
            f"Shown: the part's surface ({rec['triangles']:,} triangles), coloured by "
            f"{e(rec['label'])} from 0 to {rec['vmax']:.4g} (the pictures' scale) and "
            + (f"deformed × {mag:g} (the pictures' magnification)" if mag > 1 else
               "deformed to scale" if mag == 1 else
               "undeformed (the displacements exceed the part's size)")
            + "; the undeformed shape as a faint grey ghost with its edges. The check boxes "
            f"below it show the particles ({rec['shown']:,}, each coloured by its own value, at "
            "the same magnification) or hide the surface. "
            + (f"The blue wire sphere and pin mark particle {pk['particle']} "
               f"({e(pk['group'])}, {pk['value']:.4g}), the headline's. "
               if pk and rec.get("settled", True) else
               "NOT SETTLED: the state shown is not an equilibrium. "
               if not rec.get("settled", True) else "")
            + "Drag to rotate, wheel to zoom, shift-drag to pan. "
            f'<a href="{e(rec["file"])}">Open it alone</a> ({rec["bytes"] / 1e6:.1f} MB, '
            "vtk.js, works offline).</p>")
        return "\n".join(out)
    pk = rec["peak"]
    shown, total = rec["context"]
    ctx = (f"; context (sediment): {shown:,} of its {total:,} particles, plain sand spheres"
           + (" — those nearest the coloured parts" if shown < total else "")
           + ", at the peak frame") if total else ""
    out.append(
        f'<iframe id="view3d-frame" src="{e(rec["file"])}" title="3D view of the peak frame" '
        'style="width:100%;height:620px;border:1px solid #ddd"></iframe>')
    out.append(
        f'<p class="note" id="view3d-what" data-shown="{rec["shown"]}" '
        f'data-context="{shown}" data-context-total="{total}" '
        f'data-frames="{len(rec["frames"])}" data-bytes="{rec["bytes"]}">'
        f"Shown: every particle of the coloured parts ({rec['shown']:,}) as a sphere coloured by "
        f"{e(rec['label'])} from 0 to {rec['vmax']:.4g} (the pictures' scale, opaque){e(ctx)}. "
        + (f"The blue wire sphere and pin mark the peak particle {pk['particle']} "
           f"({e(pk['group'])}, {pk['value']:.4g} at iteration {pk['iteration']}). "
           if pk else "")
        + f"The slider moves the coloured parts through {len(rec['frames'])} of the dumped frames "
        f"(iterations {rec['frames'][0]}–{rec['frames'][-1]}, the peak's included). Drag to "
        "rotate, wheel to zoom, shift-drag to pan. "
        f'<a href="{e(rec["file"])}">Open it alone</a> ({rec["bytes"] / 1e6:.1f} MB, vtk.js, '
        "works offline).</p>")
    return "\n".join(out)

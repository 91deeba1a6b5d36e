"""The stress field of a run as files other programs open: a VTK time series and a LAMMPS dump.

``RUNDIR/vtk/run.pvd``
    A ParaView collection (PVD) of one VTK XML PolyData file a dumped frame
    (``vtk/frame_ITERATION.vtp``, each particle a vertex), with the iteration as the time value,
    so ParaView's time slider, pyvista (``pv.get_reader``) and OVITO step through the run. Point
    data, per particle: ``id`` (LAMMPS atom id), ``group_id`` (0-based, the order of
    ``scene.json``), ``group_NAME`` (1 on the particles of group NAME, 0 elsewhere: the names as
    OVITO can read them, which takes no string arrays), ``type``, ``mol``, ``radius``,
    ``original`` (o),
    ``displacement`` (p − o) and its magnitude ``displacement_magnitude``, ``velocity`` where the
    dump holds vx vy vz (geometry in float32), and every measure by its name (``paper``,
    ``accumulated``, ``strain``, ``d2min``, ``virial`` if recorded, any measure
    :func:`rackstress.stress.post.compute_fields` adds; for a scene with a material
    ``von_mises`` in its stress unit, ``stress`` (6 components xx yy zz xy yz xz, ParaView's
    symmetric-tensor order), ``principal`` (3, largest first), ``safety`` and ``bind_strain``)
    in float64 — the very numbers of ``summary.json``'s peaks. ``displacement`` is in the
    scene's length unit. No field data: the iteration is the PVD's time value.
    ``rackstress run`` writes the leading measure only (``paper``; ``von_mises`` for a scene
    with a material) beside ``displacement`` (``measures="default"``); ``rackstress stress
    RUNDIR`` writes every one (magpod-small: 14.8 MB against 25.5 MB).
    The particles of a sediment that never move and whose every array is the same in every
    frame are written once, ``vtk/rest.vtp``, listed as the PVD's ``part="1"`` at every
    time beside the frame (``part="0"``), which then holds the others: ParaView and pyvista read
    each time as a two-block dataset (:func:`resting`; the ``ovito`` variant keeps every
    particle in every frame).
    Two variants (``fmt``): ``"paraview"`` (the default) stores each array raw in the file's
    appended section, zlib-compressed, which ParaView and pyvista (VTK's XML readers) read: the
    arrays that do not change (ids, groups, radii, original positions) and the resting particles
    cost next to nothing, a quarter of the uncompressed size on magpod-small (written by
    :class:`_Vtp` as VTK's writer lays out its appended data, each block's zlib stream deflated
    by ISA-L, the arrays that do not change compressed once for every frame). ``"ovito"`` writes
    them inline, base64, uncompressed: OVITO 3.17 reads neither VTK's appended data nor
    compressed arrays (checked with the ``ovito`` Python module: "The parser does not support
    compressed data arrays"); ``rackstress stress RUNDIR --vtk-format ovito``.
``RUNDIR/stress.dump``
    A LAMMPS ``dump custom`` text file, OVITO's native input: ``id type mol x y z radius
    [vx vy vz] group dx dy dz paper accumulated strain d2min [virial]``; OVITO maps ``radius`` to
    the particle radius and keeps the others as named properties. An undefined value (e.g. the
    strain of a particle with no neighbours) is written ``nan``.

Both are written into a temporary name and renamed when complete: a reader never sees half.

Radii: the groups' ``radius`` in ``scene.json`` if recorded, else a built-in scene is rebuilt from
``scene.json`` to take its radii; if neither is possible (a TOML scene, a plain LAMMPS run) the data
file's diameter column is used, else half the part's median nearest-neighbour distance (touching
spheres).
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from rackstress.errors import StorageError, storage_error
from rackstress.lib.runfiles import PVD
from rackstress.engines.dumpio import frame_text
from rackstress.stress.measures import positions

FLOAT = "%.10g"


def radii(run) -> np.ndarray:
    """Radius of every particle (id order); see the module docstring for where it comes from."""
    r = getattr(run, "radii", None)
    if r is not None:
        return np.asarray(r, dtype=np.float64)
    r = _scene_radii(run)
    if r is None:
        r = np.empty(run.n_atoms)
        for part in run.parts.values():
            r[part.index] = _touching_radius(run.o[part.index])
    run.radii = r
    return r


def _scene_radii(run):
    scene = run.scene or {}
    groups = scene.get("groups") or []
    if groups and all("radius" in g for g in groups):          # recorded in scene.json
        out = np.empty(run.n_atoms)
        for g in groups:
            part = run.parts.get(g["name"])
            if part is None:
                return None
            out[part.index] = np.broadcast_to(np.asarray(g["radius"], float), (part.n,))
        return out
    name, params = scene.get("scene"), scene.get("params") or {}
    try:
        from rackstress import scenes

        if name not in scenes.BUILDERS:
            return None
        known = scenes.parameters(name)
        sc = scenes.build(name, **{k: v for k, v in params.items() if k in known})
        out = np.empty(run.n_atoms)
        for gname, part in run.parts.items():
            g = sc.groups.get(gname)
            if g is None or g.n != part.n:
                return None
            out[part.index] = g.r
        return out
    except Exception:  # noqa: BLE001 - a scene that cannot be rebuilt: estimate instead
        return None


def _touching_radius(o: np.ndarray) -> float:
    if len(o) < 2:
        return 0.5
    from scipy.spatial import cKDTree

    d = cKDTree(o).query(o, k=2)[0][:, 1]
    return 0.5 * float(np.median(d)) or 0.5


def group_ids(run) -> tuple[np.ndarray, list]:
    """(0-based group id of every particle, group names in order)."""
    gid = np.zeros(run.n_atoms, dtype=np.int32)
    names = list(run.parts)
    for k, part in enumerate(run.parts.values()):
        gid[part.index] = k
    return gid, names


def _velocity(ts):
    if all(c in ts.data for c in ("vx", "vy", "vz")):
        return np.column_stack([ts.data["vx"], ts.data["vy"], ts.data["vz"]])
    return None


def _swap_in(tmp: Path, final: Path) -> None:
    old = final.with_name(f".{final.name}.old{os.getpid()}")
    if final.exists():
        os.replace(final, old)
    os.replace(tmp, final)
    if old.exists():
        shutil.rmtree(old, ignore_errors=True) if old.is_dir() else old.unlink()


# ----------------------------------------------------------------------------- VTK
def frame_name(step: int) -> str:
    return f"frame_{int(step):07d}.vtp"


#: the VTK variants (module docstring)
VTK_FORMATS = ("paraview", "ovito")
#: which measures a frame carries: every one (``rackstress stress``), or the leading one
#: (:attr:`~rackstress.stress.post.Fields.default`: ``paper``, ``von_mises`` with a material)
#: beside ``displacement`` (``rackstress run``: magpod-small's series 16 MB, not 27 MB)
MEASURES = ("all", "default")


#: the particles that never move nor change in any array, written once (module docstring)
REST = "rest.vtp"


def resting(run, fields, chosen: dict) -> np.ndarray:
    """Which particles (id order) of a resting group (kind ``sediment``: what the dump leaves
    out) sit at their original position in every frame, with every array of ``chosen``
    (measure → (frames, particles[, k])) the same in every frame: their frame-0 values are then
    theirs at every time, exactly (NaN equal to NaN). A scene without one keeps one dataset a
    frame."""
    still = np.zeros(run.n_atoms, bool)
    for part in run.parts.values():
        if part.kind == "sediment":
            still[part.index] = True
    if not still.any():
        return still
    o = run.o
    for k in range(len(fields.steps)):
        ts = run.trajectory[k]
        still &= (positions(ts) == o).all(axis=1)
        v = _velocity(ts)
        if v is not None:
            still &= (v == 0).all(axis=1)
    for vals in chosen.values():
        cols = getattr(vals, "cols", None)      # measures.Columns: only ``cols`` vary
        if cols is None:
            a = vals.reshape(len(vals), run.n_atoms, -1)
        else:
            a = vals.data.reshape(len(vals), len(cols), 1)
        same = ((a == a[:1]) | (np.isnan(a) & np.isnan(a[:1]))).all(axis=(0, 2))
        if cols is not None:
            whole = np.ones(run.n_atoms, bool)
            whole[cols] = same
            same = whole
        still &= same
    return still


def _int32(a):
    """A ``vtkTypeInt32Array`` of ``a`` (a vertex cell array's offsets or connectivity)."""
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkCommonCore import vtkTypeInt32Array

    v = vtkTypeInt32Array()
    v.SetNumberOfTuples(len(a))
    vtk_to_numpy(v)[:] = a
    return v


#: VTK's XML type names of the arrays a frame holds
_VTK_TYPES = {"int32": "Int32", "int64": "Int64", "float32": "Float32", "float64": "Float64",
              "uint8": "UInt8"}


class _Vtp:
    """VTK XML PolyData files (``.vtp``) of vertex clouds, written as VTK's own writer writes
    the ``paraview`` variant (``vtkXMLPolyDataWriter``, appended raw data, UInt32 headers,
    zlib streams in 32 KiB blocks: the same XML elements, arrays and layout; only its optional
    RangeMin/RangeMax hints are left out), in NumPy. The arrays that do not change from frame
    to frame (ids, groups, radii, original positions, the cells) are compressed once for all
    the frames: a third of VTK's time a frame on magpod-small, and no VTK to import.

    ``deflate``: what makes each block's zlib stream. ``"isal"`` (the default): ISA-L
    (python-isal's ``isal_zlib``) at ``level`` (0-3), a standard zlib stream VTK's reader
    inflates as any other; an array compressed once takes, block by block, the smaller of
    ISA-L's stream and zlib's level-1 one (zlib's is a third smaller on the ids' and cells'
    counting sequences, which every frame repeats). ``"zlib"``: Python's zlib at ``level``,
    byte for byte the compressed bytes of VTK's writer. Level 1 by measure: magpod-small,
    ``rackstress run``'s series (102 frames, 13.2 MB of arrays), CPU of the blocks alone (11
    passes interleaved, load 1.1): zlib 1 0.19 s, 11.54 MB; ISA-L 0 0.021 s, 15.11 MB; ISA-L
    1 0.021 s, 11.56 MB; ISA-L 2 0.021 s, 11.56 MB; ISA-L 3 0.034 s, 11.52 MB."""

    BLOCK = 32768
    DEFLATE = ("isal", "zlib")

    def __init__(self, level: int = 1, deflate: str = "isal"):
        if deflate not in self.DEFLATE:
            raise ValueError(f"unknown deflate '{deflate}'; choose one of "
                             f"{', '.join(self.DEFLATE)}")
        self.level, self.deflate = level, deflate

    def blob(self, a: np.ndarray, once: bool = False) -> tuple[str, int, bytes]:
        """(VTK type, components, VTK's compressed bytes: a header of UInt32 block count,
        block size, last block's size and each block's compressed size, then the blocks).
        ``once``: an array written in every frame but compressed once (class docstring)."""
        import zlib

        a = np.ascontiguousarray(a)
        kind = _VTK_TYPES[a.dtype.name]
        raw = a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes()
        B = self.BLOCK
        parts = [raw[i:i + B] for i in range(0, len(raw), B)]
        if self.deflate == "zlib":
            blocks = [zlib.compress(p, self.level) for p in parts]
        else:
            from isal.isal_zlib import compress

            blocks = [compress(p, self.level) for p in parts]
            if once:
                blocks = [min(b, zlib.compress(p, 1), key=len) for b, p in zip(blocks, parts)]
        last = len(raw) - (len(blocks) - 1) * B if blocks else 0
        head = np.array([len(blocks), B, last, *map(len, blocks)], dtype="<u4").tobytes()
        return kind, (a.shape[1] if a.ndim > 1 else 1), head + b"".join(blocks)

    def cells(self, n: int) -> dict:
        """The blobs of ``n`` vertices' cells and of the empty lines, strips and polygons."""
        empty = self.blob(np.zeros(0, np.int64))
        return {"Verts": (self.blob(np.arange(n, dtype=np.int32), once=True),
                          self.blob(np.arange(1, n + 1, dtype=np.int32), once=True)),
                "Lines": (empty, empty), "Strips": (empty, empty), "Polys": (empty, empty)}

    @staticmethod
    def text(n: int, point_data: list, points, cells: dict) -> bytes:
        """The file: ``point_data`` [(name, blob)], ``points`` a blob, ``cells`` :meth:`cells`."""
        xml, data, at = [], [], 0

        def entry(name, blob, indent):
            nonlocal at
            kind, ncomp, b = blob
            comp = f' NumberOfComponents="{ncomp}"' if ncomp > 1 else ""
            xml.append(f'{indent}<DataArray type="{kind}" Name="{name}"{comp} '
                       f'format="appended" offset="{at}"/>')
            data.append(b)
            at += len(b)

        xml += ['<VTKFile type="PolyData" version="0.1" byte_order="LittleEndian" '
                'header_type="UInt32" compressor="vtkZLibDataCompressor">', "  <PolyData>",
                f'    <Piece NumberOfPoints="{n}" NumberOfVerts="{n}" NumberOfLines="0" '
                'NumberOfStrips="0" NumberOfPolys="0">', "      <PointData>"]
        for name, blob in point_data:
            entry(name, blob, " " * 8)
        xml += ["      </PointData>", "      <CellData>", "      </CellData>", "      <Points>"]
        entry("points", points, " " * 8)
        xml.append("      </Points>")
        for kind in ("Verts", "Lines", "Strips", "Polys"):
            xml.append(f"      <{kind}>")
            entry("connectivity", cells[kind][0], " " * 8)
            entry("offsets", cells[kind][1], " " * 8)
            xml.append(f"      </{kind}>")
        xml += ["    </Piece>", "  </PolyData>", '  <AppendedData encoding="raw">', "   _"]
        return ("\n".join(xml).encode() + b"".join(data)
                + b"\n  </AppendedData>\n</VTKFile>\n")


def write_vtk(run, fields, outdir, progress: bool = False, fmt: str = "paraview",
              measures: str = "all", compressor: str = "zlib", level: int = 1,
              writer: str = "numpy", deflate: str = "isal", extra=()) -> Path:
    """Write ``outdir/run.pvd`` and one ``.vtp`` per frame; return the ``.pvd`` path.
    ``fmt``: ``"paraview"`` (compressed, appended) or ``"ovito"`` (module docstring).
    ``measures``: ``"all"`` (every measure, ``rackstress stress``) or ``"default"`` (the leading
    measure only and no ``displacement_magnitude``, ``rackstress run``: :data:`MEASURES`).
    ``compressor`` (``zlib``, ``lz4``, ``lzma``) and ``level``: VTK's XML compressors, for
    ``bench`` comparisons; zlib streams at level 1 are what :data:`MEASURES`' sizes were
    measured with.
    ``writer``: ``"numpy"`` writes the ``paraview`` variant with zlib streams itself
    (:class:`_Vtp`, a third of VTK's time), made by ``deflate``: ``"isal"`` (ISA-L at
    ``level``, 0-3: a third of the time again) or ``"zlib"`` (VTK's own compressed bytes);
    ``"vtk"`` (and every other variant) through ``vtkXMLPolyDataWriter``.
    ``extra``: (name, write(path)) pairs of further files of the directory (a static run's
    ``surface.vtp``), written with the series, before it replaces the old directory.

    Example
    -------
    >>> import pyvista as pv                                              # doctest: +SKIP
    >>> r = pv.get_reader("runs/plane-rack/vtk/run.pvd"); r.set_active_time_value(36)
    >>> r.read()[0].point_data["paper"].max()                             # doctest: +SKIP
    """
    from rackstress.lib.progress import progress_bar

    outdir = Path(outdir)
    tmp = outdir.with_name(f".{outdir.name}.tmp{os.getpid()}")
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    if measures not in MEASURES:
        raise ValueError(f"unknown measures '{measures}'; choose one of {', '.join(MEASURES)}")
    every = measures == "all"
    chosen = dict(fields.values) if every else {fields.default: fields.values[fields.default]}
    if every:
        chosen.update(getattr(fields, "extras", {}))           # stress tensor, principal, ...
    gid, names = group_ids(run)
    o = run.o
    r = radii(run)
    f32 = np.float32

    def frame_arrays(k, ts):
        """(points, [per-frame arrays]) of frame ``k``, every particle."""
        p = positions(ts)
        disp = p - o
        out = [("displacement", disp.astype(f32))]
        if every:
            out.append(("displacement_magnitude", np.linalg.norm(disp, axis=1).astype(f32)))
        v = _velocity(ts)
        if v is not None:
            out.append(("velocity", v.astype(f32)))
        out += [(m, vals[k]) for m, vals in chosen.items()]
        return p.astype(f32), out

    def static(rows):
        """The arrays of the particles ``rows`` that do not change from frame to frame."""
        out = [("id", run.data.ids[rows].astype(np.int32)), ("group_id", gid[rows]),
               ("type", run.data.types[rows].astype(np.int32)),
               ("mol", run.data.mols[rows].astype(np.int32)), ("radius", r[rows].astype(f32)),
               ("original", o[rows].astype(f32))]
        for j, name in enumerate(names):              # the names, as OVITO can read them
            out.append((f"group_{name}", (gid[rows] == j).astype(np.int32)))
        return out

    if fmt == "paraview" and compressor == "zlib" and writer == "numpy":   # as VTK writes it
        vtp = _Vtp(level, deflate)

        def dataset(rows):
            return (len(rows), [(name, vtp.blob(a, once=True)) for name, a in static(rows)],
                    vtp.cells(len(rows)))

        def frame_file(data, rows, p, per_frame):
            n, fixed, cells = data
            return vtp.text(n, fixed + [(name, vtp.blob(a[rows])) for name, a in per_frame],
                            vtp.blob(p[rows]), cells)
    else:                                             # VTK's own writer
        from vtkmodules.util.numpy_support import numpy_to_vtk
        from vtkmodules.vtkCommonCore import vtkPoints
        from vtkmodules.vtkCommonDataModel import vtkCellArray, vtkPolyData
        from vtkmodules.vtkIOXML import vtkXMLPolyDataWriter

        def arr(a, name):
            v = numpy_to_vtk(np.ascontiguousarray(a), deep=True)
            v.SetName(name)
            return v

        vw = vtkXMLPolyDataWriter()
        if fmt == "ovito":
            vw.SetDataModeToBinary()          # inline base64: OVITO reads neither appended
            vw.SetCompressorTypeToNone()      # data nor compressed arrays, only Int32/64 and
            #                                   Float32/64 arrays, no field data (OVITO 3.17)
        elif fmt == "paraview":
            vw.SetDataModeToAppended()        # raw bytes, not base64
            vw.EncodeAppendedDataOff()
            {"zlib": vw.SetCompressorTypeToZLib, "lz4": vw.SetCompressorTypeToLZ4,
             "lzma": vw.SetCompressorTypeToLZMA}[compressor]()
            vw.SetCompressionLevel(level)
        else:
            raise ValueError(f"unknown VTK format '{fmt}'; choose one of "
                             f"{', '.join(VTK_FORMATS)}")
        vw.WriteToOutputStringOn()            # VTK's own file output crashes (SIGSEGV) when
        #                                       the disk fills: it writes to memory, Python
        #                                       to the disk

        def dataset(rows):
            """A vertex cloud of the particles ``rows`` with the arrays that do not change."""
            poly = vtkPolyData()
            verts = vtkCellArray()            # Int32 ids: half the bytes of 64-bit ones
            verts.SetData(_int32(np.arange(len(rows) + 1)), _int32(np.arange(len(rows))))
            poly.SetVerts(verts)
            for name, a in static(rows):
                poly.GetPointData().AddArray(arr(a, name))
            return poly

        def frame_file(poly, rows, p, per_frame):
            pts = vtkPoints()
            pts.SetData(arr(p[rows], "points"))
            poly.SetPoints(pts)
            for name, a in per_frame:
                poly.GetPointData().AddArray(arr(a[rows], name))
            vw.SetInputData(poly)
            if not vw.Write():
                raise OSError(f"{tmp}: VTK could not write a frame")
            return vw.GetOutputString()

    rest = resting(run, fields, chosen) if fmt == "paraview" else np.zeros(run.n_atoms, bool)
    rows = np.flatnonzero(~rest)
    entries = []
    try:
        if rest.any():                    # written once, listed at every time (module docstring)
            p0, per0 = frame_arrays(0, run.trajectory[0])
            still = np.flatnonzero(rest)
            _write_bytes(tmp / REST, frame_file(dataset(still), still, p0, per0))
        data = dataset(rows)
        with progress_bar(len(fields.steps), progress, "VTK frames") as bar:
            bar.unit = "frame"
            for k, step in enumerate(fields.steps):
                p, per_frame = frame_arrays(k, run.trajectory[k])
                name = frame_name(step)
                _write_bytes(tmp / name, frame_file(data, rows, p, per_frame))
                entries.append((int(step), name))
                bar.update(1)
        lines = ['<?xml version="1.0"?>',
                 '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">',
                 "  <Collection>"]
        for s, f in entries:
            lines.append(f'    <DataSet timestep="{s}" group="" part="0" file={quoteattr(f)}/>')
            if rest.any():
                lines.append(f'    <DataSet timestep="{s}" group="" part="1" '
                             f'file={quoteattr(REST)}/>')
        lines += ["  </Collection>", "</VTKFile>", ""]
        _write_bytes(tmp / PVD, "\n".join(lines).encode())
        for name, write in extra:
            write(tmp / name)
        _swap_in(tmp, outdir)
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, OSError) and exc.errno is not None:
            raise storage_error(exc, "write the VTK series", exc.filename or outdir) from None
        raise
    return outdir / PVD


def _write_bytes(path: Path, data) -> None:
    """Write ``data`` (bytes or str) to ``path``; an OS error (a full disk) raises ``OSError``
    naming the path."""
    with open(path, "wb") as fh:
        fh.write(data if isinstance(data, bytes) else data.encode())


class VtkJob:
    """:func:`write_vtk` in a forked process (:class:`~rackstress.runs.forked.ForkedJob`), while
    this one goes on (the pictures: the machine's other core); :meth:`join` returns the
    ``.pvd`` path and the wall time, or raises the child's error. Without fork it writes at
    :meth:`join`."""

    def __init__(self, run, fields, outdir, fmt: str = "paraview", measures: str = "all",
                 extra=()):
        import tempfile
        import time

        from rackstress.runs.forked import ForkedJob

        self.t0 = time.perf_counter()
        fd, name = tempfile.mkstemp(prefix=".vtk-job-", suffix=".json",
                                    dir=Path(outdir).parent)
        os.close(fd)
        self.job = ForkedJob(lambda: str(write_vtk(run, fields, Path(outdir), fmt=fmt,
                                                    measures=measures, extra=extra)), name)

    def join(self) -> tuple[Path, float]:
        import time

        from rackstress.runs.forked import ForkedError

        try:
            pvd = self.job.join()
        except ForkedError as exc:
            if exc.storage:          # a full disk stays a storage error (exit 5)
                raise StorageError(exc.message.split(": ", 1)[-1]) from None
            if exc.exitcode is not None:
                raise OSError("writing the VTK files failed: the VTK writer ended with exit "
                              f"code {exc.exitcode}") from None
            raise OSError(f"writing the VTK files failed: {exc.message}") from None
        return Path(pvd), time.perf_counter() - self.t0

    def kill(self):
        self.job.kill()


# ----------------------------------------------------------------------------- LAMMPS dump
#: a dynamic run's per-particle peaks over its frames (:func:`write_peaks_over_time`)
PEAKS_VTP = "peaks_over_time.vtp"


def write_peaks_over_time(run, fields, path) -> None:
    """``vtk/peaks_over_time.vtp`` (a run in time with a material part): every particle at
    its original position with each measure's largest value over the run's frames
    (``<measure>_max``), the iteration it was
    reached at (``<measure>_max_iteration``, the first where it ties) and, in a physical-units
    run, its time (``<measure>_max_time``, iteration × dt): where and when a moving part was
    stressed most, beside the frame-by-frame series. A particle never finite has NaN.

    Example
    -------
    >>> import pyvista as pv                                              # doctest: +SKIP
    >>> pv.read("runs/impact/vtk/peaks_over_time.vtp")["von_mises_max_time"].max()
    """
    import pyvista as pv

    f32 = np.float32
    pd = pv.PolyData(np.asarray(run.o, f32))
    steps = np.asarray(fields.steps, np.int64)
    gid, _ = group_ids(run)
    pd.point_data["id"] = run.data.ids.astype(np.int32)
    pd.point_data["group_id"] = gid
    dt = run.dt if run.time_unit is not None else None
    rows = np.arange(len(run.o))
    for m, vals in fields.values.items():
        v = np.asarray(vals, float)
        fin = np.isfinite(v)
        k = np.argmax(np.where(fin, v, -np.inf), axis=0)
        seen = fin.any(axis=0)
        pd.point_data[f"{m}_max"] = np.where(seen, v[k, rows], np.nan).astype(f32)
        pd.point_data[f"{m}_max_iteration"] = np.where(seen, steps[k], -1)
        if dt is not None:
            pd.point_data[f"{m}_max_time"] = np.where(seen, steps[k] * dt, np.nan)
    pd.save(str(path))


def stress_dump_columns(run, fields, with_velocity: bool) -> list:
    cols = ["id", "type", "mol", "x", "y", "z", "radius"]
    if with_velocity:
        cols += ["vx", "vy", "vz"]
    return cols + ["group", "dx", "dy", "dz", *fields.values]


def write_stress_dump(run, fields, path, progress: bool = False) -> Path:
    """Write the measures as named columns of a LAMMPS ``dump custom`` file (module docstring).

    Example
    -------
    >>> write_stress_dump(run, compute_fields(run), "runs/plane-rack/stress.dump")  # doctest: +SKIP
    """
    from rackstress.lib.progress import progress_bar

    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    gid, _ = group_ids(run)
    r = radii(run)
    o = run.o
    ids, types, mols = run.data.ids, run.data.types, run.data.mols
    with_v = _velocity(run.trajectory[0]) is not None
    cols = stress_dump_columns(run, fields, with_v)
    # id type mol: integers; x y z radius [vx vy vz]; group: integer; dx dy dz and the measures
    fmt = " ".join(["%d", "%d", "%d"] + [FLOAT] * (4 + 3 * with_v) + ["%d"]
                   + [FLOAT] * (3 + len(fields.values)))
    try:
        with open(tmp, "w") as fh, progress_bar(len(fields.steps), progress, "stress dump") as bar:
            bar.unit = "frame"
            for k, step in enumerate(fields.steps):
                ts = run.trajectory[k]
                p = positions(ts)
                blocks = [ids, types, mols, p, r]
                if with_v:
                    blocks.append(_velocity(ts))
                blocks += [gid, p - o] + [vals[k] for vals in fields.values.values()]
                fh.write(frame_text(step, p, cols, np.column_stack(blocks), fmt))
                bar.update(1)
        os.replace(tmp, path)
    except BaseException as exc:
        tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError) and exc.errno is not None:
            raise storage_error(exc, "write", path) from None
        raise
    return path

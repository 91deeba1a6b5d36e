"""Stress-recovery candidates for the governing stress, each against converged FEA at the
same points, on ``rackstress bench governing``'s parts (docs/stress.md "Patch recovery").

For the C frame, its filleted twin and the bracket at spacings h and h/√2 (the filleted frame
at h/2 too): the particles' ``continuum`` stresses (the bindings' virial per cell with the
free faces' moment restored) recovered by a least-squares polynomial over a patch of
particles (:func:`rackstress.stress.tensor.patch_recover`) — linear or quadratic, over 1.5 to
3 spacings, of every particle, of the interior ones only, or (the last, the default route's)
of the regular cells and the supported ones (:func:`rackstress.stress.tensor.regular_cells`)
— and read at the cell's surface
point (:func:`rackstress.stress.tensor.recovery_points`, the default route's) or at the
nearest point of the part's true surface (``singular.npz``'s); the governing stress of each
(the bench's zone and singular points) over FEA's (P2, graded, the finest run's supports and
loads: :func:`rackstress.validity.graded.reference`, one size). Also, at the particle read
nearest FEA's governing point: its continuum value, FEA at its centre, at its surface point and
at the nearest point of the true surface — how far the field rises between the particle and
the surface.

    PYTHONPATH=workflow python scripts/recovery_candidates.py docs/benchmarks/recovery-candidates.json
"""
from __future__ import annotations

import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

#: (degree, radius in spacings, which particles: every one (False), the interior ones only
#: (True) or the regular cells and the supported ones ("regular": the default route's))
CANDIDATES = [(1, 2.5, False), (1, 1.5, False), (1, 2.0, False), (1, 3.0, False),
              (1, 1.5, True), (1, 2.0, True), (1, 2.5, True),
              (2, 2.0, False), (2, 2.5, False), (2, 3.0, False), (2, 2.5, True), (2, 3.0, True),
              (1, 2.5, "regular")]
PARTS = {"cframe": (1.0, 1 / math.sqrt(2)), "cframe-filleted": (1.0, 1 / math.sqrt(2), 0.5),
         "bracket": (1.0, 1 / math.sqrt(2))}


def _vm(s):
    xx, yy, zz, xy, yz, xz = s.T
    return np.sqrt(0.5 * ((xx - yy) ** 2 + (yy - zz) ** 2 + (zz - xx) ** 2)
                   + 3 * (xy ** 2 + yz ** 2 + xz ** 2))


def _recover(T, o, s, h, pts, samples, deg, R, which):
    if which is False:
        return T.patch_recover(o, s, h, pts, degree=deg, radius=R)
    use = samples[which]
    rec, ok = T.patch_recover(o, np.where(use[:, None], s, np.nan), h, pts, degree=deg,
                              radius=R, return_ok=True)
    if (~ok).any():
        rec[~ok] = T.patch_recover(o, s, h, pts, degree=deg, radius=R)[~ok]
    return rec


def part(name, scene, spacing, h_far, h_near, scales, work: Path) -> dict:
    import trimesh

    from rackstress.bench.governing import _level
    from rackstress.lib.runfiles import SINGULAR
    from rackstress.stress import tensor as T
    from rackstress.stress.governing import read_singular, zone
    from rackstress.stress.measures import ParticleStress, read_fractions
    from rackstress.stress.rundata import boundary_rows, load_run
    from rackstress.validity.graded import governing_fe, reference

    runs = [_level(scene, spacing, f, work / f"{name}-{k}") for k, f in enumerate(scales)]
    coarse = read_singular(runs[0]["dir"])
    pname = next(iter(coarse))
    sp0, wall, sing = coarse[pname]
    z = zone(sp0, wall)
    t0 = time.process_time()
    ref = reference(runs[-1]["dir"], h_far, h_near, singular=sing)
    fe = governing_fe(ref, z)
    sol = ref["solution"]
    out = {"name": name, "zone": z, "fea": {"governing": fe["value"],
                                            "position": fe["position"], **ref["fe"],
                                            "cpu_s": time.process_time() - t0},
           "rows": []}
    for r in runs:
        rd = load_run(r["dir"])
        idx = rd.parts[pname].index
        o, h = rd.o[idx], float(r["spacing"])
        with np.load(Path(r["dir"]) / SINGULAR) as zz:
            tm = trimesh.Trimesh(zz["surface_0_vertices"], zz["surface_0_faces"],
                                 process=False)
        s = ParticleStress(rd, method="continuum").run().results.stress[-1][idx]
        faces = T.free_faces(o, h)
        phi = read_fractions(rd)
        samples = {True: T.interior(faces),
                   "regular": T.regular_cells(o, h, None if phi is None else phi[idx])
                   | boundary_rows(rd)[0][idx].any(axis=1)}
        cell = T.recovery_points(o, h, faces)
        surf = cell.copy()
        onb = np.any(faces != 0, axis=1)
        surf[onb] = trimesh.proximity.closest_point(tm, cell[onb])[0]
        row = {"spacing": h, "particles": int(len(o)), "candidates": []}
        for label, pts in (("cell", cell), ("surface", surf)):
            d, _ = sing.distance(pts)
            away = d >= z
            for deg, R, only_inner in CANDIDATES:
                v = _vm(_recover(T, o, s, h, pts, samples, deg, R, only_inner))
                j = int(np.flatnonzero(away)[np.argmax(v[away])])
                fe_j = float(sol.at(pts[j:j + 1])["von_mises"][0])
                row["candidates"].append({
                    "points": label, "degree": deg, "radius": R, "interior_only": only_inner,
                    "governing": float(v[j]), "ratio": float(v[j] / fe["value"]),
                    "read_at": [float(x) for x in pts[j]], "fea_there": fe_j})
        # the particle read nearest FEA's governing point: how the field rises to the surface
        k = int(np.argmin(np.linalg.norm(cell - np.asarray(fe["position"]), axis=1)))
        at = sol.at(np.array([o[k], cell[k], surf[k]]))["von_mises"]
        row["nearest_to_fea_point"] = {
            "position": [float(x) for x in o[k]], "continuum": float(_vm(s[k:k + 1])[0]),
            "fea_at_centre": float(at[0]), "fea_at_cell_surface_point": float(at[1]),
            "fea_at_true_surface": float(at[2]),
            "depth": float(np.linalg.norm(surf[k] - o[k]))}
        out["rows"].append(row)
        print(name, h, "done", flush=True)
    return out


def main(path: str) -> None:
    from rackstress.bench import machine
    from rackstress.bench.governing import cases

    t0 = time.perf_counter()
    start = machine()
    res = []
    with tempfile.TemporaryDirectory(prefix="rs-candidates-") as tmp:
        work = Path(tmp)
        for name, scene, spacing, h_far, h_near in cases(work):
            if name in PARTS:
                res.append(part(name, scene, spacing, h_far, h_near, PARTS[name], work))
    data = {"command": "PYTHONPATH=workflow python scripts/recovery_candidates.py " + path,
            "machine": start, "wall_s": time.perf_counter() - t0, "parts": res}
    Path(path).write_text(json.dumps(data, indent=1) + "\n")


if __name__ == "__main__":
    main(sys.argv[1])

"""The peak of a concave curved face (a fillet, a hole) from the particles beneath it.

The lattice's stress is right where its particles are (docs/stress.md "Patch recovery": at
the filleted C frame's fillet a particle's value agrees with FEA at its centre), but at a
fillet of radius ρ a few spacings across the field rises steeply in the last half spacing to
the surface — on that frame FEA's von Mises halves within 0.3·ρ of the arc — and no
polynomial fit of the particles reaches it. Near a circular concave face the field across it
falls like the hoop stress at Kirsch's hole, a constant and terms in (ρ/r)² and (ρ/r)⁴
(r = ρ + x, x the depth below the face); one power between them,

    σ(x) = A + B·(ρ/(ρ + x))³,

fitted by least squares (two unknowns, robust to the lattice's scatter) to the particles'
``continuum`` von Mises stress (at their centres) in a tube along the face's normal, with ρ
from the part's geometry (how far its surface turns across a window of :data:`WINDOW`
spacings, :func:`rackstress.model.singular.concave_turning`), with A, B ≥ 0, gives σ(0), the
face's peak:
the **notch reading**. On exact samples at the lattice's depths (half a spacing and on) it
reads 0.955 / 0.973 / 0.989 of Kirsch's edge value at ρ of 2.5 / 4 / 8 spacings (by hand,
tests/test_notch.py) and 0.96–0.97 of converged FEA's at the filleted C frame's fillet
(ρ = 2, 2.8, 4 spacings); what it reads from the particles, against converged FEA, is
measured by ``rackstress bench validity --concentrations`` and ``rackstress bench
governing``.
"""
from __future__ import annotations

import numpy as np

#: The window across which the surface's turning gives a face's radius, in spacings.
WINDOW = 2.0
#: Faces read: radius from :data:`MIN_RADIUS` (below it the edge is sharp, a singular point:
#: rackstress.model.singular, 1.43 spacings) to :data:`MAX_RADIUS` spacings (flatter faces
#: carry no steep rise the patch fit misses).
MIN_RADIUS = 1.43
MAX_RADIUS = 20.0
#: The tube along a face's normal: particles within :data:`TUBE` spacings of its axis and
#: down to :data:`DEPTH` spacings below the face.
TUBE = 0.75
DEPTH = 3.0
#: A concave edge is a curved face's only where the window's turning is spread over its
#: facets: where the edge's own angle is at least this share of its window's turning, the
#: window sees one fold between facets wider than itself — a crease of the file, not a face
#: whose radius its facets give. Its "radius" is the window's (window·spacing / angle): on the
#: SOLO upper leg a 12.4° fold reads 29.7 mm at 3.2 mm and 21.0 mm at 2.26 mm; the submodel
#: there, graded toward the fold, read its weak singularity as the mesh allowed (2.21 / 2.01
#: / 1.82 MPa graded to 0.28 / 1.1 / 2.3 mm, its ball moving along the fold; the FE check
#: 1.94 MPa 6 mm from it); the patch fit reads it, as any face (measured while building
#: this). Half the concave edges of 1.4 – 20 spacings that the corpus' coarser files give
#: at 1 – 2.3 mm are such folds; a fillet tessellated finer than the window is not one.
CREASE_SHARE = 0.5
#: A reading needs this many particles at two depths at least half a spacing apart.
MIN_SAMPLES = 3


#: The power of the field's fall across the face (module docstring).
POWER = 3.0


def basis(x, rho: float) -> np.ndarray:
    """The field's shape across a concave face of radius ``rho`` at depth ``x``:
    (ρ/(ρ + x))^:data:`POWER` (module docstring).

    >>> float(basis(0.0, 2.0)), float(basis(2.0, 2.0))
    (1.0, 0.125)
    """
    return (float(rho) / (float(rho) + np.asarray(x, float))) ** POWER


def surface_value(depth, values, rho: float, spacing: float) -> float | None:
    """σ(0) = A + B of :func:`basis`'s two-term fit A + B·(ρ/(ρ + x))³ to ``values`` at
    ``depth`` (least squares with A, B ≥ 0: a von Mises stress, a far field and a rise toward
    the face — where the samples fall toward the face the fit is their mean, not an
    extrapolation below them), or None where the samples cannot carry it (fewer than :data:`MIN_SAMPLES`, or
    their depths within half a spacing of each other).

    >>> x = np.array([0.5, 1.5, 2.5])
    >>> round(surface_value(x, 3.0 + 2.0 * basis(x, 2.0), 2.0, 1.0), 9)   # exact: A + B
    5.0
    """
    x, v = np.asarray(depth, float), np.asarray(values, float)
    ok = np.isfinite(v) & np.isfinite(x)
    x, v = x[ok], v[ok]
    if len(x) < MIN_SAMPLES or np.ptp(x) < 0.5 * spacing:
        return None
    from scipy.optimize import nnls

    A = np.column_stack([np.ones(len(x)), basis(np.maximum(x, 0.0), rho)])
    c, _ = nnls(A, v)
    return float(c[0] + c[1])


def faces(vertices, faces_, spacing: float):
    """The concave curved faces of a closed surface at the scale of ``spacing``: points along
    its concave edges (every half spacing), with the radius there, the unit normal into the
    part and the facets' spacing across the face (an arc's chord: the window's length × the
    edge's own angle over the window's turning): (points (k, 3), radius (k,), normal (k, 3),
    chord (k,)); only radii between :data:`MIN_RADIUS` and :data:`MAX_RADIUS` spacings, and
    not the file's creases (:data:`CREASE_SHARE`).

    >>> import trimesh
    >>> hole = trimesh.creation.cylinder(3.0, 4.0, sections=256)         # a hole's face,
    >>> _ = hole.invert()                                                # facets 0.07 apart
    >>> bool(len(faces(hole.vertices, hole.faces, 0.5)[0]))
    True
    >>> coarse = trimesh.creation.cylinder(3.0, 4.0, sections=24)        # 0.8 apart: folds
    >>> _ = coarse.invert()
    >>> len(faces(coarse.vertices, coarse.faces, 0.5)[0])
    0
    """
    from rackstress.model.singular import concave_turning, sample_segments

    E, own, turning, inward = concave_turning(vertices, faces_, spacing, window=WINDOW)
    if not len(E):
        return np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)), np.zeros(0)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = WINDOW * float(spacing) / turning
        chord = WINDOW * float(spacing) * own / turning
    keep = (rho >= MIN_RADIUS * spacing) & (rho <= MAX_RADIUS * spacing) \
        & (own < CREASE_SHARE * turning)
    pts, which = sample_segments(E[keep], 0.5 * float(spacing))
    return pts, rho[keep][which], inward[keep][which], chord[keep][which]


def readings(o, values, points, rho, normal, spacing: float) -> np.ndarray:
    """The notch reading (:func:`surface_value`) at each face point from the particles ``o``
    with ``values`` (their continuum von Mises) in its tube (:data:`TUBE`, :data:`DEPTH`);
    NaN where the tube holds too few."""
    from scipy.spatial import cKDTree

    o = np.asarray(o, float)
    a = float(spacing)
    out = np.full(len(points), np.nan)
    if not len(points) or not len(o):
        return out
    tree = cKDTree(o)
    centre = points + 0.5 * DEPTH * a * normal
    reach = np.hypot(0.5 * DEPTH * a, TUBE * a) * (1 + 1e-9)
    for k, near in enumerate(tree.query_ball_point(centre, reach)):
        if not near:
            continue
        near = np.asarray(near)
        rel = o[near] - points[k]
        x = rel @ normal[k]
        off = np.linalg.norm(rel - x[:, None] * normal[k], axis=1)
        m = (off <= TUBE * a) & (x >= 0.0) & (x <= DEPTH * a)
        v = surface_value(x[m], np.asarray(values)[near[m]], float(rho[k]), a)
        if v is not None:
            out[k] = v
    return out


# --------------------------------------------------------------------------- the submodel
#: The submodel's ball about a face point, in spacings: its cut lies where the particles' field
#: is the continuum's (on the concentrations bench's parts, from 1.2 spacings below the face
#: the particles' continuum stress is within 2 % of converged FEA's at their centres, while
#: the first layer reads 0.86–0.98 of it, with where the lattice's layers fall), and far
#: enough from the centre that the error of the cut's displacement there has decayed: on the
#: bench's plate with a hole, filleted and notched bars at 0.4–0.6 mm the readings scattered
#: 0.94–1.08 of converged FEA with a ball of 3 spacings, 0.98–1.04 with 4 (measured while
#: building this).
SUBMODEL_RADIUS = 4.0
#: ... and at least this many times the face's radius ρ: the cut must also lie where the
#: notch's own field has settled, and that is on the notch's scale, not the lattice's. A ball
#: of 4 spacings is 0.7–1.2 ρ on the concentrations bench's hole (ρ 3.2 mm) and notch (ρ 2 mm)
#: at 0.35–0.6 mm; its cut crosses the steep field beside the root, where the fitted
#: displacement's error bears on the reading: driven by converged FEA's own displacement at
#: the particles (with FEA's ν), at the root, a ball of 4 spacings read 0.96–1.05 of FEA's
#: peak over eight spacings 0.35–0.6 mm (standard deviation 0.024 / 0.025, hole / notch), one
#: of 1.5 ρ 0.96–1.00 (0.012 / 0.009). From the particles, the governing reading's worst
#: |reading/FEA − 1| over those spacings went from 0.087 / 0.068 / 0.075 (hole / notch /
#: filleted bar) to 0.060 / 0.040 / 0.049, its standard deviation from 0.047 / 0.047 / 0.030
#: to 0.024 / 0.019 / 0.018; 2ρ reads as 1.5ρ within 2.2 % (measured while building this)
SUBMODEL_RHO = 1.5
#: The submodel's mesh: P2 tetrahedra of at most this × the ball's radius, graded to
#: :data:`SUBMODEL_FINE` × min(spacing, radius of the face) at the face point.
SUBMODEL_SIZE = 0.25
SUBMODEL_FINE = 0.125
#: The submodel's centre lies at least this many spacings from the part's sharp convex edges
#: (where the face meets a free face: a plate's hole at its top and bottom): there the cut
#: is mostly free surface, and the particles' displacement fitted at it extrapolates across
#: the edge (the plate with a hole at 0.42 mm read 1.15 of converged FEA at its rim, measured
#: while building this); a wall 2.5 spacings thick keeps its middle.
SUBMODEL_CLEAR = 1.25
#: ... an edge being sharp where its two faces turn outward by at least this many degrees
EDGE_DEG = 30.0
#: The particles' displacement at a point of the cut: a Gaussian-weighted least-squares fit
#: over those within this many spacings (the patch fit's reach), quadratic where at least
#: :data:`QUADRATIC` particles are there, else linear.
BOUNDARY_REACH = 2.5
QUADRATIC = 20


def boundary_displacement(o, u, x, spacing: float) -> np.ndarray:
    """The particles' displacement ``u`` (at their original positions ``o``) at the points
    ``x`` (k, 3): a local least-squares fit of the particles within :data:`BOUNDARY_REACH`
    spacings, weighted by exp(−r²/(2·1.25²)) (r in spacings), quadratic where at least
    :data:`QUADRATIC` particles are there, else linear (the eight nearest at least).

    >>> o = np.random.default_rng(0).uniform(-3, 3, (400, 3))
    >>> u = 0.01 * o + 0.002 * o[:, [0]] ** 2                 # a quadratic field: exact
    >>> x = np.array([[0.5, -0.2, 0.1]])
    >>> bool(np.allclose(boundary_displacement(o, u, x, 1.0), 0.01 * x + 0.002 * x[:, [0]] ** 2))
    True
    """
    from scipy.spatial import cKDTree

    a = float(spacing)
    tree = cKDTree(o)
    out = np.zeros((len(x), 3))
    for k, nb in enumerate(tree.query_ball_point(x, BOUNDARY_REACH * a)):
        if len(nb) < 8:
            nb = tree.query(x[k], 8)[1]
        nb = np.asarray(nb)
        r = (o[nb] - x[k]) / a
        P = np.column_stack([np.ones(len(nb)), r])
        if len(nb) >= QUADRATIC:
            P = np.column_stack([P, _quadratic_terms(r)])
        w = np.exp(-0.5 * np.sum(r * r, axis=1) / 1.25 ** 2)[:, None]
        out[k] = np.linalg.lstsq(P * w, u[nb] * w, rcond=None)[0][0]
    return out


def _quadratic_terms(r: np.ndarray) -> np.ndarray:
    """The quadratic columns of :func:`boundary_displacement`'s fit that its samples ``r``
    (k×3, on the cubic lattice) determine: r_d² where they lie on at least three planes
    across axis d, r_d·r_e where on at least two across both. Where the samples lie on two
    planes across d (a point on a face, the lattice's two outer layers within reach), r_d² is
    a sum of 1 and r_d on them, the fit has no unique value at r = 0, and the least-norm one
    is off by a share of the curvature's term: a linear field's displacement at points of a
    face came out up to 9 % of the field off (tests/test_notch.py); every cut that meets the
    part's surface has such points.

    >>> r = np.array([[x, y, 0.0] for x in (-1, 0, 1) for y in (0.5, 1.5)])
    >>> _quadratic_terms(r).shape[1]                  # x² and x·y; y has two planes, z one
    2
    """
    planes = [len(np.unique(np.round(r[:, d], 6))) for d in range(3)]
    cols = [r[:, d] ** 2 for d in range(3) if planes[d] >= 3]
    cols += [r[:, d] * r[:, e] for d in range(3) for e in range(d + 1, 3)
             if planes[d] >= 2 and planes[e] >= 2]
    return np.column_stack(cols) if cols else np.zeros((len(r), 0))


def clear_of_edges(vertices, faces_, points, spacing: float) -> np.ndarray:
    """Per point (k, 3), whether it lies at least :data:`SUBMODEL_CLEAR` spacings from every
    sharp convex edge of the closed surface (its two faces turning outward by at least
    :data:`EDGE_DEG`).

    >>> import trimesh
    >>> box = trimesh.creation.box([4, 4, 4])                # edges at ±2
    >>> clear_of_edges(box.vertices, box.faces, np.array([[0, -2, 0], [0, -2, 1.8]]), 1.0).tolist()
    [True, False]
    """
    import trimesh
    from scipy.spatial import cKDTree

    from rackstress.model.singular import sample_segments

    m = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces_), process=False)
    sharp = m.face_adjacency_convex & (m.face_adjacency_angles >= np.radians(EDGE_DEG))
    x = np.asarray(points, float).reshape(-1, 3)
    if not sharp.any():
        return np.ones(len(x), bool)
    on, _ = sample_segments(m.vertices[m.face_adjacency_edges[sharp]], 0.25 * float(spacing))
    return cKDTree(on).query(x)[0] >= SUBMODEL_CLEAR * float(spacing) * (1 - 1e-6)


def ball_piece(vertices, faces_, centre, radius: float):
    """The part's closed surface (vertices, faces) cut to the ball of ``radius`` about
    ``centre`` (manifold3d): (vertices, faces) of the piece."""
    import trimesh

    part = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces_), process=True)
    ball = trimesh.creation.icosphere(subdivisions=4, radius=float(radius))
    ball.apply_translation(np.asarray(centre, float))
    piece = trimesh.boolean.intersection([part, ball], engine="manifold")
    return np.asarray(piece.vertices, float), np.asarray(piece.faces, np.int64)


def submodel_radius(spacing: float, rho: float, reach: float = np.inf) -> float:
    """The submodel's ball radius about a face of radius ``rho``: :data:`SUBMODEL_RADIUS`
    spacings, or :data:`SUBMODEL_RHO` × ``rho`` where that is the larger — but grown past the
    spacings' no farther than ``reach`` (the distance to the nearest particle a clamp, a load
    or a contact bears on: inside the ball it would be free surface).

    >>> submodel_radius(0.5, 1.0), submodel_radius(0.5, 2.0), submodel_radius(0.5, 2.0, 2.5)
    (2.0, 3.0, 2.5)
    """
    return max(SUBMODEL_RADIUS * float(spacing), min(SUBMODEL_RHO * float(rho), float(reach)))


def submodel_fine(spacing: float, rho: float, chord: float = 0.0) -> float:
    """The submodel's mesh size at its face point: :data:`SUBMODEL_FINE` × min(spacing, ρ),
    but no finer than the facets' spacing across the face (``chord``, :func:`faces`): the
    file knows the face to its facets, and a mesh finer than them reads the folds between
    them, each a weak re-entrant corner, whose stress grows as the mesh shrinks — on the SOLO
    upper leg refined to 2.26 mm, at a face point whose facets lie 1.65 mm apart (its edge
    turns 6.4° of the window's 17.6°), the submodel graded to 0.28 mm read 2.22 MPa, graded to
    the facets 1.88, the FE check 1.94 MPa 6 mm from it (measured while building this).

    >>> submodel_fine(1.0, 4.0), submodel_fine(1.0, 4.0, 0.5)
    (0.125, 0.5)
    """
    return max(SUBMODEL_FINE * min(float(spacing), float(rho)), float(chord))


#: The ball's radius, × :func:`submodel_radius`, tried in turn where gmsh cannot mesh
#: the piece (the sphere cutting the part's facets into overlapping ones: the filleted C frame
#: at 0.71 mm, measured while building this), or where its sphere meets a face of the part at
#: a glancing angle (:data:`SEAM_DEG`)
RADII = (1.0, 1.1, 0.9, 1.25, 0.8)
#: gmsh remeshes the ball's piece in patches cut where its facets turn by 40° or more
#: (rackstress.lib.tet.gmsh_volume): where the sphere meets a face of the part at less (a wall
#: thinner than the ball, its far face cut at a glancing angle), the two are one patch, their
#: edge is rounded off and the piece's corner cut away. A 6 mm bar, a ball of 4 mm about a
#: point of its side (its faces met at 39°): the tetrahedra held 1.7 % less than the piece,
#: and a uniform 10 MPa read 10.41 at the ball's centre (9.56 with 3.2 mm, 18°). A radius
#: whose sphere meets the part's faces at this angle or more is taken first
#: (:func:`seam_angle`); where none of :data:`RADII` does, the steepest (measured while
#: building this; the SO-101 mounting plate's FE check ball met its plate at 40.4°)
SEAM_DEG = 45.0


def seam_angle(vertices, faces_, piece, centre, R: float) -> float:
    """The smallest angle (degrees) at which the ball's sphere (radius ``R`` about ``centre``)
    meets the part's own surface (``vertices``, ``faces_``) in its ``piece`` (v, f of
    :func:`ball_piece`): between the outward normals of the two triangles on either side of
    their edge (90 where it cuts a face square; 0 where it grazes it). A triangle of the piece
    is the part's where its centre lies on the part's surface.

    >>> import trimesh
    >>> box = trimesh.creation.box([20, 6, 6])            # faces at z = ±3
    >>> c = np.array([0.0, -3.0, 0.0])                    # a point of the face y = −3
    >>> piece = ball_piece(box.vertices, box.faces, c, 3.2)
    >>> 15 < seam_angle(box.vertices, box.faces, piece, c, 3.2) < 21   # acos(3/3.2) = 20°
    True
    """
    import trimesh

    v, f = np.asarray(piece[0], float), np.asarray(piece[1])
    if not len(f):
        return 90.0
    m = trimesh.Trimesh(v, f, process=False)
    V, F = np.asarray(vertices, float), np.asarray(faces_)
    c = np.asarray(centre, float)
    tri = V[F]
    near = np.all((tri.max(axis=1) >= c - 1.01 * R) & (tri.min(axis=1) <= c + 1.01 * R), axis=1)
    if not near.any():
        return 90.0
    own = _distance_to_surface(V, F[near], m.triangles_center) <= 1e-6 * R
    i, j = m.face_adjacency.T
    seam = own[i] != own[j]
    if not seam.any():
        return 90.0
    return float(np.degrees(m.face_adjacency_angles[seam]).min())


def _distance_to_surface(V: np.ndarray, F: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Each point's exact distance to the triangles ``F`` of ``V``, by VTK's cell locator
    (pyvista's ``find_closest_cell``): trimesh's ``closest_point`` gave the same distances
    (within 6e-8 of a 3 mm ball, the same triangles on the surface) in 140× the time — 8.5 s
    for the 5,078 triangles of a ball's piece against 692 of the part (measured 2026-12-02)."""
    import pyvista as pv

    poly = pv.PolyData(V, np.hstack([np.full((len(F), 1), 3), F]).ravel())
    _, closest = poly.find_closest_cell(points, return_closest_point=True)
    return np.linalg.norm(np.asarray(closest) - points, axis=1)


def _ball_mesh(vertices, faces_, centre, R: float, fine: float, piece=None):
    """P2-ready tetrahedra (p 3×N, t 4×M) of the part within the ball of radius ``R`` about
    ``centre`` (``piece``: :func:`ball_piece`'s, where made already): gmsh remeshes the piece,
    graded toward the centre to ``fine``; where tiny
    facets remain side by side its classification does not end (the FE check's experience,
    validity.solid), and where it cannot remesh, the piece is filled inside its own
    triangles."""
    from rackstress.lib import tet

    v, f = piece if piece is not None else ball_piece(vertices, faces_, centre, R)
    f = tet.drop_slivers(v, f)
    tiny = tet.SLIVER_AREA * float(np.ptp(v, axis=0).max()) ** 2
    if not (tet._twice_areas(v, f) <= tiny).any():
        try:
            return tet.gmsh_volume(v, f, SUBMODEL_SIZE * R, centre[None], fine,
                                   reparametrize=True)
        except Exception:  # noqa: BLE001 - gmsh's own words: the piece's own triangles, below
            pass
    return tet.gmsh_volume(v, f, SUBMODEL_SIZE * R, None, None, reparametrize=False)


def submodel(vertices, faces_, centre, o, u, spacing: float, rho: float, E: float,
             nu: float, radius: float | None = None, displace=None, fine: float | None = None,
             bears=None, radii=RADII):
    """The classical global–local submodel of the face about ``centre`` (a face point): the
    part's true shape within a ball of ``radius`` (:func:`submodel_radius`) about it
    (:func:`ball_piece`), P2 tetrahedra by gmsh graded toward the face point, its cut (the
    ball's sphere) displaced as the particles are (:func:`boundary_displacement` of their
    displacements ``u`` at ``o``), the part's own surface inside the ball free — except
    where something bears on it: ``bears`` = (x k×3, directions k×3 bool, side), the
    particles a support holds (in the directions it holds), a load pulls or a contact presses
    (all three), and their cells' side; the nodes inside those cells are displaced in those
    directions as the cut is (every boundary of the global–local submodel that is not free
    surface; before, a clamped hole's face inside the ball was free, and the FE check's local
    reading of the SO-101 mounting plate beside its screw hole fell from 0.70 to 0.44 MPa,
    where with it held it reads 0.72) — solved with
    the material's E and ν. ``displace`` (points k×3 → displacements k×3) instead of ``o``
    and ``u``: the cut displaced by another model's field (the FE check's own local
    refinement, validity.solid.local_peak); ``fine`` the mesh size at the face point instead
    of :data:`SUBMODEL_FINE` × min(spacing, ρ); ``radii`` the ball's radii, × ``radius``, tried
    in turn (:data:`RADII`), a ball whose mesh is poor (more than
    :data:`rackstress.lib.tet.POOR_SLIVERS` of its tetrahedra slivers) as one that does not
    mesh. Returns the :class:`rackstress.lib.tet.Solution`
    (``.at(points)`` evaluates its stress). Raises where gmsh cannot mesh the piece (its own
    words) or is not installed (ImportError: the ``fem`` extra)."""
    from rackstress.engines.linear import factorize
    from rackstress.lib import tet

    a = float(spacing)
    centre = np.asarray(centre, float)
    fine = float(fine) if fine else submodel_fine(a, rho)
    errors, glancing, got = [], [], None

    def meshed(R, piece):
        try:
            p, t = _ball_mesh(vertices, faces_, centre, R, fine, piece)
        except ImportError:
            raise
        except Exception as exc:  # noqa: BLE001 - gmsh's own words, said if every ball fails
            errors.append(str(exc))
            return None
        # a ball filled inside its piece's own facets can be slivers through and through: its
        # nodal stress is no reading (the filleted C frame at 0.5 mm: a check ball 99 %
        # slivers read 6,386 MPa where its first ball read 189; measured while building this)
        share = tet.sliver_share(p.T, t.T)
        if share > tet.POOR_SLIVERS:
            errors.append(f"the ball of radius {R:.3g} meshed {100 * share:.0f} % slivers")
            return None
        return p, t

    for R in float(radius or submodel_radius(a, rho)) * np.asarray(radii):
        try:
            piece = ball_piece(vertices, faces_, centre, R)
        except ImportError:
            raise
        except Exception as exc:  # noqa: BLE001 - manifold3d's own words, said if all fail
            errors.append(str(exc))
            continue
        seam = seam_angle(vertices, faces_, piece, centre, R)
        if seam < SEAM_DEG:
            glancing.append((seam, R, piece))
            continue
        got = meshed(R, piece)
        if got is not None:
            break
    else:       # no ball meets the part steeply and meshes: the steepest that meshes
        for seam, R, piece in sorted(glancing, key=lambda b: -b[0]):
            got = meshed(R, piece)
            if got is not None:
                break
    if got is None:
        raise RuntimeError(f"gmsh could not mesh the ball at {len(radii)} radii: "
                           + "; ".join(dict.fromkeys(errors)))
    p, t = got
    mesh = tet.Tet2(p.T, t.T)
    X = mesh.X
    # the cut: the boundary's nodes on the ball's (faceted) sphere, and the midpoints between
    # them; the rest of the boundary is the part's own surface, free
    faces4, once = tet._faces_once(mesh.t)
    nv = len(mesh.p)
    on_bnd = np.zeros(len(X), bool)
    on_bnd[np.unique(faces4[once])] = True
    cut = on_bnd & (np.linalg.norm(X - centre, axis=1) >= (1 - 5e-3) * R)
    cut[nv:] = cut[mesh.edges[:, 0]] & cut[mesh.edges[:, 1]]
    fixed = np.repeat(cut[:, None], 3, axis=1)
    if bears is not None and len(bears[0]):
        from rackstress.lib.cells import in_cells

        i, j = in_cells(X, bears[0], bears[2])
        np.logical_or.at(fixed, i, np.asarray(bears[1], bool)[j])
    given = fixed.any(axis=1)
    U = np.zeros((len(X), 3))
    U[given] = (displace(X[given]) if displace is not None else
                boundary_displacement(np.asarray(o, float), np.asarray(u, float), X[given], a))
    U[~fixed] = 0.0
    K = mesh.stiffness(E, nu).tocsr()
    fx = fixed.ravel()
    Uv = U.ravel()
    fac = factorize(K[~fx][:, ~fx].tocsr())
    try:
        Uv[~fx] = fac.solve(-(K[~fx][:, fx] @ Uv[fx]))
    finally:
        getattr(fac, "free", lambda: None)()
    U = Uv.reshape(-1, 3)
    return tet.Solution(mesh, U, tet.project_strain(mesh, U), float(E), float(nu),
                        info={"radius": float(R), "seam_deg": float(seam)})


def surface_peak(sol, centre, radius: float, keep=None):
    """The submodel's largest nodal von Mises stress on the part's own surface (not its cut)
    within a third of ``radius`` of ``centre``, where ``keep`` (points k×3 → bool k) allows:
    (value, position), or (None, None). The FE check's local refinement reads its ball so
    (validity.solid), and the notch reading the same way: the face's peak near the ball's
    centre, not only at it — on a coarsely faceted face the peak sits on a facet edge between
    the face points (the SO-100 upper arm at 1.9 mm: 0.746 MPa at the centre, 0.894 on the
    surface within R/3, the FE check's local reading 0.893; measured while building this)."""
    from rackstress.lib.tet import _faces_once

    X = sol.mesh.X
    faces4, once = _faces_once(sol.mesh.t)
    bnd = np.zeros(len(X), bool)
    bnd[np.unique(faces4[once])] = True
    nv = len(sol.mesh.p)
    bnd[nv:] = bnd[sol.mesh.edges[:, 0]] & bnd[sol.mesh.edges[:, 1]]
    sel = bnd & (np.linalg.norm(X - np.asarray(centre, float), axis=1) <= radius / 3)
    if keep is not None and sel.any():
        sel[sel] = np.asarray(keep(X[sel]), bool)
    if not sel.any():
        return None, None
    vm = sol.nodal()["von_mises"]
    k = np.flatnonzero(sel)[int(np.argmax(vm[sel]))]
    return float(vm[k]), X[k]


#: The submodel's check (:func:`cut_check`): its reading again with a ball of this × its
#: radius, at least :data:`CHECK_SPACINGS` spacings; it stands where the two agree within
#: :data:`CHECK_AGREE` of the larger — beyond the submodel's measured error (0.06,
#: governing.NOTCH_SUBMODEL_ERROR) and a 3-spacing ball's scatter (0.94–1.08 of converged FEA,
#: :data:`SUBMODEL_RADIUS`). On the corpus' finger link refined to 2.26 mm a ball of 24 mm read
#: 2.59 MPa at a face where the FE check has 0.72 and a ball of 9 mm 0.77: the large ball's
#: cut crosses the part's other features; driven by the FE check's own displacements it read
#: 1.6–3.9 as its radius moved from 13 to 26 mm, the 9 mm one 0.76 (measured while building
#: this)
CHECK_RADIUS = 0.75
CHECK_SPACINGS = 3.0
CHECK_AGREE = 0.15


def cut_check(vertices, faces_, centre, o, u, spacing: float, rho: float, E: float, nu: float,
              radius: float, value: float, bears=None, fine: float | None = None,
              peak: bool = False, keep=None):
    """The classical submodel's own check: a reading may not depend on where its cut lies. The
    submodel (:func:`submodel`) about ``centre`` read again with a ball of :data:`CHECK_RADIUS`
    × ``radius`` (the first ball's, which read ``value``), at least :data:`CHECK_SPACINGS`
    spacings, as the first was read: at ``centre``, or with ``peak`` by :func:`surface_peak`
    (``keep`` as it takes it). Returns (its reading, its radius, whether the two
    agree within :data:`CHECK_AGREE` of the larger); ``bears`` and ``fine`` as
    :func:`submodel` takes them. Raises as :func:`submodel` does."""
    R2 = max(CHECK_SPACINGS * float(spacing), CHECK_RADIUS * float(radius))
    sol = submodel(vertices, faces_, centre, o, u, spacing, rho, E, nu, radius=R2,
                   bears=bears, fine=fine)
    other = surface_peak(sol, centre, R2, keep)[0] if peak else None
    if other is None:
        other = float(sol.at(np.asarray(centre, float)[None])["von_mises"][0])
    agree = abs(other - value) <= CHECK_AGREE * max(abs(value), abs(other))
    return other, R2, bool(agree)


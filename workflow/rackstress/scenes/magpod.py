"""MagPod, the bipedal robot of Section 4 (Eqs. 27–33), walking on a soft sediment.

The operators are the paper's, coefficient for coefficient (directed: docs/model.md, "Directed coefficients"):

* body (Eq. 27): attract(rightleg, 200⟨r∈{2,3} ∧ breg_r,i = rreg_j ≠ 0⟩)
  • attract(leftleg, 200⟨l∈{6,7} ∧ breg_l,i = lreg_j ≠ 0⟩) • collide(rightleg, 100⟨r∈{2,3}⟩)
  • collide(leftleg, 100⟨l∈{6,7}⟩) • bind(bodyrack, 100) • dampen(10);
* each leg (Eqs. 28–30, b = r for the right leg, l for the left):
  attract(body, 300⟨b∈{1,4,5,8} ∧ mag_i = breg_b,j ≠ 0⟩) • collide(body, 100⟨b∈{1,4,5,8}⟩)
  • collide(body, 5⟨b∈{2,3,6,7}⟩) • collide(sediment, 50) • bind(rack, 100) • force((0,−50,0))
  • dampen(10 + 85⟨contact(sediment) ∧ b∈{2,3,6,7}⟩);
* racks (Eq. 23): bind(host, 0.5) • dampen(1);
* sediment (Eq. 31): collide(rightleg, 1) • collide(leftleg, 1) • dampen(50);
* schedule (Section 5): (r, l) = (4,6) → (1,7) → (2,8) → (3,5), ``phase_steps`` (1200) each,
  repeated ``cycles`` times; dt = 0.01 (Eq. 33).

The paper gives particle counts but no shapes. The geometry here is this module's design; every
choice is a keyword parameter of :func:`magpod`:

* axes: y is up, MagPod walks towards **+x**, so its right side is **+z** (x × y = z);
  the sediment's top surface is the plane y = 0;
* body: a simple-cubic block of 19 (x) × 9 (y) × 17 (z) = 2907 particles, radius 1, spacing 2
  (touching neighbours), centred on x = z = 0; it floats (no force but the legs holds it up);
* leg (382 particles each, radius 1, spacing 2): a column of 4 (x) × 3 (z) × 12 (y) = 144
  particles standing on a two-layer foot of 7 (x) × 17 (z) × 2 = 238: a sole 14 units long
  (along the walk) and 34 wide. The column's inner face touches the body's side face (centre
  distance 2 = sum of radii, zero force). The foot extends 2 columns behind the column and 6
  inward (under the body, which floats high enough for a lifted foot to pass under it). The
  foot is short along the walk so that a step (one gait cycle) is longer than a foot: the prints
  of one foot stay apart instead of merging into a trough; it is wide so that its weight spreads
  over ~40 sediment particles (the sediment has no support but its damping, Eq. 31);
* attraction regions: on each side face of the body, 4 × 4 patches (x × y), four layers deep;
  the leg's region "R" is the top four rows of its column, all 4 × 3 particles of each row.
  A particle's index is 1 + (its column in the patch) + 4·(its row in the patch), on the body
  and on the leg alike (depth shares the index), so the index-matched attraction pulls each
  leg row to the same body row and each leg column to the same body column: it aligns the leg
  upright as well as attracting it (Section 4.1). Each matched index couples 4 × 3 particles,
  192 pairs a region: a lift pulls with 300·192 = 57,600 against the leg's push-down
  50·382 = 19,100; a pull on the body is 200·192 = 38,400. Per particle that is 300·4 = 1200 on
  a leg's R particle and 200·3 = 600 on a body region particle, which the racks (bind 100 × 6)
  resist with ~0.5–1.5 units of local deformation: the "stress around region R" of Section 5.2;
* region placement (Section 4.1's motion principle), right side (left side 5–8 likewise):
  3 = rear, low (body rows 2–5, body columns 2–5); 2 = middle, low (columns 7–10);
  1 = front (columns 12–15), raised by one row so that the swinging leg is carried clear of the
  sediment and then dropped; 4 = the top four rows (5–8) above region 3: the lift.
  Regions one step of 5 columns (10 units) apart and pulling rows near the body's mid-height
  (rows 2–5 of 0–8) are measured choices: a step of 4 columns gave ~14 units a cycle, less than a
  foot length, and pulling rows lower down (1–4) tilted the body nose-up faster (31° against
  23° after three cycles).
  Gait: (4,6) lift the right leg while the planted left leg pulls the body from region 5 to 6;
  (1,7) swing it to the front while the body is pulled on to region 7; (2,8) the right leg is
  dropped onto the sediment and pulls the body to region 2 while the left leg is lifted; (3,5)
  the body is pulled to region 3 and the left leg swings to the front. Every phase moves the
  body one region step (5 columns = 10 units) relative to the planted leg; as a one-sided pull
  also yaws the body, its centre advances about half of that, ~18–21 units a cycle;
* sediment: 300 (x) × 100 (z) particles of radius 2 at spacing 3 in the plane y = −2 (its top at
  y = 0): neighbours overlap, which costs nothing (there are no sediment–sediment forces) and
  leaves no hole a leg particle could slip through (between four neighbours the hole has
  radius 3/√2 − 2 ≈ 0.12). Measured: with touching sediment (spacing 4, holes of radius 0.83)
  the soles pushed the sediment aside and sank through it to ~10 units below its top, and the
  lifts could not pull them clear; at spacing 3 a planted sole stays in the sediment 2–5 units
  deep and the lift raises it clear. It extends ``sediment_back`` columns behind the body's
  centre, the rest ahead, centred in z. The soles start resting on it (sole centres at y = 1);
* initial pose: the right leg at region 3's columns, the left leg at region 5's columns, as after
  a (3, 5) phase; the body at the height where both legs' R regions face the low rows.

Measured (magpod-small, 4 cycles = 19,200 iterations, LAMMPS exact mode, which matches the
reference engine to ~1e-8): the body's centre advances 21.5, 19.6, 18.8 and 18.2 units in the
four cycles (a foot is 14 long), pitches nose-up (14.7°, 20.1°, 22.8°, 25.3° at the cycle
ends: the paper's "tilts upright", Section 5.1), yaws and rolls within a cycle (the paper's
swing and sway) and drifts ~5 units a cycle to its right; each stance presses the sediment down
by up to ~3 units, and a planted sole sinks ~10 units, pushing the one-particle-thick sediment
down and aside (it has no support but its damping). The constant-magnitude attraction exceeds
what the collisions can hold at small overlap, so a leg's R region sinks a few units into the
body's side while it is attracted.
"""
from __future__ import annotations

import numpy as np

from rackstress.errors import SceneError
from rackstress.model.operators import (Attract, Bind, Collide, Const, Contact, Dampen, Force,
                                        Matched, PhaseIn, rack_forces)
from rackstress.model.particles import Group, rack
from rackstress.model.scene import Phase, Scene

#: The gait (Section 4.1): (r, l) pairs, each run ``phase_steps`` iterations.
GAIT = ((4, 6), (1, 7), (2, 8), (3, 5))
#: Body regions in which a leg is pulled by the body / pulls the body (Eq. 28).
LEG_PULLED = (1, 4, 5, 8)
LEG_PULLING = (2, 3, 6, 7)


def _grid(xs, ys, zs) -> np.ndarray:
    """All (x, y, z) combinations, x fastest then z then y (bottom layer first)."""
    y, z, x = np.meshgrid(np.asarray(ys, float), np.asarray(zs, float), np.asarray(xs, float),
                          indexing="ij")
    return np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)


def _leg(side: int, x0: float, z_inner: float, y_foot: float, *, spacing: float, col_nx: int,
         col_nz: int, col_ny: int, foot_nx: int, foot_nz: int, foot_ny: int, foot_heel: int,
         foot_inset: int, toe_width: int, n: int, region_rows: int):
    """One leg: positions (n×3) and its R-region index vector.

    ``side`` is +1 for the right leg (+z), −1 for the left; ``x0`` is the x of the column's rear
    particle column, ``z_inner`` the z of its inner (body-facing) layer, ``y_foot`` the centre
    height of the foot's bottom layer.
    """
    s = spacing
    col_x = x0 + s * np.arange(col_nx)
    col_z = z_inner + side * s * np.arange(col_nz)
    col_y = y_foot + s * (foot_ny + np.arange(col_ny))
    column = _grid(col_x, col_y, col_z)
    foot_x = x0 + s * (np.arange(foot_nx) - foot_heel)
    foot_z = z_inner + side * s * (np.arange(foot_nz) - foot_inset)
    foot = _grid(foot_x, y_foot + s * np.arange(foot_ny), foot_z)
    n_toes = n - len(column) - len(foot)
    if n_toes < 0:
        raise SceneError(f"leg column ({len(column)}) and foot ({len(foot)}) already exceed "
                         f"{n} particles")
    toes = []
    row = 0
    while n_toes > 0:
        k = min(toe_width, n_toes)
        first = (foot_nz - k) // 2
        zs = z_inner + side * s * (np.arange(first, first + k) - foot_inset)
        xs = np.full(k, foot_x[-1] + s * (row + 1))
        toes.append(np.stack([xs, np.full(k, y_foot), zs], axis=1))
        n_toes -= k
        row += 1
    pos = np.concatenate([column, foot] + toes)
    # R region: the top ``region_rows`` rows of the column, index 1 + column + ncol·row.
    reg = np.zeros(len(pos), dtype=np.int64)
    ci = np.rint((column[:, 0] - x0) / s).astype(int)
    ri = np.rint((column[:, 1] - col_y[0]) / s).astype(int) - (col_ny - region_rows)
    inside = ri >= 0
    reg[:len(column)][inside] = 1 + ci[inside] + col_nx * ri[inside]
    return pos, reg


def magpod(body_nx: int = 19, body_ny: int = 9, body_nz: int = 17, spacing: float = 2.0,
           radius: float = 1.0, leg_particles: int = 382, leg_nx: int = 4, leg_nz: int = 3,
           leg_ny: int = 12, foot_nx: int = 7, foot_nz: int = 17, foot_ny: int = 2,
           foot_heel: int = 2, foot_inset: int = 6, toe_width: int = 14, region_rows: int = 4,
           region_depth: int = 4, region_rear: int = 2, region_step: int = 5,
           region_low: int = 2, swing_raise: int = 1, lift_shift: int = 0,
           foot_gap: float = 0.0, sediment_nx: int = 300, sediment_nz: int = 100, sediment_radius: float = 2.0,
           sediment_spacing: float = 3.0, sediment_back: int = 25, rack_offset: float = 5.0,
           phase_steps: int = 1200, cycles: int = 4, dt: float = 0.01,
           name: str = "magpod") -> Scene:
    """MagPod (Eqs. 27–33) with the geometry described in the module docstring.

    Body: ``body_nx × body_ny × body_nz`` lattice (x forward, y up, z right), ``spacing`` 2 and
    ``radius`` 1 (touching). Legs: ``leg_particles`` each: a ``leg_nx × leg_nz × leg_ny`` column
    on a ``foot_nx × foot_nz × foot_ny`` foot; the foot extends ``foot_heel`` columns behind the
    column and ``foot_inset`` columns inward (under the body); the rest are toes, rows of up to
    ``toe_width`` in front of the bottom foot layer. Regions: ``region_rows`` rows × ``leg_nx``
    columns patches, ``region_depth`` layers into the body; rear region at body column
    ``region_rear``, middle and front ``region_step`` and 2·``region_step`` columns ahead; the
    front (swing) region ``swing_raise`` rows above the low ones; the lift region in the top
    rows, ``lift_shift`` columns ahead of the rear one. ``foot_gap``: extra height of the feet
    above the sediment at the start (0: touching). Sediment: ``sediment_nx × sediment_nz``
    particles of ``sediment_radius`` at ``sediment_spacing`` (touching when spacing = 2·radius),
    top at y = 0, ``sediment_back`` columns behind x = 0. ``rack_offset``: Section 3.2's five
    units. ``phase_steps`` iterations a gait phase, ``cycles`` gait cycles, time step ``dt``.
    """
    params = {k: v for k, v in locals().items()}
    s = float(spacing)
    P = int(leg_nx)
    for label, v in (("region_rows", region_rows), ("region_depth", region_depth)):
        if v < 1:
            raise SceneError(f"magpod: {label} must be >= 1")
    if region_rows > leg_ny:
        raise SceneError("magpod: region_rows exceeds the leg column height")
    front = region_rear + 2 * region_step
    lift_col = region_rear + lift_shift
    if region_rear < 0 or front + P > body_nx or lift_col < 0 or lift_col + P > body_nx:
        raise SceneError(f"magpod: regions (rear column {region_rear}, step {region_step}, "
                         f"width {P}) do not fit a body {body_nx} columns long")
    if (region_low < 0 or region_low + swing_raise + region_rows > body_ny
            or region_depth > body_nz):
        raise SceneError("magpod: regions do not fit the body's side face")

    # ---------------------------------------------------------------- heights
    y_foot = float(radius + foot_gap)                 # foot bottom layer; sediment top at y = 0
    y_leg_top = y_foot + s * (foot_ny + leg_ny - 1)  # top row of the column
    # the low regions' top row faces the R region's top row
    y_body0 = y_leg_top - s * (region_low + region_rows - 1)

    # ---------------------------------------------------------------- body and its regions
    bx = s * (np.arange(body_nx) - (body_nx - 1) / 2)
    by = y_body0 + s * np.arange(body_ny)
    bz = s * (np.arange(body_nz) - (body_nz - 1) / 2)
    body_o = _grid(bx, by, bz)
    ix = np.rint((body_o[:, 0] - bx[0]) / s).astype(int)
    iy = np.rint((body_o[:, 1] - by[0]) / s).astype(int)
    iz = np.rint((body_o[:, 2] - bz[0]) / s).astype(int)

    def patch(col0: int, row0: int, side: int) -> np.ndarray:
        depth = (body_nz - 1 - iz) if side > 0 else iz      # layers in from that side face
        a, b = ix - col0, iy - row0
        inside = (a >= 0) & (a < P) & (b >= 0) & (b < region_rows) & (depth < region_depth)
        out = np.zeros(len(body_o), dtype=np.int64)
        out[inside] = 1 + a[inside] + P * b[inside]
        return out

    mid = region_rear + region_step
    top = body_ny - region_rows
    low = region_low
    layout = {1: (front, low + swing_raise), 2: (mid, low), 3: (region_rear, low),
              4: (lift_col, top)}
    regions = {}
    for k, (c0, r0) in layout.items():
        regions[f"breg{k}"] = patch(c0, r0, +1)        # right side: 1–4
        regions[f"breg{k + 4}"] = patch(c0, r0, -1)    # left side: 5–8
    body = Group("body", body_o, radius, kind="body", meta={"regions": regions})

    # ---------------------------------------------------------------- legs
    leg_kw = dict(spacing=s, col_nx=leg_nx, col_nz=leg_nz, col_ny=leg_ny, foot_nx=foot_nx,
                  foot_nz=foot_nz, foot_ny=foot_ny, foot_heel=foot_heel, foot_inset=foot_inset,
                  toe_width=toe_width, n=leg_particles, region_rows=region_rows)
    z_face = bz[-1]
    r_pos, rreg = _leg(+1, bx[region_rear], z_face + s, y_foot, **leg_kw)   # at region 3
    l_pos, lreg = _leg(-1, bx[front], -z_face - s, y_foot, **leg_kw)        # at region 5
    rightleg = Group("rightleg", r_pos, radius, kind="leg", meta={"regions": {"rreg": rreg}})
    leftleg = Group("leftleg", l_pos, radius, kind="leg", meta={"regions": {"lreg": lreg}})

    # ---------------------------------------------------------------- racks and sediment
    bodyrack = rack(body, "bodyrack", offset=rack_offset)
    rightrack = rack(rightleg, "rightrack", offset=rack_offset)
    leftrack = rack(leftleg, "leftrack", offset=rack_offset)
    sx = sediment_spacing * (np.arange(sediment_nx) - sediment_back)
    sz = sediment_spacing * (np.arange(sediment_nz) - (sediment_nz - 1) / 2)
    sediment = Group("sediment", _grid(sx, [-float(sediment_radius)], sz), sediment_radius,
                     kind="sediment")

    groups = {g.name: g for g in (body, rightleg, leftleg, bodyrack, rightrack, leftrack,
                                  sediment)}

    # ---------------------------------------------------------------- operators
    def leg_forces(var: str, index: str, rack_name: str) -> list:   # Eq. 28
        pulled, pulling = (PhaseIn(var, LEG_PULLED),), (PhaseIn(var, LEG_PULLING),)
        return [
            Attract("body", Matched(index, f"breg{{{var}}}", 300.0), when=pulled),
            Collide("body", Const(100.0), when=pulled),
            Collide("body", Const(5.0), when=pulling),
            Collide("sediment", Const(50.0)),
            Bind(rack_name, Const(100.0)),
            Force((0.0, -50.0, 0.0)),
            Dampen(10.0, 85.0, when=(Contact("sediment"),) + pulling),
        ]

    r_pull, l_pull = (PhaseIn("r", (2, 3)),), (PhaseIn("l", (6, 7)),)
    operators = {
        "body": [                                                      # Eq. 27
            Attract("rightleg", Matched("breg{r}", "rreg", 200.0), when=r_pull),
            Attract("leftleg", Matched("breg{l}", "lreg", 200.0), when=l_pull),
            Collide("rightleg", Const(100.0), when=r_pull),
            Collide("leftleg", Const(100.0), when=l_pull),
            Bind("bodyrack", Const(100.0)),
            Dampen(10.0),
        ],
        "rightleg": leg_forces("r", "rreg", "rightrack"),             # Eq. 29
        "leftleg": leg_forces("l", "lreg", "leftrack"),               # Eq. 30
        "bodyrack": rack_forces("body"),                              # Eq. 23
        "rightrack": rack_forces("rightleg"),
        "leftrack": rack_forces("leftleg"),
        "sediment": [Collide("rightleg", Const(1.0)), Collide("leftleg", Const(1.0)),
                     Dampen(50.0)],                                    # Eq. 31
    }
    phases = [Phase(f"{r}-{l}", int(phase_steps), {"r": r, "l": l}) for r, l in GAIT]
    return Scene(name, groups, operators, phases, dt=dt, cycles=int(cycles), params=params,
                 report=gait_report)


#: MagPod walks towards +x (y up, right side +z).
WALK = np.array([1.0, 0.0, 0.0])
#: A leg stands on the sediment (pulls the body) in these phases of its side's variable.
STANCE = {"rightleg": ("r", (2, 3)), "leftleg": ("l", (6, 7))}


def sole(scene: Scene, leg: str, p: np.ndarray) -> np.ndarray:
    """Positions of a leg's sole: the particles of its lowest original layer."""
    o = scene.groups[leg].o
    low = o[:, 1] < o[:, 1].min() + 0.5 * float(scene.params.get("spacing", 2.0))
    return p[scene.slice(leg)][low]


def gait_report(scene: Scene, records) -> dict:
    """Per gait cycle: body centre of mass, advance along the walk, pitch, footprint depth;
    per stance (a phase end at which a sole touches the sediment): where that foot stood
    (Section 5.1's "tilts upright" and "trail of footprints");
    per phase: the body's centre, pitch (nose-up rotation about the lateral z axis, degrees)
    and ``up_y``, the vertical component of its up axis (≤ 0 would be capsized).

    ``records`` are the states at phase ends (:class:`rackstress.model.scene.PhaseEnd`), the first
    the initial state. The footprint depth is the largest downward displacement of a sediment
    particle from its original height.
    """
    from rackstress.lib.cells import any_closer
    # Kabsch by NumPy's SVD: best_fit's minimizer without scipy.spatial, whose import (0.2 s)
    # would fall between the last step and the post-processing
    from rackstress.lib.rigid import kabsch as best_fit

    body, sed = scene.slice("body"), scene.slice("sediment")
    o = scene.original_positions()
    start = records[0].p[body].mean(axis=0)
    cycles, stances, phases = [], [], []
    prev = start
    last_phase = scene.phases[-1].name
    for rec in records[1:]:
        R, _ = best_fit(o[body], rec.p[body])
        phases.append({"cycle": rec.cycle, "phase": rec.phase, "step": rec.step,
                       "body_com": rec.p[body].mean(axis=0).tolist(),
                       "pitch_deg": float(np.degrees(np.arctan2(R[1, 0], R[0, 0]))),
                       # y-component of the body's up axis: 1 upright, <= 0 capsized
                       "up_y": float(R[1, 1])})
        reach = float(scene.groups["sediment"].r.max() + scene.groups["rightleg"].r.max())
        for leg, (var, values) in STANCE.items():
            s = sole(scene, leg, rec.p)
            # a stance: the sole touches the sediment (pulling, or just landed from a swing);
            # by cells (lib/cells.py): scipy.spatial's import is not on the run's path
            if any_closer(s, rec.p[sed], reach):
                stances.append({"leg": leg, "cycle": rec.cycle, "phase": rec.phase,
                                "step": rec.step, "pulling": rec.vars.get(var) in values,
                                "x": float(s[:, 0].mean()), "z": float(s[:, 2].mean()),
                                "sole_y": float(s[:, 1].min())})
        if rec.phase == last_phase:
            com = rec.p[body].mean(axis=0)
            depth = float(np.max(o[sed, 1] - rec.p[sed, 1]))
            cycles.append({"cycle": rec.cycle, "step": rec.step, "body_com": com.tolist(),
                           "advance": float((com - prev) @ WALK),
                           "pitch_deg": phases[-1]["pitch_deg"],
                           "footprint_depth": depth})
            prev = com
    return {"walk_direction": WALK.tolist(), "body_com_start": start.tolist(),
            "cycles": cycles, "stances": stances, "phases": phases}


def magpod_small(sediment_nx: int = 56, sediment_nz: int = 36, sediment_back: int = 10,
                 phase_steps: int = 1200, cycles: int = 1, body_nx: int = 19, body_ny: int = 9,
                 body_nz: int = 17, spacing: float = 2.0, radius: float = 1.0,
                 leg_particles: int = 382, leg_nx: int = 4, leg_nz: int = 3, leg_ny: int = 12,
                 foot_nx: int = 7, foot_nz: int = 17, foot_ny: int = 2, foot_heel: int = 2,
                 foot_inset: int = 6, toe_width: int = 14, region_rows: int = 4,
                 region_depth: int = 4, region_rear: int = 2, region_step: int = 5,
                 region_low: int = 2, swing_raise: int = 1, lift_shift: int = 0,
                 foot_gap: float = 0.0, sediment_radius: float = 2.0, sediment_spacing: float = 3.0,
                 rack_offset: float = 5.0, dt: float = 0.01) -> Scene:
    """The same MagPod on a sediment patch just large enough for a short walk.

    Defaults: 56 × 36 sediment particles (168 × 108 units at spacing 3), 10 columns (30 units)
    behind the body's centre: the soles start within x ∈ [−19, 15], z ∈ [−39, 39]; MagPod
    advances ~19–23 units a cycle and drifts a few units a cycle to its right, so four cycles
    (19,200 iterations) stay on the patch. One cycle by default (the README's first command);
    ``phase_steps`` can be lowered for quick checks; the rest is as :func:`magpod`.
    """
    kw = {k: v for k, v in locals().items()}
    scene = magpod(name="magpod-small", **kw)
    scene.params = dict(kw)        # this builder's own keywords, so --set/rebuilds round-trip
    return scene


#: the keywords of a MagPod in physical units that state the mapping (the rest are its walk's)
MAPPING_KEYS = ("unit_length_mm", "leg_material", "g")


def _physical(walk, name: str, kw: dict) -> Scene:
    """``walk(**rest)`` (a MagPod's walk, in paper units; ``rest`` the keywords ``kw`` has
    beside :data:`MAPPING_KEYS`), named ``name`` and marked physical: after the run
    :mod:`rackstress.stress.legs` reads its legs in MPa under the mapping ``kw`` states
    (checked before the walk is built); ``kw`` the builder's own keywords (``--set``
    round-trips)."""
    for label in ("unit_length_mm", "g"):
        if not kw[label] > 0:
            raise SceneError(f"{name}: {label} must be positive, got {kw[label]!r}")
    from rackstress.model.materials import PRESETS

    if kw["leg_material"] not in PRESETS:
        raise SceneError(f"{name}: leg_material must be one of "
                         f"{', '.join(PRESETS)}, got {kw['leg_material']!r}")
    scene = walk(**{k: v for k, v in kw.items() if k not in MAPPING_KEYS})
    scene.name = name
    scene.params = dict(kw, physical=True)
    return scene


def magpod_physical_small(unit_length_mm: float = 5.0, leg_material: str = "aluminium",
                          g: float = 9.81, sediment_nx: int = 56, sediment_nz: int = 36,
                          sediment_back: int = 10, phase_steps: int = 1200, cycles: int = 1,
                          dt: float = 0.01) -> Scene:
    """magpod-small in physical units: the same walk, its aluminium legs' von Mises in MPa.

    The walk is :func:`magpod_small`'s, unchanged (paper units); after the run
    :mod:`rackstress.stress.legs` gives each leg its quasi-static stress per frame under a
    stated mapping: ``unit_length_mm`` millimetres per paper unit (a guess: the paper gives no
    size), legs of ``leg_material`` (a preset of :mod:`rackstress.model.materials`), the
    paper's push-down on the legs read as ``g`` (m/s²). docs/magpod/physical.md.

    Examples
    --------
    >>> sc = magpod_physical_small()
    >>> sc.name, sc.params["physical"], sc.n_particles
    ('magpod-physical-small', True, 5705)
    """
    return _physical(magpod_small, "magpod-physical-small", dict(locals()))


def magpod_physical(unit_length_mm: float = 5.0, leg_material: str = "aluminium",
                    g: float = 9.81, sediment_nx: int = 300, sediment_nz: int = 100,
                    sediment_back: int = 25, phase_steps: int = 1200, cycles: int = 4,
                    dt: float = 0.01) -> Scene:
    """The paper's MagPod in physical units: :func:`magpod`'s whole walk (33,689 particles,
    four gait cycles on the full sediment, paper units, unchanged), its legs' von Mises in MPa
    per frame under the mapping of :func:`magpod_physical_small` (docs/magpod/physical.md).

    Examples
    --------
    >>> sc = magpod_physical()
    >>> sc.name, sc.params["physical"], sc.n_particles
    ('magpod-physical', True, 33689)
    """
    return _physical(magpod, "magpod-physical", dict(locals()))

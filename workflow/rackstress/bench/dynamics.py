"""``rackstress bench dynamics``: time stepping in physical units against analytical answers.

Three validations, each at three spacings, on the LAMMPS engine as ``rackstress run`` steps
(the scene's own time step: half the predicted stability limit, docs/units.md):

* **free vibration** (``examples/dynamics/vibration.toml``): the aluminium cantilever of
  ``examples/cantilever`` moving down at 100 mm/s when its root face is clamped. The tip's
  vertical velocity, sampled every few steps, is Fourier transformed (Hann window, zero
  padded ×16) and the frequencies of its peaks refined together by a least-squares fit of a
  sum of sinusoids to the record (:func:`peaks`); the three lowest are f1–f3. Compared with Euler–Bernoulli, f_n = (β_nL)²/(2πL²)·√(EI/(ρA)),
  β_nL = 1.8751, 4.6941, 7.8548, and with the Timoshenko beam (shear and rotary inertia,
  κ = 10(1 + ν)/(12 + 11ν), Cowper's for a rectangle), solved here by its own finite elements
  (:func:`timoshenko`, 800 elements: converged to 0.01 %), which is what a bar of L/h = 10
  follows: its f2 and f3 lie 5 % and 11 % below Euler–Bernoulli's.
* **a bar striking a wall** (``examples/dynamics/impact.toml``): the bar moving at v = 1 m/s
  along −x when its end face is held. Behind the compression front the bar is at rest under
  σ_xx = −ρ·c·v, c = √(E/ρ) the bar speed (one-dimensional stress: the long-wavelength
  limit of the lattice's longitudinal waves in a bar whose faces are free; the lattice is
  calibrated to E, so its c is the material's, as far as its E_eff is). Measured at
  mid-length: σ_xx averaged over the cross-section's particles (the bindings' virial over
  each particle's share of the bar), its plateau the mean between the front's passage and the
  return of the free end's reflection, its arrival time that of the step carrying the same
  impulse up to the plateau, against x/c.

* **two bars in contact** (``examples/dynamics/collision.toml``): equal aluminium bars
  touching through ``[[contact]]`` (the materials' contact, :func:`rackstress.scenes.physical.
  contacts`), one moving at 1 m/s: σ_xx = −ρ·c·v/2 in the struck one, contact for 2L/c, and
  after it the motion exchanged (the momentum kept).

Writes ``docs/benchmarks/dynamics.{md,json,png}``.
"""
from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from rackstress.bench import (ONE_THREAD, machine, program, rackstress_command, repository_file,
                              timed, write_json)

VIBRATION = repository_file("examples", "dynamics", "vibration.toml")
IMPACT = repository_file("examples", "dynamics", "impact.toml")
COLLISION = repository_file("examples", "dynamics", "collision.toml")
#: the bar of both scenes (mm, MPa, tonne/mm³)
E, NU, RHO, L, H = 70000.0, 0.33, 2.7e-9, 100.0, 10.0
#: Euler–Bernoulli's β_n·L of a clamped–free beam
BETA_L = (1.8751, 4.6941, 7.8548)
SPACINGS = (2.0, 1.25, 1.0)
#: the vibration's duration at each spacing (s): two periods of f1 (the least-squares fit of
#: :func:`peaks` needs no more; 5 ms gave the same f1–f3 to the Hz at 1.25 mm)
DURATION = {2.0: 0.0025, 1.25: 0.0025, 1.0: 0.0025}
#: steps between samples of the tip (a sample every ~2 µs: Nyquist far above f3)
SAMPLE_STEPS = 10


def euler_bernoulli(E=E, rho=RHO, L=L, h=H) -> np.ndarray:
    """f1–f3 (Hz, lengths in mm, E in MPa, ρ in t/mm³) of a clamped–free square bar."""
    return np.array(BETA_L) ** 2 / (2 * np.pi * L ** 2) * np.sqrt(E * h ** 2 / 12 / rho)


def timoshenko(E=E, nu=NU, rho=RHO, L=L, h=H, n: int = 800, modes: int = 3) -> np.ndarray:
    """Bending frequencies (Hz) of a clamped–free Timoshenko beam of square section h × h:
    linear elements (bending exact, shear at one point: no locking), consistent mass with
    rotary inertia, κ = 10(1 + ν)/(12 + 11ν).

    Example
    -------
    >>> f = timoshenko(n=200)
    >>> bool(abs(f[0] / euler_bernoulli()[0] - 0.992) < 0.001)
    True
    """
    import scipy.linalg as sl

    G, A, I = E / (2 * (1 + nu)), h * h, h ** 4 / 12
    kappa = 10 * (1 + nu) / (12 + 11 * nu)
    le, N = L / n, 2 * (n + 1)
    K, M = np.zeros((N, N)), np.zeros((N, N))
    kb = E * I / le * np.array([[0, 0, 0, 0], [0, 1, 0, -1], [0, 0, 0, 0], [0, -1, 0, 1.0]])
    B = np.array([-1 / le, -0.5, 1 / le, -0.5])                 # w' − θ at the midpoint
    ke = kb + kappa * G * A * le * np.outer(B, B)
    me = np.zeros((4, 4))
    lumped = np.array([[2.0, 1.0], [1.0, 2.0]]) * le / 6
    me[np.ix_([0, 2], [0, 2])] = rho * A * lumped
    me[np.ix_([1, 3], [1, 3])] = rho * I * lumped
    for e in range(n):
        d = np.arange(2 * e, 2 * e + 4)
        K[np.ix_(d, d)] += ke
        M[np.ix_(d, d)] += me
    free = np.arange(2, N)                                      # w = θ = 0 at the clamp
    w2 = sl.eigh(K[np.ix_(free, free)], M[np.ix_(free, free)], eigvals_only=True,
                 subset_by_index=[0, modes - 1])
    return np.sqrt(w2) / (2 * np.pi)


def peaks(t: np.ndarray, x: np.ndarray, count: int = 3, floor: float = 0.05) -> np.ndarray:
    """The ``count`` lowest spectral peaks (Hz) of the signal ``x`` sampled at ``t``: Hann
    window, zero padding ×16, local maxima above ``floor`` of the largest (a Hann window's
    side lobes are 0.027 of their peak), then every peak found refined together by least
    squares — the frequencies of a sum of sinusoids (its amplitudes and phases solved
    linearly for each trial) fitted to the record. A few periods suffice: the window's own
    bias (−0.5 % on f1 over two of its periods) is gone.

    Example
    -------
    >>> t = np.arange(4000) * 1e-5
    >>> np.round(peaks(t, np.sin(2 * np.pi * 123.4 * t) + 0.5 * np.sin(2 * np.pi * 777 * t),
    ...                2), 2).tolist()
    [123.4, 777.0]
    """
    from scipy.optimize import least_squares

    x = np.asarray(x, float) - np.mean(x)
    t = np.asarray(t, float)
    n, dt = len(x), float(t[1] - t[0])
    pad = 16 * n
    S = np.abs(np.fft.rfft(x * np.hanning(n), pad))
    f = np.fft.rfftfreq(pad, dt)
    k = np.flatnonzero((S[1:-1] > S[:-2]) & (S[1:-1] > S[2:]) & (S[1:-1] > floor * S.max())) + 1
    first = []
    for i in k:
        a, b, c = np.log(S[i - 1:i + 2])
        first.append(f[i] + 0.5 * (a - c) / (a - 2 * b + c) * (f[1] - f[0]))
    first = np.asarray(first)
    tt = t - t[0]

    def residual(freqs):
        w = 2 * np.pi * freqs[None, :] * tt[:, None]
        A = np.hstack([np.cos(w), np.sin(w), np.ones((n, 1))])
        coef, *_ = np.linalg.lstsq(A, x, rcond=None)
        return A @ coef - x

    scale = float(first.max()) if len(first) else 1.0
    fit = least_squares(lambda u: residual(u * scale), first / scale, xtol=1e-12, ftol=1e-12)
    return np.sort(fit.x * scale)[:count]


def _stepped(path: Path, spacing: float, duration: float | None, every: int, sample):
    """Step the scene of ``path`` at ``spacing`` on LAMMPS, calling ``sample(t, positions)``
    every ``every`` steps (and at step 0); returns (scene, wall seconds, steps)."""
    from rackstress.engines.driver import drive
    from rackstress.engines.lammps.deck import compile_deck
    from rackstress.engines.lammps.runner import LammpsRun
    from rackstress.model.scene import steps_for
    from rackstress.scenes import load

    sc = load(str(path), {"spacing": spacing})
    if duration is not None:
        sc.phases[0] = replace(sc.phases[0], steps=steps_for(duration, sc.dt), duration=duration)
    run = LammpsRun(compile_deck(sc, "exact", plugin=None), None)
    try:
        sample(0.0, run.positions())
        t0 = time.perf_counter()
        out = drive(run, check_every=every,
                    on_chunk=lambda eng: sample(eng.step_count * sc.dt, eng.positions()))
        wall = time.perf_counter() - t0
    finally:
        run.close()
    return sc, wall, out.steps


def vibration(spacing: float, duration: float | None = None, echo=print) -> dict:
    """f1–f3 of the clamped bar at ``spacing`` from its tip's vertical velocity."""
    t, z = [], []
    tip = None

    def sample(time_, p):
        nonlocal tip
        if tip is None:
            tip = np.isclose(p[:, 0], p[:, 0].max())
        t.append(time_)
        z.append(float(p[tip, 2].mean()))

    sc, wall, steps = _stepped(VIBRATION, spacing, duration or DURATION.get(spacing), SAMPLE_STEPS,
                               sample)
    t, z = np.asarray(t), np.asarray(z)
    f = peaks(t[1:], np.diff(z) / np.diff(t))
    ref_t, ref_eb = timoshenko(), euler_bernoulli()
    row = {"spacing": spacing, "particles": sc.n_particles, "dt": sc.dt, "steps": steps,
           "duration": float(t[-1]), "wall_s": wall, "f": f.tolist(),
           "timoshenko": ref_t.tolist(), "euler_bernoulli": ref_eb.tolist(),
           "vs_timoshenko": (f / ref_t[:len(f)] - 1).tolist(),
           "vs_euler_bernoulli": (f / ref_eb[:len(f)] - 1).tolist(),
           "history": {"t": t.tolist(), "tip_z": z.tolist()}}
    echo(f"  vibration at {spacing:g} mm ({sc.n_particles:,} particles, {steps:,} steps, "
         f"{wall:.1f} s): f = {', '.join(f'{x:.0f}' for x in f)} Hz; against Timoshenko "
         + ", ".join(f"{100 * e:+.1f} %" for e in row["vs_timoshenko"]))
    return row


def _section_stress(scene, section: np.ndarray, volume: float):
    """σ_xx(p) of a cross-section's particles ``section``: their bindings' virial
    Σ_j r_x·f_x / (2V) over the section's volume (as rackstress.bench.cantilever.virial, the
    pairs found once for every frame sampled)."""
    from rackstress.engines.static import _bind_pairs
    from rackstress.model.operators import Bind

    I_, J, C, Q = _bind_pairs(scene)
    keep = np.isin(I_, section)
    I_, J, C, Q = I_[keep], J[keep], C[keep], Q[keep]
    m = scene.masses()[I_]

    def sxx(p: np.ndarray) -> float:
        f = Bind.accel(p[I_], p[J], C, Q) * m[:, None]
        return float(((p[J, 0] - p[I_, 0]) * f[:, 0]).sum() / 2 / volume)

    return sxx


def _plateau(t: np.ndarray, s: np.ndarray, arrive: float, back: float):
    """The stress behind a wave front: the samples from a quarter of the way between its
    arrival and the return of its reflection to a fifth of that interval before the return,
    and their mean."""
    window = (t > arrive + 0.25 * (back - arrive)) & (t < back - 0.2 * (back - arrive))
    return window, float(s[window].mean())


def impact(spacing: float, echo=print) -> dict:
    """σ_xx at mid-length of the bar striking the wall, over time, at ``spacing``."""
    from rackstress.bench.cantilever import cells
    from rackstress.scenes import load

    sc0 = load(str(IMPACT), {"spacing": spacing})
    o = sc0.original_positions()
    xs = np.unique(o[:, 0])
    mid = np.flatnonzero(np.isclose(o[:, 0], xs[np.argmin(np.abs(xs - L / 2))]))
    sxx = _section_stress(sc0, mid, cells(o, spacing)[mid].sum())
    t, s = [], []

    def sample(time_, p):
        t.append(time_)
        s.append(sxx(p))

    sc, wall, steps = _stepped(IMPACT, spacing, None, 1, sample)
    t, s = np.asarray(t), np.asarray(s)
    c = np.sqrt(E / RHO)                                         # mm/s
    v = float(-sc.params["speed"])
    x = float(o[mid, 0].mean())
    arrive, back = x / c, (2 * L - x) / c                         # the front, the reflection
    amp = RHO * c * v                                             # −ρ·c·|v| (compression)
    window, plateau = _plateau(t, s, arrive, back)
    # the arrival: the step at t_a that carries the same impulse up to the plateau's start T,
    # σ_p·(T − t_a) = ∫₀ᵀ σ dt (the front rises in stairs, the bar's lateral ringing, so the
    # time it first reaches half the plateau jumps between them with the spacing)
    T = float(t[window][0])
    upto = t <= T
    su, tu = s[upto], t[upto]
    t_half = T - float((0.5 * (su[1:] + su[:-1]) * np.diff(tu)).sum()) / plateau
    row = {"spacing": spacing, "particles": sc.n_particles, "dt": sc.dt, "steps": steps,
           "wall_s": wall, "x": x, "c": c, "speed": v, "sigma_expected": amp,
           "sigma_plateau": plateau, "sigma_ratio": plateau / amp,
           "sigma_spread": float(s[window].std()),
           "arrival_expected": arrive, "arrival": t_half, "arrival_ratio": t_half / arrive,
           "history": {"t": t.tolist(), "sigma_xx": s.tolist()}}
    echo(f"  impact at {spacing:g} mm ({sc.n_particles:,} particles, {steps} steps, "
         f"{wall:.2f} s): σ_xx {plateau:.2f} MPa against ρcv {amp:.2f} "
         f"({100 * (plateau / amp - 1):+.1f} %), the front at {t_half * 1e6:.2f} µs against "
         f"{arrive * 1e6:.2f} ({100 * (t_half / arrive - 1):+.1f} %)")
    return row


def collision(spacing: float, echo=print) -> dict:
    """Two equal bars through ``[[contact]]``: σ_xx at the struck bar's mid-length, how long
    the bars touch, and their velocities after (equal bars exchange their motion)."""
    from rackstress.bench.cantilever import cells
    from rackstress.scenes import load

    sc0 = load(str(COLLISION), {"spacing": spacing})
    o = sc0.original_positions()
    left, right = sc0.slice("left"), sc0.slice("right")
    xr = o[right, 0]
    x0 = float(xr.min())
    half = float(xr.max() - x0)
    xs = np.unique(xr)
    mid = np.flatnonzero(np.isclose(o[:, 0], xs[np.argmin(np.abs(xs - (x0 + half / 2)))])
                         & (np.arange(len(o)) >= right.start))
    sxx = _section_stress(sc0, mid, cells(o - np.array([x0, 0.0, 0.0]), spacing)[mid].sum())
    facing_l = np.flatnonzero(np.isclose(o[:, 0], o[left, 0].max())
                              & (np.arange(len(o)) < left.stop))
    facing_r = np.flatnonzero(np.isclose(o[:, 0], x0) & (np.arange(len(o)) >= right.start))
    t, s, gap, com = [], [], [], []

    def sample(time_, p):
        t.append(time_)
        s.append(sxx(p))
        gap.append(float(p[facing_r, 0].mean() - p[facing_l, 0].mean()))
        com.append((float(p[left, 0].mean()), float(p[right, 0].mean())))

    sc, wall, steps = _stepped(COLLISION, spacing, None, 1, sample)
    t, s, gap, com = np.asarray(t), np.asarray(s), np.asarray(gap), np.asarray(com)
    c = np.sqrt(E / RHO)
    v = float(sc.params["speed"])
    length = float(o[left, 0].max() - o[left, 0].min()) + spacing      # each bar's, n·a
    arrive, back = (half / 2) / c, (2 * length - half / 2) / c
    window, plateau = _plateau(t, s, arrive, back)
    touching = gap < spacing                    # R = the sum of the radii = one spacing
    end = int(np.flatnonzero(touching)[-1]) + 1 if touching.any() else 0
    duration = float(t[min(end, len(t) - 1)])
    tail = t > t[-1] - 0.15 * (t[-1] - duration)                        # after the contact
    vel = [float(np.polyfit(t[tail], com[tail, k], 1)[0]) for k in (0, 1)]
    row = {"spacing": spacing, "particles": sc.n_particles, "dt": sc.dt, "steps": steps,
           "wall_s": wall, "c": c, "speed": v, "length": length,
           "sigma_expected": -RHO * c * v / 2, "sigma_plateau": plateau,
           "sigma_ratio": plateau / (-RHO * c * v / 2), "sigma_spread": float(s[window].std()),
           "contact_expected": 2 * length / c, "contact": duration,
           "contact_ratio": duration / (2 * length / c),
           "velocity_after": vel, "momentum_ratio": (vel[0] + vel[1]) / v,
           "history": {"t": t.tolist(), "sigma_xx": s.tolist(), "gap": gap.tolist()}}
    echo(f"  collision at {spacing:g} mm ({sc.n_particles:,} particles, {steps} steps, "
         f"{wall:.2f} s): σ_xx {plateau:.2f} MPa against −ρcv/2 {-RHO * c * v / 2:.2f} "
         f"({100 * (row['sigma_ratio'] - 1):+.1f} %); in contact {duration * 1e6:.2f} µs "
         f"against 2L/c {2 * length / c * 1e6:.2f}; after: {vel[0]:.0f} and {vel[1]:.0f} mm/s "
         f"(against 0 and {v:.0f})")
    return row


#: steps of each timed run of :func:`contact_cost`, and how many times each variant runs
COST_STEPS, COST_REPEAT = 1000, 3


def contact_cost(spacing: float, steps: int = COST_STEPS, repeat: int = COST_REPEAT,
                 echo=print) -> dict:
    """What contact costs a step: the two bars of the collision, run ``steps`` steps on LAMMPS
    with their ``[[contact]]`` and without it (the same two parts, passing through each other),
    the variants alternating ``repeat`` times, the best CPU time of each (one process: the
    machine's load touches both alike)."""
    import tempfile

    from rackstress.engines.driver import drive
    from rackstress.engines.lammps.deck import compile_deck
    from rackstress.engines.lammps.runner import LammpsRun
    from rackstress.scenes import load

    text = COLLISION.read_text()
    plain = text.replace('[[contact]]\nbetween = ["left", "right"]', "")
    assert plain != text, "the collision scene's [[contact]] table moved"
    best = {"contact": float("inf"), "none": float("inf")}
    with tempfile.TemporaryDirectory() as tmp:
        paths = {"contact": COLLISION, "none": Path(tmp) / "collision-plain.toml"}
        paths["none"].write_text(plain)
        n = None
        for _ in range(repeat):
            for name, path in paths.items():
                sc = load(str(path), {"spacing": spacing})
                sc.phases[0] = replace(sc.phases[0], steps=steps,
                                       duration=steps * sc.dt)
                n = sc.n_particles
                run = LammpsRun(compile_deck(sc, "exact", plugin=None), None)
                try:
                    c0 = time.process_time()
                    drive(run, check_every=steps)
                    best[name] = min(best[name], time.process_time() - c0)
                finally:
                    run.close()
    row = {"spacing": spacing, "particles": n, "steps": steps, "repeat": repeat,
           "cpu_contact_s": best["contact"], "cpu_none_s": best["none"],
           "ms_per_step_contact": 1e3 * best["contact"] / steps,
           "ms_per_step_none": 1e3 * best["none"] / steps,
           "ratio": best["contact"] / best["none"]}
    echo(f"  contact cost at {spacing:g} mm ({n:,} particles): "
         f"{row['ms_per_step_contact']:.3f} ms a step with [[contact]], "
         f"{row['ms_per_step_none']:.3f} without ({row['ratio']:.2f}×)")
    return row


def run_bench(out: Path | None = None, spacings=SPACINGS, echo=print, quick: bool = False,
              examples: bool = True) -> dict:
    """The validations at each spacing, then (``examples``) the drop test and the pin joint
    as a user runs them, serial, under ``mpiexec -n 2`` and in plain ``lmp`` (``quick``: at
    the coarse spacings ``DROP_QUICK_SPACING`` and ``PIN_QUICK_SPACING``); writes
    dynamics.{json,md,png} into ``out``."""
    from rackstress.bench import out_dir

    out = out_dir(out)
    t0 = time.perf_counter()
    start = machine()
    echo("rackstress bench dynamics: free vibration of the cantilever, a bar striking a wall, "
         "two bars in contact, the drop test and the pin joint")
    data = {"vibration": [vibration(a, echo=echo) for a in spacings],
            "impact": [impact(a, echo=echo) for a in spacings],
            "collision": [collision(a, echo=echo) for a in spacings],
            "cost": [contact_cost(a, echo=echo) for a in spacings],
            "wall_s": None, "machine": start}
    if examples:
        import os

        data["examples_load_at_start"] = list(os.getloadavg())
        data["drop"] = drop(DROP_QUICK_SPACING if quick else DROP_SPACING, echo=echo)
        data["assembly"] = assembly(PIN_QUICK_SPACING if quick else PIN_SPACING, echo=echo)
        data["examples_load_at_end"] = list(os.getloadavg())
    data["wall_s"] = time.perf_counter() - t0
    plot(data, out / "dynamics.png")
    write_json(out / "dynamics.json", {**data, **{k: [{x: y for x, y in r.items()
                                                       if x != "history"} for r in data[k]]
                                                   for k in ("vibration", "impact", "collision")}})
    (out / "dynamics.md").write_text(report(data))
    echo(f"wrote {out / 'dynamics.md'} ({data['wall_s']:.0f} s)")
    return data


def plot(data: dict, path: Path) -> None:
    """The tip's history and spectrum at the finest spacing; σ_xx at mid-length over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(16, 4))
    for row in data["vibration"]:
        h = row["history"]
        t, z = np.asarray(h["t"]), np.asarray(h["tip_z"])
        v = np.diff(z) / np.diff(t)
        n = len(v)
        S = np.abs(np.fft.rfft((v - v.mean()) * np.hanning(n), 16 * n))
        f = np.fft.rfftfreq(16 * n, t[1] - t[0])
        keep = f < 16000
        ax[0].semilogy(f[keep], S[keep] / S.max(), lw=0.8, label=f"{row['spacing']:g} mm")
    for k, x in enumerate(data["vibration"][0]["timoshenko"]):
        ax[0].axvline(x, color="k", ls="--", lw=0.6, label="Timoshenko" if k == 0 else None)
    for k, x in enumerate(data["vibration"][0]["euler_bernoulli"]):
        ax[0].axvline(x, color="grey", ls=":", lw=0.8, label="Euler–Bernoulli" if k == 0 else None)
    ax[0].set(xlabel="frequency [Hz]", ylabel="tip velocity spectrum (relative)",
              title="free vibration: the tip's spectrum", ylim=(1e-4, 2))
    ax[0].legend(fontsize=8)
    for row in data["impact"]:
        h = row["history"]
        ax[1].plot(np.asarray(h["t"]) * 1e6, h["sigma_xx"], lw=0.9, label=f"{row['spacing']:g} mm")
    r = data["impact"][0]
    ax[1].axhline(r["sigma_expected"], color="k", ls="--", lw=0.7, label="−ρ·c·v")
    ax[1].axvline(r["arrival_expected"] * 1e6, color="grey", ls=":", lw=0.8, label="x / c")
    ax[1].axvline((2 * L - r["x"]) / r["c"] * 1e6, color="grey", ls="-.", lw=0.8,
                  label="reflection back")
    ax[1].set(xlabel="time [µs]", ylabel="σ_xx at mid-length [MPa]",
              title="a bar striking a wall at 1 m/s")
    ax[1].legend(fontsize=8)
    for row in data["collision"]:
        h = row["history"]
        ax[2].plot(np.asarray(h["t"]) * 1e6, h["sigma_xx"], lw=0.9,
                   label=f"{row['spacing']:g} mm")
    r = data["collision"][0]
    ax[2].axhline(r["sigma_expected"], color="k", ls="--", lw=0.7, label="−ρ·c·v/2")
    ax[2].axvline(r["contact_expected"] * 1e6, color="grey", ls=":", lw=0.8,
                  label="2L/c: contact ends")
    ax[2].set(xlabel="time [µs]", ylabel="σ_xx at the struck bar's mid-length [MPa]",
              title="two bars through [[contact]], 1 m/s")
    ax[2].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def report(data: dict) -> str:
    """docs/benchmarks/dynamics.md from the bench's data."""
    v, m = data["vibration"], data["impact"]
    lines = [
        "# Dynamics: free vibration, a bar striking a wall, two bars in contact, in physical "
        "units" + ("; the drop test and the pin joint on every engine" if data.get("drop")
                   else ""),
        "",
        "Generated by `rackstress bench dynamics` (workflow/rackstress/bench/dynamics.py); do "
        "not edit by hand. The scenes are in `examples/dynamics/`, stepped on LAMMPS as "
        "`rackstress run` steps them, at the scene's own time step (half the predicted "
        f"stability limit). Machine: {data['machine']['cores']} cores ({data['machine']['cpu']}), "
        f"load average {data['machine']['load_avg_at_start'][0]:.2f} at the start; "
        f"{data['wall_s']:.0f} s in all.",
        "",
        "## Free vibration of the cantilever",
        "",
        "The aluminium bar 100 × 10 × 10 mm (E = 70 GPa, ν = 0.33, 2700 kg/m³) moving down at "
        "100 mm/s when its root face is clamped, 2.5 ms (two periods of f1). f1–f3 are the "
        "three lowest peaks of the tip's vertical velocity spectrum, their frequencies refined "
        "by a least-squares fit of sinusoids to the record. *Timoshenko*: the beam with shear and rotary inertia "
        "(κ = 10(1 + ν)/(12 + 11ν)), by its own 800 finite elements; *E–B*: Euler–Bernoulli, "
        "β_nL = 1.8751, 4.6941, 7.8548. At L/h = 10 the bar follows Timoshenko: its f2 and f3 "
        "are 5 % and 11 % below Euler–Bernoulli's. What the lattice itself gets wrong: a "
        "particle's inertia is its whole cell's, ρ·a³, also for the free end's layer, whose "
        "cell is half outside the bar (its stiffness is weighted for that, docs/calibration.md "
        "\"Walls of any thickness\"; its mass is not), which lowers f by about a/L; and five "
        "layers across the bar lump its bending stiffness coarsely.",
        "",
        "| spacing [mm] | particles | steps | wall [s] | f1, f2, f3 [Hz] | Timoshenko [Hz] | "
        "against Timoshenko | against E–B |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in v:
        lines.append(
            f"| {r['spacing']:g} | {r['particles']:,} | {r['steps']:,} | {r['wall_s']:.1f} | "
            + ", ".join(f"{x:.0f}" for x in r["f"]) + " | "
            + ", ".join(f"{x:.0f}" for x in r["timoshenko"]) + " | "
            + ", ".join(f"{100 * x:+.1f} %" for x in r["vs_timoshenko"]) + " | "
            + ", ".join(f"{100 * x:+.1f} %" for x in r["vs_euler_bernoulli"]) + " |")
    lines += [
        "",
        "## A bar striking a wall",
        "",
        "The same bar moving at 1 m/s along −x when its end face x = 0 is held. Behind the "
        "compression front it is at rest under σ_xx = −ρ·c·v with c = √(E/ρ) = "
        f"{m[0]['c'] / 1e3:,.0f} m/s, the bar speed (the long-wavelength limit of the lattice's "
        "longitudinal waves in a bar with free faces; the lattice is calibrated to E, so its c "
        "is the material's as far as its E_eff is). *σ_xx*: the mid-length cross-section's "
        "mean (the bindings' virial over each particle's share of the bar), its plateau the "
        "mean from a quarter of the way between the front and the return of the free end's "
        "reflection to a fifth of that interval before it (± its standard deviation: the ringing of "
        "the dispersive front); *arrival*: the time t_a of the step that carries the same "
        "impulse up to the plateau's start T, σ_plateau·(T − t_a) = ∫₀ᵀ σ_xx dt (the front "
        "rises in stairs — the bar's lateral ringing — so where it first reaches half the "
        "plateau is not a sound measure).",
        "",
        "| spacing [mm] | particles | steps | wall [s] | σ_xx plateau [MPa] | −ρ·c·v [MPa] | "
        "ratio | arrival [µs] | x / c [µs] | ratio |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in m:
        lines.append(
            f"| {r['spacing']:g} | {r['particles']:,} | {r['steps']:,} | {r['wall_s']:.1f} | "
            f"{r['sigma_plateau']:.2f} ± {r['sigma_spread']:.2f} | {r['sigma_expected']:.2f} | "
            f"{r['sigma_ratio']:.3f} | {r['arrival'] * 1e6:.2f} | "
            f"{r['arrival_expected'] * 1e6:.2f} | {r['arrival_ratio']:.3f} |")
    c = data["collision"]
    lines += [
        "",
        "## Two parts in contact",
        "",
        "Two aluminium bars 50 × 10 × 10 mm end to end (`examples/dynamics/collision.toml`), "
        "the left one moving at 1 m/s into the right one at rest, touching through "
        "`[[contact]]`: the paper's collide (Eq. 10) with its coefficient from the two "
        "materials, the pair stiffness E*·a (docs/calibration.md \"Contact\"). Equal bars "
        "exchange their motion: a wave of σ_xx = −ρ·c·v/2 runs into each, and after 2L/c the "
        "left bar stands still and the right one leaves at v. *L* is the lattice's bar, n·a "
        "(its particles sit on both end faces: 26 layers of 2 mm carry 52 mm of bar), "
        "*contact* the time until the facing layers are again the sum of their radii apart, "
        "*after* the bars' velocities fitted over the last part of the run; their sum is "
        "the momentum, which the contact keeps.",
        "",
        "| spacing [mm] | particles | steps | wall [s] | σ_xx plateau [MPa] | −ρ·c·v/2 [MPa] | "
        "ratio | contact [µs] | 2L/c [µs] | ratio | after [mm/s] | momentum after/before |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in c:
        lines.append(
            f"| {r['spacing']:g} | {r['particles']:,} | {r['steps']:,} | {r['wall_s']:.2f} | "
            f"{r['sigma_plateau']:.2f} ± {r['sigma_spread']:.2f} | {r['sigma_expected']:.2f} | "
            f"{r['sigma_ratio']:.3f} | {r['contact'] * 1e6:.2f} | "
            f"{r['contact_expected'] * 1e6:.2f} | {r['contact_ratio']:.3f} | "
            f"{r['velocity_after'][0]:.0f}, {r['velocity_after'][1]:.0f} | "
            f"{r['momentum_ratio']:.4f} |")
    if data.get("cost"):
        lines += [
            "",
            "**What contact costs a step**: the same two bars run "
            f"{data['cost'][0]['steps']:,} steps with their `[[contact]]` and without it (then "
            "they pass through each other), on LAMMPS in this process, the variants alternating "
            f"{data['cost'][0]['repeat']} times, the best CPU time of each. The contact is "
            "the plugin's `rs/collide`, one fix a side, over the pairs its own search finds "
            "near the other part (LAMMPS' `pair_style lepton` gives the same forces to "
            "round-off but parses its expression every step).",
            "",
            "| spacing [mm] | particles | with `[[contact]]` [ms a step] | without [ms a step] | "
            "ratio |",
            "|---|---|---|---|---|",
        ]
        for r in data["cost"]:
            lines.append(f"| {r['spacing']:g} | {r['particles']:,} | "
                         f"{r['ms_per_step_contact']:.3f} | {r['ms_per_step_none']:.3f} | "
                         f"{r['ratio']:.2f} |")
    lines += ["", "![The tip's spectrum, σ_xx at mid-length, the bars in contact](dynamics.png)",
              ""]
    if data.get("drop"):
        lines += examples_report(data)
    return "\n".join(lines)


# ----------------------------------------------------------------------------- the examples
#: the two examples the targets name, run as a user runs them (``rackstress run``)
DROP = repository_file("examples", "dynamics", "drop.toml")
PIN_JOINT = repository_file("examples", "assembly", "pin-joint.toml")
#: the drop's spacing (mm) for about 20,000 particles, bracket and floor together, and the
#: quick variant's (a few hundred: seconds)
DROP_SPACING, DROP_QUICK_SPACING = 0.875, 3.0
#: the pin joint's spacing: the scene's own (1 mm), and the quick variant's
PIN_SPACING, PIN_QUICK_SPACING = 1.0, 2.0
#: the targets, one core: the drop over its impact, the assembly's static solve (s)
DROP_TARGET_S, ASSEMBLY_TARGET_S = 60.0, 30.0
def _command(cmd, cwd=None, timeout: float = 3600.0):
    """:func:`rackstress.bench.timed` on one thread a rank
    (:data:`rackstress.bench.ONE_THREAD`)."""
    return timed(cmd, cwd=cwd, timeout=timeout, env=ONE_THREAD)


def _rackstress(*args, ranks: int = 1):
    """``rackstress ARGS`` as a user runs it, on one thread a rank, under ``mpiexec -n ranks``
    when ranks > 1."""
    return _command(rackstress_command(*args, ranks=ranks))


def _frames_of(dump: Path, o: np.ndarray) -> tuple:
    """(steps, positions frames × n × 3 in id order) of a rackstress or plain-lmp dump, a
    particle a frame leaves out at ``o`` (engines/dumpio.read_frames)."""
    from rackstress.engines.dumpio import read_frames

    steps, frames = [], []
    for s, p in read_frames(dump, o):
        steps.append(s)
        frames.append(p)
    return np.asarray(steps), np.asarray(frames)


def _dump_unit(x: np.ndarray) -> np.ndarray:
    """One unit of the 10th significant digit of each coordinate (the dump's ``%.10g``), of 1
    where it is smaller (the precision of the scene's lengths)."""
    return 10.0 ** (np.floor(np.log10(np.maximum(np.abs(x), 1.0))) - 9)


def _compare(frames: tuple, ref: tuple) -> dict:
    """How far a trajectory is from the reference one over the steps both dumped (a plain
    ``lmp`` deck has no extra final frame: ``rackstress run`` adds one when the run's last
    step is not a multiple of the dump interval): the largest position difference (mm) in
    their last common frame and over every common frame, and whether every coordinate is the
    reference's to the dump's precision (one unit of its 10th digit)."""
    (s1, x1), (s2, x2) = frames, ref
    common, i1, i2 = np.intersect1d(s1, s2, return_indices=True)
    if not len(common):
        return {"frames": 0, "frames_own": int(len(s1)), "frames_ref": int(len(s2))}
    x1, x2 = x1[i1], x2[i2]
    d = np.abs(x1 - x2)
    worst = d.max(axis=(1, 2))
    return {"frames": int(len(common)), "frames_own": int(len(s1)), "frames_ref": int(len(s2)),
            "last_step": int(common[-1]),
            "final_max_mm": float(d[-1].max()), "any_frame_max_mm": float(worst.max()),
            "first_step_differing": (int(common[np.flatnonzero(worst > 0)[0]])
                                     if (worst > 0).any() else None),
            "to_dump_precision": bool((d <= _dump_unit(x2) * 1.000001).all())}


def _peak_of(rundir: Path, group: str) -> dict:
    """The run's own record of its largest von Mises stress over the frames in ``group``
    (summary.json ``groups.<group>.peak.von_mises``: value, when, which particle) and its
    governing stress (``stress.governing``: the largest away from singular points)."""
    import json

    s = json.loads((Path(rundir) / "summary.json").read_text())
    pk = s["groups"][group]["peak"]["von_mises"]
    gov = (s.get("stress") or {}).get("governing") or {}
    return {"value": pk["value"], "time": pk["time"], "iteration": pk["iteration"],
            "particle": pk["particle"], "original": pk["original"], "units": pk["units"],
            "governing": gov.get("value"), "governing_part": gov.get("group"),
            "governing_time": (gov["iteration"] * s["dt"] if gov.get("iteration") is not None
                               else None),
            "governing_particle": gov.get("particle")}


def drop(spacing: float = DROP_SPACING, engines=("mpi", "lmp"), root: Path | None = None,
         echo=print, dump_every: int | None = None) -> dict:
    """``examples/dynamics/drop.toml`` at ``spacing`` as a user runs it: ``rackstress run``
    on one core (LAMMPS, the plugin), the particles, steps, wall and CPU time and the peak von
    Mises stress over the impact (the run's own summary.json: its largest over the frames,
    which particle and when). ``engines``: the same scene also under ``mpiexec -n 2``
    (``"mpi"``) and as a deck in plain ``lmp`` (``"lmp"``: ``rackstress deck``, then ``lmp
    -in in.lammps``, its trajectory measured by ``rackstress stress`` beside the run's
    scene.json), each against the serial run: its positions, frame by frame, and its peak.
    ``root``: keep the runs in a new directory there (default: a temporary one, removed);
    ``dump_every``: the runs' ``--dump-every`` (default the scene's own, ~100 frames)."""
    import shutil
    import tempfile

    from rackstress.stress.rundata import load_run

    tmp = Path(tempfile.mkdtemp(prefix="drop-", dir=root))
    try:
        sets = ["--set", f"spacing={spacing:g}"]
        if dump_every:
            sets += ["--dump-every", str(dump_every)]
        common = ["--no-render", "--no-progress", *sets]
        serial = tmp / "serial"
        _, wall, cpu = _rackstress("run", DROP, "--out", serial, *common)
        s = _summary(serial)
        run = load_run(serial)
        o = run.o
        nb = len(run.parts["bracket"].index)
        row = {"spacing": spacing, "particles": s["n_particles"], "bracket": nb,
               "floor": s["n_particles"] - nb, "steps": s["steps"], "dt": s["dt"],
               "duration": s["steps"] * s["dt"], "frames": None, "ranks": s.get("ranks"),
               "sim_wall_s": s["wall_s"], "driver_s": s.get("driver_s"),
               "command_wall_s": wall, "command_cpu_s": cpu,
               "peak": _peak_of(serial, "bracket"), "target_s": DROP_TARGET_S,
               "speed": float(np.sqrt(2 * 9810.0 * 500.0))}
        ref = _frames_of(_trajectory(serial), o)
        row["frames"] = int(len(ref[0]))
        row["contact"] = _drop_contact(serial, s["dt"])
        row["velocity"] = _drop_energy(ref, run, s["dt"])
        say = (f"  drop at {spacing:g} mm ({row['particles']:,} particles: bracket {nb:,}, "
               f"floor {row['floor']:,}; {row['steps']:,} steps): simulation "
               f"{row['sim_wall_s']:.1f} s, the command {wall:.1f} s wall, {cpu:.1f} s CPU; "
               f"peak von Mises {row['peak']['value']:.1f} MPa at "
               f"{row['peak']['time'] * 1e6:.1f} µs (particle {row['peak']['particle']})")
        echo(say)
        if "mpi" in engines:
            mpi = tmp / "mpi"
            _, w2, c2 = _rackstress("run", DROP, "--out", mpi, *common, ranks=2)
            s2 = _summary(mpi)
            row["mpi"] = {"ranks": s2.get("ranks"), "sim_wall_s": s2["wall_s"],
                          "command_wall_s": w2, "command_cpu_s": c2,
                          "peak": _peak_of(mpi, "bracket"),
                          **_compare(_frames_of(_trajectory(mpi), o), ref)}
            echo(f"    mpiexec -n 2: {_agreement(row['mpi'], row['peak'])}")
        if "lmp" in engines:
            deck = tmp / "deck"
            _rackstress("deck", DROP, "--out", deck, *sets)
            _, w3, c3 = _command([program("lmp"), "-in", "in.lammps", "-log", "log.lammps",
                                  "-screen", "none"], cwd=deck)
            # measured as a run: the serial run's scene.json beside lmp's data and dump
            meas = tmp / "lmp"
            meas.mkdir()
            for f in serial.iterdir():
                if f.is_file() and f.name in ("scene.json", "summary.json", "singular.npz",
                                              "volumes.npz", "bindings.npz"):
                    shutil.copy(f, meas / f.name)
            shutil.copy(deck / "particles.data", meas / "particles.data")
            shutil.copy(deck / "trajectory.dump", meas / "trajectory.dump")
            same_data = (deck / "particles.data").read_bytes() == \
                (serial / "particles.data").read_bytes()
            same_deck = (deck / "in.lammps").read_text() == (serial / "in.lammps").read_text()
            _rackstress("stress", meas, "--no-vtk", "--no-dump", "--no-progress")
            row["lmp"] = {"lmp_wall_s": w3, "lmp_cpu_s": c3, "same_data_file": same_data,
                          "same_deck": same_deck,
                          "peak": _peak_of(meas, "bracket"),
                          **_compare(_frames_of(meas / "trajectory.dump", o), ref)}
            echo(f"    plain lmp: {_agreement(row['lmp'], row['peak'])}")
        return row
    finally:
        if root is None:                  # ``root`` given: its runs are kept there
            shutil.rmtree(tmp, ignore_errors=True)


def _drop_contact(rundir: Path, dt: float) -> dict | None:
    """The bracket–floor contact's largest pressure over the frames (stress.json ``contact``),
    on which part and when."""
    import json

    st = json.loads((Path(rundir) / "stress.json").read_text())
    for c in st.get("contact") or []:
        if c.get("touching"):
            return {"peak": c["peak"], "group": c["group"], "particle": c["particle"],
                    "time": c["iteration"] * dt, "units": c["units"]}
    return None


def _summary(rundir: Path) -> dict:
    import json

    return json.loads((Path(rundir) / "summary.json").read_text())


def _trajectory(rundir: Path) -> Path:
    """A finished run's trajectory (``trajectory.dump.gz``), or the text one."""
    gz = Path(rundir) / "trajectory.dump.gz"
    return gz if gz.is_file() else Path(rundir) / "trajectory.dump"


def _agreement(r: dict, peak: dict) -> str:
    if not r.get("frames"):
        return "no frame in common"
    pos = ("every frame's positions the serial run's to the dump's precision"
           if r["to_dump_precision"] else
           f"positions within {r['any_frame_max_mm']:.3g} mm of the serial run's over "
           f"{r['frames']} frames ({r['final_max_mm']:.3g} mm at the end)")
    return (f"{pos}; peak von Mises {r['peak']['value']:.4f} MPa against "
            f"{peak['value']:.4f} at {r['peak']['time'] * 1e6:.2f} µs")


def _drop_energy(ref: tuple, run, dt: float) -> dict:
    """The bracket's vertical velocity (mm/s: its centre of mass, one material on one
    lattice, so the mean of its particles, differenced between frames) over the first frames
    and the last, against √(2·g·h): it lands, and does not leave faster than it came."""
    steps, x = ref
    b = run.parts["bracket"].index
    yc = x[:, b, 1].mean(axis=1)
    v = np.diff(yc) / np.diff(steps * dt)
    return {"v_start": float(v[0]), "v_end": float(v[-1]), "v_min": float(v.min()),
            "v_max": float(v.max())}


def assembly(spacing: float = PIN_SPACING, engines=("mpi", "lmp"), root: Path | None = None,
             echo=print) -> dict:
    """``examples/assembly/pin-joint.toml`` (static) as a user runs it: ``rackstress run`` on
    one core, the particles, Newton steps, active sets, wall and CPU, the largest contact
    pressure and the governing stress. ``engines``: ``"mpi"``, the same under ``mpiexec -n
    2`` (the solve is rank 0's alone, engines/static.py; LAMMPS on both ranks checks the
    equilibrium it found); ``"lmp"``, the equilibrium's deck the run leaves (``in.lammps``:
    its positions, ``run 0``) in plain ``lmp``, its largest unbalanced force against the
    run's own check."""
    import json
    import shutil
    import tempfile

    tmp = Path(tempfile.mkdtemp(prefix="pin-", dir=root))
    try:
        common = ["--no-render", "--no-progress", "--set", f"spacing={spacing:g}"]
        serial = tmp / "serial"
        _, wall, cpu = _rackstress("run", PIN_JOINT, "--out", serial, *common)
        s = _summary(serial)
        st = json.loads((serial / "stress.json").read_text())
        row = {"spacing": spacing, "particles": s["n_particles"],
               "status": s["status"], "iterations": s["iterations"],
               "contact_sets": s.get("contact_sets"), "factorizations": s.get("factorizations"),
               "solver": s.get("solver"), "residual": s["residual"],
               "solve_s": s.get("solve_s"), "sim_wall_s": s["wall_s"],
               "command_wall_s": wall, "command_cpu_s": cpu, "target_s": ASSEMBLY_TARGET_S,
               **_assembly_stress(serial, st)}
        echo(f"  pin joint at {spacing:g} mm ({row['particles']:,} particles): {row['status']} "
             f"in {row['iterations']} Newton steps, {row['contact_sets']} active sets; solve "
             f"{row['solve_s']:.1f} s, the command {wall:.1f} s wall, {cpu:.1f} s CPU; contact "
             f"pressure up to {row['contact_peak']:.1f} MPa, governing {row['governing']:.1f} "
             f"MPa ({row['governing_part']})")
        p_ref = _final_positions(serial)
        if "mpi" in engines:
            mpi = tmp / "mpi"
            _, w2, c2 = _rackstress("run", PIN_JOINT, "--out", mpi, *common, ranks=2)
            s2 = _summary(mpi)
            st2 = json.loads((mpi / "stress.json").read_text())
            d = np.abs(_final_positions(mpi) - p_ref)
            row["mpi"] = {"ranks": s2.get("ranks"), "status": s2["status"],
                          "iterations": s2["iterations"], "residual": s2["residual"],
                          "residual_engine": s2["residual_engine"],
                          "command_wall_s": w2, "command_cpu_s": c2,
                          "final_max_mm": float(d.max()),
                          "to_dump_precision": bool((d <= _dump_unit(p_ref) * 1.000001).all()),
                          **_assembly_stress(mpi, st2)}
            echo(f"    mpiexec -n 2: {s2['status']}, positions within "
                 f"{row['mpi']['final_max_mm']:.3g} mm; contact pressure "
                 f"{row['mpi']['contact_peak']:.4f} MPa, governing "
                 f"{row['mpi']['governing']:.4f} MPa")
        if "lmp" in engines:
            plain = tmp / "lmp"
            plain.mkdir()
            for name in ("in.lammps", "particles.data", "equilibrium.dump"):
                shutil.copy(serial / name, plain / name)
            _, w3, c3 = _command([program("lmp"), "-in", "in.lammps", "-log", "log.lammps",
                                  "-screen", "none"], cwd=plain)
            rows = (plain / "forces.dump").read_text().split("ITEM: ATOMS")[1].splitlines()[1:]
            fa = np.array([ln.split() for ln in rows if ln.strip()], float)
            fa = fa[np.argsort(fa[:, 0])][:, 1:4]
            from rackstress.scenes import load

            sc = load(str(PIN_JOINT), {"spacing": spacing})
            md = np.concatenate([np.full(g.n, s["masses"][n]) for n, g in sc.groups.items()])
            worst = float(np.linalg.norm(fa * (sc.masses() / md)[:, None], axis=1).max())
            row["lmp"] = {"lmp_wall_s": w3, "lmp_cpu_s": c3,
                          "residual": worst / s["applied_load_total"],
                          "residual_run": s["residual_engine"]}
            echo(f"    plain lmp (the equilibrium's deck, run 0): unbalanced "
                 f"{row['lmp']['residual']:.4g} of the load against the run's "
                 f"{s['residual_engine']:.4g}")
        return row
    finally:
        if root is None:                  # ``root`` given: its runs are kept there
            shutil.rmtree(tmp, ignore_errors=True)


def _assembly_stress(rundir: Path, st: dict) -> dict:
    """The largest contact pressure (stress.json ``contact``: per contact and part) and the
    governing stress (``governing``) of a pin-joint run, in MPa."""
    touching = [c for c in st["contact"] if c.get("touching")]
    contacts = {f"{c['group']} ({'–'.join(c['parts'])})": c["peak"] for c in touching}
    top = max(touching, key=lambda c: c["peak"])
    gov = st.get("governing") or {}
    return {"contact": contacts, "contact_peak": top["peak"], "contact_peak_on": top["group"],
            "contact_peak_parts": top["parts"], "governing": gov.get("value"),
            "governing_part": gov.get("group"),
            "governing_parts": {k: ((v or {}).get("governing") or {}).get("value")
                                for k, v in (st.get("governing_parts") or {}).items()}}


def _final_positions(rundir: Path) -> np.ndarray:
    """The equilibrium a static run wrote (its last frame), in id order."""
    from rackstress.stress.rundata import load_run

    run = load_run(rundir)
    return _frames_of(_trajectory(rundir), run.o)[1][-1]


def _s(x, digits: int = 1) -> str:
    return "—" if x is None else f"{x:,.{digits}f}"


def _positions(r: dict) -> str:
    """The agreement of a trajectory with the serial run's, in words (:func:`_compare`)."""
    if not r.get("frames", 1):
        return "no frame in common"
    n = f"{r['frames']} frames"
    if r.get("frames_own", r["frames"]) != r.get("frames_ref", r["frames"]):
        n += (f" (its {r['frames_own']} against {r['frames_ref']}: `rackstress run` adds the "
              "last step's frame)")
    if r.get("any_frame_max_mm") == 0.0:
        return f"identical in every dumped digit, {n}"
    if r.get("to_dump_precision"):
        return (f"the same to the dump's precision (`%.10g`): at most "
                f"{r['any_frame_max_mm']:.2g} mm, one unit of the 10th digit, from step "
                f"{r['first_step_differing']:,} on; {n}")
    return (f"{r['final_max_mm']:.3g} mm at the end, {r['any_frame_max_mm']:.3g} mm at most "
            f"over {n}")


def examples_report(data: dict) -> list:
    """The drop test's and the pin joint's sections of docs/benchmarks/dynamics.md."""
    d, a = data["drop"], data.get("assembly")
    pk = d["peak"]
    load0, load1 = data["examples_load_at_start"], data["examples_load_at_end"]
    met = d["sim_wall_s"] <= d["target_s"]
    drv = d.get("driver_s") or {}
    lines = [
        "## The examples on every engine: the drop test and the pin joint",
        "",
        "Each run as a user runs it, `rackstress run SCENE --set spacing=… --no-render` in a "
        "process of its own (LAMMPS and the compiled plugin, every library on one thread: "
        "`MKL_NUM_THREADS`, `OMP_NUM_THREADS`, `OPENBLAS_NUM_THREADS`, `NUMBA_NUM_THREADS` = "
        "1), then the same scene under the venv's `mpiexec -n 2` and in plain `lmp`. "
        "*Simulation*: the run's own `wall_s` (summary.json), the time stepping or the static "
        "solve; *command*: the whole process, from its start to its last file (the scene "
        "built, the run, the stress measures: `rackstress run`'s post-processing, partly "
        "beside the run), its CPU time every process's and thread's. Load average "
        f"{load0[0]:.2f} when these runs started, {load1[0]:.2f} when they ended (2 cores, "
        "shared: the CPU time is the sounder figure; two ranks of one run contend with "
        "whatever else runs).",
        "",
        "### A drop test",
        "",
        "`examples/dynamics/drop.toml`: the aluminium bracket of `examples/bracket/` falling "
        f"0.5 m onto a steel floor, arriving at √(2·g·h) = {d['speed'] / 1e3:.3f} m/s on the "
        "end of its leg, through `[[contact]]` from the two materials, "
        f"{d['duration'] * 1e6:.0f} µs (the impact and a first swing of the arm). At "
        f"{d['spacing']:g} mm: {d['particles']:,} particles, the bracket {d['bracket']:,} and "
        f"the floor {d['floor']:,}. *Peak*: the run's own record (summary.json "
        "`groups.bracket.peak.von_mises`), the largest von Mises stress of any bracket "
        f"particle over the run's {d['frames']} frames, which particle and when (every "
        "particle's own peak and its time: the run's `vtk/peaks_over_time.vtp`); "
        "*governing*: the largest away from the singular points (summary.json "
        "`stress.governing`).",
        "",
        "| spacing [mm] | particles | steps | simulation [s] | command wall [s] | command CPU "
        "[s] | peak von Mises [MPa] | at [µs] | particle (its original x, y, z [mm]) | "
        "governing [MPa] |",
        "|---|---|---|---|---|---|---|---|---|---|",
        f"| {d['spacing']:g} | {d['particles']:,} | {d['steps']:,} | {d['sim_wall_s']:.1f} | "
        f"{d['command_wall_s']:.1f} | {d['command_cpu_s']:.1f} | {pk['value']:.1f} | "
        f"{pk['time'] * 1e6:.1f} | {pk['particle']} ("
        + ", ".join(f"{x:.2f}" for x in pk["original"]) + f") | {_s(pk['governing'])} |",
        "",
        f"**Target** (one core, {d['target_s']:.0f} s for 20,000 particles over the impact): "
        + ("met" if met else "**not met**") + f", {d['sim_wall_s']:.1f} s of simulation "
        f"({d['particles']:,} particles, {d['steps']:,} steps: "
        f"{1e3 * d['sim_wall_s'] / d['steps']:.2f} ms a step"
        + (f"; {drv['steps_s']:.1f} s of it in LAMMPS' steps, {drv.get('checks_s', 0):.1f} s "
           f"in the watchdog's checks" if drv.get("steps_s") is not None else "")
        + f"); the whole command {d['command_wall_s']:.1f} s.",
        "",
        "| engine | simulation [s] | wall [s] | CPU [s] | positions against the serial run | "
        "peak von Mises [MPa] | at [µs] |",
        "|---|---|---|---|---|---|---|",
        f"| `rackstress run`, 1 rank | {d['sim_wall_s']:.1f} | {d['command_wall_s']:.1f} | "
        f"{d['command_cpu_s']:.1f} | — | {pk['value']:.4f} | {pk['time'] * 1e6:.2f} |",
    ]
    if d.get("mpi"):
        m = d["mpi"]
        lines.append(f"| `mpiexec -n 2 rackstress run` | {m['sim_wall_s']:.1f} | "
                     f"{m['command_wall_s']:.1f} | "
                     f"{m['command_cpu_s']:.1f} | {_positions(m)} | {m['peak']['value']:.4f} | "
                     f"{m['peak']['time'] * 1e6:.2f} |")
    if d.get("lmp"):
        m = d["lmp"]
        lines.append(f"| `rackstress deck`, then `lmp -in in.lammps` | — | {m['lmp_wall_s']:.1f} "
                     f"(lmp) | {m['lmp_cpu_s']:.1f} | {_positions(m)} | "
                     f"{m['peak']['value']:.4f} | {m['peak']['time'] * 1e6:.2f} |")
    lines += [
        "",
        "The positions are compared frame by frame, every particle of every frame both "
        "dumped (the scene has no resting group: each frame holds all of them). Plain `lmp` "
        "runs the deck `rackstress deck` writes ("
        + ("the run's own `in.lammps` and `particles.data`, byte for byte"
           if (d.get("lmp") or {}).get("same_data_file") and (d.get("lmp") or {}).get(
               "same_deck") else "**not** the run's own deck")
        + "); its trajectory is measured by `rackstress stress` beside the serial run's "
        "scene.json, so its peak is the same measure of lmp's own positions. Two ranks split "
        "the particles between them, and each particle's forces can be summed in another order "
        "where its neighbours sit on the other rank: round-off apart, which an impact that "
        "rings for hundreds of microseconds could grow; over this run it stays within the "
        "dump's last digit, and the peak is the same to every digit printed.",
        "",
        "**The contact**: the scene places the leg's end one spacing (the contact's R, two "
        "radii) above the floor's top layer, so the impact starts at t = 0. "
        + (f"Its largest contact pressure, {d['contact']['peak']:.1f} MPa on the "
           f"{d['contact']['group']}, comes at {d['contact']['time'] * 1e6:.1f} µs; for scale, "
           "a plane wave in a bar striking a bar of the other material carries "
           "v·Z₁·Z₂/(Z₁ + Z₂) = 32.0 MPa (Z = √(E·ρ), 13.7 and 39.6 MN·s/m³; a hand "
           "estimate, not the bracket's three-dimensional leg end). " if d.get("contact")
           else "")
        + f"**What the bracket does**: it arrives at {-d['velocity']['v_start']:,.0f} mm/s (its "
        "centre of mass over the first frames) and its centre of mass moves at "
        f"{d['velocity']['v_end']:+,.0f} mm/s (+: up) at the end, the rest of the impact "
        "ringing in the bracket (no damping).",
        "",
    ]
    if a:
        lines += [
            "### An assembly: the pin joint, static",
            "",
            "`examples/assembly/pin-joint.toml`: an aluminium lug pinned in an aluminium "
            "clevis by a steel pin, touching only through `[[contact]]`, 5 kN in double shear "
            "(the quarter model). A static run settles the contact by active sets (a penalty "
            "Newton on the pairs in contact, taken anew until they stay): *Newton steps* and "
            "*active sets* are summary.json's `iterations` and `contact_sets`. *Contact "
            "pressure*: stress.json `contact`, the largest on any part; *governing*: the "
            "largest von Mises stress away from the singular points (the contact's edges "
            "among them, docs/stress.md).",
            "",
            "| spacing [mm] | particles | status | Newton steps | active sets | solve [s] | "
            "simulation [s] | command wall [s] | command CPU [s] | largest contact pressure "
            "[MPa] | governing [MPa] |",
            "|---|---|---|---|---|---|---|---|---|---|---|",
            f"| {a['spacing']:g} | {a['particles']:,} | {a['status']} | {a['iterations']} | "
            f"{a['contact_sets']} | {_s(a['solve_s'])} | {a['sim_wall_s']:.1f} | "
            f"{a['command_wall_s']:.1f} | {a['command_cpu_s']:.1f} | {a['contact_peak']:.1f} "
            f"(on the {a['contact_peak_on']}) | {_s(a['governing'])} ({a['governing_part']}) |",
            "",
            "By hand (the scene's comments, F = 5 kN, d = 10 mm, lug t = 10 mm): bearing "
            "F/(d·t) = 50 MPa, the close fit's cosine contact pressure 4F/(π·d·t) = 63.7 MPa "
            "at its peak, the pin's bending as a beam on the cheeks 153 MPa (the handbook's "
            "conservative model). The largest contact pressure sits on a hole's rim, where the "
            "contact reaches a face's edge (singular: it grows as the spacing shrinks); the "
            "governing stress is read away from such points.",
            "",
            f"**Target** (one core, {a['target_s']:.0f} s for the static assembly): "
            + ("met" if a["sim_wall_s"] <= a["target_s"] else "**not met**")
            + f", {a['sim_wall_s']:.1f} s (the whole command {a['command_wall_s']:.1f} s).",
            "",
        ]
        if a.get("mpi"):
            m = a["mpi"]
            lines += [
                "**Under `mpiexec -n 2`**: a static run's solve is not parallel. Rank 0 alone "
                "solves the equilibrium (`rackstress.runs.run.execute_static`: Newton's method "
                "on a sparse tangent, SciPy and PARDISO in one process) and broadcasts it; "
                "LAMMPS on both ranks then computes the forces at it (`run 0`), the run's "
                "check. So two ranks give the serial run's answer, not a faster one: "
                f"{m['status']}, {m['iterations']} Newton steps, the equilibrium "
                + ("identical to the serial run's in every dumped digit"
                   if m["final_max_mm"] == 0.0 else
                   "the serial run's to the dump's precision" if m["to_dump_precision"] else
                   f"within {m['final_max_mm']:.3g} mm of the serial run's")
                + f", the largest contact pressure {m['contact_peak']:.4f} MPa (serial "
                f"{a['contact_peak']:.4f}), governing {_s(m['governing'], 4)} MPa (serial "
                f"{_s(a['governing'], 4)}); LAMMPS on two ranks leaves "
                f"{m['residual_engine']:.3g} of the load unbalanced; the command "
                f"{m['command_wall_s']:.1f} s wall, {m['command_cpu_s']:.1f} s CPU.",
                "",
            ]
        if a.get("lmp"):
            m = a["lmp"]
            lines += [
                "**In plain `lmp`**: a static scene is no deck LAMMPS can solve — LAMMPS "
                "steps in time, the equilibrium is the Newton solver's. What a static run "
                "leaves is the equilibrium's deck: `in.lammps` reads the equilibrium's "
                "positions (`equilibrium.dump`) and runs `run 0`, writing the forces there "
                f"(`forces.dump`). Plain `lmp` on it: the largest unbalanced force "
                f"{m['residual']:.4g} of the load against the run's own check "
                f"{m['residual_run']:.4g} ({m['lmp_wall_s']:.1f} s).",
                "",
            ]
    return lines

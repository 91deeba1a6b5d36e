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

from rackstress.bench import machine, repository_file, write_json

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


def run_bench(out: Path | None = None, spacings=SPACINGS, echo=print) -> dict:
    """Both validations at each spacing; writes dynamics.{json,md,png} into ``out``."""
    from rackstress.bench import out_dir

    out = out_dir(out)
    t0 = time.perf_counter()
    echo("rackstress bench dynamics: free vibration of the cantilever, a bar striking a wall, "
         "two bars in contact")
    data = {"vibration": [vibration(a, echo=echo) for a in spacings],
            "impact": [impact(a, echo=echo) for a in spacings],
            "collision": [collision(a, echo=echo) for a in spacings],
            "cost": [contact_cost(a, echo=echo) for a in spacings],
            "wall_s": None, "machine": None}
    data["wall_s"] = time.perf_counter() - t0
    data["machine"] = machine()
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
        "units",
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
    return "\n".join(lines)

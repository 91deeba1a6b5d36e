"""Benchmarks: ``rackstress bench stability | accuracy | perf``.

Each writes JSON, a Markdown table (and a plot where it has one) under ``docs/benchmarks/``:

* :mod:`.stability` — the largest stable time step of Eq. 5, measured by bisection on the
  reference engine, beside the linear prediction of :mod:`rackstress.model.stability`;
* :mod:`.accuracy` — work-precision: errors against a converged reference run at fixed physical
  times, for every engine and mode and several time steps;
* :mod:`.perf` — wall time per 1200 MagPod iterations, serial and under ``mpiexec -n 2``, with
  LAMMPS' own timing breakdown and the Python callback's share.
"""
from __future__ import annotations

import json
import os
import platform
from pathlib import Path

#: Where the benchmark outputs go (relative to the repository, else the working directory).
DEFAULT_OUT = Path(__file__).resolve().parents[3] / "docs" / "benchmarks"


def repository_file(*parts: str) -> Path:
    """A file of the repository (``examples/``, ``scenes/``) a benchmark reads: beside the
    source tree (an editable install), else in the working directory (a checkout, where the
    tests and CI run); the path beside the source tree when neither has it (its reader names
    it in its error)."""
    here = Path(__file__).resolve().parents[3].joinpath(*parts)
    there = Path.cwd().joinpath(*parts)
    return there if not here.exists() and there.exists() else here


#: every process a benchmark starts on one thread (MKL's PARDISO, NumPy's BLAS, numba): one
#: core a rank
ONE_THREAD = {"MKL_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
              "NUMBA_NUM_THREADS": "1"}


def program(name: str) -> Path:
    """A program beside this Python (the venv's ``mpiexec``, ``lmp``)."""
    import sys

    return Path(sys.executable).parent / name


def rackstress_command(*args, ranks: int = 1) -> list:
    """``rackstress ARGS`` as a user runs it (this Python's package), under ``mpiexec -n
    ranks`` when ranks > 1."""
    import sys

    cmd = [sys.executable, "-m", "rackstress.cli", *map(str, args)]
    return [str(program("mpiexec")), "-n", str(ranks), *cmd] if ranks > 1 else cmd


def timed(cmd, cwd=None, timeout: float = 3600.0, env: dict | None = None):
    """Run ``cmd`` (a real process; ``env`` added to this one's environment): (stdout +
    stderr, wall s, CPU s of it and its children — every rank under ``mpiexec``). A command
    that fails raises RuntimeError with the end of its output."""
    import resource
    import subprocess
    import time

    cmd = [str(c) for c in cmd]
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **(env or {})})
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}:\n"
                           f"{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}")
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return proc.stdout + proc.stderr, wall, cpu


def out_dir(out: Path | None) -> Path:
    out = Path(out) if out is not None else DEFAULT_OUT
    out.mkdir(parents=True, exist_ok=True)
    return out


def machine() -> dict:
    """What the numbers were measured on (timings are comparable only as ratios in one run)."""
    try:
        load = os.getloadavg()
    except OSError:  # pragma: no cover
        load = None
    cpu = None
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:  # pragma: no cover
        pass
    return {"cores": os.cpu_count(), "cpu": cpu, "python": platform.python_version(),
            "platform": platform.platform(), "load_avg_at_start": load,
            "note": "2 cores shared with other work: compare timings within one run, as ratios"}


def write_json(path: Path, data) -> None:
    from rackstress.lib.jsonio import write_json as _w

    _w(path, data)


def md_table(header: list, rows: list) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    for r in rows:
        out.append("| " + " | ".join(str(x) for x in r) + " |")
    return "\n".join(out) + "\n"


def fmt(x, digits: int = 3) -> str:
    if x is None:
        return "—"
    if isinstance(x, str):
        return x
    if x != x:  # nan
        return "nan"
    if x in (float("inf"), float("-inf")):
        return "∞"
    return f"{x:.{digits}g}"


__all__ = ["DEFAULT_OUT", "out_dir", "machine", "write_json", "md_table", "fmt", "json"]

"""What the machine can give a run: memory, checked before anything large is built."""
from __future__ import annotations

import os

from rackstress.errors import SceneError

#: Bytes per particle while a lattice is built (index grids, positions, radii, the scene's
#: copies): measured peak for a 100³ lattice in ``scenes.load`` is about 150 B a particle.
BUILD_BYTES_PER_PARTICLE = 200


def available_memory() -> int:
    """Bytes this process can still have: the machine's ``MemAvailable`` (physical memory if
    unknown), less if the process is limited — its address space (``ulimit -v``, as a batch
    system sets it) less what it has mapped, or its control group's ``memory.max`` (a job's
    memory on a cluster, a container's) less what the group uses."""
    have = None
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    have = int(line.split()[1]) * 1024
                    break
    except OSError:
        pass
    if have is None:
        have = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    return min([have, *_limits()])


def _limits() -> list[int]:
    """What ``ulimit -v`` and the cgroup (v2) leave this process, where they are set."""
    import resource

    out = []
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        try:
            with open("/proc/self/status") as fh:
                size = next(int(ln.split()[1]) * 1024 for ln in fh if ln.startswith("VmSize:"))
        except (OSError, StopIteration, ValueError):
            size = 0
        out.append(max(0, soft - size))
    try:
        rel = next(ln.strip().split("::", 1)[1] for ln in open("/proc/self/cgroup")
                   if ln.startswith("0::"))
        base = f"/sys/fs/cgroup{rel.rstrip('/')}"
        with open(f"{base}/memory.max") as fh:
            cap = fh.read().strip()
        if cap != "max":
            with open(f"{base}/memory.current") as fh:
                out.append(max(0, int(cap) - int(fh.read().strip())))
    except (OSError, StopIteration, ValueError, IndexError):
        pass
    return out


def require_memory(need: int, what: str) -> None:
    """Raise :class:`SceneError` if ``need`` bytes exceed what the machine has available."""
    have = available_memory()
    if need > have:
        limited = " (its limit: ulimit -v or the job's memory)" if _limits() else ""
        raise SceneError(f"{what} needs about {need / 2**30:.1f} GiB and this machine has "
                         f"{have / 2**30:.1f} GiB available{limited}: make it smaller or use a "
                         "larger machine")


def cpu_children() -> float:
    """CPU seconds (user + system) of this process's ended children (a benchmark's runs,
    the FE check's fTetWild)."""
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime

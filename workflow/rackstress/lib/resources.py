"""What the machine can give a run: memory, checked before anything large is built."""
from __future__ import annotations

import os

from rackstress.errors import SceneError

#: Bytes per particle while a lattice is built (index grids, positions, radii, the scene's
#: copies): measured peak for a 100³ lattice in ``scenes.load`` is about 150 B a particle.
BUILD_BYTES_PER_PARTICLE = 200


def available_memory() -> int:
    """Bytes the machine can still give (``MemAvailable``; physical memory if unknown)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def require_memory(need: int, what: str) -> None:
    """Raise :class:`SceneError` if ``need`` bytes exceed what the machine has available."""
    have = available_memory()
    if need > have:
        raise SceneError(f"{what} needs about {need / 2**30:.1f} GiB and this machine has "
                         f"{have / 2**30:.1f} GiB available: make it smaller or use a larger "
                         "machine")

#!/usr/bin/env python
"""Regenerate the committed LAMMPS decks of the paper's scenes under lammps_inputs/.

    python scripts/make_decks.py [OUTDIR]      (default: lammps_inputs/ beside this script)

Each deck is a directory with ``particles.data`` and ``in.lammps`` as ``rackstress deck`` writes
them (the exact ones with the compiled plugin's fixes: they run standalone in the venv's
``lmp``). A test regenerates them into a temporary directory and fails if any byte differs.
"""
from __future__ import annotations

import sys
from pathlib import Path

from rackstress import scenes
from rackstress.engines.lammps.deck import write_deck
from rackstress.runs.run import default_dump_every

#: deck directory → (scene, parameters, mode)
DECKS = {
    "plane-bound-d2": ("plane-bound", {"d": 2.0}, "exact"),
    "plane-bound-d10": ("plane-bound", {"d": 10.0}, "exact"),
    "plane-bound-d100": ("plane-bound", {"d": 100.0}, "exact"),
    "plane-rack": ("plane-rack", {}, "exact"),
    "plane-rack-fast": ("plane-rack", {}, "fast"),
}


def main(out: Path) -> None:
    for name, (scene, params, mode) in DECKS.items():
        sc = scenes.build(scene, **params)
        write_deck(sc, out / name, mode, default_dump_every(sc), plugin=mode == "exact")
        print(f"wrote {out / name}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent.parent / "lammps_inputs")

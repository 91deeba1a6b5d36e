#!/usr/bin/env python
"""Figures 1–2 of the paper, recomputed: the plane experiments as pictures.

    python scripts/plot_planes.py [--out docs/planes.png]

Top row (Fig. 1): plane-bound with within(2), within(10), within(100) after 180 steps.
Bottom row (Fig. 2): plane-rack after 0, 60, 120, 180 steps (racks in red).
Particles are coloured by their distance from the desired position (best-fit rigid motion),
the paper's stress measure; the reference engine computes every state.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from rackstress.lib import rigid
from rackstress import scenes  # noqa: E402
from rackstress.engines.driver import drive  # noqa: E402
from rackstress.engines.reference import Reference  # noqa: E402


def states(scene, at):
    """Positions at the steps ``at`` (the one driver, stepping the reference engine)."""
    ref = Reference(scene.with_steps(max(at)))
    out = {0: ref.p.copy()} if 0 in at else {}
    drive(ref, on_chunk=lambda e: out.__setitem__(e.step_count, e.p.copy())
          if e.step_count in at else None)
    return out


def draw(ax, scene, p, title, vmax):
    o = scene.groups["plane"].o
    sl = scene.slice("plane")
    dev = rigid.deformation(o, p[sl])
    ax.scatter(p[sl, 0], p[sl, 2], p[sl, 1], c=dev, cmap="Reds", vmin=0, vmax=vmax, s=6,
               edgecolors="grey", linewidths=0.2)
    if "planerack" in scene.groups:
        r = p[scene.slice("planerack")]
        ax.scatter(r[:, 0], r[:, 2], r[:, 1], c="red", s=20)
    ax.set_title(title, fontsize=9)
    ax.set_xlim(-8, 28), ax.set_ylim(-8, 28), ax.set_zlim(-8, 28)
    ax.set_xlabel("x"), ax.set_ylabel("z"), ax.set_zlabel("y (up)")
    ax.view_init(elev=20, azim=-60)
    return dev.max()


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("docs/planes.png"))
    args = ap.parse_args()
    fig = plt.figure(figsize=(14, 7))
    for k, d in enumerate((2.0, 10.0, 100.0)):
        sc = scenes.build("plane-bound", d=d)
        p = states(sc, {180})[180]
        ax = fig.add_subplot(2, 4, k + 1, projection="3d")
        m = draw(ax, sc, p, f"plane-bound within({d:g}), step 180", 2.0)
        ax.text2D(0.02, 0.02, f"max deformation {m:.2f}", transform=ax.transAxes, fontsize=8)
    sc = scenes.build("plane-rack")
    st = states(sc, {0, 60, 120, 180})
    for k, step in enumerate((0, 60, 120, 180)):
        ax = fig.add_subplot(2, 4, 5 + k, projection="3d")
        m = draw(ax, sc, st[step], f"plane-rack, step {step}", 2.0)
        ax.text2D(0.02, 0.02, f"max deformation {m:.2f}", transform=ax.transAxes, fontsize=8)
    fig.suptitle("Plane experiments (Figs. 1–2): colour = distance from the desired position "
                 "(white 0 → red ≥ 2 units); rack particles red dots", fontsize=10)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"saved {args.out}")


if __name__ == "__main__":
    main()

#!/usr/bin/env python
"""MagPod's geometry as a picture: body, legs, attraction regions, racks, a sediment patch.

    python scripts/plot_magpod_geometry.py [OUT.png]     (default docs/magpod/geometry.png)
"""
import sys
import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from rackstress.scenes import build
sc = build("magpod-small", sediment_nx=16, sediment_nz=18, sediment_back=6)
fig = plt.figure(figsize=(18, 6.5))
views = [(20, -60, "oblique (front-right)"), (0, -90, "right side (+z towards viewer)"), (0, 0, "front (+x towards viewer)")]
region_colors = {1: "tab:red", 2: "tab:orange", 3: "gold", 4: "tab:purple",
                 5: "tab:red", 6: "tab:orange", 7: "gold", 8: "tab:purple"}
for k, (elev, azim, title) in enumerate(views):
    ax = fig.add_subplot(1, 3, k + 1, projection="3d")
    def sc3(p, **kw):
        # plot with y up: matplotlib's z axis shows our y
        ax.scatter(p[:, 0], p[:, 2], p[:, 1], **kw)
    g = sc.groups
    body = g["body"]; regs = body.meta["regions"]
    inreg = np.zeros(body.n, bool)
    for name in sorted(regs):
        inreg |= regs[name] > 0
    sc3(body.o[~inreg], s=2, c="lightsteelblue", alpha=0.25, label="body")
    for r in range(1, 9):
        m = regs[f"breg{r}"] > 0
        sc3(body.o[m], s=6, c=region_colors[r], alpha=0.9,
            label=f"breg{r}" if r <= 4 else None, marker="o" if r <= 4 else "^")
    for leg, idx, col in (("rightleg", "rreg", "seagreen"), ("leftleg", "lreg", "darkcyan")):
        L = g[leg]; m = L.meta["regions"][idx] > 0
        sc3(L.o[~m], s=3, c=col, alpha=0.5, label=leg)
        sc3(L.o[m], s=8, c="navy", alpha=0.9, label="leg region R" if leg == "rightleg" else None)
    racks = np.concatenate([g[n].o for n in ("bodyrack", "rightrack", "leftrack")])
    sc3(racks, s=30, c="crimson", marker="x", label="rack particles")
    sc3(g["sediment"].o, s=4, c="sienna", alpha=0.3, label="sediment (patch)")
    ax.set_xlabel("x (walk →)"); ax.set_ylabel("z (right →)"); ax.set_zlabel("y (up)")
    ax.view_init(elev=elev, azim=azim); ax.set_title(title)
    allp = sc.original_positions(); ext = np.ptp(allp, axis=0)
    ax.set_box_aspect((ext[0], ext[2], ext[1] + 10))
    if k == 0:
        ax.legend(loc="upper left", fontsize=7, markerscale=1.5)
fig.suptitle("MagPod geometry: regions 1/5 front (raised), 2/6 middle, 3/7 rear, 4/8 lift;"
             " right side (+z) circles, left side triangles", fontsize=9)
fig.tight_layout()
out = sys.argv[1] if len(sys.argv) > 1 else "docs/magpod/geometry.png"
fig.savefig(out, dpi=110)
print(f"saved {out}")

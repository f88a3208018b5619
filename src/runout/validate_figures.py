"""One picture per validation check: the deposit (or the sliding history) against its reference."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def draw_case(res, traj, kind: str, out: Path) -> str:
    """Draw check `res` (a runout.validate.CaseResult) from its trajectory; returns the PNG path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = out / f"{res.case}.png"
    verdict = "met" if res.met else "NOT met"
    if kind == "incline":
        fig, ax = plt.subplots(figsize=(6, 4), constrained_layout=True)
        t, s, theory = (np.asarray(res.extra[k]) for k in ("t", "s", "theory"))
        ax.plot(t, theory, "k--", label="g (sin θ − μ cos θ) t² / 2")
        ax.plot(t, s, "C0", label="MPM block (centre of mass)")
        ax.set_xlabel("t (s)")
        ax.set_ylabel("distance down the slope (m)")
        ax.legend()
    else:
        fig, ax = plt.subplots(figsize=(9, 3.6), constrained_layout=True)
        p0 = traj.positions[0, traj.soil]
        p1 = traj.positions[-1, traj.soil]
        ground = ~traj.soil
        if ground.any():
            g = traj.positions[0, ground]
            ax.scatter(g[:, 0], g[:, 1], s=1, c="#9a9a9a")
        ax.scatter(p0[:, 0], p0[:, 1], s=1, c="#cccccc", label="start")
        d = np.linalg.norm(p1 - p0, axis=1)
        sc = ax.scatter(p1[:, 0], p1[:, 1], s=2, c=d, cmap="viridis", label="end")
        fig.colorbar(sc, ax=ax, label="displacement (m)")
        if kind == "column" and "width" in res.extra and res.quantity == "L^n":
            w = res.extra["width"]
            for value, style, label in ((res.low, ":", "allowed band"), (res.high, ":", None)):
                if np.isfinite(value):
                    ax.axvline(w * (1 + value), color="r", ls=style, label=label)
            if "reference" in res.extra:
                ax.axvline(w * (1 + res.extra["reference"]), color="r", ls="--", label="paper's MPM")
        ax.set_aspect("equal")
        x_hi = max(float(p1[:, 0].max()), float(p0[:, 0].max())) * 1.15 + 10
        if kind == "column" and np.isfinite(res.high) and "width" in res.extra:
            x_hi = max(x_hi, res.extra["width"] * (1 + res.high) * 1.05)
        ax.set_xlim(0, min(x_hi, traj.bounds[0][1]))
        ax.set_ylim(0, traj.bounds[1][1])
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.legend(loc="upper right", fontsize=7)
    ax.set_title(f"{res.case}: {res.quantity} = {res.measured:.3f}, allowed [{res.low:.3g}, {res.high:.3g}] ({verdict})",
                 fontsize=8)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return str(path)

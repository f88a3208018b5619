"""How well can any neural MPM at a given cell size carry a scene's points? The grid's floor.

The neural MPM moves each point by a grid velocity interpolated at the point (runout.transfer,
the MPM's quadratic B-spline). Whatever the U-Net learns, its points can only follow the MPM as
closely as some grid field of that cell size lets them. Two oracles, each rolled out from rest
frame by frame on the engine's own points (their positions drift from the MPM's, as a rollout's
do), against the MPM's trajectory:

- `p2g`: the MPM's own frame displacements moved to the grid at the MPM's positions (mass-weighted
  mean per node), interpolated at the rolled-out points: what a U-Net that predicts the MPM's
  grid velocity exactly would do;
- `p2g-K`: the same field after K sweeps of (lumped-mass preconditioned) Richardson iteration
  towards the least-squares field of the MPM's displacements at the MPM's positions
  (g += P2G(d - G2P(g)) / mass): how much sharper a cheap projection gets;
- `fit`: per frame, the grid field whose interpolation carries the rolled-out points closest to
  the MPM's next positions (least squares, ridge `--ridge` x the mean weight on nodes no point
  touches much): the best any grid field of that cell size can do, one frame at a time.

Reported per scene: mean position error over frames (m, as `runout evaluate heldout`), the
final right and left fronts (largest and smallest soil x, m) against the MPM's, as a share of
the MPM's front travel. Scenes come from a dataset's split, or are run through the MPM cache:

    PYTHONPATH=src .venv/bin/python experiments/neural_mpm_grid_floor.py --data data/dam8 --split train --scenes 184,186,151
    PYTHONPATH=src .venv/bin/python experiments/neural_mpm_grid_floor.py --scene examples/dam.toml --point-spacing 4
    PYTHONPATH=src .venv/bin/python experiments/neural_mpm_grid_floor.py --data data/ft8 --split valid --limit 16

A dataset's scenes are at its own cell size; --cell-size sets the oracle's grid (8 m: the
engine's; 4 m: what halving the cell would buy on the same MPM run).
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import torch

from runout.defaults import PARTICLE_TYPE_KINEMATIC
from runout.neural_mpm.engine import sharpened
from runout.transfer import GridTransfer

PAD = 2  # nodes outside every wall, as the engine's grid


def grid_of(bounds: np.ndarray, dx: float) -> tuple[np.ndarray, tuple[int, int, int]]:
    origin = bounds[:, 0] - PAD * dx
    cells = [math.ceil(float(bounds[d, 1] - bounds[d, 0]) / dx - 1e-9) for d in range(2)]
    return origin, (1, cells[0] + 1 + 2 * PAD, cells[1] + 1 + 2 * PAD)


def transfer(x: torch.Tensor, origin: torch.Tensor, dx: float, shape) -> GridTransfer:
    return GridTransfer(x - origin, torch.zeros(x.shape[0], dtype=torch.long), dx, shape)


def interpolation_matrix(t: GridTransfer, nodes: int) -> torch.Tensor:
    """[P, nodes] dense: row p holds point p's nine weights at its nodes."""
    a = torch.zeros(t.w.shape[0], nodes, dtype=t.w.dtype)
    a.scatter_add_(1, t.ids, t.w)
    return a


def roll(truth: np.ndarray, soil: np.ndarray, bounds: np.ndarray, dx: float, oracle: str, ridge: float) -> np.ndarray:
    """[F, P, 2] the oracle's rollout from truth[0]; kinematic points stay put."""
    pos = torch.from_numpy(truth.astype(np.float64))
    moving = torch.from_numpy(soil)[:, None]
    o, shape = grid_of(bounds, dx)
    origin = torch.from_numpy(o)
    lo, hi = torch.from_numpy(bounds[:, 0]), torch.from_numpy(bounds[:, 1])
    nodes = shape[1] * shape[2]
    x = pos[0].clone()
    out = [x.clone()]
    s = torch.from_numpy(soil)
    for f in range(pos.shape[0] - 1):
        here = transfer(x[s], origin, dx, shape)
        if oracle.startswith("p2g"):
            mpm = transfer(pos[f, s], origin, dx, shape)
            step = pos[f + 1, s] - pos[f, s]
            g = mpm.to_grid(torch.cat([torch.ones_like(step[:, :1]), step], 1))
            fade = 1.0 / torch.clamp(g[:, :1], min=1e-9)
            # p2g-K: the engine's own K sweeps towards the least-squares field
            grid = sharpened(mpm, step, torch.ones_like(step[:, :1]), g[:, 1:] * fade, fade, int(oracle[4:] or 0))
            v = here.to_points(grid)
        else:
            a = interpolation_matrix(here, nodes)
            a = a[:, a.sum(0) > 0]  # the nodes some point touches; the others carry nothing
            want = pos[f + 1, s] - x[s]  # the displacement that would land each point on the MPM's next position
            reg = ridge * float(a.sum(0).mean())
            lhs = a.T @ a + reg * torch.eye(a.shape[1], dtype=a.dtype)
            v = a @ torch.linalg.solve(lhs, a.T @ want)
        x = x.clone()
        x[s] = torch.minimum(torch.maximum(x[s] + v, lo), hi)
        out.append(x.clone())
    return torch.stack(out).numpy()


def measures(pred: np.ndarray, truth: np.ndarray, soil: np.ndarray) -> dict:
    err = np.linalg.norm(pred[:, soil] - truth[:, soil], axis=-1).mean()
    x0, xt, xp = truth[0, soil, 0], truth[-1, soil, 0], pred[-1, soil, 0]
    right_travel, left_travel = xt.max() - x0.max(), x0.min() - xt.min()
    return {"position_error_m": float(err),
            "right_m": (float(xp.max()), float(xt.max()), float(right_travel)),
            "left_m": (float(xp.min()), float(xt.min()), float(left_travel))}


def from_dataset(data: str, split: str, picks: list[int] | None, limit: int | None):
    """(name, positions [F, P, 2], soil [P], bounds [2, 2]) of the chosen scenes of a split;
    picks are scene numbers of the generator (k; the split's own order otherwise)."""
    import json
    from pathlib import Path

    meta = json.loads((Path(data) / "metadata.json").read_text())
    bounds = np.asarray(meta["bounds"], dtype=np.float64)
    z = np.load(Path(data) / f"{split}.npz", allow_pickle=True)
    code = {"train": None, "valid": 8, "test": 9}[split]
    numbers = [k for k in range(meta["count"]) if (k % 10 == code if code is not None else k % 10 < 8)]
    order = picks if picks is not None else numbers[:limit]
    for k in order:
        item = z[f"simulation_{numbers.index(k)}"]
        yield f"{Path(data).name}/{split}/scene {k}", np.asarray(item[0]), np.asarray(item[1]) != PARTICLE_TYPE_KINEMATIC, bounds


def from_scene(path: str, spacing: float | None):
    """The scene's MPM run (through the MPM cache, as `runout compare`), its points at
    `spacing` m (None: the scene's own)."""
    from runout.defaults import MPM_CACHE
    from runout.mpm.cache import MpmCache
    from runout.scene import load_scene

    scene = load_scene(path)
    if spacing is not None:
        scene = scene.with_point_spacing(spacing, path)
    traj = MpmCache(MPM_CACHE).load(scene, "cpu", progress=False)
    yield path, traj.positions.astype(np.float64), np.asarray(traj.soil), np.asarray(traj.bounds, dtype=np.float64)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data")
    p.add_argument("--split", default="valid")
    p.add_argument("--scenes", help="generator scene numbers, comma-separated")
    p.add_argument("--limit", type=int, default=16)
    p.add_argument("--scene", help="a scene TOML run through the MPM cache instead of a dataset")
    p.add_argument("--point-spacing", type=float)
    p.add_argument("--cell-size", type=float, default=8.0, help="the oracle's grid, m")
    p.add_argument("--oracles", default="p2g,fit")
    p.add_argument("--ridge", type=float, default=1e-3)
    a = p.parse_args()
    torch.set_num_threads(1)
    if a.scene:
        scenes = from_scene(a.scene, a.point_spacing)
    else:
        picks = [int(k) for k in a.scenes.split(",")] if a.scenes else None
        scenes = from_dataset(a.data, a.split, picks, a.limit)
    oracles = a.oracles.split(",")
    totals = {o: [] for o in oracles}
    print(f"grid {a.cell_size:g} m; right/left: oracle front, MPM front (m), error as a share of the MPM's front travel")
    for name, pos, soil, bounds in scenes:
        line = [f"{name:<28} travel R {pos[-1, soil, 0].max() - pos[0, soil, 0].max():6.1f} m "
                f"L {pos[0, soil, 0].min() - pos[-1, soil, 0].min():6.1f} m"]
        for o in oracles:
            m = measures(roll(pos, soil, bounds, a.cell_size, o, a.ridge), pos, soil)
            r, l = m["right_m"], m["left_m"]
            rs = (r[0] - r[1]) / max(r[2], 1e-9) if r[2] > 1 else float("nan")
            ls = (l[1] - l[0]) / max(l[2], 1e-9) if l[2] > 1 else float("nan")
            totals[o].append(m["position_error_m"])
            line.append(f"{o}: {m['position_error_m']:5.2f} m, R {r[0] - r[1]:+6.1f} m ({rs:+.0%}), "
                        f"L {l[1] - l[0]:+6.1f} m ({ls:+.0%})")
        print(" | ".join(line), flush=True)
    for o in oracles:
        print(f"mean position error, {o}: {np.mean(totals[o]):.3f} m over {len(totals[o])} scenes")


if __name__ == "__main__":
    main()

"""Synthetic GNS datasets for the GNS tests (no MPM needed), and a check of the generator.

A block of soil points on a 2 m lattice, starting at rest 3 m above its resting place on
a row of kinematic ground points, settles onto it (critically damped) and spreads sideways
by an amount set by tan(phi) (and reduced by cohesion): smooth, material-dependent
dynamics that come to rest.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from runout.simfiles import statistics, write_metadata, write_simulations

FRAME_DT = 0.0375  # s
BOUNDS = [[0.0, 60.0], [0.0, 30.0]]  # m


def falling_block(frames: int, tan_phi: float, cohesion: float = 0.0, columns: int = 6, rows: int = 4):
    """(positions [T, N, 2] float32 m, particle_type [N], material [N, 2] [tan phi, c/100])."""
    xs = 20.0 + 2.0 * np.arange(columns)
    soil = np.stack(np.meshgrid(xs, 4.0 + 2.0 * np.arange(rows), indexing="xy"), -1).reshape(-1, 2)
    ground = np.stack([np.arange(10.0, 50.0, 2.0), np.full(20, 2.0)], -1)
    t = np.arange(frames)[:, None] / 5.0  # in units of the settling time, 5 frames
    settle = (1.0 + t) * np.exp(-t)  # 1 -> 0, starting and ending at rest
    y = soil[None, :, 1] + 3.0 * settle  # m, 3 m above the resting height at first
    spread = (1.0 - tan_phi) * (1.0 - cohesion) * 0.15 * (soil[:, 0] - xs.mean())
    x = soil[None, :, 0] + spread[None] * (1.0 - settle)
    moving = np.stack([x, y], -1)
    positions = np.concatenate([np.broadcast_to(ground, (frames, len(ground), 2)), moving], axis=1)
    ptype = np.concatenate([np.full(len(ground), 3), np.full(len(soil), 6)]).astype(np.int64)
    material = np.tile(np.array([[tan_phi, cohesion]], dtype=np.float32), (len(ptype), 1))
    return positions.astype(np.float32), ptype, material


def write_dataset(folder: Path, frames: int = 20, n_train: int = 3, width: int = 1, n_valid: int = 1) -> Path:
    """train.npz, valid.npz and metadata.json of falling blocks; material width 1 or 2."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)

    def sims(n):
        out = []
        for _ in range(n):
            p, t, m = falling_block(frames, rng.uniform(0.2, 0.8), rng.uniform(0.1, 0.6) if width > 1 else 0.0)
            out.append((p, t, m[:, :width]))
        return out

    train = sims(n_train)
    write_simulations(folder / "train.npz", train)
    write_simulations(folder / "valid.npz", sims(n_valid))
    meta = statistics(train, radius=4.6)
    meta.update(bounds=BOUNDS, dt=FRAME_DT)
    write_metadata(folder / "metadata.json", meta)
    return folder


def test_falling_block_comes_to_rest_on_the_ground():
    positions, ptype, _ = falling_block(100, 0.5)
    soil = ptype == 6
    assert positions[0, soil, 1].min() > positions[-1, soil, 1].min() + 2.9  # it fell
    assert np.abs(positions[-1] - positions[-2]).max() < 1e-4  # and stopped
    assert (positions[:, ~soil] == positions[0, ~soil]).all()  # ground never moves

"""Training windows for the neural MPM, drawn from a dataset split held in memory.

A window of simulation s at frame t0 is the input (positions at t0, the velocities of frames
t0 - history + 1 ... t0, each x_t - x_(t-1) in m per frame, zero at and before frame 0: the
scene at rest) and the targets (positions of frames t0 + 1 ... t0 + span). A share of the
windows start at frame 0, where every scene starts when a user runs it; a share is mirrored
left-right (x -> x_lo + x_hi - x), a true sample of the physics since the MPM is mirror-exact
(tests/test_mirror.py) while the training slopes all face one way (docs/datasets.md).

Several datasets may train together (the fine-tuning slopes and the `columns` stage, say):
each batch is drawn from one of them, chosen with its share, so a batch's scenes share one
domain and the grid stays that domain's size. Within a dataset the simulations are drawn
uniformly, or with weight_by_motion towards those that move most (half the zoned dams stand
still, and an engine trained on them uniformly under-moves the ones that fail).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from runout.defaults import PARTICLE_TYPE_KINEMATIC
from runout.errors import InputError
from runout.metrics import soil_displacement
from runout.neural_mpm.engine import Points
from runout.simfiles import read_metadata, read_simulations


MOTION_FLOOR_M = 8.0  # m added to each simulation's displacement under weight_by_motion: still scenes keep a weight


@dataclass
class Window:
    """A batch of windows as one flat set of points."""

    x: torch.Tensor  # [P, 2] m at the window's start
    velocities: torch.Tensor  # [history, P, 2] m per frame, oldest first
    targets: torch.Tensor  # [span, P, 2] m
    points: Points


class WindowSampler:
    """Simulations with every frame in memory (float32 on the CPU): positions [T, N, 2] m,
    fixed [N] (kinematic points), material [N, k] per simulation; bounds [2, 2] m shared, or
    [S, 2, 2] one per simulation; source [S] the dataset of each simulation (0, 1, ...) and
    shares the part of the batches each dataset gives (default: one dataset)."""

    def __init__(self, positions: list[np.ndarray], fixed: list[np.ndarray], material: list[np.ndarray],
                 bounds, history: int, meta: dict | None = None, source: list[int] | None = None,
                 shares: list[float] | None = None, metas: list[dict] | None = None):
        self.positions = [torch.from_numpy(np.ascontiguousarray(p, dtype=np.float32)) for p in positions]
        self.fixed = [torch.from_numpy(np.asarray(f, dtype=bool)) for f in fixed]
        self.material = [torch.from_numpy(np.asarray(m, dtype=np.float32)) for m in material]
        bounds = torch.tensor(np.asarray(bounds, dtype=np.float32))
        self.bounds = bounds.expand(len(self.positions), 2, 2) if bounds.dim() == 2 else bounds
        self.history = history
        self.meta = meta or {"bounds": np.asarray(bounds).tolist()}  # the (first) dataset's metadata.json
        self.metas = metas or [self.meta]  # each dataset's metadata.json
        self.source = torch.zeros(len(self.positions), dtype=torch.long) if source is None else torch.as_tensor(source)
        self.shares = torch.tensor(shares if shares is not None else [1.0], dtype=torch.float64)
        self.members = [torch.nonzero(self.source == k).flatten() for k in range(len(self.shares))]
        self.motion_weighting = 0.0
        self.weights = torch.ones(len(self.positions), dtype=torch.float64)

    def weight_by_motion(self, exponent: float | list[float]) -> "WindowSampler":
        """Draw each dataset's simulations with weights (D + MOTION_FLOOR_M)^exponent instead of
        uniformly, D (m) the mean distance its soil points end from where they started: with
        exponent 1 a dam that fails by 50 m is drawn about 7 times as often as one that stands
        still. One exponent for every dataset or one per dataset (the columns drawn uniformly
        while the dams are weighted, say); 0 draws uniformly, exactly as before."""
        exponents = [float(exponent)] * len(self.shares) if np.isscalar(exponent) else [float(e) for e in exponent]
        if len(exponents) != len(self.shares):
            raise InputError(f"--motion-weighting: {len(exponents)} exponents for {len(self.shares)} datasets; give one "
                             "for all or one per dataset.")
        self.motion_weighting = max(exponents)
        moved = [soil_displacement(p.numpy(), ~f.numpy()) for p, f in zip(self.positions, self.fixed)]
        mean = torch.tensor([(d.mean() if d.size else 0.0) + MOTION_FLOOR_M for d in moved], dtype=torch.float64)
        self.weights = mean ** torch.tensor(exponents, dtype=torch.float64)[self.source]
        return self

    @classmethod
    def from_split(cls, data: str | Path, split: str, history: int, material_width: int) -> "WindowSampler":
        """The simulations of DATA/SPLIT.npz, with DATA/metadata.json's bounds."""
        return cls.from_splits([data], split, history, material_width)

    @classmethod
    def from_splits(cls, datas: list[str | Path], split: str, history: int, material_width: int,
                    shares: list[float] | None = None) -> "WindowSampler":
        """The simulations of every DATA/SPLIT.npz; each batch from one dataset, chosen with
        `shares` (default: in proportion to their simulations). The datasets must share their
        point spacing and frame spacing: the engine has one of each."""
        positions, fixed, material, bounds, source, metas = [], [], [], [], [], []
        for k, data in enumerate(Path(d) for d in datas):
            meta = read_metadata(data)
            sims = read_simulations(data / f"{split}.npz")
            widths = {0 if m is None else m.shape[1] for _, _, m in sims}
            if widths != {material_width}:
                raise InputError(f"{data / f'{split}.npz'}: holds {sorted(widths)} material features per point; "
                                 f"the engine reads {material_width} ([tan phi, c / 100 kPa]).")
            for key in ("cell_size", "dt"):
                if metas and key in meta and key in metas[0] and not np.isclose(meta[key], metas[0][key]):
                    raise InputError(f"{data / 'metadata.json'}: {key} = {meta[key]:g} differs from {datas[0]}'s "
                                     f"{metas[0][key]:g}; datasets trained together must share it.")
            positions += [p for p, _, _ in sims]
            fixed += [np.asarray(t) == PARTICLE_TYPE_KINEMATIC for _, t, _ in sims]
            material += [m for _, _, m in sims]
            bounds += [meta["bounds"]] * len(sims)
            source += [k] * len(sims)
            metas.append(meta)
        counts = [source.count(k) for k in range(len(metas))]
        if shares is None:
            shares = [float(c) for c in counts]
        if len(shares) != len(metas) or min(shares) < 0 or sum(shares) <= 0:
            raise InputError(f"the data shares {list(shares)} must be one non-negative number per dataset "
                             f"({len(metas)}), not all zero.")
        for data, count, share in zip(datas, counts, shares):
            if share > 0 and count == 0:
                raise InputError(f"{Path(data) / f'{split}.npz'}: holds no simulations but is given a share of {share:g}.")
        return cls(positions, fixed, material, np.asarray(bounds, dtype=np.float32), history, metas[0], source,
                   list(shares), metas)

    def __len__(self) -> int:
        return len(self.positions)

    def draw(self, batch: int, span: int, rest_share: float, mirror_share: float, generator: torch.Generator,
             noise: float = 0.0) -> Window:
        """`batch` windows of `span` target frames, drawn with `generator`, all from one dataset.
        With `noise` > 0 (m per frame), Gaussian noise of that std is added to the soil's input
        velocities of frames after frame 0, drawn last (noise 0 draws what it always drew); the
        velocities of the scene at rest, frame 0 and before, stay exact, and so do the targets."""
        members = (torch.arange(len(self)) if len(self.members) == 1
                   else self.members[int(torch.multinomial(self.shares, 1, generator=generator))])
        if self.motion_weighting:
            sims = members[torch.multinomial(self.weights[members], batch, replacement=True, generator=generator)].tolist()
        else:
            sims = members[torch.randint(len(members), (batch,), generator=generator)].tolist()
        rest = (torch.rand(batch, generator=generator) < rest_share).tolist()
        mirror = (torch.rand(batch, generator=generator) < mirror_share).tolist()
        starts = torch.rand(batch, generator=generator).tolist()
        xs, vels, targets, fixed, material, scene, known = [], [], [], [], [], [], []
        for b, (s, r, flip, u) in enumerate(zip(sims, rest, mirror, starts)):
            pos = self.positions[s]
            last = pos.shape[0] - 1 - span
            if last < 0:
                raise InputError(f"simulation {s} has {pos.shape[0]} frames; a window needs more than {span}.")
            t0 = 0 if r else int(u * (last + 1))
            frames = pos[max(t0 - self.history, 0):t0 + span + 1]
            if flip:
                frames = frames.clone()
                frames[..., 0] = self.bounds[s, 0, 0] + self.bounds[s, 0, 1] - frames[..., 0]
            lead = min(t0, self.history)  # frames before t0 in `frames`
            steps = frames[1:lead + 1] - frames[:lead]
            pad = frames.new_zeros(self.history - lead, *frames.shape[1:])
            xs.append(frames[lead])
            vels.append(torch.cat([pad, steps]))
            targets.append(frames[lead + 1:])
            fixed.append(self.fixed[s])
            material.append(self.material[s])
            scene.append(torch.full((pos.shape[1],), b, dtype=torch.long))
            known.append((torch.arange(self.history) >= self.history - lead)[:, None] & ~self.fixed[s][None])
        points = Points(torch.cat(fixed), torch.cat(material), torch.cat(scene), self.bounds[sims])
        velocities = torch.cat(vels, 1)
        if noise > 0:
            kick = torch.randn(velocities.shape, generator=generator) * noise
            velocities = velocities + kick * torch.cat(known, 1)[..., None]
        return Window(torch.cat(xs), velocities, torch.cat(targets, 1), points)

    def velocity_statistics(self) -> dict:
        """Mean and standard deviation per axis of the soil's frame velocities over the data
        (m per frame), and their root mean square over both axes ("scale")."""
        total, square, count = torch.zeros(2, dtype=torch.float64), torch.zeros(2, dtype=torch.float64), 0
        for pos, fixed in zip(self.positions, self.fixed):
            v = (pos[1:, ~fixed] - pos[:-1, ~fixed]).double().reshape(-1, 2)
            total += v.sum(0)
            square += (v ** 2).sum(0)
            count += v.shape[0]
        mean, mean_square = total / max(count, 1), square / max(count, 1)
        std = (mean_square - mean ** 2).clamp(min=0.0).sqrt()
        return {"mean": mean.tolist(), "std": std.tolist(), "scale": float(mean_square.mean().sqrt())}

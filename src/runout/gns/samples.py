"""Training samples: windows of `history` positions and the next frame, from a split file.

All simulations of a split live on the training device; a batch picks windows uniformly
over every (simulation, start frame) pair with a CPU generator (indices only) and slices
the device tensors, so no data crosses to the device during training.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass
from pathlib import Path

import torch

from runout.errors import InputError
from runout.gns.schema import HISTORY, FeatureSchema, material_names_for_width
from runout.simfiles import read_simulations


@dataclass
class TrainingBatch:
    window: torch.Tensor  # [N, history, 2] m, graphs concatenated
    next_position: torch.Tensor  # [N, 2] m
    particle_type: torch.Tensor  # [N]
    material: torch.Tensor  # [N, k]
    graph: torch.Tensor  # [N] graph index within the batch


class Simulations:
    """The simulations of one split file on `device`."""

    def __init__(self, path: str | Path, device: torch.device, history: int = HISTORY, material_names=None):
        sims = read_simulations(path)
        widths = {0 if m is None else m.shape[1] for _, _, m in sims}
        if len(widths) != 1:
            raise InputError(f"{path}: simulations have different material feature widths {sorted(widths)}; use one.")
        self.path = Path(path)
        self.history = history
        self.material_names = tuple(material_names or material_names_for_width(widths.pop()))
        self.positions = [torch.from_numpy(p).to(device) for p, _, _ in sims]
        self.particle_type = [torch.from_numpy(t).to(device) for _, t, _ in sims]
        self.material = [
            (torch.zeros((len(t), 0)) if m is None else torch.from_numpy(m)).to(device) for _, t, m in sims
        ]
        self._first_window = [0]
        for p in self.positions:
            self._first_window.append(self._first_window[-1] + p.shape[0] - history)

    def __len__(self) -> int:
        return len(self.positions)

    @property
    def n_windows(self) -> int:
        return self._first_window[-1]

    def schema(self, base: FeatureSchema = FeatureSchema()) -> FeatureSchema:
        """The node-feature schema these data call for (base's other fields)."""
        return base.with_material_features(self.material_names)

    def sample(self, batch_size: int, generator: torch.Generator) -> TrainingBatch:
        picks = torch.randint(self.n_windows, (batch_size,), generator=generator).tolist()
        parts = [self._window(k) for k in picks]
        window, nxt, ptype, material = (torch.cat(x) for x in zip(*parts))
        graph = torch.cat([torch.full((len(p[0]),), g, device=window.device) for g, p in enumerate(parts)])
        return TrainingBatch(window, nxt, ptype, material, graph)

    def _window(self, k: int):
        sim = bisect.bisect_right(self._first_window, k) - 1
        t = k - self._first_window[sim]
        frames = self.positions[sim][t : t + self.history + 1].transpose(0, 1)  # [N, history + 1, 2]
        return frames[:, :-1], frames[:, -1], self.particle_type[sim], self.material[sim]

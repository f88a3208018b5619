"""Training samples: windows of `history` positions and the true positions after them, from a split file.

A window at frame stride K starting at frame t holds frames t, t + K, ..., t + (history - 1) K
and its target is frame t + history K; every start frame t that fits is a window, so every
frame is used (K = 1: consecutive frames). A sample for n pushforward steps (runout.train)
also holds the true frames t + (history + 1) K, ..., t + (history + n) K, the last of which
is then its target, so its start t must leave room for them. All simulations of a split live
on the training device; a batch picks windows uniformly over every (simulation, start frame)
pair that fits with a CPU generator (indices only) and slices the device tensors, so no data
crosses to the device during training.
"""

from __future__ import annotations

import bisect
import copy
from dataclasses import dataclass
from pathlib import Path

import torch

from runout.errors import InputError
from runout.gns.schema import HISTORY, FeatureSchema, material_names_for_width
from runout.simfiles import read_simulations


@dataclass
class TrainingBatch:
    window: torch.Tensor  # [N, history, 2] m, graphs concatenated
    future: torch.Tensor  # [N, unroll + 1, 2] m: the true positions of the next steps; the last is the target
    particle_type: torch.Tensor  # [N]
    material: torch.Tensor  # [N, k]
    graph: torch.Tensor  # [N] graph index within the batch

    @property
    def unroll(self) -> int:
        """Pushforward steps between the window and the target."""
        return self.future.shape[1] - 1


class Simulations:
    """The simulations of one split file on `device`, sampled in windows at frame stride 1
    (with_stride: the same data at another stride), with 0 or more pushforward steps."""

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
        self._index_windows(1)

    def _index_windows(self, stride: int) -> None:
        self.stride = stride
        self._first_window: dict[int, list[int]] = {}  # unroll -> first window index of each simulation, then the total
        self.check_windows(0)

    def check_windows(self, unroll: int) -> None:
        """InputError unless some simulation has a window for `unroll` pushforward steps."""
        if self.n_windows_for(unroll) == 0:
            span = (self.history + unroll) * self.stride
            steps = f" and {unroll} pushforward steps" if unroll else ""
            raise InputError(
                f"{self.path}: no simulation has more than {span} frames, which a window of {self.history} "
                f"positions at frame stride {self.stride}{steps} spans; choose a smaller --frame-stride"
                f"{' or --pushforward' if unroll else ''}."
            )

    def _windows(self, unroll: int) -> list[int]:
        if unroll not in self._first_window:
            span = (self.history + unroll) * self.stride  # frames from a window's first position to its target
            first = [0]
            for p in self.positions:
                first.append(first[-1] + max(p.shape[0] - span, 0))
            self._first_window[unroll] = first
        return self._first_window[unroll]

    def with_stride(self, stride: int) -> "Simulations":
        """The same simulations (the same device tensors), sampled at frame stride `stride`."""
        if stride == self.stride:
            return self
        other = copy.copy(self)
        other._index_windows(stride)  # a new index; the copy shares only the tensors
        return other

    def __len__(self) -> int:
        return len(self.positions)

    @property
    def n_windows(self) -> int:
        return self.n_windows_for(0)

    def n_windows_for(self, unroll: int) -> int:
        """Windows with room for `unroll` pushforward steps after their target's one."""
        return self._windows(unroll)[-1]

    def moments(self) -> dict:
        """vel_mean, vel_std, acc_mean, acc_std of the differences at this stride K,
        v = x_{t+K} - x_t and a = v_{t+K} - v_t over every start frame t, pooled over every
        point (m per step, m per step^2), as runout.simfiles.Moments pools the 1-frame
        differences for metadata.json; float64 sums on the device, one host copy at the end."""
        k = self.stride
        sums = torch.zeros((2, 3, 2), dtype=torch.float64, device=self.positions[0].device)  # [vel/acc, n/sum/square, xy]
        for p in self.positions:
            v = p[k:].double() - p[:-k].double()
            for row, d in enumerate((v, v[k:] - v[:-k])):
                sums[row, 0] += d.shape[0] * d.shape[1]
                sums[row, 1] += d.sum((0, 1))
                sums[row, 2] += d.square().sum((0, 1))
        n, total, squares = sums.cpu().unbind(1)
        mean = total / n.clamp(min=1)
        std = (squares / n.clamp(min=1) - mean.square()).clamp(min=0).sqrt()
        return {"vel_mean": mean[0].tolist(), "vel_std": std[0].tolist(), "acc_mean": mean[1].tolist(), "acc_std": std[1].tolist()}

    def schema(self, base: FeatureSchema = FeatureSchema()) -> FeatureSchema:
        """The node-feature schema these data call for (base's other fields)."""
        return base.with_material_features(self.material_names)

    def sample(self, batch_size: int, generator: torch.Generator, unroll: int = 0) -> TrainingBatch:
        """`batch_size` windows drawn uniformly from those with room for `unroll` pushforward steps."""
        picks = torch.randint(self.n_windows_for(unroll), (batch_size,), generator=generator).tolist()
        parts = [self._window(k, unroll) for k in picks]
        window, future, ptype, material = (torch.cat(x) for x in zip(*parts))
        graph = torch.cat([torch.full((len(p[0]),), g, device=window.device) for g, p in enumerate(parts)])
        return TrainingBatch(window, future, ptype, material, graph)

    def _window(self, k: int, unroll: int = 0):
        """(window [N, history, 2], future [N, unroll + 1, 2], particle_type, material) of window k."""
        first = self._windows(unroll)
        sim = bisect.bisect_right(first, k) - 1
        t = k - first[sim]
        span = (self.history + unroll) * self.stride
        frames = self.positions[sim][t : t + span + 1 : self.stride].transpose(0, 1)  # [N, history + unroll + 1, 2]
        return frames[:, : self.history], frames[:, self.history :], self.particle_type[sim], self.material[sim]

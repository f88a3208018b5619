"""Training windows: `history` positions and the true positions after them, from a split file.

A window at frame stride K starting at frame t holds frames t, t + K, ..., t + (history - 1) K
and its target is frame t + history K; every start frame t that fits is a window, so every
frame is used (K = 1: consecutive frames). Windows also start before frame 0, down to
t = -(history - 1) K, with frame 0 standing for every frame before it: the MPM starts from rest
(after its geostatic relaxation), so these are the windows of a scene at rest, which is how
every user's rollout starts (runout.gns.rollout). Points that move at frame 0 (family a's thrown
blocks, up to 15 m/s: runout.trajectory.first_frame_velocity) stand before it where that
velocity puts them, x(t) = x(0) + t v(0), as a rollout's start_window places them; held at
frame 0 they would ask for a jump from standing still to full speed in one step. A sample for
n pushforward steps (runout.train)
also holds the true frames t + (history + 1) K, ..., t + (history + n) K, the last of which
is then its target, so its start t must leave room for them. All simulations of a split live
on the training device; a batch picks windows uniformly over every (simulation, start frame)
pair that fits with a CPU generator (indices only) and slices the device tensors, so no data
crosses to the device during training. `mirrored` reflects a share of a batch's windows
left-right about the domain's centre, a scene the physics allows as readily (the MPM's deposit
of a mirror-symmetric mound is mirror-symmetric, tests/test_mpm_physics.py) and the families
under-sample: every slope of families b and c fails to the right.
"""

from __future__ import annotations

import bisect
import copy
from dataclasses import dataclass, replace
from pathlib import Path

import torch

from runout.defaults import FRAME_DT
from runout.errors import InputError
from runout.contract import HISTORY, material_names_for_width
from runout.gns.schema import FeatureSchema
from runout.simfiles import read_simulations
from runout.trajectory import first_frame_velocity


@dataclass
class TrainingBatch:
    window: torch.Tensor  # [N, history, 2] m, graphs concatenated
    future: torch.Tensor  # [N, unroll + 1, 2] m: the true positions of the next steps; the last is the target
    particle_type: torch.Tensor  # [N]
    material: torch.Tensor  # [N, k]
    graph: torch.Tensor  # [N] graph index within the batch
    held: torch.Tensor | None = None  # [N] leading window positions that are frame 0 held (the scene at rest)

    @property
    def unroll(self) -> int:
        """Pushforward steps between the window and the target."""
        return self.future.shape[1] - 1


class TrainingWindows:
    """The simulations of one split file on `device`, sampled in windows at frame stride 1
    (with_stride: the same data at another stride), with 0 or more pushforward steps."""

    def __init__(self, path: str | Path, device: torch.device, history: int = HISTORY, material_names=None,
                 rest_windows: bool = True, frame_dt: float = FRAME_DT):
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
        self.rest_windows = rest_windows
        # m per dataset frame: each point's velocity at frame 0 (zero for points at rest), which
        # places it in the frames before frame 0 of a window from rest
        self.start_step = [
            torch.from_numpy(first_frame_velocity(p[0].cpu().numpy(), p[1].cpu().numpy(), t.cpu().numpy(), frame_dt)
                             * frame_dt).to(p) if p.shape[0] > 1 else torch.zeros_like(p[0])
            for p, t in zip(self.positions, self.particle_type)
        ]
        self._index_windows(1)

    @property
    def first_start(self) -> int:
        """The earliest window start frame: -(history - 1) K with rest windows, else 0."""
        return -(self.history - 1) * self.stride if self.rest_windows else 0

    @property
    def starts_at_rest(self) -> list[bool]:
        """Whether each simulation starts with every point at rest (no velocity at frame 0)."""
        return [not bool(step.any()) for step in self.start_step]

    def _index_windows(self, stride: int) -> None:
        self.stride = stride
        self._first_window: dict[int, list[int]] = {}  # unroll -> first window index of each simulation, then the total
        self.check_windows(0)

    def check_windows(self, unroll: int) -> None:
        """InputError unless some simulation has a window for `unroll` pushforward steps."""
        if self.n_windows_for(unroll) == 0:
            span = (self.history + unroll) * self.stride + self.first_start
            steps = f" and {unroll} pushforward steps" if unroll else ""
            start = " from rest" if self.rest_windows else ""
            raise InputError(
                f"{self.path}: no simulation has more than {span} usable frames, which a window of {self.history} "
                f"positions{start} at frame stride {self.stride}{steps} spans; choose a smaller --frame-stride"
                f"{' or --pushforward' if unroll else ''}."
            )

    def _windows(self, unroll: int) -> list[int]:
        if unroll not in self._first_window:
            span = (self.history + unroll) * self.stride  # frames from a window's first position to its target
            first = [0]
            for sim in range(len(self.positions)):
                first.append(first[-1] + max(self.positions[sim].shape[0] - span - self.first_start, 0))
            self._first_window[unroll] = first
        return self._first_window[unroll]

    def with_stride(self, stride: int) -> "TrainingWindows":
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

    def sample(self, batch_size: int, generator: torch.Generator, unroll: int = 0, onset_share: float = 0.0,
               onset_frames: int = 20) -> TrainingBatch:
        """`batch_size` windows drawn uniformly from those with room for `unroll` pushforward steps;
        with onset_share > 0, each is drawn with that probability from the onset instead: a
        simulation chosen uniformly, then a start among its first onset_frames frames (counted
        from the earliest start, so windows at rest included), where failure begins and the
        material decides whether anything moves."""
        picks = torch.randint(self.n_windows_for(unroll), (batch_size,), generator=generator).tolist()
        if onset_share > 0.0:
            first = self._windows(unroll)
            onset = torch.rand(batch_size, generator=generator) < onset_share
            sims = torch.randint(len(self.positions), (batch_size,), generator=generator).tolist()
            offsets = torch.randint(onset_frames, (batch_size,), generator=generator).tolist()
            for b in range(batch_size):
                count = first[sims[b] + 1] - first[sims[b]]  # the simulation's windows, earliest start first
                if onset[b] and count > 0:
                    picks[b] = first[sims[b]] + min(offsets[b], count - 1)
        parts = [self._window(k, unroll) for k in picks]
        window, future, ptype, material = (torch.cat(x) for x in list(zip(*parts))[:4])
        graph = torch.cat([torch.full((len(p[0]),), g, device=window.device) for g, p in enumerate(parts)])
        held = torch.cat([torch.full((len(p[0]),), p[4], device=window.device) for p in parts])
        return TrainingBatch(window, future, ptype, material, graph, held)

    def _window(self, k: int, unroll: int = 0):
        """(window [N, history, 2], future [N, unroll + 1, 2], particle_type, material, held) of
        window k; held: how many of its leading positions are frame 0 or before it (0 for a start
        after it): the scene's start, which a rollout is given exactly."""
        first = self._windows(unroll)
        sim = bisect.bisect_right(first, k) - 1
        t = k - first[sim] + self.first_start  # start frame; frame 0 stands for the frames before it
        raw = t + self.stride * torch.arange(self.history + unroll + 1)  # dataset frames, negative before frame 0
        index = raw.clamp(min=0)
        device = self.positions[sim].device
        frames = self.positions[sim][index.to(device)]  # [history + unroll + 1, N, 2]
        if t < 0:  # before frame 0 each point stands where its frame-0 velocity puts it (at rest: frame 0)
            before = (raw - index).to(device=device, dtype=frames.dtype)  # frames before frame 0 (<= 0)
            frames = frames + before[:, None, None] * self.start_step[sim][None]
        frames = frames.transpose(0, 1)  # [N, history + unroll + 1, 2]
        held = int((index[: self.history] == 0).sum())
        return frames[:, : self.history], frames[:, self.history :], self.particle_type[sim], self.material[sim], held


def mirrored(batch: TrainingBatch, x_range, share: float, generator: torch.Generator,
             graphs: int | None = None) -> TrainingBatch:
    """`batch` with each of its graphs, with probability `share` (drawn from `generator`, one
    draw per graph), reflected left-right about the centre of the domain's x_range ([x_lo,
    x_hi] in m, a pair or a tensor): x -> x_lo + x_hi - x in every window and future position;
    y, types and materials unchanged. The walls stay where they are, so the reflected scene
    lies in the same domain. share 0: the batch itself, and no draw. graphs: how many graphs the
    batch holds, when the caller knows (it spares reading batch.graph back from a GPU each step)."""
    if share <= 0.0:
        return batch
    if graphs is None:
        graphs = int(batch.graph.max()) + 1 if batch.graph.numel() else 0
    flip = (torch.rand(graphs, generator=generator) < share).to(batch.graph.device)[batch.graph.long()]
    axis = x_range[0] + x_range[1]

    def reflect(positions: torch.Tensor) -> torch.Tensor:
        x = torch.where(flip[:, None], axis - positions[..., 0], positions[..., 0])
        return torch.stack([x, positions[..., 1]], dim=-1)

    return replace(batch, window=reflect(batch.window), future=reflect(batch.future))

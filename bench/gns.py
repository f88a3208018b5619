"""GNS speed: training steps/s at batch 2 and rollout ms/step on ~6,000-point graphs.

Graphs: a 150 x 40 lattice at 2 m spacing (jittered by up to 0.2 m), R = 4.6 m, the full
network (latent 128, two hidden layers of 128, 10 processor steps). Prints ratios against
the public reference (geoelements/gns) measured on the same 2-core CPU: 3.22 s per rollout
step, 25.2 s per training step at batch 2, 9.6 GiB peak training memory.

    .venv/bin/python bench/gns.py [--device cpu|cuda] [--threads 2] [--bf16] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import resource
import time
from dataclasses import dataclass

import torch

from runout.gns.graph import radius_graph
from runout.gns.schema import FeatureSchema, NetworkConfig
from runout.gns.simulator import GraphNetworkSimulator, Normalisation
from runout.gns.windows import TrainingBatch
from runout.train import Context, TrainConfig, _train_step

REFERENCE = {"rollout_s": 3.22, "train_s": 25.2, "train_peak_gib": 9.6}  # geoelements/gns, this 2-core CPU
RADIUS = 4.6  # m
BOUNDS = [[0.0, 300.0], [0.0, 152.0]]  # m
STATS = Normalisation((0.0, -0.01), (0.05, 0.05), (0.0, -1e-3), (5e-3, 5e-3), 0.067 * 0.0375)


def lattice_window(seed: int, device, frames: int = 7) -> torch.Tensor:
    """[6000, frames, 2] positions (m): a jittered 2 m lattice moving slowly downhill."""
    gen = torch.Generator().manual_seed(seed)
    ij = torch.stack(torch.meshgrid(torch.arange(150.0), torch.arange(40.0), indexing="ij"), -1).reshape(-1, 2)
    x = ij * 2.0 + 1.0 + (torch.rand(ij.shape, generator=gen) - 0.5) * 0.4
    return torch.stack([x + torch.tensor([0.02, -0.01]) * t for t in range(frames)], dim=1).to(device)


@dataclass
class LatticeData:
    """Stands in for runout.gns.windows.TrainingWindows: always the same two lattice graphs
    (of at least 7 + unroll frames)."""

    frames: list[torch.Tensor]

    def sample(self, batch_size: int, generator, unroll: int = 0) -> TrainingBatch:
        n = self.frames[0].shape[0]
        device = self.frames[0].device
        window = torch.cat([f[:, :6] for f in self.frames[:batch_size]])
        future = torch.cat([f[:, 6 : 7 + unroll] for f in self.frames[:batch_size]])
        ptype = torch.full((n * batch_size,), 6, device=device)
        material = torch.full((n * batch_size, 1), 0.5, device=device)
        graph = torch.arange(batch_size, device=device).repeat_interleave(n)
        return TrainingBatch(window, future, ptype, material, graph)


def timed(fn, repeats: int, device) -> float:
    """Wall seconds per call; also prints this process's CPU seconds per call, which on a
    shared, loaded machine is what a single thread would take alone."""
    fn()  # warm-up
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    sync()
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(repeats):
        fn()
    sync()
    wall, cpu = (time.perf_counter() - t0) / repeats, (time.process_time() - c0) / repeats
    print(f"  ({wall:.3f} s wall, {cpu:.3f} s CPU per call; load average {os.getloadavg()[0]:.1f})")
    return wall


def peak_gib(device) -> float:
    if device.type == "cuda":
        return torch.cuda.max_memory_allocated() / 2**30
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # KiB -> GiB (Linux)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--bf16", action="store_true", help="autocast the network to bfloat16")
    ap.add_argument("--no-checkpoint-layers", action="store_true", help="keep every processor activation in training")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    torch.manual_seed(0)
    sim = GraphNetworkSimulator(FeatureSchema(material_features=("tan_phi",)), STATS, RADIUS, NetworkConfig()).to(device)
    bounds = torch.tensor(BOUNDS, device=device)
    frames = [lattice_window(s, device) for s in (0, 1)]
    n = frames[0].shape[0]
    senders, _ = radius_graph(frames[0][:, 5], RADIUS)
    print(f"device {device}, {args.threads} threads, {n} points, {len(senders)} edges "
          f"({len(senders) / n:.1f} per point incl. self), {sum(p.numel() for p in sim.parameters())} parameters")
    autocast = torch.autocast(device.type, dtype=torch.bfloat16, enabled=args.bf16)

    ptype = torch.full((n,), 6, device=device)
    material = torch.full((n, 1), 0.5, device=device)
    search = timed(lambda: radius_graph(frames[0][:, 5], RADIUS), args.repeats, device)
    sim.eval()
    args_rollout = (frames[0][:, :6], ptype, material, bounds)
    with torch.no_grad(), autocast:
        step = timed(lambda: sim.next_positions(*args_rollout), args.repeats, device)
        reduced = sim(*args_rollout).float()
    if args.bf16:
        with torch.no_grad():
            exact = sim(*args_rollout)
        error = (reduced - exact).norm() / exact.norm()
        print(f"bf16 accuracy: relative RMS error of the normalised acceleration {error:.2e} (untrained weights)")
    print(f"rollout: {step * 1e3:.0f} ms/step (neighbour search {search * 1e3:.1f} ms), peak {peak_gib(device):.2f} GiB"
          f" -> {REFERENCE['rollout_s'] / step:.1f}x faster than the reference")

    sim.train()
    cfg = TrainConfig(data=None, out=None, bf16=args.bf16, checkpoint_layers=not args.no_checkpoint_layers)
    optimizer = torch.optim.Adam(sim.parameters(), lr=1e-4)
    data = LatticeData(frames)
    ctx = Context(device)
    counter = iter(range(10**9))
    train = timed(lambda: _train_step(sim, sim, optimizer, data, bounds, cfg, next(counter), ctx), args.repeats, device)
    memory = peak_gib(device)
    print(f"training (batch 2): {train:.2f} s/step = {1 / train:.2f} steps/s, peak {memory:.2f} GiB"
          f" -> {REFERENCE['train_s'] / train:.1f}x faster, {memory / REFERENCE['train_peak_gib']:.2f} of the reference memory")


if __name__ == "__main__":
    main()

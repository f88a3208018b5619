"""Cost of pushforward training: seconds per training step with n = 0, 1, ..., N unrolled steps.

The graphs of bench/gns.py (two jittered 6,000-point lattices at batch 2, R = 4.6 m) and,
by default, the CPU campaign's network (latent and hidden 64, 5 processor steps). Each
unrolled step is one forward pass without gradient before the training step; the table
gives wall and CPU seconds per step (CPU seconds are what a loaded machine hides least) and
the cost over n = 0. `runout train --pushforward N` draws n uniformly from 0..N, so its
mean cost is the mean of the rows.

    .venv/bin/python experiments/pushforward.py [--pushforward 2] [--threads 1] [--bf16] [--repeats 4]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))  # the lattice graphs of bench/gns.py
from gns import BOUNDS, RADIUS, STATS, LatticeData, lattice_window  # noqa: E402
from runout.gns.schema import FeatureSchema, NetworkConfig
from runout.gns.simulator import GraphNetworkSimulator
from runout.train import Context, TrainConfig, _train_step, unrolled_steps


def seconds_per_step(fn, steps: list[int]) -> tuple[float, float]:
    """(wall, CPU) seconds per call of fn(step) over `steps`, after one warm-up call."""
    fn(steps[0])
    t0, c0 = time.perf_counter(), time.process_time()
    for step in steps[1:]:
        fn(step)
    n = len(steps) - 1
    return (time.perf_counter() - t0) / n, (time.process_time() - c0) / n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pushforward", type=int, default=2)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=4, help="timed training steps per n")
    ap.add_argument("--latent", type=int, default=64)
    ap.add_argument("--message-passing-steps", type=int, default=5)
    ap.add_argument("--bf16", action="store_true", help="autocast the network to bfloat16")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    device = torch.device("cpu")
    torch.manual_seed(0)
    network = NetworkConfig(args.latent, args.latent, 2, args.message_passing_steps)
    sim = GraphNetworkSimulator(FeatureSchema(material_features=("tan_phi",)), STATS, RADIUS, network).train()
    data = LatticeData([lattice_window(s, device, frames=7 + args.pushforward) for s in (0, 1)])
    cfg = TrainConfig(data=None, out=None, bf16=args.bf16, pushforward=args.pushforward)
    optimizer = torch.optim.Adam(sim.parameters(), lr=1e-6)
    bounds = torch.tensor(BOUNDS, device=device)
    ctx = Context(device)
    print(f"{data.frames[0].shape[0]} points x 2 graphs, latent {args.latent}, {args.message_passing_steps} processor "
          f"steps, {'bf16' if args.bf16 else 'fp32'}, {args.threads} thread(s), load average {os.getloadavg()[0]:.1f}")
    print("| unrolled steps n | s/step (wall) | s/step (CPU) | CPU over n = 0 |")
    print("|---|---|---|---|")
    base = None
    for n in range(args.pushforward + 1):
        steps = [s for s in range(10_000) if unrolled_steps(cfg.seed, s, cfg.pushforward) == n][: args.repeats + 1]
        wall, cpu = seconds_per_step(lambda s: _train_step(sim, sim, optimizer, data, bounds, cfg, s, ctx), steps)
        base = base or cpu
        print(f"| {n} | {wall:.3f} | {cpu:.3f} | +{100 * (cpu / base - 1):.0f} % |")
    print(f"(load average {os.getloadavg()[0]:.1f} at the end)")


if __name__ == "__main__":
    main()

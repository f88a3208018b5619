"""What buys GNS training steps per CPU-second (issue: the GNS recipe, item 4): eager against
torch.compile of the network, bfloat16 autocast, recomputing the processor's activations in
backward (the default, less memory) against keeping them, one process with T threads against two gloo
ranks of one thread each (DistributedDataParallel, as torchrun runs `runout train`), and the
connectivity radius (in point spacings; the default is 2.3).

Each configuration trains the recipe's network (latent 64, hidden 64, 5 message-passing
steps, batch 2 graphs per process unless a bN token says otherwise) on real windows of a dataset (default data/ft8) with the
real training step (runout.train._train_step), after --warmup steps (compilation included
there), and prints graphs per second: steps/s times graphs per step (2 per process).
Measure on a quiet machine; on a loaded one, say so beside the figure.

    .venv/bin/python bench/train_throughput.py --data data/ft8 --configs bf16:1 bf16+keep:1 bf16+keep:2 gloo+bf16+keep:2
    .venv/bin/python bench/train_throughput.py --configs bf16+keep:2 gloo+bf16+keep+b1:2   # the campaign's batch of 2, two ways
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import torch
import torch.distributed as dist
import torch.multiprocessing as mp

from runout.contract import RADIUS_PER_SPACING as DEFAULT_SPACINGS
from runout.gns.schema import FeatureSchema, NetworkConfig
from runout.gns.simulator import GraphNetworkSimulator, Normalisation
from runout.gns.windows import TrainingWindows
from runout.simfiles import read_metadata
from runout.train import Context, TrainConfig, _train_step, noise_scale

NETWORK = NetworkConfig(latent=64, hidden=64, hidden_layers=2, message_passing_steps=5)



def build(data_dir: Path, radius_spacings: float,
          device: torch.device) -> tuple[GraphNetworkSimulator, TrainingWindows, torch.Tensor]:
    meta = read_metadata(data_dir)
    data = TrainingWindows(data_dir / "train.npz", device, material_names=meta.get("material_features"))
    stats = Normalisation.from_metadata(meta, 0.3 * noise_scale(meta))
    radius = float(meta["default_connectivity_radius"]) * radius_spacings / DEFAULT_SPACINGS
    torch.manual_seed(0)
    simulator = GraphNetworkSimulator(data.schema(FeatureSchema()), stats, radius, NETWORK).to(device).train()
    return simulator, data, torch.tensor(meta["bounds"], dtype=torch.float32, device=device)


def measure(data_dir: Path, kind: str, steps: int, warmup: int, rank: int = 0, world: int = 1) -> dict:
    """Seconds per step of one process (rank of world) for configuration `kind`: tokens joined
    by '+', each of eager (nothing), bf16, keep (no recomputation in backward), compile, rS."""
    device = torch.device("cpu")
    tokens = set(kind.split("+"))
    radius = [float(t[1:]) for t in tokens if t.startswith("r")]
    batch = [int(t[1:]) for t in tokens if t.startswith("b") and t[1:].isdigit()]
    simulator, data, bounds = build(data_dir, radius[0] if radius else DEFAULT_SPACINGS, device)
    model = simulator
    if "compile" in tokens:
        simulator.network = torch.compile(simulator.network, dynamic=True)
    if world > 1:
        model = torch.nn.parallel.DistributedDataParallel(simulator)
    cfg = TrainConfig(data=data_dir, out=Path("."), bf16="bf16" in tokens, noise=0.3, exact_rest=True,
                      checkpoint_layers="keep" not in tokens, batch_size=batch[0] if batch else 2)
    optimizer = torch.optim.Adam(simulator.parameters(), lr=1e-4)
    ctx = Context(device, rank, world)
    for step in range(warmup):
        _train_step(model, simulator, optimizer, data, bounds, cfg, step, ctx)
    t0, c0 = time.perf_counter(), time.process_time()
    for step in range(warmup, warmup + steps):
        _train_step(model, simulator, optimizer, data, bounds, cfg, step, ctx)
    return {"s_per_step": (time.perf_counter() - t0) / steps, "cpu_s_per_step": (time.process_time() - c0) / steps}


def _rank(rank: int, world: int, data_dir: Path, kind: str, steps: int, warmup: int, port: int, results) -> None:
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    torch.set_num_threads(1)
    dist.init_process_group("gloo", rank=rank, world_size=world)
    results[rank] = measure(data_dir, kind, steps, warmup, rank, world)
    dist.destroy_process_group()


def _batch(kind: str) -> int:
    """Graphs per step of one process: the bS token, else 2."""
    return next((int(t[1:]) for t in kind.split("+") if t.startswith("b") and t[1:].isdigit()), 2)


def run(data_dir: Path, config: str, steps: int, warmup: int) -> dict:
    kind, threads = config.split(":")
    threads = int(threads)
    if kind.startswith("gloo"):  # `threads` ranks of one thread each, e.g. gloo+bf16+keep:2
        results = mp.Manager().dict()
        kind = kind.removeprefix("gloo").removeprefix("+") or "eager"
        mp.spawn(_rank, args=(threads, data_dir, kind, steps, warmup, 29500 + os.getpid() % 1000, results), nprocs=threads)
        per_step = max(r["s_per_step"] for r in results.values())
        graphs = _batch(kind) * threads
    else:
        torch.set_num_threads(threads)
        per_step = measure(data_dir, kind, steps, warmup)["s_per_step"]
        graphs = _batch(kind)
    return {"config": config, "s_per_step": round(per_step, 4), "graphs_per_s": round(graphs / per_step, 3),
            "load_average": round(os.getloadavg()[0], 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path("data/ft8"))
    ap.add_argument("--configs", nargs="+",
                    default=["bf16:1", "bf16+keep:1", "bf16+keep:2", "gloo+bf16+keep:2", "bf16+keep+compile:1", "bf16+keep+r1.8:1"],
                    help="KIND:THREADS, KIND tokens joined by '+': eager, bf16, keep (processor activations kept for "
                         "backward, not recomputed), compile, rS (radius S point spacings), bN (N graphs per step of each "
                         "process; 2 by default), and a leading gloo (THREADS = ranks of one thread each)")
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--warmup", type=int, default=20)
    args = ap.parse_args()
    for config in args.configs:
        print(json.dumps(run(args.data, config, args.steps, args.warmup)), flush=True)


if __name__ == "__main__":
    main()

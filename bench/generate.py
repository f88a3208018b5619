"""Benchmark: seconds to generate a finetune training dataset with the batched MPM.

    python bench/generate.py                          # 100 finetune scenes on CPU
    python bench/generate.py --count 10 --frames 60   # a smaller CPU measurement
    python bench/generate.py --device cuda --count 1027 --batch 128   # the full finetune set on a GPU

Prints the wall time of `runout generate` (sampling, MPM, part files, split files), the
scenes per second, and the machine it ran on. The dataset goes to a scratch directory that
is removed afterwards unless --keep is given.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import tempfile
import time
from pathlib import Path

import torch

from runout.dataset import summarize
from runout.generate import GenerateConfig, generate


def machine(device: str) -> str:
    if device.startswith("cuda"):
        return f"{torch.cuda.get_device_name(0)}, torch {torch.__version__}"
    return f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPU cores, {torch.get_num_threads()} torch threads, torch {torch.__version__}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stage", default="finetune", choices=["base", "finetune"])
    parser.add_argument("--count", type=int, default=100, help="scenes (at least 10)")
    parser.add_argument("--device", default="cpu", help="cpu or cuda")
    parser.add_argument("--batch", type=int, default=None, help="scenes per MPM batch (default 16 on CPU, 128 on CUDA)")
    parser.add_argument("--frames", type=int, default=480, help="output frames per scene")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None, help="dataset directory (default: a scratch directory)")
    parser.add_argument("--keep", action="store_true", help="keep the generated dataset")
    args = parser.parse_args()

    batch = args.batch or (128 if args.device.startswith("cuda") else 16)
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_generate_"))
    if out.exists() and any(out.iterdir()):
        raise SystemExit(f"{out} is not empty; give an empty --out so the run starts from scratch")
    config = GenerateConfig(args.stage, args.count, args.seed, batch=batch, frames=args.frames)
    start = time.perf_counter()
    generate(config, out, device=args.device, progress=True)
    seconds = time.perf_counter() - start
    train = summarize(out)["splits"]["train"]
    print(
        f"generate {args.stage}: {args.count} scenes x {args.frames} frames, batch {batch}, {args.device} "
        f"({machine(args.device)}): {seconds:.1f} s, {seconds / args.count:.2f} s/scene; "
        f"train points per scene {train['points'][0]}-{train['points'][1]}"
    )
    if not args.keep:
        shutil.rmtree(out)


if __name__ == "__main__":
    main()

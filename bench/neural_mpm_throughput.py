"""What buys neural-MPM training steps per CPU-second (issue 57 item 4): threads, channels-last
memory for the U-Net's convolutions, torch.compile of the U-Net, bfloat16 autocast (only
where the CPU has native bf16: avx512_bf16 or AMX; on an AVX2-only CPU it is emulated and
slower), K (chained calls per loss), m (frames per call) and the input velocities' sharpening
sweeps (`--velocity-sweeps`: each is two more point-grid transfers per call).

Each configuration runs the real training step (runout.neural_mpm.training.Run.step) on
real windows of a dataset (default data/ft8, batch 8, m = 8, 8 m cells) after --warmup
steps (compilation included there) and prints steps per wall-second and per CPU-second of
the process (CPU time on every thread: the pilots' budget). Measure on a quiet machine; on a
loaded one, say so beside the figure.

    .venv/bin/python bench/neural_mpm_throughput.py --configs eager:1 channels_last:1 compile:1 eager:2
    .venv/bin/python bench/neural_mpm_throughput.py --configs eager:1 --calls 2,3,4
    .venv/bin/python bench/neural_mpm_throughput.py --configs eager:1 --calls 2 --frames-per-call 16 --sweeps 0,4,8
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import time
from contextlib import nullcontext

import torch

from runout.neural_mpm.engine import NeuralMPMConfig
from runout.neural_mpm.training import Run, TrainSettings


def native_bf16() -> bool:
    flags = open("/proc/cpuinfo").read() if platform.system() == "Linux" else ""
    return "avx512_bf16" in flags or "amx_bf16" in flags


def measure(data: str, kind: str, threads: int, calls: int, steps: int, warmup: int, cell: float,
            frames_per_call: int = NeuralMPMConfig.frames_per_call, sweeps: int = 0) -> dict:
    """Steps per wall- and CPU-second of one configuration: tokens joined by '+' of eager
    (nothing), channels_last, compile, bf16."""
    tokens = set(kind.split("+"))
    torch.set_num_threads(threads)
    settings = TrainSettings(data=data, out="/tmp/runout-bench-nmpm", calls=calls, valid_every=0, progress=False,
                             steps=10 ** 9, log_every=10 ** 9)
    shutil.rmtree(settings.out, ignore_errors=True)  # a new run each time
    config = NeuralMPMConfig(cell_size=cell, point_spacing=4.0, frames_per_call=frames_per_call, velocity_sweeps=sweeps)
    run = Run.start(settings, config, resume=False)
    if "channels_last" in tokens:
        run.engine.net = run.engine.net.to(memory_format=torch.channels_last)
        forward = run.engine.net.forward
        run.engine.net.forward = lambda x: forward(x.contiguous(memory_format=torch.channels_last))
    if "compile" in tokens:
        run.engine.net = torch.compile(run.engine.net, dynamic=False)
    autocast = torch.autocast("cpu", dtype=torch.bfloat16) if "bf16" in tokens else nullcontext()
    with autocast:
        for step in range(warmup):
            run.step(step)
        wall, cpu = time.perf_counter(), time.process_time()
        for step in range(warmup, warmup + steps):
            run.step(step)
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return {"config": kind, "threads": threads, "calls": calls, "cell_m": cell, "frames_per_call": frames_per_call,
            "velocity_sweeps": sweeps, "steps": steps,
            "steps_per_wall_s": steps / wall, "steps_per_cpu_s": steps / cpu}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", default="data/ft8")
    p.add_argument("--configs", nargs="+", default=["eager:1", "channels_last:1", "compile:1", "eager:2"],
                   help="KIND:THREADS, KIND = tokens joined by '+' of eager, channels_last, compile, bf16")
    p.add_argument("--calls", default="3", help="K values, comma-separated")
    p.add_argument("--cell-size", type=float, default=8.0)
    p.add_argument("--frames-per-call", type=int, default=NeuralMPMConfig.frames_per_call)
    p.add_argument("--sweeps", default="0", help="velocity sweeps, comma-separated")
    p.add_argument("--steps", type=int, default=40)
    p.add_argument("--warmup", type=int, default=5)
    a = p.parse_args()
    print(f"# {platform.processor() or platform.machine()}, native bf16: {native_bf16()}, torch {torch.__version__}")
    for spec in a.configs:
        kind, threads = spec.split(":")
        if "bf16" in kind and not native_bf16():
            print(f"# {spec}: skipped, this CPU has no native bf16 (it would be emulated)")
            continue
        for calls in (int(k) for k in a.calls.split(",")):
            for sweeps in (int(n) for n in a.sweeps.split(",")):
                torch.manual_seed(0)
                print(json.dumps(measure(a.data, kind, int(threads), calls, a.steps, a.warmup, a.cell_size,
                                         a.frames_per_call, sweeps)), flush=True)


if __name__ == "__main__":
    main()

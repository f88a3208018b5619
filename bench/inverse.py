"""Inverse-analysis cost on the paper's dam: seconds per L-BFGS-B evaluation (forward rollout,
reverse-mode backward pass with each step recomputed) and peak memory.

The dam is examples/dam.toml with the free parameters of examples/dam_inverse.toml (c1, c2,
phi3); the rollout runs the scene's 400 frames (394 steps) unless --steps says otherwise.
Without --model the full-size network (latent 128, 10 processor steps, R = 4.6 m) is
randomly initialised: the cost per step depends on the graph size, not on the weights.
Peak memory: CUDA max allocated; on CPU the bytes autograd holds for the backward pass
(saved-tensor hooks) and the process's peak RSS. Goals: <= 6 s per iteration and <= 8 GB on
one H100 (paper: ~62 s per iteration on a Quadro RTX 5000, 20 s forward + 42 s gradient).

--engine picks what evaluates the loss and its gradient, as `runout invert --engine` does:
the GNS (gns), the neural MPM (neural-mpm, from --model; the scene refilled at the model's
point spacing, as `runout invert` fills it), the MPM's reverse-mode AD (mpm-ad: the Warp
kernels and their adjoint) or central finite differences (mpm-fd). The MPM engines run the
scene as written (4 m cells, 2 points per cell) unless --cell-size refills it (8: the neural
MPM's points). Issue 57 item 6 asks the neural MPM's evaluation to be faster than mpm-ad's.

    .venv/bin/python bench/inverse.py [--model CKPT] [--device cpu|cuda] [--steps 394]
                                      [--repeats 2] [--threads 2] [--no-checkpoint]
    .venv/bin/python bench/inverse.py --engine mpm-fd [--steps 394]   # the 2P + 1 = 7 MPM runs
    .venv/bin/python bench/inverse.py --engine neural-mpm --model models/neural-mpm.pt [--repeats 1]
    .venv/bin/python bench/inverse.py --engine mpm-ad [--cell-size 8] [--repeats 1]
"""

from __future__ import annotations

import argparse
import resource
import statistics
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from runout.gns.checkpoint import load_simulator
from runout.gns.engine import GnsEngine
from runout.gns.schema import FeatureSchema, NetworkConfig
from runout.gns.simulator import GraphNetworkSimulator, Normalisation
from runout.inverse import load_inverse_spec
from runout.inverse.forward import inverse_problem
from runout.inverse.mpm_ad import MpmAutodiff
from runout.inverse.mpm_fd import MpmFiniteDifference
from runout.inverse.observation import Observation
from runout.learned.load import load_engine
from runout.learned.scenes import at_model_spacing
from runout.scene import fill_points

REPO = Path(__file__).resolve().parents[1]
SPEC = REPO / "examples" / "dam_inverse.toml"
STATS = Normalisation((0.0, -0.01), (0.05, 0.05), (0.0, -1e-3), (5e-3, 5e-3), 0.067 * 0.0375)  # as bench/gns.py


def simulator_for(model: str | None, device: str) -> tuple[GraphNetworkSimulator, str]:
    if model:
        return load_simulator(model, device), model
    torch.manual_seed(0)
    return GraphNetworkSimulator(FeatureSchema(), STATS, 4.6, NetworkConfig()).to(device).eval(), "random full-size GNS"


def dam_observation(spec, steps: int) -> Observation:
    """The dam at rest as the target: the loss value does not change the cost."""
    points = fill_points(spec.scene)
    return Observation((steps,), points.position[None].copy(), steps, points.position, points.particle_type,
                       points.material_id, None)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default=None, help="GNS checkpoint (default: random full-size network), or the "
                    "neural MPM's (needed for --engine neural-mpm)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--steps", type=int, default=None, help="frames rolled out from rest (default: the dam scene's frames - 1)")
    ap.add_argument("--repeats", type=int, default=2, help="timed evaluations after one warm-up")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--no-checkpoint", action="store_true", help="keep every step's activations")
    ap.add_argument("--engine", choices=("gns", "neural-mpm", "mpm-ad", "mpm-fd"), default="gns")
    ap.add_argument("--cell-size", type=float, default=None, help="mpm-ad, mpm-fd: refill the dam at this cell size (m)")
    args = ap.parse_args()
    if args.engine == "neural-mpm" and not args.model:
        ap.error("--engine neural-mpm needs --model (e.g. models/neural-mpm.pt)")
    if args.cell_size is not None and not args.engine.startswith("mpm"):
        ap.error("--cell-size is for the MPM engines (a learned engine fills the scene at its own spacing)")
    torch.set_num_threads(args.threads)

    spec = load_inverse_spec(SPEC)
    if args.cell_size is not None:
        spec = replace(spec, scene=replace(spec.scene, domain=replace(spec.scene.domain, cell_size=args.cell_size)))
    steps = args.steps or spec.scene.time.frames - 1
    values = np.array([p.initial for p in spec.free])
    if args.engine == "neural-mpm":
        engine = load_engine(args.model, args.device, expect="neural-mpm")
        spec = replace(spec, scene=at_model_spacing(spec.scene, engine))
        observation = dam_observation(spec, steps)
        evaluate = inverse_problem(spec, observation, engine, checkpoint=not args.no_checkpoint).evaluate
        model_name = f"neural MPM {args.model}"
    elif args.engine.startswith("mpm"):
        observation = dam_observation(spec, steps)
        if args.engine == "mpm-fd":
            evaluate = MpmFiniteDifference(spec, observation, device=args.device)
            model_name = f"MPM, {2 * len(spec.free) + 1} scenes in one batch"
        else:
            evaluate, model_name = MpmAutodiff(spec, observation, device=args.device), "MPM reverse-mode AD (Warp)"
        model_name += f", {spec.scene.domain.cell_size:g} m cells"
    else:
        observation = dam_observation(spec, steps)
        simulator, model_name = simulator_for(args.model, args.device)
        evaluate = inverse_problem(spec, observation, GnsEngine(simulator), checkpoint=not args.no_checkpoint).evaluate
    evaluate(values)  # warm-up
    runs = [evaluate(values) for _ in range(args.repeats)]
    report(runs, len(observation.initial), steps, model_name, args, spec.names)


def report(runs, n_points: int, steps: int, model_name: str, args, names: list[str]) -> None:
    forward = statistics.median(r.forward_s for r in runs)
    backward = statistics.median(r.backward_s for r in runs)
    peak = max(r.peak_memory_bytes for r in runs)
    print(f"dam: {n_points} points, {steps} steps, {model_name}, device {args.device}, "
          f"threads {args.threads}" + ("" if args.engine.startswith("mpm") else f", checkpoint {not args.no_checkpoint}")
          + f", free {', '.join(names)}")
    print(f"per evaluation: forward {forward:.2f} s, backward {backward:.2f} s, total {forward + backward:.2f} s "
          f"({1000 * (forward + backward) / steps:.1f} ms per step)")
    if args.device.startswith("cuda"):
        print(f"peak memory: {peak / 1e9:.2f} GB (torch.cuda.max_memory_allocated); goal <= 8 GB, <= 6 s per iteration")
    else:
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # KiB -> bytes (Linux)
        print(f"peak memory: {peak / 1e6:.1f} MB held for the backward pass (saved-tensor hooks); "
              f"process peak RSS {rss / 1e9:.2f} GB")


if __name__ == "__main__":
    main()

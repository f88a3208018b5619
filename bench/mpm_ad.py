"""MPM inverse gradients on the small dam: reverse-mode AD (--engine mpm-ad) against central
finite differences (--engine mpm-fd): agreement and seconds per evaluation for P = 1, 3, 8.

The target is the MPM run of examples/small_dam.toml (10 m cells, 336 moving points) at its
own strengths, observed at the last frame; each engine evaluates the loss and its gradient
once at a start away from the truth. P = 1: c of the lower downstream shell; P = 3: also phi
of the upper shell and c of the core; P = 8: phi and c of all four materials.

    .venv/bin/python bench/mpm_ad.py [--frames 160] [--threads 1] [--fd-step 0.01] [--sizes 1,3,8]
                                     [--scene examples/small_dam.toml] [--cell-size M] [--compile]
                                     [--repeat 3] [--backend torch]

Both engines are warmed up by one evaluation at the first size before anything is timed (the
first autograd pass of a process, and with --compile torch.compile's compilation); the first
calls' seconds are printed apart. Each engine is then timed --repeat times, the two
engines alternating, and the fastest evaluation of each is reported (on a shared machine the
slower ones measure the other jobs). Both engines run the fused Warp kernels (runout.mpm.kernels,
kernels_ad), as `runout invert` does; --backend torch runs them on the torch solver, the tests'
oracle, and --compile (torch only) its substep through torch.compile (mpm-fd:
runout.mpm.simulate(compile=True); mpm-ad: DifferentiableMpm(compile=True)).

--scene examples/dam.toml --cell-size 8 --frames 400 runs the paper's dam (section 5.2) at the
CPU models' resolution instead (its materials have the same names).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from runout.inverse import load_inverse_spec, load_observation
from runout.inverse.mpm_ad import MpmAutodiff
from runout.inverse.mpm_fd import MpmFiniteDifference
from runout.mpm import simulate
from runout.scene import Scene, load_scene, save_scene
from runout.trajectory import save_trajectory

REPO = Path(__file__).resolve().parents[1]
# (material, property, start, lower, upper); truth: the scene's values
FREE = [
    ("m1_downstream_lower", "c", 30.0, 20.0, 60.0),
    ("m3_downstream_upper", "phi", 36.0, 30.0, 45.0),
    ("m2_core", "c", 90.0, 50.0, 150.0),
    ("m1_downstream_lower", "phi", 3.0, 0.0, 10.0),
    ("m2_core", "phi", 12.0, 5.0, 20.0),
    ("m3_downstream_upper", "c", 15.0, 0.0, 30.0),
    ("m4_upstream_shell", "phi", 38.0, 30.0, 45.0),
    ("m4_upstream_shell", "c", 15.0, 0.0, 30.0),
]


def write_spec(folder: Path, free, last_frame: int) -> Path:
    tables = {}
    for material, prop, start, lower, upper in free:
        tables.setdefault(material, []).append(f"{prop} = {{ initial = {start}, lower = {lower}, upper = {upper} }}")
    body = "".join(f"[parameters.{m}]\n" + "\n".join(rows) + "\n" for m, rows in tables.items())
    path = folder / f"spec_{len(free)}.toml"
    path.write_text(f'scene = "scene.toml"\n[target]\ntrajectory = "target"\nframes = [{last_frame}]\n{body}')
    return path


def bench_scene(path: Path, frames: int, cell_size: float | None) -> Scene:
    """The scene at PATH with `frames` frames, refilled at `cell_size` m cells when given."""
    scene = load_scene(path).with_frames(frames)
    if cell_size is not None:
        scene = replace(scene, domain=replace(scene.domain, cell_size=cell_size))
    return scene


def write_target(folder: Path, scene: Scene) -> None:
    """FOLDER/scene.toml and FOLDER/target: the MPM run of the scene at its own strengths."""
    save_scene(scene, folder / "scene.toml")
    save_trajectory(simulate([scene], progress=False)[0], folder / "target")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=160)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--fd-step", type=float, default=0.01)
    ap.add_argument("--sizes", default="1,3,8")
    ap.add_argument("--scene", type=Path, default=REPO / "examples" / "small_dam.toml")
    ap.add_argument("--cell-size", type=float, default=None, help="refill the scene at this cell size (m)")
    ap.add_argument("--compile", action="store_true", help="--backend torch: torch.compile the substep in both engines")
    ap.add_argument("--repeat", type=int, default=3, help="timed evaluations per engine and size (fastest kept)")
    ap.add_argument("--backend", choices=("torch", "warp"), default="warp", help="the MPM under both engines")
    args = ap.parse_args()
    if args.compile and args.backend != "torch":
        ap.error("--compile needs --backend torch (the Warp kernels are compiled already)")
    torch.set_num_threads(args.threads)
    scene = bench_scene(args.scene, args.frames, args.cell_size)
    print(f"{args.scene.name} at {scene.domain.cell_size:g} m cells; load average {os.getloadavg()[0]:.2f}, "
          f"{args.threads} thread(s), {args.frames} frames, fd step {args.fd_step}, "
          f"{'torch.compile' if args.compile else 'eager'}, MPM on {args.backend}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        write_target(folder, scene)
        sizes = [int(s) for s in args.sizes.split(",")]
        first: dict[str, float] = {}
        rows = []
        for p in sizes:
            spec = load_inverse_spec(write_spec(folder, FREE[:p], args.frames - 1))
            observation = load_observation(spec)
            start = np.array([q.initial for q in spec.free])  # the spec's order: grouped by material
            ad_engine = MpmAutodiff(spec, observation, compile=args.compile, backend=args.backend)
            fd_engine = MpmFiniteDifference(spec, observation, step=args.fd_step, compile=args.compile,
                                            backend=args.backend)
            if p == sizes[0]:  # warm-up: one-off set-up of the first autograd pass, and compilation
                for name, engine in (("mpm-fd", fd_engine), ("mpm-ad", ad_engine)):  # each compiles its own
                    # graphs: mpm-fd 2 (no grad; relaxation, frame), mpm-ad 4 (also their forward and backward)
                    t0 = time.perf_counter()
                    engine(start)
                    first[name] = time.perf_counter() - t0
            best = {}
            for _ in range(args.repeat):
                for name, engine in (("mpm-ad", ad_engine), ("mpm-fd", fd_engine)):
                    t0 = time.perf_counter()
                    ev = engine(start)
                    total = time.perf_counter() - t0
                    if name not in best or total < best[name][1]:
                        best[name] = (ev, total)
            (ad, ad_total), (fd, fd_total) = best["mpm-ad"], best["mpm-fd"]
            rows.append((p, spec, ad, ad_total, fd, fd_total, os.getloadavg()[0]))
        print(f"first calls (P = {sizes[0]}, set-up{' and compilation' if args.compile else ''} included): "
              + ", ".join(f"{name} {s:.1f} s" for name, s in first.items()))
        print("| P | engine | MPM runs | forward s | backward s | total s | held MB | gradient (per kPa or degree) |")
        print("|---|---|---|---|---|---|---|---|")
        for p, spec, ad, ad_total, fd, fd_total, load in rows:
            for name, ev, runs, total in (("mpm-ad", ad, 1, ad_total), ("mpm-fd", fd, 2 * p + 1, fd_total)):
                grad = ", ".join(f"{q.name} {g:.4g}" for q, g in zip(spec.free, ev.gradient))
                print(f"| {p} | {name} | {runs} | {ev.forward_s:.2f} | {ev.backward_s:.2f} | {total:.2f} | "
                      f"{ev.peak_memory_bytes / 1e6:.2f} | {grad} |")
            rel = np.abs(ad.gradient - fd.gradient) / np.maximum(np.abs(fd.gradient), 1e-30)
            print(f"|   | AD / FD | loss {ad.loss:.5g} vs {fd.loss:.5g} m^2 | relative gradient difference "
                  f"{', '.join(f'{r:.2g}' for r in rel)} | | | load {load:.2f} | cost ratio {ad_total / fd_total:.2f} |")
        print(f"load average {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()

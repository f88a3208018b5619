"""Training pilots at equal wall time, compared by validation rollouts (issue: CPU recipe).

Each pilot is one `runout train` run of --minutes wall time (its own --max-hours) with a
preset of settings; `--parallel 2` runs two at once with one thread each, so each pilot
gets one core of a 2-core machine for the same time. Afterwards every pilot's last
checkpoint rolls out the first --valid trajectories of the dataset's valid split over all
their frames, and the table gives the mean |runout error| (relative, farthest soil point at
the last frame) and the mean position MSE over the rollout (m^2), beside the steps reached.

    python experiments/train_pilots.py --data data/base8 --out runs/pilots --minutes 10 --parallel 2
    python experiments/train_pilots.py --data data/base8 --out runs/pilots --evaluate-only
    python experiments/train_pilots.py --data data/ft8 --out runs/ftpilots --init models/slope.pt \
        --pilots ft-stride2 ft-stride1 --minutes 25 --parallel 1 --threads 1 --valid 6

Results go to OUT/pilots.json and a Markdown table on stdout (pasted into docs/training.md).

Stopping it (SIGTERM or Ctrl-C) while pilots train asks every `runout train` it started to
stop after its current step (each saves its checkpoint, so `--resume` continues it) and exits
without evaluating: no training process is left behind, none evaluates unasked.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from runout.outputs import write_atomic

# The defaults of `runout train` when these pilots ran (the paper's; since issue 54 the defaults
# are the recipe they chose): every preset below changes them, so each pilot is run from them.
BEFORE_THE_RECIPE = ["--lr", "1e-4", "--lr-decay-steps", "5e6", "--noise", "0.1", "--noisy-rest", "--pushforward", "0",
                     "--ema", "0", "--checkpoint-layers", "--onset-schedule", "", "--mirror", "0"]
# name: extra `runout train` options. The pilots of --moving-weight and --static-tail, options no
# recipe kept, left with them (issue 54); docs/training.md keeps their figures. --onset-share S
# --onset-frames F is now --onset-schedule 0:S:F.
W64 = ["--latent", "64", "--hidden", "64", "--message-passing-steps", "5", "--bf16"]
PRESETS: dict[str, list[str]] = {
    "w64-lr1e-4": [*W64, "--lr", "1e-4"],
    "w64-lr4e-4": [*W64, "--lr", "4e-4"],
    "w64-lr1e-3": [*W64, "--lr", "1e-3"],
    "w64-lr4e-4-b4": [*W64, "--lr", "4e-4", "--batch-size", "4"],
    "w64-lr4e-4-noise0.02": [*W64, "--lr", "4e-4", "--noise-std", "0.02"],
    "w64-lr4e-4-fp32": ["--latent", "64", "--hidden", "64", "--message-passing-steps", "5", "--lr", "4e-4"],
    "w128-lr4e-4": ["--latent", "128", "--hidden", "128", "--message-passing-steps", "5", "--bf16", "--lr", "4e-4"],
    "w128-mp10-lr4e-4": ["--latent", "128", "--hidden", "128", "--message-passing-steps", "10", "--bf16", "--lr", "4e-4"],
    # from a campaign checkpoint (--init PATH): the campaign's schedule, one setting changed
    "ft-stride1": [*W64, "--lr", "1e-4", "--lr-decay-steps", "300000"],
    "ft-stride2": [*W64, "--lr", "1e-4", "--lr-decay-steps", "300000", "--frame-stride", "2"],
    "ft-pushforward2": [*W64, "--lr", "1e-4", "--lr-decay-steps", "300000", "--pushforward", "2"],
    # the recipe issue (solver-6 data, from scratch, windows at rest included): noise in velocity std
    **{f"r-noise{n}": [*W64, "--lr", "4e-4", "--lr-decay-steps", "200000", "--noise", n] for n in ("0.02", "0.1", "0.3", "0.6")},
    **{f"r-noise{n}-stride{k}": [*W64, "--lr", "4e-4", "--lr-decay-steps", "200000", "--noise", n, "--frame-stride", k]
       for n in ("0.1", "0.3", "0.6") for k in ("2", "4")},
    # from an exact-rest pilot's checkpoint: pushforward k (the model's own errors instead of more noise), activations kept
    **{f"x-noise{n}-exact-pf{k}": [*W64, "--lr", "4e-4", "--lr-decay-steps", "200000", "--noise", n, "--exact-rest",
                                   "--pushforward", k, "--no-checkpoint-layers"]
       for n in ("0.01", "0.03", "0.1", "0.3") for k in ("1", "2", "3")},
    # from a pushforward pilot's checkpoint: a share of the windows drawn from the first 20 frames (the onset)
    **{f"x-noise{n}-exact-pf2-onset{f}": [*W64, "--lr", "4e-4", "--lr-decay-steps", "200000", "--noise", n,
                                          "--exact-rest", "--pushforward", "2", "--no-checkpoint-layers",
                                          "--onset-schedule", f"0:{f}:20"]
       for n in ("0.01", "0.03") for f in ("0.25", "0.5")},
    # the same, saving a weight average over about 1,000 steps (--ema 0.999): one step's weights swing the onset
    **{f"x-noise{n}-exact-pf2-onset0.25-ema": [*W64, "--lr", "4e-4", "--lr-decay-steps", "200000", "--noise", n,
                                               "--exact-rest", "--pushforward", "2", "--no-checkpoint-layers",
                                               "--onset-schedule", "0:0.25:20", "--ema", "0.999"]
       for n in ("0.01", "0.03")},
    # the recipe from scratch at frame stride 2 and 4 (one GNS step spans k frames: k times fewer rollout steps)
    **{f"x-noise0.01-exact-pf2-onset0.25-ema-stride{k}": [*W64, "--lr", "4e-4", "--lr-decay-steps", "200000", "--noise",
                                                          "0.01", "--exact-rest", "--pushforward", "2",
                                                          "--no-checkpoint-layers", "--onset-schedule", "0:0.25:20",
                                                          "--ema", "0.999", "--frame-stride", k]
       for k in ("2", "4")},
    # the recipe with 10 message-passing steps instead of 5: at rest a point's first prediction
    # sees only its receptive field, 5 x 9.2 m = 46 m at 8 m cells, less than the tallest slopes,
    # whose height sets whether cohesion holds them (c / gamma H); 10 steps see 92 m
    **{f"x-noise0.01-exact-pf2-onset0.25-ema{tail}-mp10": [
        "--latent", "64", "--hidden", "64", "--message-passing-steps", "10", "--bf16", "--lr", "4e-4",
        "--lr-decay-steps", "200000", "--noise", "0.01", "--exact-rest", "--pushforward", "2", "--no-checkpoint-layers",
        "--onset-schedule", "0:0.25:20", "--ema", "0.999", *stride]
       for tail, stride in (("", []), ("-stride2", ["--frame-stride", "2"]), ("-stride4", ["--frame-stride", "4"]))},
    # the same from a checkpoint, annealed: a quarter of the learning rate
    "x-noise0.01-exact-pf2-onset0.25-ema-lr1e-4": [*W64, "--lr", "1e-4", "--lr-decay-steps", "200000", "--noise", "0.01",
                                                    "--exact-rest", "--pushforward", "2", "--no-checkpoint-layers",
                                                    "--onset-schedule", "0:0.25:20", "--ema", "0.999"],
    # the same, the onset drawn from the first 6 frames (0.4 of the windows): one-step predictions
    # on true windows are right from frame 5 on (slope 0.9-1.0) but reach 0.10-0.17 of the first two
    # accelerations from rest, which onset share 0.25 over 20 frames and pushforward 0-2 draw for
    # 0.4 % of the windows (round 8)
    "x-noise0.01-exact-pf2-onset0.4f6-ema-lr1e-4": [*W64, "--lr", "1e-4", "--lr-decay-steps", "200000", "--noise", "0.01",
                                                     "--exact-rest", "--pushforward", "2", "--no-checkpoint-layers",
                                                     "--onset-schedule", "0:0.4:6", "--ema", "0.999"],
    # from scratch with the onset drawn more often from the first frames (round 8, round 9):
    # - onset0.4f4: share 0.4 over 4 frames, the window at rest a tenth of the draws (1,900 steps on
    #   windows at rest alone took C's first acceleration from slope 0.10 / corr 0.39 to 0.44 / 0.72
    #   on validation scenes, so the first step is learnable at 5 message-passing steps);
    # - onset0.5f2: a quarter of the draws, so that by 12,000 steps the window at rest has been seen
    #   as often as in the 3,115 steps at rest alone that taught C the first acceleration;
    # - onset0.5f1: every onset draw at rest, half the windows (a sixth without pushforward);
    # - onset0.4f4-then0.5f2: the second phase of the onset0.4f4 lineage, resumed from its
    #   checkpoint (Adam and the lr schedule go on) at a quarter: the flow first, then the start,
    #   since a model that knew the flow learned its first step fast while from scratch it came slowly
    **{f"x-noise0.01-exact-pf2-onset{name}": [*W64, "--lr", "4e-4", "--lr-decay-steps", "200000", "--noise", "0.01",
                                             "--exact-rest", "--pushforward", "2", "--no-checkpoint-layers",
                                             "--onset-schedule", f"0:{share}:{frames}", "--ema", "0.999"]
       for name, share, frames in (("0.4f4-ema", "0.4", "4"), ("0.5f2-ema", "0.5", "2"), ("0.5f1-ema", "0.5", "1"),
                                   ("0.4f4-ema-then0.5f2", "0.5", "2"))},
    **{f"r-noise{n}-pf{k}": [*W64, "--lr", "4e-4", "--lr-decay-steps", "200000", "--noise", n, "--pushforward", k]
       for n in ("0.1", "0.3", "0.6") for k in ("1", "2")},
    # from a recipe pilot's checkpoint (--init PATH, a fresh Adam each): one setting changed
    **{f"c-noise{n}": [*W64, "--lr", "4e-4", "--lr-decay-steps", "200000", "--noise", n] for n in ("0.1", "0.3", "0.6")},
    **{f"x-noise{n}-exact": [*W64, "--lr", "4e-4", "--lr-decay-steps", "200000", "--noise", n, "--exact-rest"]
       for n in ("0.1", "0.3", "0.6")},
    **{f"c-noise{n}-stride2": [*W64, "--lr", "4e-4", "--lr-decay-steps", "200000", "--noise", n, "--frame-stride", "2"]
       for n in ("0.1", "0.3", "0.6")},
    # from an exact-rest pilot's checkpoint (--init PATH): the frame stride changed, exact rest kept; the processor's
    # activations kept for backward, not recomputed (about 1.4x the steps per second on the CPU, bench/train_throughput.py)
    **{f"x-noise{n}-exact-stride{k}": [*W64, "--lr", "4e-4", "--lr-decay-steps", "200000", "--noise", n, "--exact-rest",
                                       "--frame-stride", k, "--no-checkpoint-layers"]
       for n in ("0.1", "0.3", "0.6") for k in ("2", "4")},
}


def run_pilots(names: list[str], data: Path, out: Path, minutes: float, parallel: int,
               threads: int | None = None, init: Path | None = None) -> None:
    threads = threads or max(1, (os.cpu_count() or 2) // parallel)
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads)}
    queue = list(names)
    running: list[tuple[str, subprocess.Popen]] = []

    # the pilots run in sessions of their own, so a terminal's Ctrl-C reaches only this runner, which
    # passes one SIGINT on (a second would stop a pilot at once, unsaved)
    def stop(signum, frame):  # every pilot saves after its step and stops; then exit unevaluated
        for name, proc in running:
            proc.send_signal(signal.SIGINT)
        for name, proc in running:
            proc.wait()
            print(f"stopped {name} (exit {proc.returncode}); its checkpoint resumes", flush=True)
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    while queue or running:
        while queue and len(running) < parallel:
            name = queue.pop(0)
            run = out / name
            resume = ["--resume"] if (run / "checkpoint.pt").exists() else []
            start = ["--init", str(init)] if init is not None and not resume else []
            new = [] if start or resume else ["--no-overburden"]  # a resumed or fine-tuned run keeps its checkpoint's
            cmd = [sys.executable, "-m", "runout", "train", "--data", str(data), "--out", str(run),
                   "--max-hours", f"{minutes / 60:.6f}", "--valid-every", "0", "--save-every", "500", "--keep-every", "2000",
                   "--log-every", "50", *BEFORE_THE_RECIPE, *new, *PRESETS[name], *start, *resume]
            out.mkdir(parents=True, exist_ok=True)
            log = open(out / f"{name}.log", "a")  # beside the run folder, which runout owns
            print(f"start {name}: {' '.join(cmd[2:])}", flush=True)
            running.append((name, subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT,
                                                       start_new_session=True)))
        time.sleep(5)
        for item in list(running):
            if item[1].poll() is not None:
                print(f"done {item[0]} (exit {item[1].returncode})", flush=True)
                running.remove(item)


def evaluate(names: list[str], data: Path, out: Path, n_valid: int, threads: int | None = None,
             last_step: bool = False) -> list[dict]:
    """Roll every pilot's last checkpoint out from rest (frame 0 held, as users' scenes start)
    over all frames of the first n_valid validation scenes, and score it against the MPM beside
    a prediction in which nothing moves (runout.evaluate.heldout). last_step: the checkpoint's
    last-step weights (train_model, kept by --ema runs) instead of its model, the average."""
    import numpy as np
    import torch

    from runout.dataset import split_trajectories
    from runout.evaluate.heldout import rollout_all, score, standing_still
    from runout.gns.checkpoint import load_last_step, load_simulator, read_checkpoint
    from runout.gns.engine import GnsEngine

    torch.set_num_threads(threads or os.cpu_count() or 1)
    truths = list(split_trajectories(data, "valid", n_valid))
    rows = []
    for name in names:
        path = out / name / "checkpoint.pt"
        if not path.exists():
            continue
        step = int(read_checkpoint(path)["step"])
        simulator = load_last_step(path) if last_step else load_simulator(path)
        if simulator is None:  # --last-step, and the run kept no average
            continue
        if not rows:
            rows.append({"pilot": "standing still", **score([standing_still(t) for t in truths], truths, simulator.point_spacing)})
        log = [json.loads(ln) for ln in (out / name / "log.jsonl").read_text().splitlines() if ln]
        wall = max((r.get("wall_s", 0.0) for r in log), default=0.0)
        t0 = time.perf_counter()
        predicted = rollout_all(GnsEngine(simulator), truths)
        rows.append({
            "pilot": name + (" (last step)" if last_step else ""), "options": " ".join(PRESETS[name]), "steps": step, "train_wall_s": wall,
            "s_per_step": wall / max(step, 1),
            "final_loss": float(np.mean([r["loss"] for r in log if "loss" in r][-20:])),
            **score(predicted, truths, simulator.point_spacing), "rollout_s": time.perf_counter() - t0,
        })
        print(json.dumps({k: v for k, v in rows[-1].items() if k != "per_scene"}), flush=True)
    return rows


def table(rows: list[dict]) -> str:
    lines = ["| pilot | steps | s/step | last loss | position error (m) | front error / travel | "
             "extent runout error | mean displacement (MPM) m |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        steps = f"{r['steps']} | {r['s_per_step']:.3f} | {r['final_loss']:.3f}" if "steps" in r else "— | — | —"
        lines.append(f"| {r['pilot']} | {steps} | {r['position_error_m']:.2f} | {100 * r['front_error']:.1f} % | "
                     f"{100 * r['runout_error']:.1f} % | {r['displacement_m']:.1f} ({r['displacement_mpm_m']:.1f}) |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--pilots", nargs="+", default=["w64-lr1e-4", "w64-lr4e-4", "w128-lr4e-4", "w64-lr4e-4-b4", "w64-lr1e-3", "w64-lr4e-4-noise0.02"],
                    choices=sorted(PRESETS))
    ap.add_argument("--minutes", type=float, default=10.0, help="wall time of each pilot")
    ap.add_argument("--parallel", type=int, default=2, help="pilots at once (threads split between them)")
    ap.add_argument("--valid", type=int, default=16, help="validation trajectories rolled out per pilot")
    ap.add_argument("--threads", type=int, default=None, help="threads per pilot (default: cores / --parallel)")
    ap.add_argument("--eval-threads", type=int, default=None, help="threads of the evaluation rollouts (default: all cores)")
    ap.add_argument("--init", type=Path, default=None, help="start every pilot from this checkpoint (the ft-* presets)")
    ap.add_argument("--evaluate-only", action="store_true")
    ap.add_argument("--last-step", action="store_true",
                    help="evaluate the checkpoints' last-step weights (train_model of --ema runs) instead of the average")
    args = ap.parse_args()
    if not args.evaluate_only:
        run_pilots(args.pilots, args.data, args.out, args.minutes, args.parallel, args.threads, args.init)
    rows = evaluate(args.pilots, args.data, args.out, args.valid, args.eval_threads, args.last_step)
    print(table(rows))
    # merged by pilot name, so pilots evaluated in separate runs (or processes) keep each other's rows
    path = args.out / "pilots.json"
    kept = json.loads(path.read_text()) if path.exists() else []
    fresh = {r["pilot"] for r in rows}
    write_atomic(path, json.dumps([r for r in kept if r["pilot"] not in fresh] + rows, indent=2))


if __name__ == "__main__":
    main()

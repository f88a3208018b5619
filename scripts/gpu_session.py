"""One training session of the paper's two-stage GNS training, sized for a lent GPU machine.

    PYTHONPATH=src python3 scripts/gpu_session.py --stage finetune --minutes 9 --out $OUT

In one wall-clock budget it
1. generates the stage's dataset with a fixed seed (deterministic: every session makes the
   same data; parts already on disk are kept, so a warm machine skips this step),
2. picks its starting weights: for `base`, models/base.pt if present; for `finetune`,
   models/slope-train.pt (the CPU campaign's run) or models/slope.pt if present, else
   models/base.pt (transfer: the encoder widened with a zero cohesion column), else none
   (random weights); a start trained with an onset schedule goes on in the phase it reached,
3. measures training steps/s with a short first run, then trains in chunks sized from the
   measured rate until the budget (less a reserve for the evaluation) is spent,
4. rolls the trained model out on the first test trajectory and compares it with the MPM,
5. writes at most four files to --out: base.pt or slope.pt (weights, normalisation, schema,
   cumulative step and the list of sessions that made it), log.jsonl, session.json
   (figures of this session) and eval.png.

Training uses the recipe (runout.train_settings.TrainConfig's defaults), and a committed checkpoint trained
before it (solver 3) is never a start. The weights file holds no optimiser state (Adam's moments would make it three times larger
than the 16 MB a shipped model may take), so Adam restarts each session; the learning rate
continues from the cumulative step. Needs torch, numpy, scipy, matplotlib and tqdm; not typer.
To go on with the CPU campaign's model (8 m cells, 260 fine-tuning scenes, latent 64, 5
message-passing steps), give its data settings: `--cell-size 8 --count 260` (the start's
network size is taken from it); judge the result on 16 scenes from rest before it replaces
models/slope.pt (`runout evaluate heldout`).
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import torch

from runout.errors import InputError

MODEL_NAMES = {"base": "base.pt", "finetune": "slope.pt"}
MEASURE_STEPS = 20  # steps of the first, timed run (start-up included, so the rate is cautious); always run
MIN_CHUNK = 10  # steps: a smaller remainder of the budget is left unused


class OutOfTime(Exception):
    """The session's deadline passed before the dataset was complete."""


@dataclass
class Budget:
    """Wall-clock deadlines of one session (time.monotonic seconds)."""

    start: float
    end: float
    reserve: float  # s kept for the evaluation and the files

    @classmethod
    def from_minutes(cls, minutes: float, reserve: float) -> "Budget":
        now = time.monotonic()
        return cls(now, now + 60.0 * minutes, reserve)

    @property
    def train_end(self) -> float:
        return self.end - self.reserve

    def left_for_training(self) -> float:
        return self.train_end - time.monotonic()


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--stage", choices=sorted(MODEL_NAMES), required=True, help="base (phi only) or finetune (phi and c).")
    p.add_argument("--out", type=Path, required=True, help="Folder for the session's files ($OUT on the device).")
    p.add_argument("--minutes", type=float, default=9.0, help="Wall-clock budget of the whole session (min).")
    p.add_argument("--reserve", type=float, default=60.0, help="Seconds kept for the evaluation and the files.")
    p.add_argument("--count", type=int, default=128, help="Scenes in the dataset (paper: 2000 base, 1027 finetune).")
    p.add_argument("--frames", type=int, default=480, help="Frames per scene.")
    p.add_argument("--seed", type=int, default=0, help="Dataset seed (same seed, same data in every session).")
    p.add_argument("--batch", type=int, default=64, help="Scenes per batched MPM call.")
    p.add_argument("--cell-size", type=float, default=4.0, help="MPM cell size (m); the paper's 4 m.")
    p.add_argument("--data", type=Path, default=None, help="Dataset folder (default data/gpu_<stage>_seed<S>).")
    p.add_argument("--run", type=Path, default=None, help="Scratch run folder, emptied first (default runs/gpu_<stage>).")
    p.add_argument("--models", type=Path, default=Path("models"), help="Folder of the committed checkpoints.")
    p.add_argument("--init", type=Path, default=None, help="Start from this checkpoint instead of the ones in --models.")
    p.add_argument("--device", default="auto", help="auto, cpu or cuda.")
    p.add_argument("--lr", type=float, default=None, help="Initial learning rate (default: the recipe's, TrainConfig.lr_init).")
    p.add_argument("--latent", type=int, default=128, help="Latent and hidden width (random start only).")
    p.add_argument("--message-passing", type=int, default=10, help="Processor steps (random start only).")
    p.add_argument("--bf16", action="store_true", help="Autocast the network to bfloat16.")
    p.add_argument("--eval-frames", type=int, default=0, help="Frames of the evaluation rollout (0: the whole test trajectory).")
    args = p.parse_args(argv)
    _check(args)
    args.data = args.data or Path("data") / f"gpu_{args.stage}_seed{args.seed}"
    args.run = args.run or Path("runs") / f"gpu_{args.stage}"
    if args.device == "auto":
        args.device = "cuda" if torch.cuda.is_available() else "cpu"
    return args


def _check(args: argparse.Namespace) -> None:
    if args.minutes <= 0:
        raise InputError(f"--minutes {args.minutes:g} must be positive.")
    if args.reserve < 0 or args.reserve >= 60.0 * args.minutes:
        raise InputError(f"--reserve {args.reserve:g} s must lie in [0, {60 * args.minutes:g}) s, the session's budget.")
    if args.init is not None and not args.init.is_file():
        raise InputError(f"--init {args.init}: no such checkpoint file.")


# ----------------------------------------------------------------------------- data


def ensure_dataset(args: argparse.Namespace, budget: Budget) -> dict:
    """Generate (or finish) the dataset before the training deadline; its metadata."""
    from runout.generate import GenerateConfig, generate
    from runout.simfiles import read_metadata

    config = GenerateConfig(args.stage, args.count, args.seed, args.batch, args.frames, args.cell_size)
    if _complete(args.data, config):
        print(f"dataset {args.data} is complete; not regenerating", flush=True)
        return read_metadata(args.data)
    t0 = time.monotonic()
    generate(config, args.data, device=args.device, simulate=_simulate_until(budget.train_end), progress=True)
    print(f"generated {args.count} scenes in {time.monotonic() - t0:.0f} s", flush=True)
    return read_metadata(args.data)


def _complete(folder: Path, config) -> bool:
    meta_path = folder / "metadata.json"
    if not meta_path.is_file() or not (folder / "train.npz").is_file():
        return False
    meta = json.loads(meta_path.read_text())
    wanted = {"stage": config.stage, "count": config.count, "seed": config.seed, "frames": config.frames, "cell_size": config.cell_size}
    return all(meta.get(k) == v for k, v in wanted.items())


def _simulate_until(deadline: float):
    """runout.mpm.simulate that refuses to start a batch after the deadline."""
    from runout.mpm import simulate

    def run(scenes, device="cpu", progress=False):
        if time.monotonic() > deadline:
            raise OutOfTime
        return simulate(scenes, device=device, progress=progress)

    return run


# ----------------------------------------------------------------------------- start


def starting_checkpoint(args: argparse.Namespace, meta: dict) -> tuple[Path | None, list[str]]:
    """The checkpoint to start from (None: random weights) and why others were passed over."""
    if args.init is not None:
        return args.init, []
    names = ["base.pt"] if args.stage == "base" else ["slope-train.pt", "slope.pt", "base.pt"]
    skipped = []
    for name in names:
        path = args.models / name
        if not path.is_file():
            continue
        reason = _misfit(path, meta)
        if reason is None:
            return path, skipped
        skipped.append(f"{path}: {reason}")
    return None, skipped


def _misfit(path: Path, meta: dict) -> str | None:
    """Why a checkpoint cannot start training on this data (None: it can)."""
    from runout.gns.checkpoint import read_checkpoint

    from runout.train_settings import trained_with_recipe

    ckpt = read_checkpoint(path)
    if not trained_with_recipe(ckpt.get("train", {})):
        return "trained before the recipe (on solver-3 data, or with settings the pilots replaced)"
    radius = float(meta["default_connectivity_radius"])
    if abs(float(ckpt["radius"]) - radius) > 1e-6:
        return f"connectivity radius {ckpt['radius']:g} m, the data's is {radius:g} m (another cell size)"
    have = tuple(ckpt["schema"]["material_features"])
    want = tuple(meta.get("material_features", ()))
    if want[: len(have)] != have:
        return f"material features {list(have)} do not start the data's {list(want)}"
    return None


# ----------------------------------------------------------------------------- training


def train_for_budget(args: argparse.Namespace, init: Path | None, budget: Budget) -> dict:
    """Train in chunks until the budget is spent; the measured rates and step count."""
    from runout.gns.schema import NetworkConfig
    from runout.train import TrainConfig, continued_onset, train

    shutil.rmtree(args.run, ignore_errors=True)
    network = NetworkConfig(latent=args.latent, hidden=args.latent, message_passing_steps=args.message_passing)
    recipe = ({"lr_init": args.lr} if args.lr is not None else {}) | continued_onset(init)  # the rest: TrainConfig's defaults
    cfg = TrainConfig(
        data=args.data, out=args.run, steps=MEASURE_STEPS, device=args.device, init=init,
        network=network, bf16=args.bf16, valid_every=0, log_every=10, save_every=10**9, **recipe,
    )
    t0 = time.monotonic()
    train(cfg)
    first_rate = MEASURE_STEPS / (time.monotonic() - t0)
    print(f"measured {first_rate:.3g} steps/s over the first {MEASURE_STEPS} steps (start-up included)", flush=True)
    steps, rate, chunks = MEASURE_STEPS, first_rate, []
    while (extra := int(0.9 * rate * budget.left_for_training())) >= MIN_CHUNK:
        t = time.monotonic()
        steps += extra
        train(replace(cfg, steps=steps, resume=True, init=None, log_every=100))
        rate = extra / (time.monotonic() - t)
        chunks.append({"steps": extra, "steps_per_s": round(rate, 4)})
        print(f"trained to step {steps}: {rate:.3g} steps/s", flush=True)
    return {"steps": steps, "first_steps_per_s": round(first_rate, 4), "chunks": chunks,
            "train_wall_s": round(time.monotonic() - t0, 1)}


def export_model(args: argparse.Namespace, init: Path | None, record: dict) -> Path:
    """Weights-only checkpoint in --out with the cumulative step and the session history."""
    from runout.gns.checkpoint import read_checkpoint, save_checkpoint, simulator_from_checkpoint

    ckpt = read_checkpoint(args.run / "checkpoint.pt")
    simulator = simulator_from_checkpoint(ckpt)
    step = int(ckpt["step"]) + int(ckpt["train"]["lr_step_offset"])
    earlier = read_checkpoint(init).get("sessions", []) if init is not None else []
    path = args.out / MODEL_NAMES[args.stage]
    settings = {k: v for k, v in ckpt["train"].items() if k not in ("data", "out", "init", "resume")}
    save_checkpoint(path, simulator, step=step, train=settings | {"lr_step_offset": 0}, sessions=[*earlier, record])
    return path


# ----------------------------------------------------------------------------- evaluation


def evaluate(model: Path, args: argparse.Namespace, meta: dict) -> dict:
    """Roll the model out on the first test trajectory; metrics and eval.png."""
    from runout.dataset import load_split_trajectory
    from runout.gns.checkpoint import load_simulator
    from runout.gns.rollout import RolloutDiverged, rollout_trajectory
    from runout.metrics import compare

    truth = load_split_trajectory(args.data, "test", 0)
    frames = min(args.eval_frames or truth.n_frames, truth.n_frames)
    simulator = load_simulator(model, args.device)
    t0 = time.monotonic()
    try:
        predicted = rollout_trajectory(simulator, truth, frames, stop_speed=None)
    except RolloutDiverged as exc:
        return {"trajectory": "test_0", "frames": frames, "diverged": str(exc)}
    metrics = {"trajectory": "test_0", "frames": frames, "points": truth.n_points,
               "rollout_wall_s": round(time.monotonic() - t0, 2), **compare(predicted, truth)}
    _draw_final(predicted, truth, frames - 1, args.out / "eval.png")
    return metrics


def _draw_final(predicted, truth, frame: int, path: Path) -> None:
    from runout.plots import save_comparison

    save_comparison(truth, predicted, path, (frame, frame), (f"MPM, frame {frame}", f"GNS, frame {frame}"), height=8.0)


# ----------------------------------------------------------------------------- session


def machine() -> str:
    if torch.cuda.is_available():
        return f"{torch.cuda.get_device_name(0)}, torch {torch.__version__}"
    return f"CPU ({platform.processor() or platform.machine()}, {torch.get_num_threads()} threads), torch {torch.__version__}"


def loss_summary(log: Path) -> dict:
    lines = [json.loads(ln) for ln in log.read_text().splitlines() if ln.strip()]
    losses = [(ln["step"], ln["loss"]) for ln in lines if "loss" in ln]
    if not losses:
        return {}
    tail = [v for _, v in losses[-5:]]
    return {"first": losses[0], "last": losses[-1], "mean_last_5_logs": sum(tail) / len(tail)}


def run_session(args: argparse.Namespace) -> dict:
    budget = Budget.from_minutes(args.minutes, args.reserve)
    args.out.mkdir(parents=True, exist_ok=True)
    summary = {"stage": args.stage, "machine": machine(), "budget_min": args.minutes,
               "data": {"folder": str(args.data), "stage": args.stage, "count": args.count, "seed": args.seed,
                        "frames": args.frames, "cell_size_m": args.cell_size}}
    try:
        meta = ensure_dataset(args, budget)
    except OutOfTime:
        summary["stopped"] = "the dataset was not complete by the deadline; run the same command again on the warm machine"
        return _finish(summary, args, budget)
    init, skipped = starting_checkpoint(args, meta)
    summary.update({"init": str(init) if init else None, "skipped_checkpoints": skipped})
    print(f"starting from {init or 'random weights'}" + "".join(f"\n  not from {s}" for s in skipped), flush=True)
    if budget.left_for_training() <= 0:
        summary["stopped"] = "no time left to train after generating the data; run again"
        return _finish(summary, args, budget)
    summary["training"] = train_for_budget(args, init, budget)
    shutil.copyfile(args.run / "log.jsonl", args.out / "log.jsonl")
    summary["losses"] = loss_summary(args.out / "log.jsonl")
    record = {k: summary[k] for k in ("stage", "machine", "data", "init")} | {"steps": summary["training"]["steps"]}
    model = export_model(args, init, record)
    summary["model"] = {"file": model.name, "bytes": model.stat().st_size}
    summary["evaluation"] = evaluate(model, args, meta)
    return _finish(summary, args, budget)


def _finish(summary: dict, args: argparse.Namespace, budget: Budget) -> dict:
    summary["wall_s"] = round(time.monotonic() - budget.start, 1)
    (args.out / "session.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps(summary, indent=1), flush=True)
    return summary


def main(argv: list[str] | None = None) -> int:
    try:
        run_session(parse_args(argv))
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())

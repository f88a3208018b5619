"""`runout train` and `runout rollout`: the Graph Network Simulator from the command line."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import typer

from runout.cli.app import app
from runout.errors import InputError
from runout.scene.limits import MAX_FRAMES
from runout.train_settings import NetworkConfig, TrainConfig, format_onset_schedule, option_name

MAX_STOP_SPEED = 100.0  # m/s
SETTING_OF_PARAMETER = {"lr": "lr_init", "message_passing": "message_passing_steps"}  # `train` parameters named apart from their setting


# Defaults are TrainConfig's and NetworkConfig's fields; limits are runout.train.SETTING_LIMITS (check_settings).
@app.command()
def train(
    ctx: typer.Context,
    data: Path = typer.Option(..., "--data", help="Dataset folder with train.npz, metadata.json (and valid.npz for validation rollouts)."),
    out: Path = typer.Option(..., "--out", help="Run folder: checkpoint.pt, best.pt, log.jsonl (and tensorboard/ if installed)."),
    steps: int = typer.Option(TrainConfig.steps, "--steps", help="Train until the step counter reaches this value."),
    resume: bool = typer.Option(TrainConfig.resume, "--resume", help="Continue from OUT/checkpoint.pt exactly where it stopped."),
    init: Path = typer.Option(TrainConfig.init, "--init", help="Fine-tune from this checkpoint; extra material inputs (e.g. cohesion) start with zero weights."),
    device: str = typer.Option(TrainConfig.device, "--device", help="auto, cpu, cuda or cuda:K (under torchrun each process takes its LOCAL_RANK GPU)."),
    batch_size: int = typer.Option(TrainConfig.batch_size, "--batch-size", help="Graphs per process and step."),
    lr: float = typer.Option(TrainConfig.lr_init, option_name("lr_init"), help=f"Initial learning rate; decays as (lr - {TrainConfig.lr_final:g}) 0.1^(step / D) + {TrainConfig.lr_final:g}."),
    lr_decay_steps: float = typer.Option(TrainConfig.lr_decay_steps, "--lr-decay-steps", help="D: steps over which the learning rate falls tenfold (paper: 5e6; fit it to the budget)."),
    max_hours: float = typer.Option(TrainConfig.max_hours, "--max-hours", help="Wall-clock hours for this run; then save and stop, exit 0 (0: no limit)."),
    radius: float = typer.Option(TrainConfig.radius, "--radius", help="Connectivity radius in m (default: the dataset's, 2.3 point spacings); new runs only."),
    frame_stride: int = typer.Option(TrainConfig.frame_stride, "--frame-stride", help="Dataset frames per GNS step, 1-16 (default 1; --resume keeps the checkpoint's, --init keeps it unless this asks for another)."),
    pushforward: int = typer.Option(TrainConfig.pushforward, "--pushforward", help="Pushforward training, N = 0-10: each step rolls the model out n steps without gradient, n uniform in 0..N per step, and trains on the window it made (0: one-step training)."),
    compile_network: bool = typer.Option(TrainConfig.compile, "--compile", help="Run the network through torch.compile (dynamic shapes): 1.19x the steps per second on one CPU thread, after a first minute or so of compiling in each process; needs a C++ compiler on a CPU. The checkpoint is the same either way."),
    ema: float = typer.Option(TrainConfig.ema, "--ema", help="Save, score on the valid split and fine-tune from an exponential moving average of the weights with this decay per step, e.g. 0.999 (an average over about 1,000 steps); 0: the last step's weights. The onset of motion hangs on accelerations of 0.001 m/step², which one step's weights swing."),
    noise: float = typer.Option(TrainConfig.noise, "--noise", help="Velocity noise std of the inputs, as a fraction of the data's velocity std (mean of x and y, m per step); docs/training.md gives the pilots behind the default."),
    rest_windows: bool = typer.Option(TrainConfig.rest_windows, "--rest-windows/--no-rest-windows", help="Also train on windows that start before frame 0 (the scene at rest, where every rollout starts)."),
    exact_rest: bool = typer.Option(TrainConfig.exact_rest, "--exact-rest/--noisy-rest", help="Put no noise on a window's held copies of frame 0 (a rollout starts from the scene at rest exactly; the noise walk starts with its first step)."),
    onset_schedule: str = typer.Option(format_onset_schedule(TrainConfig.onset_schedule), "--onset-schedule", help="The onset of motion by step, STEP:SHARE:FRAMES,... (the recipe's three phases, docs/training.md): from each STEP on, a share SHARE of the windows is drawn from each simulation's first FRAMES frames (windows at rest included), the rest uniformly; before the first STEP, or with an empty schedule, every window uniformly."),
    overburden: bool = typer.Option(TrainConfig.overburden, "--overburden/--no-overburden", help="Give the network each point's depth of soil above it in its column (m / 100; at rest the overburden that sets its stress), which 5 message-passing steps of 9.2 m cannot see on a slope taller than 46 m. New runs only (default: on); --resume and --init keep the checkpoint's."),
    mirror: float = typer.Option(TrainConfig.mirror, "--mirror", help="Share of the training windows reflected left-right about the domain's centre, 0-1 (the physics has no side; the slope families all fail to the right). The recipe's is 0.5."),
    latent: int = typer.Option(NetworkConfig.latent, "--latent", help="Latent size of nodes and edges."),
    hidden: int = typer.Option(NetworkConfig.hidden, "--hidden", help="Units of each hidden MLP layer."),
    message_passing: int = typer.Option(NetworkConfig.message_passing_steps, option_name("message_passing_steps"), help="Processor steps (unshared weights)."),
    save_every: int = typer.Option(TrainConfig.save_every, "--save-every", help="Steps between checkpoints."),
    keep_every: int = typer.Option(TrainConfig.keep_every, "--keep-every", help="Every N steps also keep a copy of the checkpoint as OUT/snapshots/step-N.pt, to choose one afterwards by rollouts (0: never)."),
    log_every: int = typer.Option(TrainConfig.log_every, "--log-every", help="Steps per log.jsonl line (mean loss)."),
    valid_every: int = typer.Option(TrainConfig.valid_every, "--valid-every", help="Steps between validation rollouts (0: never)."),
    valid_trajectories: int = typer.Option(TrainConfig.valid_trajectories, "--valid-trajectories", help="Validation trajectories rolled out each time."),
    seed: int = typer.Option(TrainConfig.seed, "--seed", help="Seed of the initial weights, window sampling and noise."),
    bf16: bool = typer.Option(TrainConfig.bf16, "--bf16", help="Autocast the network to bfloat16 (faster on GPUs and on CPUs with AVX512-BF16 or AMX; elsewhere on a CPU it trains in float32, with a warning)."),
    checkpoint_layers: bool = typer.Option(TrainConfig.checkpoint_layers, "--checkpoint-layers/--no-checkpoint-layers", help="Recompute processor steps in backward to save memory."),
    progress: bool = typer.Option(TrainConfig.progress, "--progress/--no-progress", help="Show a progress bar on stderr (log.jsonl records the run either way)."),
    force: bool = typer.Option(False, "--force", help="Start afresh in --out, removing a previous run or another command's results there."),
) -> None:
    """Train the GNS on an MPM dataset (one process, or many under torchrun). Ctrl-C saves
    the checkpoint of the last whole step (exit 130); --resume continues exactly."""
    from runout import checks
    from runout.outputs import check_folder, claim
    from runout.reading import folder_to_read
    from runout.train import BEST, CHECKPOINT, LOG, SNAPSHOTS, check_settings, resumed_settings, train as run_training
    from runout.train_settings import parse_onset_schedule

    cfg = TrainConfig(
        data=data, out=out, steps=steps, batch_size=batch_size, lr_init=lr, noise=noise,
        rest_windows=rest_windows, exact_rest=exact_rest, onset_schedule=parse_onset_schedule(onset_schedule),
        seed=seed, device=device, resume=resume, init=init,
        network=NetworkConfig(latent=latent, hidden=hidden, message_passing_steps=message_passing),
        save_every=save_every, keep_every=keep_every, log_every=log_every, valid_every=valid_every,
        valid_trajectories=valid_trajectories,
        checkpoint_layers=checkpoint_layers, bf16=bf16, lr_decay_steps=lr_decay_steps,
        max_hours=max_hours, radius=radius, overburden=overburden, frame_stride=frame_stride, pushforward=pushforward, ema=ema, compile=compile_network,
        mirror=mirror, progress=progress,
    )
    check_settings(cfg)
    checks.device(device, auto=True)
    given = {SETTING_OF_PARAMETER.get(name, name) for name in ctx.params if _given(ctx, name)}
    folder_to_read(data, "dataset folder")
    folder = check_folder(out, "train", (CHECKPOINT, BEST, LOG, SNAPSHOTS, "tensorboard"), mode="resume", force=force,
                          inputs={"--data": data, "--init": init})
    if resume:
        cfg = resumed_settings(cfg, given)
    if int(os.environ.get("RANK", "0")) == 0:  # under torchrun only the writing process prepares it
        claim(folder)
    run_training(cfg)


@app.command()
def rollout(
    model: Path = typer.Option(..., "--model", help="Learned-engine checkpoint (.pt): a GNS or a neural MPM, the file says which."),
    source: Path = typer.Argument(..., help="SCENE.toml/.json (filled at the model's point spacing, starts at rest), a trajectory folder from `runout mpm`, or a dataset folder."),
    engine_name: str = typer.Option(None, "--engine", help="gns or neural-mpm: checked against the model file (optional; the file names its engine)."),
    out: Path = typer.Option(..., "--out", help="Output folder: trajectory.npz, metadata.json, metrics.json, pictures, animation."),
    frames: int = typer.Option(0, "--frames", help="Frames (of the data's dt) to cover, frame 0 included (0: the scene's or ground truth's count); a model of frame stride K writes one every K."),
    stop_speed: float = typer.Option(0.05, "--stop-speed", help="Stop once every soil point moves slower than this (m/s); 0: never stop early."),
    split: str = typer.Option("test", "--split", help="For a dataset folder: which split file."),
    index: int = typer.Option(0, "--index", help="For a dataset folder: which simulation of the split."),
    device: str = typer.Option("cpu", "--device", help="cpu, cuda or cuda:K."),
    from_frames: bool = typer.Option(False, "--from-frames", help="Start a trajectory or dataset from its first frames (the public GNS's start) instead of from rest, its frame 0 held."),
    animation: bool = typer.Option(True, "--animation/--no-animation", help="Write an animation (beside the MPM when there is one)."),
    vtk: bool = typer.Option(False, "--vtk", help="Also write ParaView files: vtk/frame_*.vtu and vtk/trajectory.pvd."),
    force: bool = typer.Option(False, "--force", help="Replace another command's results in --out (removing, and naming, the files that command wrote and this run does not rewrite; files runout did not write stay)."),
) -> None:
    """Roll the model's learned engine (GNS or neural MPM) out from rest until FRAMES or until the flow stops."""
    from runout import checks
    from runout.learned.engine import engine_label
    from runout.learned.load import load_engine
    from runout.learned.training_range import range_warnings
    from runout.rollout_run import ROLLOUT_FILES, initial_state, write_rollout_outputs
    from runout.outputs import check_folder, claim
    from runout.plots.animation import animation_name

    check_range("--frames", frames, 0, MAX_FRAMES)
    check_range("--stop-speed", stop_speed, 0.0, MAX_STOP_SPEED, " m/s")
    checks.device(device)
    writes = ROLLOUT_FILES + ((animation_name(),) if animation else ()) + (("vtk",) if vtk else ())
    folder = check_folder(out, "rollout", writes, force=force, inputs={"--model": model, "the source": source})
    engine = load_engine(model, device, expect=engine_name)
    begin = initial_state(source, split, index, engine, log=lambda line: typer.echo(line, err=True))
    initial, truth = begin.initial, begin.truth
    for line in begin.warnings:
        typer.secho(f"warning: {line}", err=True, fg=typer.colors.YELLOW)
    n_frames = frames or begin.frames
    given = engine.start_frames(from_rest=not from_frames)
    if n_frames <= given:
        raise InputError(f"--frames = {n_frames} must exceed the {given} initial frame{'s' if given > 1 else ''}.")
    if from_frames and source.is_file():
        raise InputError(f"--from-frames: {source} is a scene, which starts at rest; give a trajectory or dataset folder.")
    check_rollout_memory(initial.n_points, n_frames, device)
    for line in range_warnings(engine, initial):
        typer.secho(f"warning: {line}", err=True, fg=typer.colors.YELLOW)
    t0 = time.perf_counter()
    predicted = engine.rollout_trajectory(initial, n_frames, stop_speed or None, progress=True,
                                          from_rest=not from_frames)  # RunFailed: exit 1
    predicted.info["wall_s"] = round(time.perf_counter() - t0, 3)
    claim(folder)
    metrics = write_rollout_outputs(predicted, truth, out, engine.material_width, animation, engine_label(engine))
    if vtk:
        from runout.vtk import write_vtk

        metrics["vtk"] = str(write_vtk(predicted, out / "vtk"))
    typer.echo(json.dumps(metrics, indent=2))


def _given(ctx: typer.Context, name: str) -> bool:
    """Whether the command line (or the environment) set parameter `name`, rather than its default."""
    return getattr(ctx.get_parameter_source(name), "name", "DEFAULT") != "DEFAULT"


def check_range(option: str, value, lo, hi, unit: str = "", lo_open: bool = False) -> None:
    """InputError unless value is a finite number in [lo, hi], or (lo, hi] when lo_open
    (None passes: the option was not given)."""
    from runout import checks

    if value is not None:
        checks.number(value, option, None, lo, hi, unit, lo_open=lo_open)


def check_rollout_memory(points: int, frames: int, device: str) -> None:
    """Refuse a rollout whose frames (float32 x, y, held about three times) exceed the memory."""
    from runout.mpm.budget import GIB, device_memory

    need = 3 * 8 * points * frames
    have = device_memory(device)
    if need > have:
        raise InputError(
            f"--frames = {frames} with {points} points needs about {need / GIB:.1f} GiB of memory but this "
            f"machine has {have / GIB:.1f} GiB; ask for fewer frames."
        )


@app.command()
def average(
    checkpoints: list[Path] = typer.Argument(..., help="Checkpoints of one GNS training run (e.g. its snapshots/step-*.pt)."),
    out: Path = typer.Option(..., "--out", help="The averaged checkpoint to write (weights only, not resumable)."),
) -> None:
    """Average the weights of several checkpoints of one GNS training run into one model file (stochastic weight averaging); judge it with `runout evaluate heldout`."""
    from runout.average import average_checkpoints

    path = average_checkpoints(out, checkpoints)
    typer.echo(f"{path}: the mean of {len(checkpoints)} checkpoints' weights")

"""`runout train` (the GNS, or the neural MPM with --engine neural-mpm) and `runout rollout`
(either learned engine) from the command line."""

from __future__ import annotations

import json
import os
import time
from dataclasses import replace
from pathlib import Path

import typer

from runout.cli.app import app
from runout.errors import InputError
from runout.scene.limits import MAX_FRAMES
from runout.train_settings import (
    ENGINE_OPTIONS, ENGINES, NetworkConfig, NeuralMPMConfig, NeuralMPMSettings, TrainConfig, format_onset_schedule,
    option_name,
)

MAX_STOP_SPEED = 100.0  # m/s
SETTING_OF_PARAMETER = {"lr": "lr_init", "message_passing": "message_passing_steps"}  # `train` parameters named apart from their setting
NMPM = NeuralMPMSettings  # the neural MPM's defaults, for the help
# `train` parameters that set a neural-MPM setting of another name
NEURAL_MPM_SETTING = {"mirror": "mirror_share", "valid_trajectories": "valid_count"}
ENGINE_NAMES = {"gns": "GNS", "neural-mpm": "neural MPM"}


# Defaults are TrainConfig's and NetworkConfig's fields (the neural MPM's, NeuralMPMSettings' and
# NeuralMPMConfig's, where its help says so); limits are runout.train_settings' (check_settings,
# check_neural_mpm).
@app.command()
def train(
    ctx: typer.Context,
    data: Path = typer.Option(..., "--data", help="Dataset folder with train.npz, metadata.json (and valid.npz for validation rollouts); neural-mpm: several joined by commas, the first one's valid split the measure."),
    out: Path = typer.Option(..., "--out", help="Run folder: checkpoint.pt, best.pt, log.jsonl (neural-mpm: train.log.jsonl; and tensorboard/ if installed)."),
    engine: str = typer.Option("gns", "--engine", help="The learned engine to train: gns or neural-mpm; the options of the other engine are refused."),
    steps: int = typer.Option(TrainConfig.steps, "--steps", help=f"Train until the step counter reaches this value (neural-mpm: default {NMPM.steps:,})."),
    resume: bool = typer.Option(TrainConfig.resume, "--resume", help="Continue from OUT/checkpoint.pt exactly where it stopped."),
    init: Path = typer.Option(TrainConfig.init, "--init", help="Fine-tune from this checkpoint; extra material inputs (e.g. cohesion) start with zero weights. neural-mpm: a new run starts from this neural-MPM file's engine and weights (only --velocity-sweeps may differ from it); a resumed run continues from its own checkpoint."),
    device: str = typer.Option(TrainConfig.device, "--device", help="auto, cpu, cuda or cuda:K (under torchrun each process takes its LOCAL_RANK GPU)."),
    batch_size: int = typer.Option(TrainConfig.batch_size, "--batch-size", help=f"Graphs per process and step (neural-mpm: windows per step, default {NMPM.batch_size})."),
    lr: float = typer.Option(TrainConfig.lr_init, option_name("lr_init"), help=f"Initial learning rate; decays as (lr - {TrainConfig.lr_final:g}) 0.1^(step / D) + {TrainConfig.lr_final:g} (neural-mpm: default {NMPM.lr:g}, decays exponentially to --lr-final over D steps, constant after)."),
    lr_decay_steps: float = typer.Option(TrainConfig.lr_decay_steps, "--lr-decay-steps", help="D: steps over which the learning rate falls tenfold (paper: 5e6; fit it to the budget). neural-mpm: the steps of its decay to --lr-final (default: a new run's --steps; --resume keeps the run's, so a larger --steps goes on at --lr-final)."),
    max_hours: float = typer.Option(TrainConfig.max_hours, "--max-hours", help="Wall-clock hours for this run; then save and stop, exit 0 (0: no limit)."),
    max_cpu_hours: float = typer.Option(None, "--max-cpu-hours", help="neural-mpm: CPU hours of the whole run (this process's on every thread, after those its checkpoint records); then save and stop, exit 0 (0: no limit)."),
    calls: int = typer.Option(NMPM.calls, "--calls", help="neural-mpm: K, the engine's calls chained in each window's loss (it learns from its own predictions)."),
    lr_final: float = typer.Option(NMPM.lr_final, "--lr-final", help="neural-mpm: the learning rate at the end of its decay."),
    rest_share: float = typer.Option(NMPM.rest_share, "--rest-share", help="neural-mpm: share of the training windows that start at frame 0, from rest."),
    data_shares: str = typer.Option(NMPM.data_shares, "--data-shares", help="neural-mpm: the part of the batches from each dataset of --data, e.g. 3,1 (default: by their scenes)."),
    threads: int = typer.Option(NMPM.threads, "--threads", help="neural-mpm: CPU threads of the training (1: the pilots' measure of CPU time)."),
    front_loss: float = typer.Option(NMPM.front_loss, "--front-loss", help="neural-mpm: weight of the fronts in the loss, 0-100: per scene and frame the squared distance (cells²) between the predicted and the MPM's largest soil x and between their smallest (the runout fronts L_f), beside the mean over all points (0: the points alone)."),
    toe_loss: float = typer.Option(NMPM.toe_loss, "--toe-loss", help="neural-mpm: weight of the toes in the loss, 0-100: per scene and frame the mean squared position error (cells²) of the soil points in each side's outermost 5 % by true x, the two sides summed, beside the mean over all points (0: the points alone)."),
    motion_weighting: str = typer.Option(str(NMPM.motion_weighting), "--motion-weighting", help="neural-mpm: draw each dataset's simulations with weight (D + 8 m)^E, D the mean distance its soil ends from where it started, E this exponent 0-4 (0: uniformly; 1: a dam failing by 50 m about 7 times as often as one standing still); one for every dataset, or one per dataset of --data joined by commas (1,0,0,1)."),
    cell_size: float = typer.Option(NeuralMPMConfig.cell_size, "--cell-size", help="neural-mpm: m between the grid's nodes (new runs only; --resume keeps the checkpoint's engine)."),
    history: int = typer.Option(NeuralMPMConfig.history, "--history", help="neural-mpm: past frame velocities per input (new runs only)."),
    frames_per_call: int = typer.Option(NeuralMPMConfig.frames_per_call, "--frames-per-call", help="neural-mpm: m, the frames predicted per U-Net call (new runs only)."),
    velocity_sweeps: int = typer.Option(NeuralMPMConfig.velocity_sweeps, "--velocity-sweeps", help="neural-mpm: sweeps that sharpen the input velocities towards the grid field that carries the points as they moved (0: the mass-weighted mean per node; new runs only)."),
    widths: str = typer.Option(",".join(map(str, NeuralMPMConfig.widths)), "--widths", help="neural-mpm: the U-Net's channels per level, joined by commas (new runs only)."),
    radius: float = typer.Option(TrainConfig.radius, "--radius", help="Connectivity radius in m (default: the dataset's, 2.3 point spacings); new runs only."),
    frame_stride: int = typer.Option(TrainConfig.frame_stride, "--frame-stride", help="Dataset frames per GNS step, 1-16 (default 1; --resume keeps the checkpoint's, --init keeps it unless this asks for another)."),
    pushforward: int = typer.Option(TrainConfig.pushforward, "--pushforward", help="Pushforward training, N = 0-10: each step rolls the model out n steps without gradient, n uniform in 0..N per step, and trains on the window it made (0: one-step training)."),
    compile_network: bool = typer.Option(TrainConfig.compile, "--compile", help="Run the network through torch.compile (dynamic shapes): 1.19x the steps per second on one CPU thread, after a first minute or so of compiling in each process; needs a C++ compiler on a CPU. The checkpoint is the same either way."),
    ema: float = typer.Option(TrainConfig.ema, "--ema", help=f"Save, score on the valid split and fine-tune from an exponential moving average of the weights with this decay per step, e.g. 0.999 (an average over about 1,000 steps); 0: the last step's weights (neural-mpm: default {NMPM.ema:g}). The onset of motion hangs on accelerations of 0.001 m/step², which one step's weights swing."),
    noise: float = typer.Option(TrainConfig.noise, "--noise", help=f"Velocity noise std of the inputs, as a fraction of the data's velocity std (mean of x and y, m per step); docs/training.md gives the pilots behind the default. neural-mpm: default {NMPM.noise:g}, a fraction of the data's velocity scale (RMS, m per frame), on the input velocities of windows after frame 0 only."),
    rest_windows: bool = typer.Option(TrainConfig.rest_windows, "--rest-windows/--no-rest-windows", help="Also train on windows that start before frame 0 (the scene at rest, where every rollout starts)."),
    exact_rest: bool = typer.Option(TrainConfig.exact_rest, "--exact-rest/--noisy-rest", help="Put no noise on a window's held copies of frame 0 (a rollout starts from the scene at rest exactly; the noise walk starts with its first step)."),
    onset_schedule: str = typer.Option(format_onset_schedule(TrainConfig.onset_schedule), "--onset-schedule", help="The onset of motion by step, STEP:SHARE:FRAMES,... (the recipe's three phases, docs/training.md): from each STEP on, a share SHARE of the windows is drawn from each simulation's first FRAMES frames (windows at rest included), the rest uniformly; before the first STEP, or with an empty schedule, every window uniformly."),
    overburden: bool = typer.Option(TrainConfig.overburden, "--overburden/--no-overburden", help="Give the network each point's depth of soil above it in its column (m / 100; at rest the overburden that sets its stress), which 5 message-passing steps of 9.2 m cannot see on a slope taller than 46 m. New runs only (default: on); --resume and --init keep the checkpoint's."),
    mirror: float = typer.Option(TrainConfig.mirror, "--mirror", help=f"Share of the training windows reflected left-right about the domain's centre, 0-1 (the physics has no side; the slope families all fail to the right). The recipe's is 0.5 (neural-mpm: {NMPM.mirror_share:g})."),
    latent: int = typer.Option(NetworkConfig.latent, "--latent", help="Latent size of nodes and edges."),
    hidden: int = typer.Option(NetworkConfig.hidden, "--hidden", help="Units of each hidden MLP layer."),
    message_passing: int = typer.Option(NetworkConfig.message_passing_steps, option_name("message_passing_steps"), help="Processor steps (unshared weights)."),
    save_every: int = typer.Option(TrainConfig.save_every, "--save-every", help=f"Steps between checkpoints (neural-mpm: default {NMPM.save_every})."),
    keep_every: int = typer.Option(TrainConfig.keep_every, "--keep-every", help="Every N steps also keep a copy of the checkpoint as OUT/snapshots/step-N.pt, to choose one afterwards by rollouts (0: never)."),
    log_every: int = typer.Option(TrainConfig.log_every, "--log-every", help="Steps per log.jsonl line (mean loss)."),
    valid_every: int = typer.Option(TrainConfig.valid_every, "--valid-every", help=f"Steps between validation rollouts (0: never; neural-mpm: default {NMPM.valid_every:,}, and on the last step)."),
    valid_trajectories: int = typer.Option(TrainConfig.valid_trajectories, "--valid-trajectories", help=f"Validation trajectories rolled out each time (neural-mpm: default {NMPM.valid_count}, from rest)."),
    seed: int = typer.Option(TrainConfig.seed, "--seed", help="Seed of the initial weights, window sampling and noise."),
    bf16: bool = typer.Option(TrainConfig.bf16, "--bf16/--no-bf16", help="Autocast the network to bfloat16 (faster on GPUs and on CPUs with AVX512-BF16 or AMX; elsewhere on a CPU it trains in float32, with a warning). neural-mpm: the U-Net in the training steps only; points, transfers and validation stay float32."),
    checkpoint_layers: bool = typer.Option(TrainConfig.checkpoint_layers, "--checkpoint-layers/--no-checkpoint-layers", help="Recompute processor steps in backward to save memory."),
    progress: bool = typer.Option(TrainConfig.progress, "--progress/--no-progress", help="Show a progress bar on stderr (log.jsonl records the run either way)."),
    force: bool = typer.Option(False, "--force", help="Start afresh in --out, removing a previous run or another command's results there."),
) -> None:
    """Train a learned engine on an MPM dataset: the GNS (one process, or many under torchrun)
    or, with --engine neural-mpm, the neural MPM. Ctrl-C saves the checkpoint of the last whole
    step (exit 130); --resume continues exactly."""
    from runout import checks
    from runout.outputs import check_folder, claim
    from runout.reading import folder_to_read
    from runout.train import BEST, CHECKPOINT, LOG, SNAPSHOTS, check_settings, resumed_settings, train as run_training
    from runout.train_settings import parse_onset_schedule

    _check_engine_options(ctx, engine)
    if engine == "neural-mpm":
        return _train_neural_mpm(ctx, data, out, resume, force)
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


def _check_engine_options(ctx: typer.Context, engine: str) -> None:
    """InputError for an --engine other than gns or neural-mpm, or an option of the other engine."""
    if engine not in ENGINES:
        raise InputError(f"--engine = {engine} must be one of {', '.join(ENGINES)}.")
    for other, names in ENGINE_OPTIONS.items():
        given = [p.opts[0] for p in ctx.command.params if p.name in names and _given(ctx, p.name)]
        if other != engine and given:
            raise InputError(f"{given[0]} is an option of --engine {other} only; leave it out to train the {ENGINE_NAMES[engine]}.")


def _train_neural_mpm(ctx: typer.Context, data: Path, out: Path, resume: bool, force: bool) -> None:
    """`runout train --engine neural-mpm`: the options shared with the GNS take the neural
    MPM's defaults where not given; checks, then the run (runout.training.engines)."""
    from dataclasses import fields

    from runout.outputs import check_folder, claim
    from runout.reading import folder_to_read
    from runout.train_settings import check_neural_mpm, motion_exponents, parse_widths

    values = {NEURAL_MPM_SETTING.get(name, name): value for name, value in ctx.params.items() if _given(ctx, name)}
    if values.get("init") is not None:
        shaped = [name for name in ("cell_size", "history", "frames_per_call", "widths") if _given(ctx, name)]
        if shaped:
            option = "--" + shaped[0].replace("_", "-")
            raise InputError(f"{option} comes from the --init file's engine; leave it out (only --velocity-sweeps may "
                             "differ from it).")
        values["init"] = str(values["init"])
    settings = NeuralMPMSettings(**{f.name: values[f.name] for f in fields(NeuralMPMSettings) if f.name in values})
    no_limit = {name: None for name in ("max_hours", "max_cpu_hours") if getattr(settings, name) == 0}  # 0: no limit
    settings = replace(settings, data=str(data), out=str(out), **no_limit)
    config = NeuralMPMConfig(cell_size=ctx.params["cell_size"], history=ctx.params["history"],
                             frames_per_call=ctx.params["frames_per_call"], widths=parse_widths(ctx.params["widths"]),
                             velocity_sweeps=ctx.params["velocity_sweeps"])
    check_neural_mpm(settings, config)
    folders = [Path(d.strip()) for d in str(data).split(",") if d.strip()]
    for folder in folders:
        folder_to_read(folder, "dataset folder")
    motion_exponents(settings.motion_weighting, len(folders))
    if settings.init is not None:  # one sentence now for a missing or other engine's file, before the folder is made
        from runout.learned.load import load_engine

        if (name := load_engine(settings.init).name) != "neural-mpm":
            raise InputError(f"--init {settings.init}: holds a {name} model; a neural-MPM run starts from a neural-mpm "
                             "checkpoint.")
    run_folder = check_folder(out, "train", ("checkpoint.pt", "best.pt", "train.log.jsonl"), mode="resume", force=force,
                              inputs={"--data" if len(folders) == 1 else f"--data ({k + 1} of {len(folders)})": folder
                                      for k, folder in enumerate(folders)} | {"--init": settings.init})
    claim(run_folder)
    from runout.training.engines import train_neural_mpm

    train_neural_mpm(settings, config, resume)


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
    from runout.memory import GIB, device_memory

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

"""The settings of a training run, torch-free: for the GNS, TrainConfig (every field a `runout
train` option derives its default from; the defaults are the recipe the pilots chose,
docs/training.md), SETTING_LIMITS (the allowed value of every setting a user gives, one table)
and check_settings; for the neural MPM, its TrainSettings and NeuralMPMConfig with their limits
(check_neural_mpm); and ENGINE_OPTIONS, the `runout train` options only one engine takes.
runout.train and runout.neural_mpm.training run them; the command line reads them without
loading torch.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path

from runout import checks
from runout.contract import SCHEMA_LIMITS
from runout.gns.schema import MAX_STEPS, NETWORK_LIMITS, NetworkConfig  # noqa: F401  (NetworkConfig re-exported for the command line)
from runout.neural_mpm.config import CONFIG_LIMITS, MAX_LEVELS, MAX_WIDTH, WHOLE, NeuralMPMConfig, widths_allowed
from runout.neural_mpm.settings import TrainSettings as NeuralMPMSettings

PUSHFORWARD_LIMITS = (0, 10)  # allowed --pushforward: the most rollout steps before a training step


@dataclass
class TrainConfig:
    """A training run's settings. The defaults are the recipe (RECIPE names the settings the
    pilots of docs/training.md chose, rounds 1-12): a learning rate and decay for budgets of tens
    of thousands of steps, noise 0.01 of the velocity std, no noise on the scene at rest,
    pushforward 2, a weight average, activations kept (no recomputation), the onset of motion
    drawn in three phases (the start from rest first, then the decelerations), the overburden
    input, and half the windows mirrored left-right (the physics has no side; the slope families
    all fail to the right)."""

    data: Path
    out: Path
    steps: int = 2_000_000  # final value of the step counter
    batch_size: int = 2  # graphs per process and step
    lr_init: float = 4e-4
    lr_final: float = 1e-6
    lr_decay_steps: float = 200_000.0  # steps over which the learning rate falls tenfold (the paper's 5e6 suits millions of steps)
    noise: float = 0.01  # velocity noise std as a fraction of the data's velocity std
    rest_windows: bool = True  # also train on windows that start before frame 0 (a scene at rest)
    exact_rest: bool = True  # no noise on the held copies of frame 0 in a window (a rollout starts from them exactly)
    # (from step, share, frames): from each step on, that share of the windows is drawn from each
    # simulation's first `frames` frames (the onset of motion), the rest uniformly; uniformly before the first
    onset_schedule: tuple[tuple[int, float, int], ...] = ((0, 0.4, 4), (12_000, 0.5, 2), (20_000, 0.1, 4))
    seed: int = 0
    device: str = "auto"  # auto, cpu, cuda, cuda:1, ...
    resume: bool = False
    init: Path | None = None  # fine-tune from this checkpoint (widening material inputs if needed)
    network: NetworkConfig = field(default_factory=NetworkConfig)
    save_every: int = 1000
    keep_every: int = 0  # every N steps also keep a copy of the checkpoint in snapshots/ (0: never)
    log_every: int = 100
    valid_every: int = 20_000  # 0: never
    valid_trajectories: int = 1
    checkpoint_layers: bool = False  # recompute processor steps in backward (less memory, slower)
    bf16: bool = False  # autocast the network to bfloat16
    lr_step_offset: int = 0  # learning-rate schedule continues from the base model's step
    max_hours: float = 0.0  # wall-clock limit of this run; 0: none
    radius: float | None = None  # connectivity radius in m (None: the dataset's default)
    frame_stride: int | None = None  # dataset frames per GNS step (None: 1, or the checkpoint's on --resume / --init)
    pushforward: int = 2  # each step first unrolls n ~ U{0..pushforward} steps without gradient (0: one-step)
    compile: bool = False  # run the network through torch.compile (1.19x the steps on one CPU thread, docs/training.md)
    ema: float = 0.999  # decay per step of the weight average saved as the model (0: the last step's weights)
    overburden: bool | None = None  # give the network each point's depth of soil above it (None: the checkpoint's, else yes)
    progress: bool = True  # a progress bar on stderr (log.jsonl is written either way)
    mirror: float = 0.5  # share of training windows mirrored left-right about the domain's centre


@dataclass(frozen=True)
class Limit:
    lo: float
    hi: float
    unit: str = ""
    lo_open: bool = False  # (lo, hi] instead of [lo, hi]


# The allowed values of the settings a user gives, by TrainConfig (and NetworkConfig) field, one
# table: `runout train` checks its options against it before any work, train() its settings.
SETTING_LIMITS = {
    "steps": Limit(1, MAX_STEPS), "batch_size": Limit(1, 64), "lr_init": Limit(0.0, 1.0, lo_open=True),
    "lr_decay_steps": Limit(1.0, 1e12), "noise": Limit(0.0, 10.0, " velocity std"),
    "save_every": Limit(1, 1_000_000_000), "keep_every": Limit(0, 1_000_000_000), "log_every": Limit(1, 1_000_000_000), "valid_every": Limit(0, 1_000_000_000),
    "valid_trajectories": Limit(1, 10_000), "max_hours": Limit(0.0, 1000.0, " h"),
    "radius": Limit(0.1, 1000.0, " m"), "frame_stride": Limit(*SCHEMA_LIMITS["frame_stride"]),
    "pushforward": Limit(*PUSHFORWARD_LIMITS), "ema": Limit(0.0, 0.99999), "mirror": Limit(0.0, 1.0),
    **{name: Limit(lo, hi) for name, (lo, hi) in NETWORK_LIMITS.items()},
}
OPTION_NAMES = {"lr_init": "--lr"}  # the `runout train` options not named --field-name


# The settings the recipe chose, whose TrainConfig defaults are its values (docs/training.md gives
# the pilots and chunks that chose each and their figures). The campaign's scripts
# (scripts/cpu_chunk.sh) pass them explicitly (recipe_options), so a chunk says what it trains with.
RECIPE = ("lr_init", "lr_decay_steps", "noise", "exact_rest", "pushforward", "ema", "checkpoint_layers", "onset_schedule",
          "overburden", "mirror")


def recipe_settings() -> dict:
    """RECIPE's settings with TrainConfig's defaults, as a new run takes them (the overburden input on)."""
    return {name: True if name == "overburden" else getattr(TrainConfig, name) for name in RECIPE}


def recipe_options() -> list[str]:
    """The recipe as `runout train` options."""
    options = []
    for name, value in recipe_settings().items():
        if name == "onset_schedule":
            options += ["--onset-schedule", format_onset_schedule(value)]
        elif name == "exact_rest":
            options.append("--exact-rest" if value else "--noisy-rest")
        elif isinstance(value, bool):  # --checkpoint-layers/--no-checkpoint-layers, --overburden/--no-overburden, ...
            options.append(option_name(name) if value else "--no-" + option_name(name)[2:])
        else:
            options += [option_name(name), f"{value:g}"]
    return options


def trained_with_recipe(train_settings: dict) -> bool:
    """Whether a checkpoint's training settings are the recipe's generation (--exact-rest, which
    the pilots brought in on solver-6 data): the committed models before it learned solver 3."""
    return bool(train_settings.get("exact_rest"))


def format_onset_schedule(schedule) -> str:
    """The --onset-schedule text of a schedule: ((0, 0.4, 4), (12000, 0.5, 2)) -> "0:0.4:4,12000:0.5:2"."""
    return ",".join(f"{step}:{share:g}:{frames}" for step, share, frames in schedule)


def parse_onset_schedule(text: str | None) -> tuple[tuple[int, float, int], ...]:
    """--onset-schedule "STEP:SHARE:FRAMES,...", e.g. "0:0.4:4,14000:0.5:2,24000:0.1:4": from
    each STEP on, a share SHARE of the windows is drawn from each simulation's first FRAMES
    frames, the rest uniformly. Steps must rise; an empty text is no schedule (every window
    drawn uniformly). InputError naming the entry otherwise."""
    if not text:
        return ()
    schedule = []
    for entry in text.split(","):
        parts = entry.strip().split(":")
        try:
            step, share, frames = int(parts[0]), float(parts[1]), int(parts[2])
            if len(parts) != 3:
                raise ValueError
        except (ValueError, IndexError):
            raise checks.InputError(f"--onset-schedule: the entry '{entry}' is not STEP:SHARE:FRAMES "
                                    "(whole, fraction, whole), such as 0:0.4:4,14000:0.1:4.") from None
        checks.number(step, "--onset-schedule step", None, 0, MAX_STEPS, whole=True)
        checks.number(share, "--onset-schedule share", None, 0.0, 1.0)
        checks.number(frames, "--onset-schedule frames", None, 1, 1_000_000, " frames", whole=True)
        if schedule and step <= schedule[-1][0]:
            raise checks.InputError(f"--onset-schedule: the step {step} of '{entry}' must be after the step "
                                    f"{schedule[-1][0]} of the entry before it.")
        schedule.append((step, share, frames))
    return tuple(schedule)


UNIFORM = (0.0, 1)  # (onset share, onset frames) of a step before the schedule's first entry: no onset draws


def onset_at(cfg: TrainConfig, step: int) -> tuple[float, int]:
    """The (onset share, onset frames) of the training step `step`: the last --onset-schedule
    entry that has begun, else UNIFORM."""
    return schedule_phase(cfg.onset_schedule, step, UNIFORM)


def schedule_phase(schedule, step: int, default: tuple[float, int]) -> tuple[float, int]:
    """(share, frames) of the last (begin, share, frames) entry of `schedule` begun by `step`, else `default`."""
    share, frames = default
    for begin, entry_share, entry_frames in schedule:
        if step >= begin:
            share, frames = entry_share, entry_frames
    return share, frames


def option_name(setting: str) -> str:
    """The `runout train` option that sets a TrainConfig or NetworkConfig field."""
    return OPTION_NAMES.get(setting, "--" + setting.replace("_", "-"))


def check_settings(cfg: TrainConfig, names=tuple(SETTING_LIMITS)) -> None:
    """InputError naming the option of the first of the settings `names` outside
    SETTING_LIMITS (None: not given, passes); whole numbers where the field is an int."""
    for owner in (cfg, cfg.network):
        for f in fields(owner):
            value, limit = getattr(owner, f.name), SETTING_LIMITS.get(f.name)
            if f.name in names and limit is not None and value is not None:
                checks.number(value, option_name(f.name), None, limit.lo, limit.hi, limit.unit, limit.lo_open,
                              whole=str(f.type).startswith("int"))


# The `runout train` options of one engine only (by parameter name): given with the other
# engine, they are refused. Every other option serves both (--steps, --lr, --mirror, ...).
ENGINE_OPTIONS = {
    "gns": ("device", "radius", "frame_stride", "pushforward", "compile_network", "rest_windows",
            "exact_rest", "onset_schedule", "overburden", "latent", "hidden", "message_passing", "keep_every",
            "checkpoint_layers"),
    "neural-mpm": ("calls", "lr_final", "rest_share", "data_shares", "max_cpu_hours", "threads", "cell_size", "history",
                   "frames_per_call", "widths", "velocity_sweeps", "front_loss", "toe_loss", "motion_weighting"),
}
ENGINES = tuple(ENGINE_OPTIONS)

# (lowest, highest, whole, lowest excluded) of each neural-MPM setting a user gives, by TrainSettings field
NEURAL_MPM_LIMITS = {
    "steps": (1, MAX_STEPS, True, False), "batch_size": (1, 64, True, False), "calls": (1, 64, True, False),
    "lr": (0.0, 1.0, False, True), "lr_final": (0.0, 1.0, False, True), "lr_decay_steps": (1.0, 1e12, False, False),
    "rest_share": (0.0, 1.0, False, False), "noise": (0.0, 10.0, False, False), "mirror_share": (0.0, 1.0, False, False), "ema": (0.0, 0.99999, False, False),
    "front_loss": (0.0, 100.0, False, False), "toe_loss": (0.0, 100.0, False, False),
    "valid_every": (0, 1_000_000_000, True, False), "valid_count": (1, 10_000, True, False),
    "save_every": (1, 1_000_000_000, True, False), "log_every": (1, 1_000_000_000, True, False),
    "max_hours": (0.0, 1000.0, False, True), "max_cpu_hours": (0.0, 1e6, False, True), "threads": (1, 1024, True, False),
}
# The `runout train` options of the neural MPM's settings not named --field-name
NEURAL_MPM_OPTIONS = {"mirror_share": "--mirror", "valid_count": "--valid-trajectories"}


def check_neural_mpm(settings: NeuralMPMSettings, config: NeuralMPMConfig) -> None:
    """InputError naming the option of the first neural-MPM setting or engine size outside its
    range (None: not given, passes)."""
    for name, (lo, hi, whole, lo_open) in NEURAL_MPM_LIMITS.items():
        value = getattr(settings, name)
        if value is not None:
            option = NEURAL_MPM_OPTIONS.get(name, "--" + name.replace("_", "-"))
            checks.number(value, option, None, lo, hi, lo_open=lo_open, whole=whole)
    motion_exponents(settings.motion_weighting)
    for name in ("cell_size", "history", "frames_per_call", "velocity_sweeps"):
        lo, hi = CONFIG_LIMITS[name]
        checks.number(getattr(config, name), "--" + name.replace("_", "-"), None, lo, hi, whole=name in WHOLE)
    if not widths_allowed(config.widths):
        raise checks.InputError(f"--widths = {','.join(map(str, config.widths))} must be 1 to {MAX_LEVELS} whole numbers "
                                f"of channels in [1, {MAX_WIDTH}] joined by commas, such as 32,64,96.")


MOTION_WEIGHTING_MAX = 4.0  # the largest exponent of --motion-weighting


def motion_exponents(value: float | str, datasets: int | None = None) -> list[float]:
    """--motion-weighting "1" or "1,0,0,1": the exponent of each dataset's draw by motion, one for
    all or one per dataset (`datasets` of them, when known; a single one is repeated); InputError
    naming the option unless numbers in [0, 4] joined by commas, as many as the datasets."""
    text = str(value).strip()
    try:
        exponents = [float(v) for v in text.split(",")]
    except ValueError:
        raise checks.InputError(f"--motion-weighting = {text} must be one number in [0, {MOTION_WEIGHTING_MAX:g}], or one "
                                "per dataset of --data joined by commas, such as 1,0,0,1.") from None
    for e in exponents:
        checks.number(e, "--motion-weighting", None, 0.0, MOTION_WEIGHTING_MAX)
    if datasets is not None and len(exponents) not in (1, datasets):
        raise checks.InputError(f"--motion-weighting = {text} gives {len(exponents)} exponents for {datasets} "
                                f"dataset{'s' if datasets != 1 else ''}; "
                                "give one for all or one per dataset of --data.")
    return exponents * datasets if datasets is not None and len(exponents) == 1 else exponents


def parse_widths(text: str) -> tuple[int, ...]:
    """--widths "32,64,96": the U-Net's channels per level; InputError unless whole numbers joined by commas."""
    try:
        return tuple(int(w) for w in text.split(","))
    except ValueError:
        raise checks.InputError(f"--widths = {text} must be whole numbers of channels joined by commas, such as "
                                "32,64,96.") from None

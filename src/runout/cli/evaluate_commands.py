"""`runout evaluate ...`: the paper's results sections as commands, for any learned engine's
checkpoint (GNS or neural MPM; the file says which; the data-size study fine-tunes GNS
checkpoints only), and `runout evaluate heldout`, the held-out measure of any learned engine's
checkpoint.

Each study writes OUT/<study>/ (summary.json, CSV, figures); `runout evaluate report`
turns them into docs/results.md. Scenes are filled at the model's point spacing for both
engines; MPM runs are cached by scene in --cache.
"""

from __future__ import annotations

import inspect
import typing
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import typer

from runout.cli.app import app
from runout.defaults import MPM_CACHE as DEFAULT_CACHE
from runout.errors import InputError
from runout.evaluate.study_settings import PAPER_CASE, ColumnGrid, SensitivityConfig
from runout.scene import EXAMPLES
from runout.scene.limits import MAX_FRAMES

evaluate_app = typer.Typer(
    help="Measure a learned model against the MPM: held-out scenes from rest, and the paper's column, slope, diagnostics, inverse and data-size studies.",
    no_args_is_help=True,
)
app.add_typer(evaluate_app, name="evaluate")

MODEL_HELP = "Learned-engine checkpoint (GNS or neural MPM; the file says which)"

# The options every study on the example scenes takes, defined once: study_command puts them
# first in each such command's signature and hands them over as one Study.
STUDY_OPTIONS = {
    "model": (Path, typer.Option(..., "--model", help=f"{MODEL_HELP} to evaluate.")),
    "out": (Path, typer.Option(..., "--out", help="Results folder; each study writes OUT/<study>/.")),
    "device": (str, typer.Option("cpu", "--device", help="cpu or cuda, for both the MPM and the learned engine.")),
    "cache": (Path, typer.Option(DEFAULT_CACHE, "--cache", help="Folder of cached MPM runs, keyed by a hash of each scene's TOML.")),
    "examples": (Path, typer.Option(EXAMPLES, "--examples", help="Folder holding the example scenes (column_a*.toml, four_layer_slope.toml, dam.toml, dam_inverse.toml).")),
    "scale": (float, typer.Option(1.0, "--scale", help="Shrink domain and geometry by this factor in (0, 1] (cells stay the model's); 1 = the paper's geometry.")),
    "progress": (bool, typer.Option(True, "--progress/--no-progress", help="Show progress bars.")),
    "force": (bool, typer.Option(False, "--force", help="Replace another command's results in --out (other studies' results are kept).")),
}
OUT, DEVICE, PROGRESS, FORCE = (STUDY_OPTIONS[name][1] for name in ("out", "device", "progress", "force"))


@dataclass(frozen=True)
class Study:
    """The shared options of one study command (STUDY_OPTIONS)."""

    model: Path
    out: Path
    device: str
    cache: Path
    examples: Path
    scale: float
    progress: bool
    force: bool

    def start(self, name: str, frames: int | None):
        """Check the options (--device, --scale, then --frames against the model's needs),
        make OUT/NAME's place in OUT and return the engines the study runs (an StudyContext)."""
        from runout import checks
        from runout.evaluate import StudyContext, MpmCache
        from runout.evaluate.scenes import check_scale

        checks.device(self.device)
        check_scale(self.scale)
        if frames is not None:
            from runout.learned.load import load_engine

            load_engine(self.model).check_frames(frames, "--frames")
        _claim_out(self.out, name, self.force, {"--model": self.model, "--examples": self.examples})
        return StudyContext(MpmCache(self.cache), self.device, self.progress, log=typer.echo)


def study_command(func: Callable) -> Callable:
    """Register func(study: Study, **its own options) as `runout evaluate NAME`, its
    signature the shared STUDY_OPTIONS followed by its own."""
    hints = typing.get_type_hints(func)
    own = [p.replace(annotation=hints[p.name]) for p in list(inspect.signature(func).parameters.values())[1:]]
    shared = [inspect.Parameter(name, inspect.Parameter.POSITIONAL_OR_KEYWORD, default=option, annotation=kind)
              for name, (kind, option) in STUDY_OPTIONS.items()]

    def command(**options) -> None:
        func(Study(**{name: options.pop(name) for name in STUDY_OPTIONS}), **options)

    command.__name__, command.__doc__ = func.__name__, func.__doc__
    command.__signature__ = inspect.Signature(shared + own)
    command.__annotations__ = {p.name: p.annotation for p in shared + own}
    evaluate_app.command()(command)
    return func


def _claim_out(out: Path, study: str, force: bool, inputs) -> None:
    """OUT holds one subfolder per study; a study adds or replaces its own. OUT must lie apart from the study's inputs."""
    from runout.outputs import prepare_folder

    prepare_folder(out, "evaluate", (study,), mode="add", force=force, inputs=inputs)


def _label(summary: dict) -> str:
    """The name of the engine that ran a study (GNS, neural MPM), from its summary's model card."""
    from runout.evaluate.model_card import ModelCard

    return ModelCard(**summary["model"]).label


def parse_numbers(text: str, option: str) -> tuple[float, ...]:
    """'0.5,1,2' -> (0.5, 1.0, 2.0)."""
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise InputError(f"{option} {text!r} must be numbers separated by commas, e.g. 0.5,1,2.") from None
    if not values:
        raise InputError(f"{option} is empty; give numbers separated by commas, e.g. 0.5,1,2.")
    return values


def listed(values) -> str:
    """(0.5, 1.0, 2.0) -> '0.5,1,2': a default of a numbers option."""
    return ",".join(f"{v:g}" for v in values)


def parse_sizes(text: str) -> tuple[int, ...]:
    values = parse_numbers(text, "--sizes")
    if any(v != int(v) or v < 1 for v in values):
        raise InputError(f"--sizes {text!r} must be positive whole numbers, e.g. 10,50,100.")
    return tuple(int(v) for v in values)


@study_command
def columns(
    study: Study,
    aspects: str = typer.Option(listed(ColumnGrid.aspects), help="Aspect ratios H0/L0 (0.5, 1 and/or 2: the example columns)."),
    phis: str = typer.Option(listed(ColumnGrid.phis), help="Friction angles (degrees)."),
    cohesions: str = typer.Option(listed(ColumnGrid.cohesions), help="Cohesions (kPa)."),
    frames: int = typer.Option(ColumnGrid.frames, help="Frames of every run (0.0375 s apart)."),
) -> None:
    """Column-collapse grid (paper §5.1.1): normalised runout of the MPM and the learned engine, errors, R², 1:1 plots, error heat maps and the 25th/50th/75th-percentile cases over time."""
    from runout.evaluate import ColumnGrid, run_columns

    engines = study.start("columns", frames)
    grid = ColumnGrid(parse_numbers(aspects, "--aspects"), parse_numbers(phis, "--phis"),
                      parse_numbers(cohesions, "--cohesions"), frames, study.scale, study.examples)
    summary = run_columns(study.model, study.out, grid, engines)
    for b in summary["by_aspect"]:
        signed = [f"{f['phi_deg']:g}° {f['mean_signed_error_percent']:+.1f}" for f in summary["by_friction_angle"]
                  if f["aspect"] == b["aspect"]]
        typer.echo(f"a = {b['aspect']:g}: mean error {b['mean_ape_percent']:.2f} %, CV {b['cv_ape']:.2f}, R² {b['r2']:.3f}; "
                   f"signed error by φ (%, + too far): {', '.join(signed)}")
    typer.echo(f"wrote {study.out / 'columns'}/cases.csv, summary.json and figures")


@study_command
def slope(
    study: Study,
    frames: int = typer.Option(None, help="Frames (default: the scene's 480)."),
    rerun_mpm: bool = typer.Option(False, "--rerun-mpm", help="Run the MPM again (not from the cache) to time it on this machine."),
) -> None:
    """Four-layer slope (paper §5.1.2): runout error each side of x = 500 m, fields at frames 0, 80, 180 and the last, displacement-error growth, and both engines' wall time."""
    from runout.evaluate import run_slope

    engines = study.start("slope", frames)
    s = run_slope(study.model, study.out, engines, study.examples, frames, study.scale, rerun_mpm)
    typer.echo(f"runout error left {s['runout_left_m']['ape_percent']:.2f} %, right {s['runout_right_m']['ape_percent']:.2f} %; "
               f"wall time MPM {s['wall_time_s']['mpm']:.4g} s, {_label(s)} {s['wall_time_s']['predicted']:.4g} s")
    typer.echo(f"wrote {study.out / 'slope'}/summary.json and figures")


@study_command
def diagnostics(
    study: Study,
    aspect: float = typer.Option(PAPER_CASE.aspect, help="Aspect ratio of the column (0.5, 1 or 2)."),
    phi: float = typer.Option(PAPER_CASE.phi, help="Friction angle (degrees)."),
    c: float = typer.Option(PAPER_CASE.cohesion, "--c", help="Cohesion (kPa)."),
    frames: int = typer.Option(600, help="Frames of the run."),
) -> None:
    """Velocity-space and physical-space error diagnostics (paper §5.1.1) at frames 80, 200 and the last, against the model's training velocity distribution."""
    from runout.cli.gns_commands import check_range
    from runout.evaluate import ColumnCase, run_diagnostics
    from runout.evaluate.scenes import column_file
    from runout.scene import MAX_STRENGTH

    column_file(aspect)
    check_range("--phi", phi, 0.0, 60.0, " degrees")
    check_range("--c", c, 0.0, MAX_STRENGTH, " kPa")
    engines = study.start("diagnostics", frames)
    s = run_diagnostics(study.model, study.out, engines, ColumnCase(aspect, phi, c), frames, study.scale, study.examples)
    for f in s["frames"]:
        typer.echo(f"frame {f['frame']}: median velocity error {f['median_error_m_s']:.3g} m/s, "
                   f"{100 * f['share_outside_2sigma']:.1f} % of points outside 2σ")
    typer.echo(f"wrote {study.out / 'diagnostics'}/summary.json and velocity_diagnostics.png")


@study_command
def inverse(
    study: Study,
    frames: int = typer.Option(None, help="Frames of the MPM target and the rollout (default: the scene's 400)."),
    max_iterations: int = typer.Option(None, help="L-BFGS-B iterations (default: examples/dam_inverse.toml's)."),
    yardstick: bool = typer.Option(True, "--yardstick/--no-yardstick", help="Also solve the same inverse through the MPM itself (--engine mpm-ad) and report both engines' answers and seconds per iteration."),
) -> None:
    """Dam inversion (paper §5.2): MPM target, then c1 in [10, 100] kPa, c2 in [99, 101] kPa and phi3 in [5, 50] degrees back-calculated with the inverse module."""
    from runout.evaluate import run_inverse

    if max_iterations is not None and max_iterations < 1:
        raise InputError(f"--max-iterations {max_iterations} must be a positive whole number.")
    engines = study.start("inverse", frames)
    s = run_inverse(study.model, study.out, engines, study.examples, frames, study.scale, max_iterations, typer.echo,
                    yardstick)
    y = s.get("yardstick")
    for k, p in enumerate(s["parameters"]):
        beside = "" if y is None else f", MPM-AD {y['parameters'][k]['inferred']:.4g}"
        typer.echo(f"{p['name']}: inferred {p['inferred']:.4g} {p['unit']}{beside} (true {p['true']}, "
                   f"bounds [{p['lower']:g}, {p['upper']:g}])")
    typer.echo(f"seconds per L-BFGS-B iteration: {_label(s)} {s['seconds_per_iteration']:.3g}"
               + ("" if y is None else f", MPM-AD {y['seconds_per_iteration']:.3g}"))
    typer.echo(f"wrote {study.out / 'inverse'}/summary.json, target.png and run/" + ("" if y is None else " and run_mpm_ad/"))


@evaluate_app.command()
def sensitivity(
    data: Path = typer.Option(..., "--data", help="Dataset folder: train.npz, metadata.json and the held-out split."),
    init: Path = typer.Option(..., "--init", help="GNS checkpoint every subset is fine-tuned from (the study fine-tunes GNS models only)."),
    out: Path = OUT, device: str = DEVICE, progress: bool = PROGRESS, force: bool = FORCE,
    sizes: str = typer.Option(listed(SensitivityConfig.sizes), help="Subset sizes N (first N training simulations)."),
    steps: int = typer.Option(SensitivityConfig.steps, help="Fixed step budget per subset."),
    epochs: int = typer.Option(SensitivityConfig.epochs, help="Fixed epoch budget per subset."),
    budgets: str = typer.Option(",".join(SensitivityConfig.budgets), help="Budgets to run: steps, epochs or steps,epochs."),
    held_out: int = typer.Option(SensitivityConfig.held_out, "--held-out", help="Held-out simulations rolled out per model."),
    split: str = typer.Option(SensitivityConfig.split, help="Held-out split file in --data (test or valid)."),
) -> None:
    """Data-size study (paper §6): fine-tune subsets of a GNS under a fixed step and a fixed epoch budget; median and 25th-75th percentile rollout MSE on held-out simulations."""
    from runout import checks
    from runout.evaluate import run_sensitivity
    from runout.evaluate.sensitivity import check_init

    if split not in ("test", "valid"):
        raise InputError(f"--split {split!r} must be test or valid.")
    checks.device(device)
    cfg = SensitivityConfig(data, init, parse_sizes(sizes), steps, epochs, held_out, split, device=device, progress=progress,
                            budgets=tuple(b.strip() for b in budgets.split(",") if b.strip()))
    check_init(init)
    _claim_out(out, "sensitivity", force, {"--data": data, "--init": init})
    s = run_sensitivity(cfg, out)
    for r in s["results"]:
        typer.echo(f"{r['budget']:>6} N = {r['size']:>5}: median rollout MSE {r['median_mse_m2']:.4g} m² "
                   f"[{r['p25_mse_m2']:.4g}, {r['p75_mse_m2']:.4g}]")
    typer.echo(f"wrote {out / 'sensitivity'}/rollouts.csv, summary.json and figures")


@evaluate_app.command()
def heldout(
    model: Path = typer.Argument(..., help=f"{MODEL_HELP}."),
    data: Path = typer.Option(..., "--data", help="Dataset folder with metadata.json and the held-out split (test.npz or valid.npz)."),
    out: Path = typer.Option(..., "--out", help="Results folder: metrics.json, column.png (and curves.png with --log)."),
    split: str = typer.Option("test", "--split", help="Held-out split: test, or valid (the scenes training runs are judged on)."),
    limit: int = typer.Option(16, "--limit", help="Roll out the first LIMIT scenes of the split (at least 16 for a verdict)."),
    mirrored: bool = typer.Option(False, "--mirrored", help="Also roll out the same scenes reflected left-right (the families' slopes all fail to the right; a model that learned the physics scores both alike)."),
    column: Path = typer.Option(EXAMPLES / "column_a1.toml", "--column", help="Column-collapse scene run by the MPM and the model from rest, filled at the model's point spacing."),
    no_column: bool = typer.Option(False, "--no-column", help="Skip the column run (e.g. for a friction-only base model)."),
    frames: int = typer.Option(240, "--frames", help="Frames of the column runs."),
    log: Path = typer.Option(None, "--log", help="The training run's log (GNS: log.jsonl; neural MPM: train.log.jsonl, its held-out error of each dataset): also draw OUT/curves.png from it."),
    progress: bool = PROGRESS, force: bool = FORCE,
) -> None:
    """Held-out scenes from rest (position error, fronts, extent, displacement, by family and start, beside standing still) and a column collapse against the MPM, for any learned engine; writes OUT/metrics.json."""
    from runout.cli.gns_commands import check_range
    from runout.evaluate.heldout_run import WRITES, read_log, run_heldout
    from runout.learned.load import load_engine
    from runout.outputs import check_folder, claim
    from runout.reading import file_to_read, folder_to_read
    from runout.scene import load_scene

    if split not in ("test", "valid"):
        raise InputError(f"--split {split!r} must be test or valid.")
    check_range("--limit", limit, 1, 1_000_000)
    check_range("--frames", frames, 1, MAX_FRAMES)
    file_to_read(model, "model file")
    folder_to_read(data, "dataset folder")
    file_to_read(data / f"{split}.npz", f"{split} split of the dataset")
    if not no_column:
        load_scene(column)
    if log is not None:
        read_log(log)
    folder = check_folder(out, "evaluate heldout", WRITES, force=force,
                          inputs={"MODEL": model, "--data": data, "--column": column, "--log": log})
    engine = load_engine(model)
    if not no_column:
        engine.check_frames(frames, "--frames")
    claim(folder)
    run_heldout(engine, model, data, out, split, limit, mirrored, None if no_column else column, frames, log, typer.echo,
                progress)
    typer.echo(f"wrote {out / 'metrics.json'}")


@evaluate_app.command()
def report(
    out: list[Path] = typer.Option(..., "--out", help="Results folder (OUT/<study>/summary.json); give one per engine "
                                   "(--out runs/final --out runs/final-nmpm) to set them side by side."),
    doc: Path = typer.Option(Path("docs/results.md"), "--doc", help="Markdown page to write; figures go to <doc>_figures/ beside it."),
) -> None:
    """Write the results page (tables and figures) from the studies' outputs in OUT; with several
    --out (one per engine), a table sets the engines side by side and beside the paper first."""
    from runout.evaluate import write_report

    typer.echo(f"wrote {write_report(out, doc)}")

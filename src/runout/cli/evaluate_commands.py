"""`runout evaluate ...`: the paper's results sections as commands, for any GNS checkpoint.

Each study writes OUT/<study>/ (summary.json, CSV, figures); `runout evaluate report`
turns them into docs/results.md. Scenes are filled at the model's point spacing for both
engines; MPM runs are cached by scene in --cache.
"""

from __future__ import annotations

from pathlib import Path

import typer

from runout.cli.app import app
from runout.errors import InputError
from runout.evaluate.scenes import EXAMPLES
from runout.mpm.cache import DEFAULT_CACHE

evaluate_app = typer.Typer(
    help="Measure a GNS model against the MPM: the paper's column, slope, diagnostics, inverse and data-size studies.",
    no_args_is_help=True,
)
app.add_typer(evaluate_app, name="evaluate")

MODEL = typer.Option(..., "--model", help="GNS checkpoint (.pt) to evaluate.")
OUT = typer.Option(..., "--out", help="Results folder; each study writes OUT/<study>/.")
DEVICE = typer.Option("cpu", "--device", help="cpu or cuda, for both the MPM and the GNS.")
CACHE = typer.Option(DEFAULT_CACHE, "--cache", help="Folder of cached MPM runs, keyed by a hash of each scene's TOML.")
EXAMPLE_DIR = typer.Option(EXAMPLES, "--examples", help="Folder holding the example scenes (column_a*.toml, four_layer_slope.toml, dam.toml, dam_inverse.toml).")
SCALE = typer.Option(1.0, "--scale", help="Shrink domain and geometry by this factor in (0, 1] (cells stay the model's); 1 = the paper's geometry.")
PROGRESS = typer.Option(True, "--progress/--no-progress", help="Show progress bars.")
FORCE = typer.Option(False, "--force", help="Replace another command's results in --out (other studies' results are kept).")


def _claim_out(out: Path, study: str, force: bool) -> None:
    """OUT holds one subfolder per study; a study adds or replaces its own."""
    from runout.outputs import prepare_folder

    prepare_folder(out, "evaluate", (study,), mode="add", force=force)


def parse_numbers(text: str, option: str) -> tuple[float, ...]:
    """'0.5,1,2' -> (0.5, 1.0, 2.0)."""
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise InputError(f"{option} {text!r} must be numbers separated by commas, e.g. 0.5,1,2.") from None
    if not values:
        raise InputError(f"{option} is empty; give numbers separated by commas, e.g. 0.5,1,2.")
    return values


def parse_sizes(text: str) -> tuple[int, ...]:
    values = parse_numbers(text, "--sizes")
    if any(v != int(v) or v < 1 for v in values):
        raise InputError(f"--sizes {text!r} must be positive whole numbers, e.g. 10,50,100.")
    return tuple(int(v) for v in values)


def _check_frames(frames: int | None) -> None:
    if frames is not None and frames < 8:
        raise InputError(f"--frames {frames} must be at least 8 (6 input frames and a rollout).")


def _check_options(device: str, scale: float) -> None:
    """--device and --scale of a study, before any file is read."""
    from runout import checks
    from runout.evaluate.scenes import check_scale

    checks.device(device)
    check_scale(scale)


def _engines(cache: Path, device: str, progress: bool):
    from runout.evaluate import EngineRun, MpmCache

    return EngineRun(MpmCache(cache), device, progress, log=typer.echo)


@evaluate_app.command()
def columns(
    model: Path = MODEL, out: Path = OUT, device: str = DEVICE, cache: Path = CACHE, examples: Path = EXAMPLE_DIR,
    scale: float = SCALE, progress: bool = PROGRESS, force: bool = FORCE,
    aspects: str = typer.Option("0.5,1,2", help="Aspect ratios H0/L0 (0.5, 1 and/or 2: the example columns)."),
    phis: str = typer.Option("0,11.25,22.5,33.75,45", help="Friction angles (degrees)."),
    cohesions: str = typer.Option("10,25,40,55,70", help="Cohesions (kPa)."),
    frames: int = typer.Option(600, help="Frames of every run (0.0375 s apart)."),
) -> None:
    """Column-collapse grid (paper §5.1.1): normalised runout of MPM and GNS, errors, R², 1:1 plots, error heat maps and the 25th/50th/75th-percentile cases over time."""
    from runout.evaluate import ColumnGrid, run_columns

    _check_frames(frames)
    _check_options(device, scale)
    _claim_out(out, "columns", force)
    grid = ColumnGrid(parse_numbers(aspects, "--aspects"), parse_numbers(phis, "--phis"),
                      parse_numbers(cohesions, "--cohesions"), frames, scale, examples)
    summary = run_columns(model, out, grid, _engines(cache, device, progress))
    for b in summary["by_aspect"]:
        typer.echo(f"a = {b['aspect']:g}: mean error {b['mean_ape_percent']:.2f} %, CV {b['cv_ape']:.2f}, R² {b['r2']:.3f}")
    typer.echo(f"wrote {out / 'columns'}/cases.csv, summary.json and figures")


@evaluate_app.command()
def slope(
    model: Path = MODEL, out: Path = OUT, device: str = DEVICE, cache: Path = CACHE, examples: Path = EXAMPLE_DIR,
    scale: float = SCALE, progress: bool = PROGRESS, force: bool = FORCE,
    frames: int = typer.Option(None, help="Frames (default: the scene's 480)."),
    rerun_mpm: bool = typer.Option(False, "--rerun-mpm", help="Run the MPM again (not from the cache) to time it on this machine."),
) -> None:
    """Four-layer slope (paper §5.1.2): runout error each side of x = 500 m, fields at frames 0, 80, 180 and the last, displacement-error growth, and both engines' wall time."""
    from runout.evaluate import run_slope

    _check_frames(frames)
    _check_options(device, scale)
    _claim_out(out, "slope", force)
    s = run_slope(model, out, _engines(cache, device, progress), examples, frames, scale, rerun_mpm)
    typer.echo(f"runout error left {s['runout_left_m']['ape_percent']:.2f} %, right {s['runout_right_m']['ape_percent']:.2f} %; "
               f"wall time MPM {s['wall_time_s']['mpm']:.4g} s, GNS {s['wall_time_s']['gns']:.4g} s")
    typer.echo(f"wrote {out / 'slope'}/summary.json and figures")


@evaluate_app.command()
def diagnostics(
    model: Path = MODEL, out: Path = OUT, device: str = DEVICE, cache: Path = CACHE, examples: Path = EXAMPLE_DIR,
    scale: float = SCALE, progress: bool = PROGRESS, force: bool = FORCE,
    aspect: float = typer.Option(2.0, help="Aspect ratio of the column (0.5, 1 or 2)."),
    phi: float = typer.Option(11.25, help="Friction angle (degrees)."),
    c: float = typer.Option(10.0, "--c", help="Cohesion (kPa)."),
    frames: int = typer.Option(600, help="Frames of the run."),
) -> None:
    """Velocity-space and physical-space error diagnostics (paper §5.1.1) at frames 80, 200 and the last, against the model's training velocity distribution."""
    from runout.cli.gns_commands import check_range
    from runout.evaluate import ColumnCase, run_diagnostics
    from runout.evaluate.scenes import column_file
    from runout.scene import MAX_STRENGTH

    _check_frames(frames)
    _check_options(device, scale)
    column_file(aspect)
    check_range("--phi", phi, 0.0, 60.0, " degrees")
    check_range("--c", c, 0.0, MAX_STRENGTH, " kPa")
    _claim_out(out, "diagnostics", force)
    s = run_diagnostics(model, out, _engines(cache, device, progress), ColumnCase(aspect, phi, c), frames, scale, examples)
    for f in s["frames"]:
        typer.echo(f"frame {f['frame']}: median velocity error {f['median_error_m_s']:.3g} m/s, "
                   f"{100 * f['share_outside_2sigma']:.1f} % of points outside 2σ")
    typer.echo(f"wrote {out / 'diagnostics'}/summary.json and velocity_diagnostics.png")


@evaluate_app.command()
def inverse(
    model: Path = MODEL, out: Path = OUT, device: str = DEVICE, cache: Path = CACHE, examples: Path = EXAMPLE_DIR,
    scale: float = SCALE, progress: bool = PROGRESS, force: bool = FORCE,
    frames: int = typer.Option(None, help="Frames of the MPM target and the rollout (default: the scene's 400)."),
    max_iterations: int = typer.Option(None, help="L-BFGS-B iterations (default: examples/dam_inverse.toml's)."),
) -> None:
    """Dam inversion (paper §5.2): MPM target, then c1 in [10, 100] kPa, c2 in [99, 101] kPa and phi3 in [5, 50] degrees back-calculated with the inverse module."""
    from runout.evaluate import run_inverse

    _check_frames(frames)
    if max_iterations is not None and max_iterations < 1:
        raise InputError(f"--max-iterations {max_iterations} must be a positive whole number.")
    _check_options(device, scale)
    _claim_out(out, "inverse", force)
    s = run_inverse(model, out, _engines(cache, device, progress), examples, frames, scale, max_iterations, typer.echo)
    for p in s["parameters"]:
        typer.echo(f"{p['name']}: inferred {p['inferred']:.4g} {p['unit']} (true {p['true']}, bounds [{p['lower']:g}, {p['upper']:g}])")
    typer.echo(f"wrote {out / 'inverse'}/summary.json, target.png and run/")


@evaluate_app.command()
def sensitivity(
    data: Path = typer.Option(..., "--data", help="Dataset folder: train.npz, metadata.json and the held-out split."),
    init: Path = typer.Option(..., "--init", help="Checkpoint every subset is fine-tuned from."),
    out: Path = OUT, device: str = DEVICE, progress: bool = PROGRESS, force: bool = FORCE,
    sizes: str = typer.Option("10,50,100,250,500,750,1000", help="Subset sizes N (first N training simulations)."),
    steps: int = typer.Option(4_500_000, help="Fixed step budget per subset."),
    epochs: int = typer.Option(10, help="Fixed epoch budget per subset."),
    held_out: int = typer.Option(20, "--held-out", help="Held-out simulations rolled out per model."),
    split: str = typer.Option("test", help="Held-out split file in --data (test or valid)."),
) -> None:
    """Data-size study (paper §6): fine-tune subsets under a fixed step and a fixed epoch budget; median and 25th-75th percentile rollout MSE on held-out simulations."""
    from runout import checks
    from runout.evaluate import SensitivityConfig, run_sensitivity

    if split not in ("test", "valid"):
        raise InputError(f"--split {split!r} must be test or valid.")
    checks.device(device)
    cfg = SensitivityConfig(data, init, parse_sizes(sizes), steps, epochs, held_out, split, device=device, progress=progress)
    _claim_out(out, "sensitivity", force)
    s = run_sensitivity(cfg, out)
    for r in s["results"]:
        typer.echo(f"{r['budget']:>6} N = {r['size']:>5}: median rollout MSE {r['median_mse_m2']:.4g} m² "
                   f"[{r['p25_mse_m2']:.4g}, {r['p75_mse_m2']:.4g}]")
    typer.echo(f"wrote {out / 'sensitivity'}/rollouts.csv, summary.json and figures")


@evaluate_app.command()
def report(
    out: Path = OUT,
    doc: Path = typer.Option(Path("docs/results.md"), "--doc", help="Markdown page to write; figures go to <doc>_figures/ beside it."),
) -> None:
    """Write the results page (tables and figures) from the studies' outputs in OUT."""
    from runout.evaluate import write_report

    typer.echo(f"wrote {write_report(out, doc)}")

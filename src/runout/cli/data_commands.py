"""`runout families`, `runout generate`, `runout merge` and `runout inspect`: training data."""

from __future__ import annotations

import os
from pathlib import Path

import typer

from runout.cli.app import app
from runout.generate import GenerateConfig

FORCE = typer.Option(False, "--force", help="Start afresh in --out, removing a previous run or another command's results there.")
DATASET_FILES = ("generate.json", "scenes", "parts", "train.npz", "valid.npz", "test.npz", "metadata.json")


@app.command()
def families(
    family: str = typer.Option(..., "--family", help="a (blocks), b (steep slope), c (gentle slope), d (dam on a foundation), column, mound or zoned_dam (four-zone dam on the rough base)."),
    count: int = typer.Option(12, "--count", help="Scenes to draw."),
    out: Path = typer.Option(Path("families.png"), "--out", help="PNG to write."),
    stage: str = typer.Option(None, "--stage", help="base, finetune, columns, tall-columns, mounds or dams (default: base, finetune for column, mounds for mound, dams for zoned_dam)."),
    seed: int = typer.Option(0, "--seed", help="Random seed."),
    scenes: Path = typer.Option(None, "--scenes", help="Also write each scene as TOML into this directory."),
    force: bool = typer.Option(False, "--force", help="Replace another command's results in --scenes."),
) -> None:
    """Draw a grid of random scenes of one family (paper Table A.1), to look at before generating."""
    from runout.families import draw_family

    draw_family(family, out, count, stage, seed, scenes, force)
    typer.echo(f"wrote {out}" + (f" and {count} scene files in {scenes}" if scenes else ""))


@app.command()
def generate(
    stage: str = typer.Option(..., "--stage", help="base (phi only, families a-d), finetune (phi and c, b-d and columns), columns (the column study's range: phi 0-45 deg, c 5-75 kPa, 1000 x 208 m), tall-columns (the same, bases 40-120 m, aspect 1.2-2.5), mounds (layered mounds around the four-layer slope: phi 0-45 deg, c 0-75 kPa, 1000 x 200 m) or dams (four-zone dams around the inverse analysis's dam: phi 0-45 deg, a quarter of the zones undrained at phi = 0, c 0-110 kPa, 800 x 100 m)."),
    count: int = typer.Option(..., "--count", help="Scenes in the dataset (paper: 2000 base, 1027 finetune)."),
    out: Path = typer.Option(..., "--out", help="Dataset directory; rerun the same command to resume."),
    seed: int = typer.Option(GenerateConfig.seed, "--seed", help="Random seed; scene k depends only on (seed, stage, k)."),
    device: str = typer.Option("cpu", "--device", help="cpu or cuda (under torchrun each rank takes cuda:LOCAL_RANK)."),
    batch: int = typer.Option(GenerateConfig.batch, "--batch", help="Scenes per MPM batch and per part file."),
    shard: str = typer.Option(None, "--shard", help="i/n: run only batches j with j mod n = i (default: torchrun's RANK/WORLD_SIZE)."),
    frames: int = typer.Option(GenerateConfig.frames, "--frames", help="Output frames per scene, frame 0 included."),
    cell_size: float = typer.Option(GenerateConfig.cell_size, "--cell-size", help="Background cell size in m (paper: 4; the shipped CPU models: 8). Points are 2 x 2 per cell."),
    force: bool = FORCE,
) -> None:
    """Sample scenes, run them through the batched MPM and write train/valid/test.npz and
    metadata.json (GNS layout). A killed run resumes where it stopped."""
    from runout import checks
    from runout.errors import Interrupted
    from runout.generate import generate as run, parse_shard, shard_from_env
    from runout.outputs import check_folder, claim

    where = parse_shard(shard) if shard else shard_from_env(os.environ)
    if device == "cuda" and "LOCAL_RANK" in os.environ:
        device = f"cuda:{os.environ['LOCAL_RANK']}"
    checks.device(device)
    config = GenerateConfig(stage, count, seed, batch, frames, cell_size)
    config.check()
    folder = check_folder(out, "generate", DATASET_FILES, mode="resume", force=force)
    if where[0] == 0:  # one process prepares a folder that several shards share
        claim(folder)
    try:
        finished = run(config, out, shard=where, device=device)
    except KeyboardInterrupt:
        raise Interrupted(f"the finished batches are in {out / 'parts'}, and the same command resumes from them.") from None
    if finished:
        typer.echo(f"wrote {out}/train.npz, valid.npz, test.npz, metadata.json")
    else:
        typer.echo(f"shard {where[0]}/{where[1]} done; join the shards with `runout merge DIR ... --out {out}`")


@app.command()
def merge(
    dirs: list[Path] = typer.Argument(..., help="Shard directories of one `runout generate` run."),
    out: Path = typer.Option(..., "--out", help="Dataset directory to write (may be one of the shards)."),
    force: bool = typer.Option(False, "--force", help="Replace another command's results in --out."),
) -> None:
    """Join sharded generation runs into one dataset, identical to an unsharded run."""
    from runout.generate import merge as join
    from runout.outputs import prepare_folder

    shards = {d.resolve() for d in dirs}
    prepare_folder(out, "generate", DATASET_FILES, mode="resume", force=force and out.resolve() not in shards)
    join(dirs, out)
    typer.echo(f"wrote {out}/train.npz, valid.npz, test.npz, metadata.json")


@app.command()
def inspect(
    dataset: Path = typer.Argument(..., help="Dataset directory (with metadata.json) or one split .npz file."),
) -> None:
    """Print simulation counts, frames, points, ranges and statistics of a dataset, checking its files."""
    from runout.dataset import format_summary, summarize

    typer.echo(format_summary(dataset, summarize(dataset)))

"""Training datasets: sample family scenes, run them through the batched MPM, write GNS files.

Layout of a dataset directory DIR:

    DIR/generate.json          what is being generated (stage, count, seed, batch, frames, cell size)
    DIR/scenes/scene_00042.toml  every scene, so any sample can be re-run alone with `runout mpm`
    DIR/parts/part_00003.npz   finished batches (batch j = scenes j*B .. j*B+B-1), written atomically
    DIR/train.npz, valid.npz, test.npz, metadata.json   the GNS dataset, written when all parts exist

Scene k depends only on (seed, stage, k); its family follows the stage's mix and its split
is fixed by k mod 10 (8 -> valid, 9 -> test, else train). A killed run skips the parts it
already wrote; shards (`shard=(i, n)`) run batches j with j mod n == i and `merge` joins
their parts into the same files an unsharded run writes.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

import runout
from runout import checks
from runout.contract import MATERIAL_FEATURE_NAMES, WindowSchema, radius_for_spacing, spacing_for_cells
from runout.dataset import SPLITS
from runout.errors import InputError, RunFailed
from runout.families import (
    BLOCK_SIDE, BLOCK_SPEED, DAM_BASE, DAM_CENTRE, DAM_CLEARANCE, DAM_CORE_BASE, DAM_CORE_CREST, DAM_CORE_LEAN,
    DAM_CREST, DAM_EXAMPLE, DAM_FACE, DAM_HEIGHT, DAM_MIN_ZONE, DAM_SPLIT, DAM_UPSTREAM_RUN, FOUR_LAYER_CLEARANCE,
    FOUR_LAYER_SLOPE, MOUND_BASE, MOUND_CENTRE, MOUND_CREST, MOUND_FACE, MOUND_HEIGHT, MOUND_LAYERS, MOUND_LEFT_RUN,
    MOUND_MIN_LAYER, STAGES, family_sequence, sample_for_index, vertex_ranges,
)
from runout.scene import MAX_FRAMES, Scene, TimeSpec, save_scene
from runout.npz import SafeNpz, numeric
from runout.simfiles import Moments, Simulation, check_simulation, write_metadata, write_simulations
from runout.trajectory import Trajectory

MIN_COUNT = 10  # so that the valid and test splits (k mod 10 = 8, 9) are never empty
# a default model's window and the frame after it, so a model trains on the data with or without rest windows
MIN_FRAMES = WindowSchema().window_frames + 1
MAX_COUNT = 1_000_000
MAX_BATCH = 1024

Simulate = Callable[..., list[Trajectory]]  # simulate(scenes, device=..., progress=...)


@dataclass(frozen=True)
class GenerateConfig:
    """What a dataset is made of; two runs with equal configs write equal datasets."""

    stage: str
    count: int  # scenes
    seed: int = 0
    batch: int = 16  # scenes per MPM batch (and per part file)
    frames: int = 480  # output frames per scene, frame 0 included
    cell_size: float = 4.0  # m; the paper's 4 m, coarser only for quick tests

    def check(self) -> None:
        if self.stage not in STAGES:
            raise InputError(f"stage = {self.stage!r} must be one of {', '.join(STAGES)}.")
        if self.count < MIN_COUNT:
            raise InputError(f"count = {self.count} must be at least {MIN_COUNT} so every split gets scenes.")
        if self.count > MAX_COUNT:
            raise InputError(f"count = {self.count} is outside the allowed range [{MIN_COUNT}, {MAX_COUNT}].")
        if not 1 <= self.batch <= MAX_BATCH:
            raise InputError(f"batch = {self.batch} is outside the allowed range [1, {MAX_BATCH}].")
        if self.frames < MIN_FRAMES:
            raise InputError(f"frames = {self.frames} must be at least {MIN_FRAMES} (the GNS reads "
                             f"{WindowSchema().window_frames}-frame windows).")
        if self.frames > MAX_FRAMES:
            raise InputError(f"frames = {self.frames} is outside the allowed range [{MIN_FRAMES}, {MAX_FRAMES}].")
        if not 1.0 <= self.cell_size <= 16.0:
            raise InputError(f"cell_size = {self.cell_size:g} m is outside the allowed range [1, 16] m.")

    @property
    def n_batches(self) -> int:
        return -(-self.count // self.batch)

    def batch_scenes(self, j: int) -> range:
        return range(j * self.batch, min((j + 1) * self.batch, self.count))


def split_of(k: int) -> str:
    """80/10/10 split by scene index."""
    return {8: "valid", 9: "test"}.get(k % 10, "train")


def scene_for(config: GenerateConfig, k: int, family: str) -> Scene:
    """Scene k of the dataset, with the config's frames and cell size."""
    scene = sample_for_index(STAGES[config.stage], config.seed, k, family).scene
    domain = replace(scene.domain, cell_size=config.cell_size)
    return replace(scene, domain=domain, time=replace(scene.time, frames=config.frames))


def shard_from_env(env: dict) -> tuple[int, int]:
    """(rank, world size) from torchrun's RANK / WORLD_SIZE, or (0, 1)."""
    return int(env.get("RANK", 0)), int(env.get("WORLD_SIZE", 1))


def parse_shard(text: str) -> tuple[int, int]:
    """'i/n' -> (i, n) with 0 <= i < n."""
    try:
        i, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise InputError(f"--shard {text!r} must look like i/n, e.g. 0/4.") from None
    if not 0 <= i < n:
        raise InputError(f"--shard {text!r}: the shard index must lie in [0, {n - 1}].")
    return i, n


# ----------------------------------------------------------------------------- generation


def generate(
    config: GenerateConfig,
    out_dir: str | Path,
    shard: tuple[int, int] = (0, 1),
    device: str = "cpu",
    simulate: Simulate | None = None,
    progress: bool = True,
) -> bool:
    """Generate this shard's batches into out_dir, skipping parts already written. An
    unsharded run then writes the dataset files; returns True when it did."""
    config.check()
    from runout.mpm.budget import check_budget

    if simulate is None:
        from runout.mpm import simulate
    out = Path(out_dir)
    _claim(out, config)
    families = family_sequence(STAGES[config.stage], config.count)
    mine = [j for j in range(config.n_batches) if j % shard[1] == shard[0]]
    todo = [j for j in mine if not _part_path(out, j).is_file()]
    _check_parts(out, config, [j for j in mine if j not in todo])
    done = sum(len(config.batch_scenes(j)) for j in mine if j not in todo)
    total = sum(len(config.batch_scenes(j)) for j in mine)
    desc = f"{config.stage} {shard[0]}/{shard[1]}" if shard[1] > 1 else config.stage
    with tqdm(total=total, initial=done, desc=desc, unit="scene", disable=not progress) as bar:
        for j in todo:
            indices = config.batch_scenes(j)
            scenes = [scene_for(config, k, families[k]) for k in indices]
            for k, scene in zip(indices, scenes):
                save_scene(scene, out / "scenes" / f"{scene.name}.toml")
            check_budget(scenes, device=device, source=f"batch {j} of {out}")
            trajs = simulate(scenes, device=device, progress=False)
            _check_finite(out, scenes, trajs)
            _write_part(out, j, indices, trajs, STAGES[config.stage].feature_width, device)
            bar.update(len(indices))
    if shard[1] > 1:
        return False
    write_dataset(config, [out], out)
    return True


def _check_finite(out: Path, scenes: list[Scene], trajs: list[Trajectory]) -> None:
    for scene, traj in zip(scenes, trajs):
        bad = traj.first_nonfinite_frame()
        if bad is not None:
            raise RunFailed(
                f"the MPM run of {out / 'scenes' / scene.name}.toml diverged (positions are not finite from frame {bad}); "
                "the batches before it are kept."
            )


def _claim(out: Path, config: GenerateConfig) -> None:
    """Create out/ with its generate.json, or check that an existing one asks for the same."""
    (out / "scenes").mkdir(parents=True, exist_ok=True)
    (out / "parts").mkdir(exist_ok=True)
    path = out / "generate.json"
    if path.is_file():
        found = _read_config(out)
        if found != config:
            raise InputError(
                f"{path}: this directory holds a different dataset ({_describe(found)}); "
                f"use a new --out for {_describe(config)}."
            )
        return
    record = {**asdict(config), "code_version": code_version()}
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(record, indent=2))
    tmp.replace(path)


def _read_config(directory: Path) -> GenerateConfig:
    """The GenerateConfig of directory/generate.json, every field typed and in range."""
    path = directory / "generate.json"
    if not path.is_file():
        raise InputError(f"{directory}: no generate.json; not a directory made by `runout generate`.")
    data = checks.json_table(path, "generate.json")
    data.pop("code_version", None)
    kinds = {"stage": str, "count": int, "seed": int, "batch": int, "frames": int, "cell_size": (int, float)}
    for key, kind in kinds.items():
        value = data.get(key)
        if isinstance(value, bool) or not isinstance(value, kind):
            words = {str: "text", int: "a whole number"}.get(kind, "a number")
            raise InputError(f"{path}: {key} = {checks.show(value)} must be {words}.")
    unknown = sorted(set(data) - set(kinds))
    if unknown:
        raise InputError(f"{path}: unknown key '{unknown[0]}'; generate.json holds {', '.join(kinds)} and code_version.")
    config = GenerateConfig(**data)
    try:
        config.check()
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
    return config


def _describe(c: GenerateConfig) -> str:
    return f"stage {c.stage}, count {c.count}, seed {c.seed}, batch {c.batch}, frames {c.frames}, cell {c.cell_size:g} m"


def code_version() -> str:
    """Package version, plus the git commit when running from a checkout."""
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=Path(runout.__file__).parent,
            capture_output=True, text=True, timeout=10, check=True,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return runout.__version__
    return f"{runout.__version__}+g{commit}"


def _part_path(out: Path, j: int) -> Path:
    return out / "parts" / f"part_{j:05d}.npz"


def _write_part(out: Path, j: int, indices: range, trajs: list[Trajectory], width: int, device: str) -> None:
    arrays = {"scenes": np.asarray(indices, dtype=np.int64), "device": np.asarray(device)}
    for k, traj in zip(indices, trajs):
        arrays[f"positions_{k}"] = traj.positions.astype(np.float32)
        arrays[f"particle_type_{k}"] = traj.particle_type.astype(np.int64)
        arrays[f"material_{k}"] = traj.material_features(width)
    path = _part_path(out, j)
    tmp = path.with_name(path.stem + ".tmp.npz")
    np.savez(tmp, **arrays)
    tmp.replace(path)


# ----------------------------------------------------------------------------- dataset files


def merge(dirs: list[str | Path], out_dir: str | Path) -> Path:
    """Join the parts of shard directories (same config) into one dataset in out_dir."""
    if not dirs:
        raise InputError("merge needs at least one shard directory.")
    dirs = [Path(d) for d in dirs]
    config = _read_config(dirs[0])
    for d in dirs[1:]:
        other = _read_config(d)
        if other != config:
            raise InputError(f"{d}: holds {_describe(other)} but {dirs[0]} holds {_describe(config)}; only shards of one run merge.")
    out = Path(out_dir)
    _claim(out, config)
    for d in dirs:
        if d.resolve() != out.resolve():
            for toml in sorted((d / "scenes").glob("*.toml")):
                shutil.copyfile(toml, out / "scenes" / toml.name)
    write_dataset(config, dirs, out)
    return out


def write_dataset(config: GenerateConfig, part_dirs: list[Path], out: Path) -> None:
    """Write train/valid/test.npz and metadata.json from the finished parts."""
    parts = _find_parts(config, part_dirs)
    stage = STAGES[config.stage]
    moments = Moments()
    devices: set[str] = set()
    splits = {name: [k for k in range(config.count) if split_of(k) == name] for name in SPLITS}
    for name in SPLITS:
        sims = _split_simulations(config, parts, name, devices)
        if name == "train":
            sims = _accumulate(sims, moments)
        write_simulations(out / f"{name}.npz", sims, compress=False)
    meta = moments.metadata(
        bounds=[[0.0, stage.width], [0.0, stage.height]], radius=radius_for_spacing(spacing_for_cells(config.cell_size)),
        dt=TimeSpec().frame_dt,
    )
    families = family_sequence(stage, config.count)
    meta.update(
        {
            "material_features": list(MATERIAL_FEATURE_NAMES[: stage.feature_width]),
            "statistics_from": "train",
            "stage": stage.name,
            "seed": config.seed,
            "count": config.count,
            "batch": config.batch,
            "frames": config.frames,
            "cell_size": config.cell_size,
            "ranges": _ranges(stage),
            "family_counts": dict(Counter(families)),
            "scene_families": families,
            "splits": splits,
            "devices": sorted(devices),
            "code_version": checks.json_table(part_dirs[0] / "generate.json", "generate.json").get("code_version"),
        }
    )
    write_metadata(out / "metadata.json", meta)


def _find_parts(config: GenerateConfig, dirs: list[Path]) -> dict[int, Path]:
    parts: dict[int, Path] = {}
    for d in dirs:
        for j in range(config.n_batches):
            if j not in parts and _part_path(d, j).is_file():
                parts[j] = _part_path(d, j)
    missing = [j for j in range(config.n_batches) if j not in parts]
    if missing:
        raise InputError(
            f"{len(missing)} of {config.n_batches} batches are not finished (first missing: part_{missing[0]:05d}); "
            "run the missing shards, then merge."
        )
    return parts


def _split_simulations(config: GenerateConfig, parts: dict[int, Path], name: str, devices: set) -> Iterator[Simulation]:
    """The simulations of one split in scene order, read lazily from the parts (through
    runout.npz.SafeNpz, each checked as a dataset's simulations are)."""
    for j in range(config.n_batches):
        with SafeNpz(parts[j]) as part:
            scenes = _part_scenes(part, config, j)
            devices.add(part.text("device"))
            for k in scenes:
                if split_of(k) == name:
                    item = (part[f"positions_{k}"], part[f"particle_type_{k}"], part[f"material_{k}"])
                    yield check_simulation(part.path, k, item)


def _part_scenes(part: SafeNpz, config: GenerateConfig, j: int) -> list[int]:
    """The scene indices a part file records, which must be batch j's."""
    scenes = numeric(part["scenes"], "scenes", part.path).tolist()
    expected = list(config.batch_scenes(j))
    if scenes != expected:
        raise InputError(f"{part.path}: scenes = {scenes} must be batch {j}'s scenes {expected}; "
                         "remove the file and run the same command to redo the batch.")
    return scenes


def _check_parts(out: Path, config: GenerateConfig, batches: list[int]) -> None:
    """The finished parts a resumed run keeps record the scenes of their batch."""
    for j in batches:
        with SafeNpz(_part_path(out, j)) as part:
            _part_scenes(part, config, j)


def _accumulate(sims: Iterator[Simulation], moments: Moments) -> Iterator[Simulation]:
    for sim in sims:
        moments.add(sim[0])
        yield sim


def _ranges(stage) -> dict:
    return {
        "friction_angle_deg": list(stage.friction_range),
        "cohesion_kpa": list(stage.cohesion_range) if stage.cohesion_range else None,
        "domain_m": [stage.width, stage.height],
        "block_side_m": list(BLOCK_SIDE),
        "block_velocity_m_per_s": list(BLOCK_SPEED),
        "vertices_m": {f: vertex_ranges(f, stage.width) for f in stage.mix
                       if f not in ("mound", "zoned_dam") and not (f == "column" and stage.column_base is not None)},
        **({"column_base_m": list(stage.column_base), "column_aspect": list(stage.column_aspect)}
           if stage.column_base is not None else {}),
        **({"mound": _mound_ranges()} if "mound" in stage.mix else {}),
        **({"zoned_dam": _dam_ranges()} if "zoned_dam" in stage.mix else {}),
        **({"undrained_share": stage.undrained_share} if stage.undrained_share else {}),
    }


def _mound_ranges() -> dict:
    return {
        "base_m": list(MOUND_BASE), "height_m": list(MOUND_HEIGHT), "crest_share": list(MOUND_CREST),
        "left_run_share": list(MOUND_LEFT_RUN), "face_deg": list(MOUND_FACE), "centre_x_m": list(MOUND_CENTRE),
        "layers": list(MOUND_LAYERS), "min_layer_m": MOUND_MIN_LAYER,
        "excluded_base_height_crest_m": list(FOUR_LAYER_SLOPE), "excluded_within_m": FOUR_LAYER_CLEARANCE,
    }


def _dam_ranges() -> dict:
    return {
        "base_m": list(DAM_BASE), "height_m": list(DAM_HEIGHT), "crest_m": list(DAM_CREST),
        "upstream_run_share": list(DAM_UPSTREAM_RUN), "face_deg": list(DAM_FACE), "centre_x_m": list(DAM_CENTRE),
        "core_base_m": list(DAM_CORE_BASE), "core_crest_share": list(DAM_CORE_CREST),
        "core_lean_deg": list(DAM_CORE_LEAN), "split_share": list(DAM_SPLIT), "min_zone_m": DAM_MIN_ZONE,
        "excluded_base_height_crest_m": list(DAM_EXAMPLE), "excluded_within_m": DAM_CLEARANCE,
    }

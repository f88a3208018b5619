"""GNS datasets: a directory of train/valid/test split files and one metadata.json.

The file layout itself (reading and writing splits and metadata, statistics) is
runout.simfiles; this module sees a dataset whole: its summary, and trajectory k of a split.
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from runout import checks
from runout.contract import WindowSchema
from runout.defaults import FRAME_DT, PARTICLE_TYPE_KINEMATIC
from runout.errors import InputError
from runout.reading import folder_to_read
from runout.simfiles import Simulation, iter_simulations, read_metadata, read_simulations
from runout.trajectory import Trajectory, trajectory_from_features

SPLITS = ("train", "valid", "test")
NEW_MODEL_TYPES = WindowSchema.particle_types  # rows of the type embedding `runout train` gives a new model


def load_split_trajectory(dataset: str | Path, split: str = "test", index: int = 0) -> Trajectory:
    """Simulation `index` of DATASET/SPLIT.npz as a Trajectory named SPLIT_INDEX, with the
    frame dt (FRAME_DT when the metadata has none) and bounds of DATASET/metadata.json; its
    material_width is the number of material features the file holds (0 for none)."""
    dataset = Path(dataset)
    sims = read_simulations(dataset / f"{split}.npz")
    if not 0 <= index < len(sims):
        raise InputError(f"{dataset / f'{split}.npz'}: index {index} is outside [0, {len(sims) - 1}].")
    return _trajectory(sims[index], read_metadata(dataset), f"{split}_{index}")


def split_trajectories(dataset: str | Path, split: str = "test", limit: int | None = None) -> Iterator[Trajectory]:
    """The first `limit` (all when None) simulations of DATASET/SPLIT.npz, read one at a
    time, as load_split_trajectory gives them."""
    dataset = Path(dataset)
    meta = read_metadata(dataset)
    k = -1
    for k, sim in enumerate(itertools.islice(iter_simulations(dataset / f"{split}.npz"), limit)):
        yield _trajectory(sim, meta, f"{split}_{k}")
    if k < 0 and limit != 0:
        raise InputError(f"{dataset / f'{split}.npz'}: holds no simulations.")


def _trajectory(sim: Simulation, meta: dict, name: str) -> Trajectory:
    positions, ptype, material = sim
    return trajectory_from_features(positions, ptype, material, meta.get("dt", FRAME_DT), meta["bounds"], name)


# ----------------------------------------------------------------------------- whole datasets


def summarize(path: str | Path) -> dict:
    """Counts, frames, points, position and feature ranges of a dataset directory (its
    metadata.json and every split present) or of one split file. Raises InputError when a
    file is malformed or the splits disagree on the number of material features."""
    path = Path(path)
    if path.is_file():
        return {"splits": {path.stem: _summarize_split(path)}, "checked": _checked(None, path)}
    folder_to_read(path, "dataset folder or split file")
    files = {name: path / f"{name}.npz" for name in SPLITS if (path / f"{name}.npz").is_file()}
    if not files:
        raise InputError(f"{path}: holds none of {', '.join(f'{n}.npz' for n in SPLITS)}.")
    meta = read_metadata(path)
    splits = {name: _summarize_split(f) for name, f in files.items()}
    widths = {name: s["material_width"] for name, s in splits.items()}
    if "material_features" in meta:
        widths["metadata.json"] = len(meta["material_features"])
    first = next(iter(widths))
    for name, w in widths.items():
        if w != widths[first]:
            raise InputError(
                f"{path}: {name} has {w} material features but {first} has {widths[first]}; "
                "every split must use the same material features."
            )
    return {"metadata": meta, "splits": splits, "checked": _checked(meta, path / "metadata.json")}


def _checked(meta: dict | None, source: Path) -> list[str]:
    """What summarize checked, as `runout inspect` reports it."""
    lines = ["every simulation: positions [T >= 7, N, 2] finite, particle_type [N], material features [N, 1 or 2] "
             f"finite, particle types within [0, {NEW_MODEL_TYPES - 1}], the {NEW_MODEL_TYPES} types a new model embeds"]
    if meta is not None:
        lo, hi, _ = checks.radius_range(meta, source)
        lines.append(f"metadata.json: dim 2, bounds increasing, dt in (0, {checks.MAX_FRAME_DT:g}] s, statistics finite "
                     f"with std > 0, connectivity radius {meta['default_connectivity_radius']:g} m within "
                     f"{checks.span(lo, hi, ' m', lo_open=lo == 0.0)}, material feature names")
    return lines


def _summarize_split(path: Path) -> dict:
    frames, points, kinematic, types = [], [], 0, []
    lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
    f_lo = f_hi = None
    width = 0
    for positions, ptype, material in iter_simulations(path):
        frames.append(positions.shape[0])
        points.append(positions.shape[1])
        kinematic += int((ptype == PARTICLE_TYPE_KINEMATIC).sum())
        types.append(np.unique(ptype))
        lo = np.minimum(lo, positions.min(axis=(0, 1)))
        hi = np.maximum(hi, positions.max(axis=(0, 1)))
        width = 0 if material is None else material.shape[1]
        if material is not None:
            f_lo = material.min(axis=0) if f_lo is None else np.minimum(f_lo, material.min(axis=0))
            f_hi = material.max(axis=0) if f_hi is None else np.maximum(f_hi, material.max(axis=0))
    if not frames:
        raise InputError(f"{path}: holds no simulations.")
    checks.particle_types(types, NEW_MODEL_TYPES, path, "a new model")
    return {
        "simulations": len(frames),
        "frames": [min(frames), max(frames)],
        "points": [min(points), max(points)],
        "points_total": int(sum(points)),
        "kinematic_points": kinematic,
        "position_range": np.stack([lo, hi], axis=1).tolist(),  # [[x_lo, x_hi], [y_lo, y_hi]] m
        "material_width": width,
        "particle_types": sorted(set(np.concatenate(types).tolist())),
        "material_range": None if f_lo is None else np.stack([f_lo, f_hi], axis=1).tolist(),
    }


def format_summary(path: str | Path, summary: dict) -> str:
    """The summary as the text `runout inspect` prints."""
    lines = [f"dataset {path}"]
    meta = summary.get("metadata")
    for name, s in summary["splits"].items():
        (x0, x1), (y0, y1) = s["position_range"]
        lines.append(
            f"  {name}: {s['simulations']} simulations, frames {s['frames'][0]}-{s['frames'][1]}, "
            f"points {s['points'][0]}-{s['points'][1]} ({s['kinematic_points']} of {s['points_total']} kinematic), "
            f"x {x0:.1f}..{x1:.1f} m, y {y0:.1f}..{y1:.1f} m, particle types {s['particle_types']}"
        )
        if s["material_range"] is not None:
            ranges = ", ".join(f"{lo:.3f}..{hi:.3f}" for lo, hi in s["material_range"])
            names = meta.get("material_features", []) if meta else []
            lines.append(f"    material features {names or s['material_width']}: {ranges}")
    if meta:
        for key in ("stage", "seed", "count", "code_version"):
            if key in meta:
                lines.append(f"  {key}: {meta[key]}")
        if "ranges" in meta:
            lines.append(f"  ranges: {json.dumps(meta['ranges'])}")
        lines.append(f"  bounds {meta['bounds']} m, connectivity radius {meta['default_connectivity_radius']:g} m, "
                     f"sequence length {meta['sequence_length']}")
        for key in ("vel_mean", "vel_std", "acc_mean", "acc_std"):
            lines.append(f"  {key}: [{', '.join(f'{v:.4e}' for v in meta[key])}] (per frame)")
    lines += [f"  checked: {line}" for line in summary["checked"]]
    return "\n".join(lines)

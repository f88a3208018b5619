"""GNS datasets: train/valid/test npz files and metadata.json (geoelements/gns layout).

Each split file holds simulations as tuples (positions [T, N, 2], particle_type [N],
material [N, k]), either as a dict of simulations {"simulation_0": tuple, ...} or as one
object array under the key "gns_data". Statistics are in per-frame units: v = x_t - x_{t-1},
a = v_t - v_{t-1} (m per frame, m per frame^2), pooled over every point and frame.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from runout.errors import InputError
from runout.trajectory import RADIUS_PER_SPACING, Trajectory, gns_tuple

REQUIRED_METADATA = (
    "bounds", "default_connectivity_radius", "dim", "sequence_length",
    "vel_mean", "vel_std", "acc_mean", "acc_std",
)

Simulation = tuple[np.ndarray, np.ndarray, np.ndarray | None]


def read_simulations(path: str | Path) -> list[Simulation]:
    """Read every simulation of a split file, in either layout, checking shapes and NaNs."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such dataset file.")
    try:
        archive = np.load(path, allow_pickle=True)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable npz file ({exc}).") from None
    with archive:
        if "gns_data" in archive.files:
            items = list(archive["gns_data"])
        else:
            keys = sorted(archive.files, key=_simulation_order)
            items = [archive[k] for k in keys]
    sims = []
    for k, item in enumerate(items):
        sims.append(_check_simulation(path, k, tuple(item)))
    if not sims:
        raise InputError(f"{path}: holds no simulations.")
    return sims


def _simulation_order(key: str):
    tail = key.rsplit("_", 1)[-1]
    return (0, int(tail), key) if tail.isdigit() else (1, 0, key)


def _check_simulation(path: Path, k: int, item: tuple) -> Simulation:
    if len(item) not in (2, 3):
        raise InputError(
            f"{path}: simulation {k} has {len(item)} entries; expected (positions, particle_type[, material])."
        )
    positions = np.asarray(item[0])
    if positions.ndim != 3 or positions.shape[2] != 2 or positions.shape[0] < 7:
        raise InputError(
            f"{path}: simulation {k} positions have shape {positions.shape}; expected [T >= 7, N, 2]."
        )
    if not np.isfinite(positions).all():
        raise InputError(f"{path}: simulation {k} positions contain NaN or infinite values.")
    n = positions.shape[1]
    ptype = np.asarray(item[1])
    if ptype.ndim == 0:
        ptype = np.full(n, int(ptype), dtype=np.int64)
    if ptype.shape != (n,):
        raise InputError(f"{path}: simulation {k} particle_type has shape {ptype.shape}; expected ({n},).")
    material = None
    if len(item) == 3 and item[2] is not None:
        material = np.asarray(item[2], dtype=np.float32)
        if material.ndim == 0:
            material = np.full((n, 1), float(material), dtype=np.float32)
        material = material.reshape(n, -1) if material.size % n == 0 else material
        if material.shape[0] != n:
            raise InputError(
                f"{path}: simulation {k} material has shape {material.shape}; expected ({n}, k)."
            )
        if not np.isfinite(material).all():
            raise InputError(f"{path}: simulation {k} material features contain NaN or infinite values.")
    return positions.astype(np.float32), ptype.astype(np.int64), material


def write_simulations(path: str | Path, sims: list[Simulation], layout: str = "dict") -> None:
    """Write simulations atomically in the dict layout (default) or the gns_data layout."""
    path = Path(path)
    tuples = []
    for positions, ptype, material in sims:
        t = np.empty(3 if material is not None else 2, dtype=object)
        t[0] = np.asarray(positions, dtype=np.float32)
        t[1] = np.asarray(ptype, dtype=np.int64)
        if material is not None:
            t[2] = np.asarray(material, dtype=np.float32)
        tuples.append(t)
    tmp = path.with_name(path.stem + ".tmp.npz")
    if layout == "dict":
        np.savez_compressed(tmp, **{f"simulation_{k}": t for k, t in enumerate(tuples)})
    elif layout == "gns_data":
        arr = np.empty(len(tuples), dtype=object)
        for k, t in enumerate(tuples):
            arr[k] = t
        np.savez_compressed(tmp, gns_data=arr)
    else:
        raise ValueError(f"unknown layout {layout!r}; use 'dict' or 'gns_data'")
    tmp.replace(path)


def trajectories_to_simulations(trajs: list[Trajectory], feature_width: int) -> list[Simulation]:
    return [tuple(gns_tuple(t, feature_width)) for t in trajs]


def statistics(sources, radius: float | None = None) -> dict:
    """GNS metadata statistics pooled over every point and frame of the given trajectories
    or (positions, ...) simulations, in per-frame units; float64 accumulation."""
    n_v = n_a = 0
    s_v = np.zeros(2)
    ss_v = np.zeros(2)
    s_a = np.zeros(2)
    ss_a = np.zeros(2)
    lo = np.full(2, np.inf)
    hi = np.full(2, -np.inf)
    seq_len = 0
    dt = None
    bounds = None
    for src in sources:
        if isinstance(src, Trajectory):
            pos = src.positions.astype(np.float64)
            dt = src.frame_dt
            bounds = src.bounds
        else:
            pos = np.asarray(src[0], dtype=np.float64)
        v = pos[1:] - pos[:-1]
        a = v[1:] - v[:-1]
        n_v += v.shape[0] * v.shape[1]
        n_a += a.shape[0] * a.shape[1]
        s_v += v.sum(axis=(0, 1))
        ss_v += (v**2).sum(axis=(0, 1))
        s_a += a.sum(axis=(0, 1))
        ss_a += (a**2).sum(axis=(0, 1))
        lo = np.minimum(lo, pos.min(axis=(0, 1)))
        hi = np.maximum(hi, pos.max(axis=(0, 1)))
        seq_len = max(seq_len, pos.shape[0])
    vel_mean = s_v / max(n_v, 1)
    acc_mean = s_a / max(n_a, 1)
    vel_std = np.sqrt(np.maximum(ss_v / max(n_v, 1) - vel_mean**2, 0.0))
    acc_std = np.sqrt(np.maximum(ss_a / max(n_a, 1) - acc_mean**2, 0.0))
    if bounds is None:
        bounds = np.stack([lo, hi], axis=1)
    if radius is None:
        radius = RADIUS_PER_SPACING * 2.0
    return {
        "bounds": np.asarray(bounds, dtype=float).tolist(),
        "sequence_length": int(seq_len),
        "default_connectivity_radius": float(radius),
        "dim": 2,
        "dt": float(dt) if dt is not None else 0.0375,
        "vel_mean": vel_mean.tolist(),
        "vel_std": vel_std.tolist(),
        "acc_mean": acc_mean.tolist(),
        "acc_std": acc_std.tolist(),
    }


def read_metadata(path: str | Path, mode: str = "train") -> dict:
    """Read metadata.json (flat, or split into "train"/"rollout"), checking required keys."""
    path = Path(path)
    if path.is_dir():
        path = path / "metadata.json"
    if not path.is_file():
        raise InputError(f"{path}: no such metadata file.")
    try:
        meta = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc}).") from None
    if mode in meta and isinstance(meta[mode], dict):
        meta = {**meta, **meta[mode]}
    missing = [k for k in REQUIRED_METADATA if k not in meta]
    if missing:
        raise InputError(f"{path}: missing required key '{missing[0]}' (needs {', '.join(REQUIRED_METADATA)}).")
    return meta


def write_metadata(path: str | Path, meta: dict) -> None:
    path = Path(path)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(meta, indent=2))
    tmp.replace(path)

"""The GNS exchange files (geoelements/gns layout): split npz files and metadata.json.

Each split file holds simulations as tuples (positions [T, N, 2], particle_type [N],
material [N, k]), either as a dict of simulations {"simulation_0": tuple, ...} or as one
object array under the key "gns_data". Statistics are in per-frame units: v = x_t - x_{t-1},
a = v_t - v_{t-1} (m per frame, m per frame^2), pooled over every point and frame.

This is the bottom layer of the data model: runout.trajectory (one run) and
runout.dataset (whole datasets) both build on it, and it imports neither.
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from runout import checks
from runout.contract import radius_for_spacing, spacing_for_cells
from runout.defaults import CELL_SIZE, FRAME_DT
from runout.errors import InputError
from runout.npz import SafeNpz, numeric
from runout.reading import file_to_read

REQUIRED_METADATA = (
    "bounds", "default_connectivity_radius", "dim", "sequence_length",
    "vel_mean", "vel_std", "acc_mean", "acc_std",
)

MAX_MATERIAL_WIDTH = 2  # [tan phi, c / 100 kPa]
MAX_PARTICLE_TYPE = 2**31 - 1  # a type is an index into a model's type table

Simulation = tuple[np.ndarray, np.ndarray, np.ndarray | None]


def read_simulations(path: str | Path) -> list[Simulation]:
    """Read every simulation of a split file, in either layout, checking shapes, NaNs and
    that all simulations have the same number of material features."""
    sims = list(iter_simulations(path))
    if not sims:
        raise InputError(f"{path}: holds no simulations.")
    return sims


def iter_simulations(path: str | Path) -> Iterator[Simulation]:
    """Yield the simulations of a split file one at a time (the dict layout is read lazily,
    so a large file never sits in memory whole), with the checks of read_simulations.
    Files are read with runout.npz.SafeNpz: a pickle that asks for more than numpy arrays
    is refused, never run."""
    path = file_to_read(path, "dataset file")
    with SafeNpz(path) as archive:
        width = None
        for k, item in enumerate(_items(archive)):
            sim = check_simulation(path, k, item)
            w = _material_width(sim)
            if width is None:
                width = w
            elif w != width:
                raise InputError(
                    f"{path}: simulation {k} has {w} material features but simulation 0 has {width}."
                )
            yield sim


def _items(archive: SafeNpz) -> Iterator[tuple]:
    """Each simulation as a tuple (positions, particle_type[, material]) from any layout:
    the gns_data object array, the dict of object arrays, or named numeric arrays
    positions_K, particle_type_K[, material_K] (no pickle at all)."""
    if "gns_data" in archive.files:
        data = archive["gns_data"]
        if data.dtype != object or data.ndim != 1:
            raise InputError(f"{archive.path}: gns_data has dtype {data.dtype} and shape {data.shape}; expected a 1-D object array of simulations.")
        for k, item in enumerate(data):
            yield _as_tuple(archive.path, k, item)
        return
    named = sorted((f for f in archive.files if f.startswith("positions_")), key=_simulation_order)
    if named:
        for key in named:
            k = key.rsplit("_", 1)[-1]
            if f"particle_type_{k}" not in archive.files:
                raise InputError(f"{archive.path}: has {key} but no particle_type_{k}.")
            material = (archive[f"material_{k}"],) if f"material_{k}" in archive.files else ()
            yield (archive[key], archive[f"particle_type_{k}"], *material)
        return
    for k, key in enumerate(sorted(archive.files, key=_simulation_order)):
        yield _as_tuple(archive.path, k, archive[key])


def _as_tuple(path: Path, k: int, item) -> tuple:
    if isinstance(item, np.ndarray) and item.dtype == object and item.ndim == 1:
        return tuple(item)
    if isinstance(item, tuple):
        return item
    kind = f"an array of dtype {item.dtype} and shape {item.shape}" if isinstance(item, np.ndarray) else f"a {type(item).__name__}"
    raise InputError(f"{path}: simulation {k} is {kind}; expected a tuple (positions, particle_type[, material]).")


def _material_width(sim: Simulation) -> int:
    return 0 if sim[2] is None else int(sim[2].shape[1])


def _simulation_order(key: str):
    tail = key.rsplit("_", 1)[-1]
    return (0, int(tail), key) if tail.isdigit() else (1, 0, key)


def check_simulation(path: Path, k: int, item: tuple) -> Simulation:
    """Simulation k of `path` as float32 positions [T >= 7, N, 2], int64 types [N] and float32
    material [N, width] or None, all finite; InputError naming what is malformed."""
    if len(item) not in (2, 3):
        raise InputError(
            f"{path}: simulation {k} has {len(item)} entries; expected (positions, particle_type[, material])."
        )
    positions = numeric(item[0], f"simulation {k} positions", path)
    if positions.ndim != 3 or positions.shape[2] != 2 or positions.shape[0] < 7:
        raise InputError(
            f"{path}: simulation {k} positions have shape {positions.shape}; expected [T >= 7, N, 2]."
        )
    if not np.isfinite(positions).all():
        raise InputError(f"{path}: simulation {k} positions contain NaN or infinite values.")
    n = positions.shape[1]
    ptype = _particle_types(path, k, numeric(item[1], f"simulation {k} particle_type", path), n)
    material = None
    if len(item) == 3 and item[2] is not None:
        material = _material(path, k, numeric(item[2], f"simulation {k} material", path), n)
    return positions.astype(np.float32), ptype.astype(np.int64), material


def _particle_types(path: Path, k: int, ptype: np.ndarray, n: int) -> np.ndarray:
    """[N] from a scalar or (N,), every type a whole number no larger than MAX_PARTICLE_TYPE
    (the range of the model's own type table is checked later, runout.checks.particle_types)."""
    if ptype.ndim == 0:
        ptype = np.full(n, ptype)
    if ptype.shape != (n,):
        raise InputError(f"{path}: simulation {k} particle_type has shape {ptype.shape}; expected ({n},).")
    with np.errstate(invalid="ignore"):
        bad = ~((np.abs(ptype) <= MAX_PARTICLE_TYPE) & (ptype == np.round(ptype)))  # NaN fails both
    if bad.any():
        value = checks.show(float(ptype[bad][0]))
        raise InputError(f"{path}: simulation {k} particle_type = {value} must be a whole number in [0, {MAX_PARTICLE_TYPE}].")
    return ptype


def _material(path: Path, k: int, material: np.ndarray, n: int) -> np.ndarray:
    """[N, width] float32 from a scalar, (N,) (the public GNS layout of one feature), (N, 1)
    or (N, 2)."""
    material = material.astype(np.float32)
    if material.ndim == 0:
        material = np.full((n, 1), float(material), dtype=np.float32)
    elif material.ndim == 1 and material.shape[0] == n:
        material = material[:, None]
    if material.ndim != 2 or material.shape[0] != n or not 1 <= material.shape[1] <= MAX_MATERIAL_WIDTH:
        raise InputError(
            f"{path}: simulation {k} material has shape {material.shape}; expected a scalar, ({n},), ({n}, 1) or ({n}, 2)."
        )
    if not np.isfinite(material).all():
        raise InputError(f"{path}: simulation {k} material features contain NaN or infinite values.")
    return material


def write_simulations(
    path: str | Path, sims: Iterable[Simulation], layout: str = "dict", compress: bool = True
) -> None:
    """Write simulations atomically in the dict layout (default) or the gns_data layout.
    The dict layout streams one simulation at a time; compress=False stores the arrays
    uncompressed (float trajectories barely compress, and storing is many times faster)."""
    if layout not in ("dict", "gns_data"):
        raise ValueError(f"unknown layout {layout!r}; use 'dict' or 'gns_data'")
    path = Path(path)
    tmp = path.with_name(path.stem + ".tmp.npz")
    tuples = (_object_tuple(sim) for sim in sims)
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(tmp, "w", compression=method, allowZip64=True) as archive:
        if layout == "dict":
            for k, t in enumerate(tuples):
                _write_array(archive, f"simulation_{k}", t)
        else:
            tuples = list(tuples)
            arr = np.empty(len(tuples), dtype=object)
            for k, t in enumerate(tuples):
                arr[k] = t
            _write_array(archive, "gns_data", arr)
    tmp.replace(path)


def _object_tuple(sim: Simulation) -> np.ndarray:
    positions, ptype, material = sim
    t = np.empty(3 if material is not None else 2, dtype=object)
    t[0] = np.asarray(positions, dtype=np.float32)
    t[1] = np.asarray(ptype, dtype=np.int64)
    if material is not None:
        t[2] = exchange_material(material)
    return t


def exchange_material(material: np.ndarray) -> np.ndarray:
    """Material features as written to files: one feature as (N,), which the public GNS
    code reads with np.full(n_particles, material); two as (N, 2)."""
    material = np.asarray(material, dtype=np.float32)
    return material[:, 0] if material.ndim == 2 and material.shape[1] == 1 else material


def _write_array(archive: zipfile.ZipFile, key: str, arr: np.ndarray) -> None:
    with archive.open(f"{key}.npy", "w", force_zip64=True) as f:
        np.lib.format.write_array(f, arr, allow_pickle=True)


class Moments:
    """Running GNS statistics of positions [T, N, 2]: per-frame velocities v = x_t - x_{t-1}
    and accelerations a = v_t - v_{t-1} pooled over every point and frame (float64 sums)."""

    def __init__(self) -> None:
        self.n_v = self.n_a = 0
        self.s_v, self.ss_v = np.zeros(2), np.zeros(2)
        self.s_a, self.ss_a = np.zeros(2), np.zeros(2)
        self.lo, self.hi = np.full(2, np.inf), np.full(2, -np.inf)
        self.sequence_length = 0

    def add(self, positions: np.ndarray) -> None:
        pos = np.asarray(positions, dtype=np.float64)
        v = pos[1:] - pos[:-1]
        a = v[1:] - v[:-1]
        self.n_v += v.shape[0] * v.shape[1]
        self.n_a += a.shape[0] * a.shape[1]
        self.s_v += v.sum(axis=(0, 1))
        self.ss_v += (v**2).sum(axis=(0, 1))
        self.s_a += a.sum(axis=(0, 1))
        self.ss_a += (a**2).sum(axis=(0, 1))
        self.lo = np.minimum(self.lo, pos.min(axis=(0, 1)))
        self.hi = np.maximum(self.hi, pos.max(axis=(0, 1)))
        self.sequence_length = max(self.sequence_length, pos.shape[0])

    def metadata(self, bounds=None, radius: float | None = None, dt: float | None = None) -> dict:
        """The GNS metadata keys; bounds default to the range the positions covered."""
        vel_mean = self.s_v / max(self.n_v, 1)
        acc_mean = self.s_a / max(self.n_a, 1)
        vel_std = np.sqrt(np.maximum(self.ss_v / max(self.n_v, 1) - vel_mean**2, 0.0))
        acc_std = np.sqrt(np.maximum(self.ss_a / max(self.n_a, 1) - acc_mean**2, 0.0))
        if bounds is None:
            bounds = np.stack([self.lo, self.hi], axis=1)
        return {
            "bounds": np.asarray(bounds, dtype=float).tolist(),
            "sequence_length": int(self.sequence_length),
            "default_connectivity_radius": float(radius_for_spacing(spacing_for_cells(CELL_SIZE)) if radius is None else radius),
            "dim": 2,
            "dt": float(FRAME_DT if dt is None else dt),
            "vel_mean": vel_mean.tolist(),
            "vel_std": vel_std.tolist(),
            "acc_mean": acc_mean.tolist(),
            "acc_std": acc_std.tolist(),
        }


def statistics(sources, radius: float | None = None, bounds=None, dt: float | None = None) -> dict:
    """GNS metadata statistics pooled over every point and frame of the given
    (positions, ...) simulations, in per-frame units; float64 accumulation."""
    moments = Moments()
    for src in sources:
        moments.add(src[0])
    return moments.metadata(bounds, radius, dt)


def read_metadata(path: str | Path, mode: str = "train") -> dict:
    """Read metadata.json (flat, or split into "train"/"rollout"), checking the required keys
    and every value a GNS reads (runout.checks.dataset_metadata)."""
    path = Path(path)
    if path.is_dir():
        path = path / "metadata.json"
    meta = checks.json_table(path, "metadata file")
    if mode in meta and isinstance(meta[mode], dict):
        meta = {**meta, **meta[mode]}
    missing = [k for k in REQUIRED_METADATA if k not in meta]
    if missing:
        raise InputError(f"{path}: missing required key '{missing[0]}' (needs {', '.join(REQUIRED_METADATA)}).")
    checks.dataset_metadata(meta, path)
    return meta


def write_metadata(path: str | Path, meta: dict) -> None:
    path = Path(path)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(meta, indent=2))
    tmp.replace(path)

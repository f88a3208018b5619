"""The checks of values runout reads from files and options, before any work: one place.

Every reader (dataset metadata.json, trajectory metadata, checkpoints, the particle types of
data given to a model, --device) calls these; each failure is an InputError whose message is
one sentence naming the file (or option), the field, the value and the allowed range, which
the command line turns into exit 2.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from runout.contract import MAX_RADIUS, WindowSchema, spacing_for_cells
from runout.errors import InputError
from runout.reading import read_json
from runout.scene.limits import MAX_DOMAIN, MAX_FRAMES, SMALLEST_SIZE

MAX_FRAME_DT = 10.0  # s between frames, as a scene's time.frame_dt allows
MAX_RADIUS_SPACINGS = 10.0  # a connectivity radius of more point spacings gives each point > 300 neighbours
DEVICE_TYPES = ("cpu", "cuda")


def show(value) -> str:
    """A value as a sentence shows it: numbers in %g, everything else as repr."""
    if isinstance(value, float):
        return f"{value:g}"
    return repr(value)


def span(lo: float, hi: float, unit: str = "", lo_open: bool = False, hi_open: bool = False) -> str:
    """'(0, 10] s', '[0, inf)', '(0, 1)' and the like."""
    return f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open or hi == math.inf else ']'}{unit}"


def number(value, field: str, source, lo: float = -math.inf, hi: float = math.inf, unit: str = "",
           lo_open: bool = False, whole: bool = False, note: str = "", hi_open: bool = False):
    """`value` when it is a finite (whole, if asked) number in the range, else InputError
    '{source}: {field} = {value} is outside the allowed range [lo, hi] unit ({note}).'
    (source None: an option, which the field names; lo_open, hi_open: the end is excluded)."""
    where = f"{source}: " if source is not None else ""
    allowed = span(lo, hi, unit, lo_open, hi_open) + (f" ({note})" if note else "")
    kinds = (int, np.integer) if whole else (int, float, np.integer, np.floating)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, kinds) or not math.isfinite(value):
        kind = "whole" if whole else "finite"
        raise InputError(f"{where}{field} = {show(value)} must be a {kind} number in {allowed}.")
    if value < lo or value > hi or (lo_open and value == lo) or (hi_open and value == hi):
        raise InputError(f"{where}{field} = {show(value)} is outside the allowed range {allowed}.")
    if lo_open and lo == 0 and value < SMALLEST_SIZE:
        raise InputError(f"{where}{field} = {show(value)} is outside the allowed range {allowed}: a positive size is "
                         f"at least {SMALLEST_SIZE:.3g}.")
    return value


def numbers(value, field: str, source, length: int, lo: float = -math.inf, unit: str = "", lo_open: bool = False) -> list:
    """A list of `length` finite numbers, each at least (above, when lo_open) lo."""
    if not isinstance(value, (list, tuple)) or len(value) != length:
        raise InputError(f"{source}: {field} = {show(value)} must be a list of {length} finite numbers{unit}.")
    return [number(v, f"{field}[{k}]", source, lo, unit=unit, lo_open=lo_open) for k, v in enumerate(value)]


def bounds(value, source, field: str = "bounds") -> np.ndarray:
    """[[x_lo, x_hi], [y_lo, y_hi]] in m: finite, each pair increasing."""
    if not isinstance(value, (list, tuple)) or len(value) != 2 or not all(isinstance(p, (list, tuple)) for p in value):
        raise InputError(f"{source}: {field} = {show(value)} must be [[x_lo, x_hi], [y_lo, y_hi]] in m.")
    for axis, pair in zip("xy", value):
        lo, hi = numbers(pair, f"{field} {axis}", source, 2, unit=" m")
        if not lo < hi:
            raise InputError(f"{source}: {field} {axis} = {show(list(pair))} must rise from {axis}_lo to a larger {axis}_hi.")
    return np.asarray(value, dtype=float)


def frame_dt(value, source, field: str = "dt") -> float:
    """Seconds between frames: finite, in (0, MAX_FRAME_DT]."""
    return float(number(value, field, source, 0.0, MAX_FRAME_DT, " s", lo_open=True))


def dataset_metadata(meta: dict, source) -> None:
    """Every value of a dataset's metadata.json a GNS reads: dim 2, bounds, dt, sequence
    length, statistics (per frame: finite, std > 0), the connectivity radius (above zero,
    within one to MAX_RADIUS_SPACINGS point spacings when cell_size says the spacing, and
    at most half the domain's longer side) and the material feature names."""
    number(meta["dim"], "dim", source, 2, 2, whole=True, note="runout is two-dimensional")
    bounds(meta["bounds"], source)
    if "dt" in meta:
        frame_dt(meta["dt"], source)
    number(meta["sequence_length"], "sequence_length", source, 1, MAX_FRAMES, " frames", whole=True)
    for key in ("vel_mean", "acc_mean"):
        numbers(meta[key], key, source, 2, unit=" m per frame")
    for key in ("vel_std", "acc_std"):
        numbers(meta[key], key, source, 2, 0.0, " m per frame", lo_open=True)
    lo, hi, note = radius_range(meta, source)
    number(meta["default_connectivity_radius"], "default_connectivity_radius", source, lo, hi, " m",
           lo_open=lo == 0.0, note=note)
    if "material_features" in meta:
        problem = WindowSchema.problem({"material_features": meta["material_features"]})
        if problem:
            raise InputError(f"{source}: {problem}.")


def radius_range(meta: dict, source) -> tuple[float, float, str]:
    """(lowest, highest, why) of a dataset's connectivity radius in m: above zero, or at
    least one point spacing when cell_size gives it, and at most MAX_RADIUS, half the longer
    side of the (checked) bounds and MAX_RADIUS_SPACINGS point spacings."""
    box = np.asarray(meta["bounds"], dtype=float)
    side = float((box[:, 1] - box[:, 0]).max())
    lo, hi, note = 0.0, min(MAX_RADIUS, side / 2), f"at most half the domain's longer side of {side:g} m"
    if "cell_size" in meta:
        cell = number(meta["cell_size"], "cell_size", source, 0.0, MAX_DOMAIN, " m", lo_open=True)
        spacing = spacing_for_cells(cell)
        lo, hi = spacing, min(hi, MAX_RADIUS_SPACINGS * spacing)
        note = f"1 to {MAX_RADIUS_SPACINGS:g} point spacings of {spacing:g} m, and {note}"
    return lo, hi, note


def trajectory_metadata(meta: dict, source) -> None:
    """What a trajectory's metadata.json must hold for runout to read it back: a table with
    bounds, and a finite positive dt, a name and a material table when present."""
    if "bounds" not in meta:
        raise InputError(f"{source}: missing the required key 'bounds'.")
    bounds(meta["bounds"], source)
    if "dt" in meta:
        frame_dt(meta["dt"], source)
    if not isinstance(meta.get("name", ""), str):
        raise InputError(f"{source}: name = {show(meta['name'])} must be text.")
    table = meta.get("materials", [])
    if not isinstance(table, list) or not all(isinstance(m, dict) for m in table):
        raise InputError(f"{source}: materials = {show(table)} must be a list of material tables.")
    if not isinstance(meta.get("info", {}), dict):
        raise InputError(f"{source}: info = {show(meta['info'])} must be a table.")


def particle_types(types: Iterable, table: int, source, model: str, first: int = 0) -> None:
    """InputError unless every particle type of every simulation (numbered from `first`) lies
    in [0, table - 1], the rows of `model`'s type embedding."""
    for k, sim_types in enumerate(types, first):
        t = np.asarray(sim_types)
        bad = t[(t < 0) | (t >= table)]
        if bad.size:
            raise InputError(
                f"{source}: simulation {k} particle_type = {int(bad[0])} is outside the allowed range "
                f"[0, {table - 1}] of the {table} types {model} embeds."
            )


def device(value: str, option: str = "--device", auto: bool = False) -> None:
    """InputError unless `value` names a device this machine runs runout on: cpu, cuda or
    cuda:K for a GPU K it has (and auto, when `auto`)."""
    if auto and value == "auto":
        return
    import torch  # here, not at the top: the file layers that use these checks stay torch-free

    try:
        dev = torch.device(value)
    except (RuntimeError, TypeError, ValueError):
        dev = None
    if dev is None or dev.type not in DEVICE_TYPES:
        choices = "auto, cpu, cuda or cuda:K" if auto else "cpu, cuda or cuda:K"
        raise InputError(f"{option} = {value!r} is not a device runout runs on; use {choices}.")
    if dev.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise InputError(f"{option} {value} was asked for but no CUDA GPU is available; use {option} cpu.")
        if dev.index is not None and dev.index >= count:
            raise InputError(f"{option} = {value!r} is outside the GPUs of this machine, cuda:0 to cuda:{count - 1}.")


def json_table(path: Path, what: str) -> dict:
    """The table a JSON file holds, or InputError naming the file (missing, not JSON, or a
    top level that is not a table)."""
    data = read_json(path, what)
    if not isinstance(data, dict):
        raise InputError(f"{path}: the top level is a {type(data).__name__}; it must be a table of keys.")
    return data

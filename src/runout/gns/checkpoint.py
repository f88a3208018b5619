"""GNS checkpoints: one file holding everything needed to rebuild, resume or fine-tune.

Keys: format, schema (node-feature layout), stats (normalisation), radius (m), network
(layer sizes), model (state dict), and for training runs optimizer, step, rng, train
(the training settings), data_ranges (what the model was trained on, see
runout.gns.training_range; its point_spacing_m is the spacing every GNS command fills a
scene at, Simulator.point_spacing). Files are written atomically (temporary file, then
os.replace), so a run killed while saving leaves the previous checkpoint intact.

Everything in a checkpoint is plain data (tensors, dicts, lists, numbers, strings), and it
is read with torch.load(weights_only=True): a file that asks the unpickler for any other
object is refused with one sentence and nothing in it runs.
"""

from __future__ import annotations

import math
import os
import pickle
import re
import warnings
from dataclasses import asdict, fields
from pathlib import Path

import torch

from runout.errors import InputError
from runout.gns.schema import FeatureSchema
from runout.gns.simulator import NetworkConfig, Normalisation, Simulator

FORMAT = "runout-gns-1"
REQUIRED_KEYS = ("format", "schema", "stats", "radius", "network", "model")
MAX_RADIUS = 1000.0  # m: a connectivity radius beyond this would join a whole domain into one clique


def checkpoint_dict(simulator: Simulator, **training_state) -> dict:
    return {
        "format": FORMAT,
        "schema": simulator.schema.to_dict(),
        "stats": simulator.stats.to_dict(),
        "radius": simulator.radius,
        "network": asdict(simulator.config),
        "model": simulator.state_dict(),
        **({"data_ranges": simulator.data_ranges} if simulator.data_ranges else {}),
        **training_state,
    }


def save_checkpoint(path: str | Path, simulator: Simulator, **training_state) -> Path:
    """Write atomically; training_state (optimizer, step, rng, train, ...) is stored as is."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(checkpoint_dict(simulator, **training_state), tmp)
    os.replace(tmp, path)
    return path


def read_checkpoint(path: str | Path) -> dict:
    """The checkpoint dictionary (tensors on CPU), checked for the keys a model needs and
    for plain data only (torch.load with weights_only=True)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such checkpoint file.")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # torch warns about pickle protocols of foreign files
            ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        raise InputError(_refusal(path, exc)) from None
    except Exception as exc:  # torch raises many types for a corrupt or foreign file
        raise InputError(f"{path}: not a readable PyTorch checkpoint ({type(exc).__name__}: {_first_line(exc)}).") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        found = ckpt.get("format") if isinstance(ckpt, dict) else type(ckpt).__name__
        raise InputError(f"{path}: format is {found!r}; expected a runout GNS checkpoint ({FORMAT!r}).")
    missing = [k for k in REQUIRED_KEYS if k not in ckpt]
    if missing:
        raise InputError(f"{path}: the checkpoint lacks the key '{missing[0]}'.")
    check_contents(ckpt, path)
    return ckpt


def _refusal(path: Path, exc: Exception) -> str:
    """One sentence for a file torch's plain-data unpickler stopped reading."""
    found = re.search(r"GLOBAL (\S+)", str(exc))
    if found:
        return (f"{path}: refused to load, because it holds the Python object '{found.group(1)}' "
                "rather than tensors and plain data (nothing in it was run).")
    detail = re.search(r"WeightsUnpickler error:\s*(.+)", str(exc))
    reason = detail.group(1).strip().rstrip(".") if detail else "not plain data"
    return f"{path}: not a readable PyTorch checkpoint of plain data ({reason}); nothing in it was run."


def _first_line(exc: Exception) -> str:
    return str(exc).strip().splitlines()[0].rstrip(".") if str(exc).strip() else "no detail"


def check_contents(ckpt: dict, path) -> None:
    """Raise InputError naming the first malformed entry of schema, stats, radius or network."""
    for key in ("schema", "stats", "network"):
        if not isinstance(ckpt[key], dict):
            raise InputError(f"{path}: the checkpoint's '{key}' is a {type(ckpt[key]).__name__}; expected a table.")
    radius = ckpt["radius"]
    if not _finite(radius) or not 0 < radius <= MAX_RADIUS:
        raise InputError(f"{path}: radius = {radius!r} is outside the allowed range (0, {MAX_RADIUS:g}] m.")
    _check_table(ckpt["network"], {f.name for f in fields(NetworkConfig)}, "network", path)
    problem = NetworkConfig.problem(ckpt["network"])
    if problem:
        raise InputError(f"{path}: network.{problem}.")
    _check_table(ckpt["schema"], {f.name for f in fields(FeatureSchema)}, "schema", path)
    problem = FeatureSchema.problem(ckpt["schema"])
    if problem:
        raise InputError(f"{path}: schema.{problem}.")
    _check_table(ckpt["stats"], {f.name for f in fields(Normalisation)}, "stats", path, require=True)
    problem = Normalisation.problem(ckpt["stats"])
    if problem:
        raise InputError(f"{path}: stats.{problem}.")
    ranges = ckpt.get("data_ranges")
    if ranges is not None and not isinstance(ranges, dict):
        raise InputError(f"{path}: the checkpoint's 'data_ranges' is a {type(ranges).__name__}; expected a table.")
    spacing = (ranges or {}).get("point_spacing_m")
    if spacing is not None and (not _finite(spacing) or not 0 < spacing <= MAX_RADIUS):
        raise InputError(f"{path}: data_ranges.point_spacing_m = {spacing!r} is outside the allowed range (0, {MAX_RADIUS:g}] m.")


def _check_table(table: dict, known: set[str], where: str, path, require: bool = False) -> None:
    unknown = sorted(set(map(str, table)) - known)
    if unknown:
        raise InputError(f"{path}: unknown key '{unknown[0]}' in the checkpoint's {where}; known keys are {', '.join(sorted(known))}.")
    missing = sorted(known - set(table)) if require else []
    if missing:
        raise InputError(f"{path}: the checkpoint's {where} lacks the key '{missing[0]}'.")


def _finite(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def simulator_from_checkpoint(ckpt: dict, source: str | Path = "<checkpoint>") -> Simulator:
    simulator = Simulator(
        FeatureSchema.from_dict(ckpt["schema"]),
        Normalisation.from_dict(ckpt["stats"]),
        ckpt["radius"],
        NetworkConfig(**ckpt["network"]),
    )
    try:
        simulator.load_state_dict(ckpt["model"])
    except (RuntimeError, TypeError, AttributeError):
        raise InputError(f"{source}: the model weights do not match the schema and layer sizes it declares.") from None
    simulator.data_ranges = ckpt.get("data_ranges")
    return simulator


def load_simulator(path: str | Path, device: str | torch.device = "cpu") -> Simulator:
    """The simulator stored in a checkpoint, on `device`, in eval mode.

    Raises runout.errors.InputError if the file is missing, unreadable, or not a runout
    GNS checkpoint. `simulator.schema.material_features` names the material inputs it
    expects: ("tan_phi",) or ("tan_phi", "c_over_100kPa")."""
    simulator = simulator_from_checkpoint(read_checkpoint(path), path)
    return simulator.to(device).eval()


def check_schema(simulator: Simulator, data_schema: FeatureSchema, model_source, data_source) -> None:
    """Raise InputError naming the first difference between a model's and the data's schema."""
    diff = simulator.schema.difference(data_schema)
    if diff is not None:
        raise InputError(
            f"{model_source} does not fit {data_source}: {diff}"
            + (" (fine-tune with --init to widen the material inputs)." if "material_features" in diff else ".")
        )


def widen_material_features(simulator: Simulator, names: tuple[str, ...], source="<model>") -> Simulator:
    """Add material inputs (e.g. cohesion) with zero weights; predictions do not change."""
    old = simulator.schema.material_features
    if tuple(names[: len(old)]) != tuple(old) or len(names) < len(old):
        raise InputError(
            f"{source}: material features [{', '.join(old)}] cannot be widened to [{', '.join(names)}]; "
            "the new list must start with the old one."
        )
    simulator.network.widen_node_input(len(names) - len(old))
    simulator.schema = simulator.schema.with_material_features(tuple(names))
    return simulator

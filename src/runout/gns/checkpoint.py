"""GNS checkpoints: one file holding everything needed to rebuild, resume or fine-tune.

Keys: format, schema (node-feature layout), stats (normalisation), radius (m), network
(layer sizes), model (state dict), and for training runs optimizer, step, rng, train
(the training settings). Files are written atomically (temporary file, then os.replace),
so a run killed while saving leaves the previous checkpoint intact.
"""

from __future__ import annotations

import os
from dataclasses import asdict
from pathlib import Path

import torch

from runout.errors import InputError
from runout.gns.schema import FeatureSchema
from runout.gns.simulator import NetworkConfig, Normalisation, Simulator

FORMAT = "runout-gns-1"
REQUIRED_KEYS = ("format", "schema", "stats", "radius", "network", "model")


def checkpoint_dict(simulator: Simulator, **training_state) -> dict:
    return {
        "format": FORMAT,
        "schema": simulator.schema.to_dict(),
        "stats": simulator.stats.to_dict(),
        "radius": simulator.radius,
        "network": asdict(simulator.config),
        "model": simulator.state_dict(),
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
    """The checkpoint dictionary (tensors on CPU), checked for the keys a model needs."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such checkpoint file.")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # torch raises many types for a corrupt or foreign file
        raise InputError(f"{path}: not a readable PyTorch checkpoint ({type(exc).__name__}: {exc}).") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        found = ckpt.get("format") if isinstance(ckpt, dict) else type(ckpt).__name__
        raise InputError(f"{path}: format is {found!r}; expected a runout GNS checkpoint ({FORMAT!r}).")
    missing = [k for k in REQUIRED_KEYS if k not in ckpt]
    if missing:
        raise InputError(f"{path}: the checkpoint lacks the key '{missing[0]}'.")
    return ckpt


def simulator_from_checkpoint(ckpt: dict, source: str | Path = "<checkpoint>") -> Simulator:
    simulator = Simulator(
        FeatureSchema.from_dict(ckpt["schema"]),
        Normalisation.from_dict(ckpt["stats"]),
        ckpt["radius"],
        NetworkConfig(**ckpt["network"]),
    )
    try:
        simulator.load_state_dict(ckpt["model"])
    except RuntimeError:
        raise InputError(f"{source}: the model weights do not match the schema and layer sizes it declares.") from None
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

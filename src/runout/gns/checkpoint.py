"""GNS checkpoints: one file holding everything needed to rebuild, resume or fine-tune.

Keys: format, schema (node-feature layout), stats (normalisation), radius (m), network
(layer sizes), model (state dict), and for training runs optimizer, step, rng, train
(the training settings), train_model (with --ema: the last step's weights, while model holds
their average, which every command uses), data_ranges (what the model was trained on, see
runout.learned.training_range; its point_spacing_m is the spacing every GNS command fills a
scene at, GraphNetworkSimulator.point_spacing). Files are written atomically (temporary file, then
os.replace, runout.learned.files.save_plain), so a run killed while saving leaves the previous
checkpoint intact.

Everything in a checkpoint is plain data (tensors, dicts, lists, numbers, strings), and it
is read with torch.load(weights_only=True): a file that asks the unpickler for any other
object is refused with one sentence and nothing in it runs. Every entry is then checked for
its type and range (runout.checks), the model weights for NaN and infinity, and the training
state (step, rng, optimizer, train settings) when present (runout.gns.checkpoint_checks).
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

import torch

from runout.errors import InputError
from runout.gns.checkpoint_checks import check_contents
from runout.gns.schema import FeatureSchema, NetworkConfig
from runout.gns.simulator import GraphNetworkSimulator, Normalisation
from runout.learned.files import GNS_FORMAT, read_plain, save_plain

FORMAT = GNS_FORMAT
REQUIRED_KEYS = ("format", "schema", "stats", "radius", "network", "model")


def checkpoint_dict(simulator: GraphNetworkSimulator, **training_state) -> dict:
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


def save_checkpoint(path: str | Path, simulator: GraphNetworkSimulator, **training_state) -> Path:
    """Write atomically; training_state (optimizer, step, rng, train, ...) is stored as is."""
    return save_plain(path, checkpoint_dict(simulator, **training_state))


def read_checkpoint(path: str | Path) -> dict:
    """The checkpoint dictionary (tensors on CPU), checked for the keys a model needs and
    for plain data only (runout.learned.files.read_plain)."""
    return check_checkpoint(read_plain(path), path)


def check_checkpoint(ckpt: object, path: str | Path) -> dict:
    """A file's contents as read (runout.learned.files.read_plain), checked as read_checkpoint does."""
    path = Path(path)
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        found = ckpt.get("format") if isinstance(ckpt, dict) else type(ckpt).__name__
        raise InputError(f"{path}: format is {found!r}; expected a runout GNS checkpoint ({FORMAT!r}).")
    missing = [k for k in REQUIRED_KEYS if k not in ckpt]
    if missing:
        raise InputError(f"{path}: the checkpoint lacks the key '{missing[0]}'.")
    check_contents(ckpt, path)
    return ckpt



def simulator_from_checkpoint(ckpt: dict, source: str | Path = "<checkpoint>") -> GraphNetworkSimulator:
    simulator = GraphNetworkSimulator(
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


def load_simulator(path: str | Path, device: str | torch.device = "cpu") -> GraphNetworkSimulator:
    """The simulator stored in a checkpoint, on `device`, in eval mode.

    Raises runout.errors.InputError if the file is missing, unreadable, or not a runout
    GNS checkpoint. `simulator.schema.material_features` names the material inputs it
    expects: ("tan_phi",) or ("tan_phi", "c_over_100kPa")."""
    simulator = simulator_from_checkpoint(read_checkpoint(path), path)
    return simulator.to(device).eval()


def load_last_step(path: str | Path, device: str | torch.device = "cpu") -> GraphNetworkSimulator | None:
    """The simulator of a checkpoint's last-step weights (train_model, kept beside the weight
    average by `runout train --ema`), on `device`, in eval mode; None when it has none."""
    ckpt = read_checkpoint(path)
    if "train_model" not in ckpt:
        return None
    return simulator_from_checkpoint({**ckpt, "model": ckpt["train_model"]}, path).to(device).eval()

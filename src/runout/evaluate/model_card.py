"""What a model is and how much training made it, for every study's summary and the report,
whichever learned engine the file holds."""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass
from pathlib import Path

from runout.learned.engine import LABELS
from runout.learned.load import engine_name


@dataclass
class ModelCard:
    path: str
    sha256: str  # first 12 hex digits of the checkpoint file
    steps: int | None  # optimiser steps of this run (None: the file was saved outside training)
    base_steps: int  # steps of the model it was fine-tuned from (0 for a model trained from scratch)
    training_data: str | None
    initialised_from: str | None
    material_features: list[str]
    parameters: int
    network: dict
    frame_stride: int = 1  # dataset frames per engine step (summaries written before it: 1)
    engine: str = "gns"  # the learned engine (summaries written before the neural MPM: gns)

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def label(self) -> str:
        """The engine's name in lines, tables and pictures: GNS, neural MPM."""
        return LABELS.get(self.engine, self.engine)

    def sentence(self) -> str:
        trained = "untrained (saved without a training run)" if self.steps is None else f"{self.steps:,} training steps"
        stride = f", frame stride {self.frame_stride}" if self.frame_stride > 1 else ""
        base = f" after {self.base_steps:,} base steps" if self.base_steps else ""
        data = f" on {self.training_data}" if self.training_data else ""
        return (f"`{self.path}` ({self.label}, sha256 {self.sha256}…, {self.parameters:,} parameters, material inputs "
                f"[{', '.join(self.material_features)}]{stride}): {trained}{base}{data}.")


def model_card(path: Path) -> ModelCard:
    if engine_name(path) == "neural-mpm":
        return _neural_mpm_card(path)
    from runout.gns.checkpoint import read_checkpoint

    ckpt = read_checkpoint(path)
    train = ckpt.get("train", {})
    return ModelCard(
        path=str(path),
        sha256=hashlib.sha256(Path(path).read_bytes()).hexdigest()[:12],
        steps=ckpt.get("step"),
        base_steps=int(train.get("lr_step_offset", 0)),
        training_data=train.get("data"),
        initialised_from=train.get("init"),
        material_features=list(ckpt["schema"]["material_features"]),
        parameters=sum(v.numel() for k, v in ckpt["model"].items() if not k.endswith(("_mean", "_scale"))),
        network=dict(ckpt["network"]),
        frame_stride=int(ckpt["schema"].get("frame_stride", 1)),
    )


def _neural_mpm_card(path: Path) -> ModelCard:
    from runout.neural_mpm.checkpoint import read_checkpoint

    ckpt = read_checkpoint(path)
    train = ckpt.get("train", {})
    config = dict(ckpt["config"])
    return ModelCard(
        path=str(path),
        sha256=hashlib.sha256(Path(path).read_bytes()).hexdigest()[:12],
        steps=ckpt.get("step"),
        base_steps=0,
        training_data=train.get("data"),
        initialised_from=None,
        material_features=["tan_phi", "c_over_100kPa"][: int(config["material_width"])],
        parameters=sum(v.numel() for v in ckpt["model"].values()),
        network=config,
        engine="neural-mpm",
    )

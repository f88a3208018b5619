"""What `runout train --engine neural-mpm` runs: the neural MPM's training task
(runout.neural_mpm.training) in the one Trainer, its engine built for the data. The GNS's
(`--engine gns`, the default) is runout.train. Torch loads when a run starts."""

from __future__ import annotations

from pathlib import Path

from runout.contract import spacing_for_cells
from runout.neural_mpm.config import NeuralMPMConfig
from runout.neural_mpm.settings import TrainSettings


def train_neural_mpm(settings: TrainSettings, config: NeuralMPMConfig, resume: bool) -> None:
    """Train (or resume) the neural-MPM run of `settings`. A new run builds the engine of
    `config` at the point spacing of the first dataset; a resumed one keeps its checkpoint's."""
    from runout.neural_mpm.training import datasets, train

    train(settings, spaced_for(config, Path(datasets(settings)[0])), resume=resume)


def spaced_for(config: NeuralMPMConfig, data: Path) -> NeuralMPMConfig:
    """The config at the spacing of the dataset's points (its metadata's point_spacing, else
    that of its cell_size, else the config's own)."""
    from dataclasses import replace

    from runout.simfiles import read_metadata

    meta = read_metadata(data)
    if meta.get("point_spacing"):
        return replace(config, point_spacing=float(meta["point_spacing"]))
    if meta.get("cell_size"):
        return replace(config, point_spacing=spacing_for_cells(float(meta["cell_size"])))
    return config

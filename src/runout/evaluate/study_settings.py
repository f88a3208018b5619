"""The settings of the evaluation studies, torch-free, so the command line derives its options
from them without loading the engines: ColumnGrid and its ColumnCase (section 5.1.1's columns:
a case is one named run of a study, as a check is one of `runout validate`), PAPER_CASE (the
diagnostics' column) and SensitivityConfig (the data-size study).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

from runout.errors import InputError
from runout.scene import EXAMPLES

PAPER_ASPECTS = (0.5, 1.0, 2.0)
PAPER_PHIS = (0.0, 11.25, 22.5, 33.75, 45.0)  # degrees
PAPER_COHESIONS = (10.0, 25.0, 40.0, 55.0, 70.0)  # kPa


@dataclass(frozen=True)
class ColumnCase:
    aspect: float  # H0 / L0
    phi: float  # degrees
    cohesion: float  # kPa

    @property
    def name(self) -> str:
        return f"column_a{self.aspect:g}_phi{self.phi:g}_c{self.cohesion:g}"


@dataclass
class ColumnGrid:
    aspects: tuple[float, ...] = PAPER_ASPECTS
    phis: tuple[float, ...] = PAPER_PHIS
    cohesions: tuple[float, ...] = PAPER_COHESIONS
    frames: int = 600
    scale: float = 1.0
    examples: Path = EXAMPLES

    def cases(self) -> list[ColumnCase]:
        return [ColumnCase(a, p, c) for a, p, c in itertools.product(self.aspects, self.phis, self.cohesions)]


PAPER_CASE = ColumnCase(aspect=2.0, phi=11.25, cohesion=10.0)  # the diagnostics' column (section 5.1.1)

PAPER_SIZES = (10, 50, 100, 250, 500, 750, 1000)
BUDGETS = ("steps", "epochs")


@dataclass
class SensitivityConfig:
    data: Path  # dataset folder: train.npz, metadata.json and the held-out split
    init: Path  # checkpoint every subset is fine-tuned from
    sizes: tuple[int, ...] = PAPER_SIZES
    steps: int = 4_500_000  # fixed-step budget
    epochs: int = 10  # fixed-epoch budget
    held_out: int = 20  # held-out simulations rolled out per model
    split: str = "test"
    batch_size: int = 2
    device: str = "cpu"
    progress: bool = True
    budgets: tuple[str, ...] = BUDGETS  # which of the two budgets to run (an epoch of 250 scenes is hours on a CPU)

    def check(self) -> None:
        if not self.sizes or min(self.sizes) < 1:
            raise InputError(f"--sizes {','.join(map(str, self.sizes))} must be positive whole numbers.")
        if not self.budgets or not set(self.budgets) <= set(BUDGETS):
            raise InputError(f"--budgets {','.join(self.budgets)!r} must name steps, epochs or both, e.g. steps,epochs.")
        for name, value in (("--steps", self.steps), ("--epochs", self.epochs), ("--held-out", self.held_out)):
            if value < 1:
                raise InputError(f"{name} = {value} must be a positive whole number.")

"""Where a study runs (StudyContext): the MPM cache, the device of both engines, whether to show
progress, and where its one-line notes go (e.g. that a scene is filled at the model's point
spacing)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from runout.mpm.cache import MpmCache


@dataclass
class StudyContext:
    """Where a study runs: no engine in it, only what every engine of the study runs with."""

    cache: MpmCache = field(default_factory=MpmCache)
    device: str = "cpu"  # cpu or cuda, for both the MPM and the learned engine
    progress: bool = True
    log: Callable[[str], None] = print

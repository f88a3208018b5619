"""Where a study runs its engines: the MPM cache, the device, whether to show progress, and
where its one-line notes go (e.g. that a scene is filled at the model's point spacing)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from runout.mpm.cache import MpmCache


@dataclass
class EngineRun:
    cache: MpmCache = field(default_factory=MpmCache)
    device: str = "cpu"  # cpu or cuda, for both the MPM and the GNS
    progress: bool = True
    log: Callable[[str], None] = print

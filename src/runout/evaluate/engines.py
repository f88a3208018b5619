"""Where a study runs its engines: the MPM cache, the device and whether to show progress."""

from __future__ import annotations

from dataclasses import dataclass, field

from runout.mpm.cache import MpmCache


@dataclass
class EngineRun:
    cache: MpmCache = field(default_factory=MpmCache)
    device: str = "cpu"  # cpu or cuda, for both the MPM and the GNS
    progress: bool = True

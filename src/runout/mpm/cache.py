"""MPM trajectories cached on disk, keyed by a hash of the solver's version and the scene's TOML.

The MPM is the slow, deterministic half of every comparison, so each trajectory is written
once to CACHE/<key>/ (trajectory.npz, metadata.json and the scene.toml it came from) and
reused by reruns and by every other model. Missing scenes run together in ONE batched
`runout.mpm.simulate` call. The key covers the whole scene (domain, time, materials,
regions, name) and `runout.mpm.SOLVER_VERSION`, so a changed solver never serves an old
result; entries of other versions stay on disk until the cache folder is cleared. The version
names the physics, not the code that runs it: the Warp kernels give the torch solver's
trajectories to float64 rounding, the same float32 records in every check measured
(docs/scene-format.md), so entries either wrote serve both; each entry's metadata names the
backend that made it.
"""

from __future__ import annotations

import hashlib
import platform
from dataclasses import dataclass
from pathlib import Path

from runout.defaults import MPM_CACHE
from runout.mpm import SOLVER_VERSION, simulate
from runout.scene import Scene, scene_to_toml
from runout.trajectory import Trajectory, load_trajectory, save_trajectory

DEFAULT_CACHE = MPM_CACHE


def scene_key(scene: Scene, solver_version: str = SOLVER_VERSION) -> str:
    """First 20 hex digits of the sha256 of the solver version and the scene's TOML text."""
    text = f"runout.mpm.SOLVER_VERSION = {solver_version!r}\n" + scene_to_toml(scene)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


@dataclass
class MpmCache:
    root: Path = DEFAULT_CACHE
    simulated: int = 0  # scenes this object has sent to the MPM (the rest were cache hits)
    prefix: str = ""  # of every entry's folder name, e.g. "mpm_"

    def path(self, scene: Scene) -> Path:
        return Path(self.root) / f"{self.prefix}{scene_key(scene)}"

    def has(self, scene: Scene) -> bool:
        return (self.path(scene) / "metadata.json").is_file()

    def ensure(self, scenes: list[Scene], device: str = "cpu", progress: bool = True) -> list[Path]:
        """Folders of every scene's MPM trajectory; the missing ones are run in one batch."""
        missing = list({scene_key(s): s for s in scenes if not self.has(s)}.values())
        if missing:
            for scene, traj in zip(missing, simulate(missing, device=device, progress=progress)):
                self._store(scene, traj, device)
            self.simulated += len(missing)
        return [self.path(s) for s in scenes]

    def load(self, scene: Scene, device: str = "cpu", progress: bool = True) -> Trajectory:
        """The scene's MPM trajectory, run first if it is not cached."""
        return load_trajectory(self.ensure([scene], device, progress)[0])

    def _store(self, scene: Scene, traj: Trajectory, device: str) -> None:
        folder = self.path(scene)
        traj.info.update({"host": platform.node(), "device": str(device), "scene_key": scene_key(scene),
                          "solver_version": SOLVER_VERSION})
        save_trajectory(traj, folder)
        (folder / "scene.toml").write_text(scene_to_toml(scene))

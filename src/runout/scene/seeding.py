"""Seeding material points: a regular lattice, points_per_cell per direction, inside each region."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from runout.defaults import PARTICLE_TYPE_KINEMATIC, PARTICLE_TYPE_SOIL
from runout.scene.geometry import points_in_polygon
from runout.scene.model import Scene, lattice_points


@dataclass
class SeedPoints:
    """Material points of one scene (numpy, float64): the MPM's initial state."""

    position: np.ndarray  # [N, 2] m
    velocity: np.ndarray  # [N, 2] m/s
    material_id: np.ndarray  # [N] index into scene.material_names
    fixed: np.ndarray  # [N] bool
    volume: float  # m^2 per point (plane strain, unit thickness)

    @property
    def particle_type(self) -> np.ndarray:
        return np.where(self.fixed, PARTICLE_TYPE_KINEMATIC, PARTICLE_TYPE_SOIL).astype(np.int64)

    def __len__(self) -> int:
        return len(self.position)


def fill_points(scene: Scene) -> SeedPoints:
    """Seed points on the lattice inside each region; a point on a shared edge goes to the
    first region that claims it."""
    lattice = lattice_points(scene.domain)
    names = scene.material_names
    claimed = np.zeros(len(lattice), dtype=bool)
    pos, vel, mid, fixed = [], [], [], []
    for r in scene.regions:
        inside = points_in_polygon(lattice, np.asarray(r.polygon)) & ~claimed
        claimed |= inside
        n = int(inside.sum())
        pos.append(lattice[inside])
        vel.append(np.tile(np.asarray(r.velocity, dtype=float), (n, 1)))
        mid.append(np.full(n, names.index(r.material), dtype=np.int64))
        fixed.append(np.full(n, r.fixed, dtype=bool))
    return SeedPoints(
        position=np.concatenate(pos),
        velocity=np.concatenate(vel),
        material_id=np.concatenate(mid),
        fixed=np.concatenate(fixed),
        volume=scene.domain.point_spacing**2,
    )

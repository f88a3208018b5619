"""What the GNS reads of a scene besides its points' positions and materials, and what holds
its points: the rigid walls and ground (Constraints, Ground), which every step's prediction is
kept within, and the overburden input (overburden_depth), each point's depth of soil.

Training, rollout and the inverse tell one story with one Constraints:

    constraints = Constraints.of(particle_type, bounds, positions, graph, simulator.point_spacing)
    next_position = simulator.step(window, particle_type, material, constraints)   # rollout (runout.gns.rollout)
    window = pushforward(simulator, window, n, particle_type, material, constraints)  # training (runout.gns.training)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from runout.defaults import PARTICLE_TYPE_KINEMATIC


@dataclass(frozen=True)
class Ground:
    """The rigid ground of one or more scenes, as the lowest height a soil point may take in
    each vertical column (m): the centre of the column's topmost kinematic point less
    GROUND_TOLERANCE point spacings (none where a column has no ground: -inf)."""

    floor: torch.Tensor  # [G, C] m
    width: float  # m, column width (one point spacing), columns from x = 0

    @classmethod
    def of(cls, positions: torch.Tensor, kinematic: torch.Tensor, graph: torch.Tensor | None, spacing: float) -> "Ground":
        col = torch.floor(positions[:, 0] / spacing).long().clamp(min=0)
        g = torch.zeros_like(col) if graph is None else graph.long()
        n_graphs, n_cols = int(g.max()) + 1 if len(g) else 1, int(col.max()) + 1 if len(col) else 1
        floor = torch.full((n_graphs * n_cols,), -math.inf, dtype=positions.dtype, device=positions.device)
        if kinematic.any():
            floor = floor.scatter_reduce(0, (g * n_cols + col)[kinematic], positions[kinematic, 1], "amax")
        return cls((floor - GROUND_TOLERANCE * spacing).reshape(n_graphs, n_cols), float(spacing))

    def floor_at(self, positions: torch.Tensor, graph: torch.Tensor | None) -> torch.Tensor:
        """The floor (m) of the column each of positions [N, 2] stands in."""
        col = torch.floor(positions[:, 0] / self.width).long().clamp(0, self.floor.shape[1] - 1)
        g = torch.zeros_like(col) if graph is None else graph.long()
        return self.floor[g, col].to(positions.dtype)

    def clamp(self, predicted: torch.Tensor, current: torch.Tensor, graph: torch.Tensor | None) -> torch.Tensor:
        """predicted [N, 2] kept out of the ground by the points now above it (at `current`):
        one that would sink below its column's floor is raised to it, and one that would move
        sideways into a column whose floor is above it (a step of the ground) keeps its x, as
        at a wall. A point now below its column's floor (under an overhang of a fixed region)
        is left alone."""
        here, there = self.floor_at(current, graph), self.floor_at(predicted, graph)
        above = current[:, 1] >= here
        blocked = above & (current[:, 1] < there)
        x = torch.where(blocked, current[:, 0], predicted[:, 0])
        floor = torch.where(blocked, here, there)
        y = torch.where(above, torch.maximum(predicted[:, 1], floor), predicted[:, 1])
        return torch.stack([x, y], dim=1)


# point spacings below the centre of a column's topmost ground point that a soil point may
# reach: the MPM's soil stays within 0.85 m (0.21 spacings) of it on 16 validation scenes of
# data/ft8 over all 480 frames, stepped ground included (docs/gns.md)
GROUND_TOLERANCE = 0.25


@dataclass(frozen=True)
class Constraints:
    """What holds the points of a graph batch (LagrangeBench's case setup): the domain
    bounds [[x_lo, x_hi], [y_lo, y_hi]] (m; [2, 2], or [N, 2, 2] per point), the mask of
    the points that move (not kinematic, type 3) and, when given, the rigid ground and the
    scene of each point. Kinematic points keep their positions; moving points are clamped
    into the domain (the rigid walls) and kept out of the ground (the MPM's fixed ground
    nodes, which soil does not pass)."""

    bounds: torch.Tensor
    movable: torch.Tensor  # [N] bool
    ground: Ground | None = None
    graph: torch.Tensor | None = None  # [N] scene of each point (None: one scene)

    @classmethod
    def of(cls, particle_type: torch.Tensor, bounds, positions: torch.Tensor | None = None,
           graph: torch.Tensor | None = None, spacing: float | None = None) -> "Constraints":
        """positions [N, 2] (m) and spacing (m): also keep soil out of the ground that the
        kinematic points among them fill."""
        bounds = torch.as_tensor(bounds, device=particle_type.device)
        movable = particle_type != PARTICLE_TYPE_KINEMATIC
        ground = None if positions is None or spacing is None else Ground.of(positions, ~movable, graph, spacing)
        return cls(bounds, movable, ground, graph)

    def constrain(self, predicted: torch.Tensor, current: torch.Tensor) -> torch.Tensor:
        """Predicted positions [N, 2] with kinematic points held at `current`, every point
        clamped into the domain and, with a ground, no soil point below its column's floor."""
        if self.ground is not None:
            predicted = self.ground.clamp(predicted, current, self.graph)
        predicted = torch.where(self.movable[:, None], predicted, current)
        return torch.clamp(predicted, self.bounds[..., 0], self.bounds[..., 1])


OVERBURDEN_SCALE = 100.0  # m: the overburden input is the depth of soil above a point over this


@torch.no_grad()
def overburden_depth(x: torch.Tensor, soil: torch.Tensor, graph: torch.Tensor | None, column: float, area: float) -> torch.Tensor:
    """Depth (m) of the soil above each point [N]: the soil points (`soil` [N] bool) strictly
    higher than it in its vertical column (columns `column` m wide from x = 0, two point
    spacings in the model: one MPM cell of 2 x 2 points; one set per
    graph), each standing for `area` m² of soil, spread over the column's width. At rest it is
    the depth below the surface (to a point spacing), the overburden that sets a point's
    geostatic stress, γ times this depth; a point sees only 46 m around it through 5
    message-passing steps of 9.2 m, less than the height of most slopes. No gradient: the
    count is piecewise constant in the positions."""
    n = x.shape[0]
    col = torch.floor(x[:, 0] / column).long()
    col = col - col.min() if n else col
    g = torch.zeros_like(col) if graph is None else graph.long()
    key = g * (int(col.max()) + 1 if n else 1) + col
    by_height = torch.argsort(x[:, 1], descending=True, stable=True)
    order = by_height[torch.argsort(key[by_height], stable=True)]  # by column, then from the top down
    counted = soil[order].long()
    before = torch.cumsum(counted, 0) - counted  # soil points earlier in the order (all columns)
    sorted_key, sorted_y = key[order], x[order, 1]
    starts_column = torch.ones(n, dtype=torch.bool, device=x.device)
    starts_column[1:] = sorted_key[1:] != sorted_key[:-1]
    starts_level = starts_column.clone()  # points at one height (at rest: one lattice row) are not above each other
    starts_level[1:] |= sorted_y[1:] != sorted_y[:-1]
    index = torch.arange(n, device=x.device)
    column_start = torch.cummax(torch.where(starts_column, index, 0), 0).values
    level_start = torch.cummax(torch.where(starts_level, index, 0), 0).values
    above = before[level_start] - before[column_start]
    depth = torch.empty(n, dtype=x.dtype, device=x.device)
    depth[order] = above.to(x.dtype) * (area / column)
    return depth

"""Point-grid transfers with the MPM's quadratic B-spline: the stencil the MPM solver uses
(runout.mpm.solver.stencil) and the neural MPM's particles-to-grid and grid-to-particles.

A point at xg (in node units, node i at xg = i) touches the 3 x 3 nodes from
floor(xg - 0.5); with f = xg - that base (in [0.5, 1.5)) the weights of the three nodes per
direction are 0.5 (1.5 - f)^2, 0.75 - (f - 1)^2, 0.5 (f - 0.5)^2, which sum to 1 and are
continuous with a continuous first derivative in xg, so both transfers are differentiable
in the points' positions and in the values moved.
"""

from __future__ import annotations

import torch


def bspline_weights(fx: torch.Tensor) -> torch.Tensor:
    """[..., 3, dim] weights of the three nodes per direction for fractional positions fx
    [..., dim] in [0.5, 1.5) node units."""
    return torch.stack((0.5 * (1.5 - fx) ** 2, 0.75 - (fx - 1.0) ** 2, 0.5 * (fx - 0.5) ** 2), dim=-2)


def stencil_2d(xg: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """First node (base [P, 2], integer), weights [P, 9] (node (a, b) at index 3 a + b) and
    fractional positions fx [P, 2] of points at xg [P, 2] node units."""
    base = torch.floor(xg - 0.5)
    fx = xg - base
    wx = bspline_weights(fx)  # [P, 3, 2]
    w = (wx[:, :, None, 0] * wx[:, None, :, 1]).reshape(-1, 9)
    return base.long(), w, fx


_A = torch.tensor([a for a in range(3) for _ in range(3)])
_B = torch.tensor([b for _ in range(3) for b in range(3)])


class GridTransfer:
    """Transfers between points and a batch of grids [B, C, NX, NY] whose node (i, j) sits at
    (i, j) dx (m) from the grid's first node. Every point must lie at least half a cell inside
    the grid's outermost nodes (the callers pad the grid around the domain)."""

    def __init__(self, positions: torch.Tensor, scene: torch.Tensor, dx: float, shape: tuple[int, int, int]):
        """positions [P, 2] m from the first node of the point's grid, scene [P] (index of
        the point's grid in the batch), shape (B, NX, NY)."""
        self.shape = shape
        batch, nx, ny = shape
        base, self.w, _ = stencil_2d(positions / dx)
        ix = base[:, :1] + _A.to(base.device)  # [P, 9]
        iy = base[:, 1:] + _B.to(base.device)
        self.ids = (scene[:, None] * nx + ix) * ny + iy  # [P, 9] flat node ids

    def to_grid(self, values: torch.Tensor) -> torch.Tensor:
        """[B, C, NX, NY]: sum over points of weight x value, for values [P, C]."""
        batch, nx, ny = self.shape
        channels = values.shape[1]
        contrib = (self.w[:, :, None] * values[:, None, :]).reshape(-1, channels)
        flat = values.new_zeros(batch * nx * ny, channels).index_add(0, self.ids.reshape(-1), contrib)
        return flat.reshape(batch, nx, ny, channels).permute(0, 3, 1, 2)

    def to_points(self, grid: torch.Tensor) -> torch.Tensor:
        """[P, C]: the grid field [B, C, NX, NY] interpolated at the points."""
        channels = grid.shape[1]
        flat = grid.permute(0, 2, 3, 1).reshape(-1, channels)
        return (flat[self.ids] * self.w[:, :, None]).sum(1)

"""The inverse's data loss: predicted positions [F, N, 2] (m) at the observed frames -> m².

Two kinds (`[loss] kind` in the spec, docs/inverse-format.md):

- "positions", the paper's: the mean over frames of the weighted mean over points of
  |p̂_i − p_i|², which needs to know where each point of the target went;
- "thickness": the mean over frames and over x bins of (t̂(x) − t(x))², with t(x) the soil's
  thickness profile (m): each soil point's area (point spacing², m²) shared between the two
  nearest bin centres in proportion to its distance (cloud-in-cell), divided by the bin
  width. It conserves the area (Σ t · width = soil area), is piecewise linear in every point's
  x and needs no point-by-point correspondence, only where the soil lies: what a survey of a
  deposit gives. It ignores a point's height, so a profile of thickness, not of elevation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from runout.inverse.spec import InverseSpec, LossSpec


def weighted_mse(predicted: torch.Tensor, target: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Mean over observed frames of the weighted mean over points of |p_hat - p|^2 (m^2).

    predicted, target [F, N, 2]; weights [N] (0 on kinematic points)."""
    squared = (predicted.to(target.dtype) - target).square().sum(dim=2)  # [F, N] m^2
    return (squared * weights).sum(dim=1).mean() / weights.sum()


def thickness_profile(x: torch.Tensor, area: torch.Tensor, x0: float, width: float, bins: int) -> torch.Tensor:
    """[F, J] thickness (m) at the bin centres x0 + (j + 1/2) width, j < bins, of points at x [F, N]
    (m) holding `area` [N] (m², 0 for points left out). Cloud-in-cell: a point between two
    centres gives each the share of its area that its distance to the other sets; a point
    beyond the first or last centre gives all of it to that one."""
    s = ((x - x0) / width - 0.5).clamp(0.0, bins - 1.0)  # position in units of bins, centre j at s = j
    left = s.detach().floor().clamp(max=max(bins - 2, 0))  # the integer part carries no gradient
    right_share = s - left  # in [0, 1]; differentiable in x
    mass = area.to(x.dtype).expand_as(x)
    profile = x.new_zeros(x.shape[0], bins)
    i = left.long()
    profile = profile.scatter_add(1, i, mass * (1.0 - right_share))
    if bins > 1:
        profile = profile.scatter_add(1, (i + 1).clamp(max=bins - 1), mass * right_share)
    return profile / width


@dataclass
class DataLoss:
    """The loss of predicted positions [F, N, 2] (m) against the target, in m²."""

    kind: str
    target: torch.Tensor  # [F, N, 2] m
    weights: torch.Tensor  # [N]: the positions loss's weights; 0 marks a kinematic point
    x0: float = 0.0  # m, left edge of the thickness bins
    width: float = 1.0  # m, bin width
    bins: int = 1
    area: torch.Tensor | None = None  # [N] m², each soil point's area (0 on kinematic points)

    def __post_init__(self):
        if self.kind == "thickness":
            self.target_profile = thickness_profile(self.target[..., 0], self.area, self.x0, self.width, self.bins)

    def __call__(self, predicted: torch.Tensor) -> torch.Tensor:
        if self.kind == "positions":
            return weighted_mse(predicted, self.target, self.weights)
        return (self._profile(predicted) - self.target_profile).square().mean()

    def residuals(self, predicted: torch.Tensor) -> torch.Tensor:
        """[n] the loss as residuals (m), loss = Σ r² / self.divisor: "positions": per frame, point
        of weight w > 0 and coordinate, √(w / w̄) (p̂ − p), w̄ the mean of those weights (so with
        uniform weights the residual is the coordinate's error); "thickness": t̂ − t per frame and
        bin. The statistics of runout.inverse.intervals read them as independent observations."""
        if self.kind == "positions":
            counted = self.weights > 0
            scale = (self.weights[counted] / self.weights[counted].mean()).sqrt()
            error = predicted.to(self.target.dtype)[:, counted] - self.target[:, counted]  # [F, N_w, 2] m
            return (error * scale[None, :, None]).reshape(-1)
        return (self._profile(predicted) - self.target_profile).reshape(-1)

    @property
    def divisor(self) -> int:
        """Σ r² / loss: frames x weighted points, or frames x bins."""
        frames = self.target.shape[0]
        return frames * (int((self.weights > 0).sum()) if self.kind == "positions" else self.bins)

    def observed(self, predicted: torch.Tensor) -> torch.Tensor:
        """[n] bool: the residuals that are observations. Every coordinate of a weighted point is;
        a thickness bin is where the target or the prediction holds soil (an empty bin far from
        the deposit stays empty whatever the strengths)."""
        if self.kind == "positions":
            return torch.ones(self.divisor * 2, dtype=torch.bool, device=self.target.device)
        return ((self._profile(predicted) > 0) | (self.target_profile > 0)).reshape(-1)

    def _profile(self, predicted: torch.Tensor) -> torch.Tensor:
        return thickness_profile(predicted[..., 0].to(self.target.dtype), self.area, self.x0, self.width, self.bins)


def data_loss(loss: LossSpec, target: np.ndarray, weights: np.ndarray, spacing: float, domain_width: float,
              device: torch.device | str = "cpu") -> DataLoss:
    """The spec's loss for a target [F, N, 2] (m) of points `spacing` m apart in a domain
    [0, domain_width] m wide; `weights` [N] from Observation.weights (0 on kinematic points)."""
    f64 = dict(dtype=torch.float64, device=torch.device(device))
    target_t = torch.tensor(target, **f64)
    weights_t = torch.tensor(weights, **f64)
    if loss.kind == "positions":
        return DataLoss("positions", target_t, weights_t)
    width = loss.bin_width if loss.bin_width is not None else 2.0 * spacing
    bins = max(1, math.ceil(domain_width / width))
    area = (weights_t > 0).to(torch.float64) * spacing**2
    return DataLoss("thickness", target_t, weights_t, 0.0, width, bins, area)


def spec_loss(spec: InverseSpec, observation, device: torch.device | str = "cpu") -> DataLoss:
    """The data loss of an inverse spec against its observation (runout.inverse.observation),
    binned over the width of the spec's domain at its point spacing."""
    domain = spec.scene.domain
    return data_loss(spec.loss, observation.positions, observation.weights(spec.loss), domain.point_spacing,
                     domain.width, device)

"""The neural MPM's network: a plain U-Net, image in, image out. It knows nothing of metres,
friction or walls: channels in, channels out, on a grid whose sides are multiples of
2^(levels - 1) (the engine pads its grids so)."""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F


def _groups(channels: int) -> int:
    return next(g for g in (8, 4, 2, 1) if channels % g == 0)


class ConvBlock(nn.Sequential):
    """Two 3 x 3 convolutions, each followed by group normalisation and GELU."""

    def __init__(self, c_in: int, c_out: int):
        super().__init__(
            nn.Conv2d(c_in, c_out, 3, padding=1), nn.GroupNorm(_groups(c_out), c_out), nn.GELU(),
            nn.Conv2d(c_out, c_out, 3, padding=1), nn.GroupNorm(_groups(c_out), c_out), nn.GELU(),
        )


class UNet(nn.Module):
    """widths[k] channels at level k (the grid halved k times). The output layer starts at
    zero, so an untrained engine predicts no motion: standing still, not noise."""

    def __init__(self, c_in: int, c_out: int, widths: tuple[int, ...]):
        super().__init__()
        self.down = nn.ModuleList(ConvBlock(a, b) for a, b in zip((c_in, *widths[:-1]), widths))
        self.up = nn.ModuleList(ConvBlock(widths[k + 1] + widths[k], widths[k]) for k in range(len(widths) - 1))
        self.out = nn.Conv2d(widths[0], c_out, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    @property
    def multiple(self) -> int:
        """The grid sides must be multiples of this."""
        return 2 ** (len(self.down) - 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for k, block in enumerate(self.down):
            x = block(x if k == 0 else F.avg_pool2d(x, 2))
            skips.append(x)
        for k in reversed(range(len(self.up))):
            x = F.interpolate(x, scale_factor=2.0, mode="nearest")
            x = self.up[k](torch.cat([x, skips[k]], dim=1))
        return self.out(x)

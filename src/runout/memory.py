"""How much memory this machine, or a device on it, has: what the MPM's budget and a learned
engine's rollout are checked against (kept apart from runout.mpm, so a learned engine's
command loads no MPM)."""

from __future__ import annotations

import os

import torch

GIB = 1024**3


def host_memory() -> int:
    """Bytes of physical memory of this machine."""
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def device_memory(device: str | torch.device) -> int:
    device = torch.device(device)
    if device.type == "cuda" and torch.cuda.is_available():
        return torch.cuda.get_device_properties(device).total_memory
    return host_memory()

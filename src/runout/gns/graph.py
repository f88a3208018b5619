"""Radius neighbour search by cell lists, in plain PyTorch (CPU and CUDA), without a cap.

Points are binned into square cells of side R; each point's candidates are the points of
its own and the 8 surrounding cells of the same graph, found by binary search in the
points sorted by cell key. Every pair closer than R (inclusive) becomes an edge, self
edges included. All work is tensor work on the points' device; the only host sync is the
number of candidate pairs (the size of the output).
"""

from __future__ import annotations

import torch

# (dx, dy) cell offsets of the 3 x 3 neighbourhood
_OFFSETS = [(dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1)]


def radius_graph(
    positions: torch.Tensor, radius: float, graph: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Edges (senders, receivers) between points of the same graph within `radius`.

    positions [N, 2] (m); graph [N] int graph index per point (None: one graph).
    Returns two int64 tensors [E]; each (s, r) pair appears once, and (s, s) is included.
    """
    n = positions.shape[0]
    device = positions.device
    if graph is None:
        graph = torch.zeros(n, dtype=torch.long, device=device)
    pos = positions.detach()
    cell = torch.floor((pos - pos.min(dim=0).values) / radius).long()  # [N, 2]
    nx, ny = int(cell[:, 0].max()) + 3, int(cell[:, 1].max()) + 3  # one spare cell each side
    cell = cell + 1
    key = (graph * ny + cell[:, 1]) * nx + cell[:, 0]
    order = torch.argsort(key)
    sorted_key = key[order]
    offsets = torch.tensor(_OFFSETS, dtype=torch.long, device=device)  # [9, 2]
    neighbour_key = key[:, None] + offsets[:, 1] * nx + offsets[:, 0]  # [N, 9]
    start = torch.searchsorted(sorted_key, neighbour_key, side="left")
    count = torch.searchsorted(sorted_key, neighbour_key, side="right") - start
    receivers, candidates = _expand_ranges(start.reshape(-1), count.reshape(-1), len(_OFFSETS))
    senders = order[candidates]
    close = (pos[senders] - pos[receivers]).square().sum(dim=1) <= radius * radius
    return senders[close], receivers[close]


def _expand_ranges(start: torch.Tensor, count: torch.Tensor, per_point: int):
    """For ranges [start, start + count) listed point-major (per_point ranges per point),
    the owning point and the index of every element of every range."""
    total = int(count.sum())
    device = start.device
    owner_range = torch.repeat_interleave(torch.arange(len(count), device=device), count, output_size=total)
    first = torch.cumsum(count, dim=0) - count  # position of each range's first element
    index = torch.arange(total, device=device) - first[owner_range] + start[owner_range]
    return owner_range // per_point, index


"""Polygon geometry of scene regions (numpy, metres): area, crossings, containment, overlap."""

from __future__ import annotations

import numpy as np


def polygon_area(p: np.ndarray) -> float:
    """Signed area (m^2), positive for counter-clockwise vertices."""
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _edges(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return p, np.roll(p, -1, axis=0)


def _cross_pairs(p: np.ndarray, q: np.ndarray, tol: float) -> np.ndarray:
    """[Ep, Eq] bool: edge i of p and edge j of q cross at a point interior to both
    (touching, sharing a vertex or running collinear is not crossing)."""
    a, b = (e[:, None, :] for e in _edges(p))
    c, d = (e[None, :, :] for e in _edges(q))

    def orient(u, v, w):
        return (v[..., 0] - u[..., 0]) * (w[..., 1] - u[..., 1]) - (v[..., 1] - u[..., 1]) * (w[..., 0] - u[..., 0])

    o1, o2, o3, o4 = orient(a, b, c), orient(a, b, d), orient(c, d, a), orient(c, d, b)
    return (((o1 > tol) & (o2 < -tol)) | ((o1 < -tol) & (o2 > tol))) & (
        ((o3 > tol) & (o4 < -tol)) | ((o3 < -tol) & (o4 > tol))
    )


def edges_cross(p: np.ndarray, q: np.ndarray, tol: float) -> bool:
    """True when an edge of polygon p properly crosses an edge of polygon q."""
    return bool(_cross_pairs(p, q, tol).any())


def polygon_self_intersects(p: np.ndarray) -> bool:
    n = len(p)
    scale = max(1.0, float(np.abs(p).max()))
    cross = _cross_pairs(p, p, 1e-9 * scale * scale)
    i, j = np.triu_indices(n, k=2)
    keep = ~((i == 0) & (j == n - 1))  # the closing edge is adjacent to the first
    return bool(cross[i[keep], j[keep]].any())


def points_in_polygon(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Crossing-number test with the half-open rule, so a point on an edge shared by two
    polygons belongs to exactly one of them. points [N, 2] -> bool [N]."""
    x, y = points[:, 0][:, None], points[:, 1][:, None]
    x0, y0 = poly[:, 0][None, :], poly[:, 1][None, :]
    x1, y1 = np.roll(poly[:, 0], -1)[None, :], np.roll(poly[:, 1], -1)[None, :]
    straddles = (y0 <= y) != (y1 <= y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_cross = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    crossings = straddles & (x < x_cross)
    return (crossings.sum(axis=1) % 2) == 1


def _strictly_inside(points: np.ndarray, poly: np.ndarray, tol: float) -> np.ndarray:
    """[N] bool: inside the polygon and farther than tol from its boundary."""
    a, b = _edges(poly)
    ab = b - a
    rel = points[:, None, :] - a[None]
    t = np.clip((rel * ab[None]).sum(-1) / np.maximum((ab**2).sum(-1), 1e-30)[None], 0, 1)
    dist = np.linalg.norm(rel - t[..., None] * ab[None], axis=-1).min(axis=1)
    return points_in_polygon(points, poly) & (dist > tol)


def _probes(p: np.ndarray, n: int = 16) -> np.ndarray:
    """Vertices, edge midpoints and a grid of interior points of polygon p."""
    lo, hi = p.min(axis=0), p.max(axis=0)
    gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], n + 2)[1:-1], np.linspace(lo[1], hi[1], n + 2)[1:-1])
    grid = np.column_stack([gx.ravel(), gy.ravel()])
    a, b = _edges(p)
    return np.vstack([p, 0.5 * (a + b), grid[points_in_polygon(grid, p)]])


def polygons_overlap(p: np.ndarray, q: np.ndarray) -> bool:
    """True when the interiors of two simple polygons intersect; shared edges are allowed.

    Either an edge of one properly crosses an edge of the other, or a vertex, edge midpoint
    or interior sample of one lies strictly inside the other."""
    scale = max(1.0, float(np.abs(p).max()), float(np.abs(q).max()))
    tol = 1e-7 * scale
    if _cross_pairs(p, q, tol * scale).any():
        return True
    return bool(_strictly_inside(_probes(p), q, tol).any() or _strictly_inside(_probes(q), p, tol).any())

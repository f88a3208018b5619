"""Explicit plane-strain MPM, batched over scenes in one flat point array: the state and one substep.

runout.mpm.setup makes the state (Grid, Points) from scenes; this module only advances it.
The scheme: quadratic B-spline shape functions with APIC transfers (MLS-MPM force form) and
a FLIP share that is a fixed rate in time (flip_share), update-stress-last:
p2g -> grid_update -> g2p -> update_stress. Units: m, s, kg per metre of thickness, Pa.
Stress tension positive. Each scene owns a block of a flat background grid (padded by PAD
nodes beyond every wall); a point knows its scene's block offset, so one index_add serves all
scenes and no scene ever touches another's nodes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from runout.defaults import FLIP_WAVE
from runout.mpm.geostatic import GRAVITY
from runout.mpm.mohr_coulomb import MaterialArrays, mobilised, update_stress
from runout.transfer import stencil_2d

PAD = 2  # grid nodes beyond each wall; quadratic B-splines reach 1.5 cells
STENCIL = [(a, b) for a in range(3) for b in range(3)]  # node index offsets of the 3 x 3 stencil


@dataclass
class Constraint:
    """Rigid frictional surface on a set of grid nodes: outward unit normals, Coulomb mu
    (inf: rough, no slip). The rough mask and the finite mu the return uses are made once here."""

    ids: torch.Tensor  # [B] node ids (no id twice within one constraint)
    normal: torch.Tensor  # [B, 2]
    mu: torch.Tensor  # [B]
    rough: torch.Tensor = field(init=False)  # [B, 1] bool: mu = inf
    finite_mu: torch.Tensor = field(init=False)  # [B, 1]: mu, 0 where rough

    def __post_init__(self) -> None:
        self.rough = torch.isinf(self.mu)[:, None]
        self.finite_mu = torch.where(self.rough, torch.zeros_like(self.mu[:, None]), self.mu[:, None])


@dataclass
class Grid:
    """All scenes' grids, flattened; boundary conditions as node lists applied in order."""

    size: int
    dx: float
    node_offset: torch.Tensor  # [S] first node of each scene
    ny_nodes: torch.Tensor  # [S] nodes per grid column of each scene
    constraints: list[Constraint]  # side walls, base and top, fixed-ground contact
    stuck: torch.Tensor  # [K] node ids deep inside fixed ground: velocity zero
    offsets: torch.Tensor  # [9, 2] stencil node offsets in metres, made once on the device


@dataclass
class Points:
    """State of the moving points of all scenes."""

    x: torch.Tensor  # [P, 2] m
    v: torch.Tensor  # [P, 2] m/s
    C: torch.Tensor  # [P, 2, 2] APIC affine velocity = velocity gradient, 1/s
    stress: torch.Tensor  # [P, 4] (sxx, syy, sxy, szz) Pa
    volume: torch.Tensor  # [P] m^2
    rest_volume: torch.Tensor  # [P] m^2 at the start (the seeding area)
    mass: torch.Tensor  # [P] kg/m
    scene: torch.Tensor  # [P] scene index
    upper: torch.Tensor  # [P, 2] domain size (clamp bound), m
    mat: MaterialArrays
    node_base: torch.Tensor  # [P] first grid node of the point's scene
    ny: torch.Tensor  # [P] nodes per grid column of the point's scene
    stencil_offsets: torch.Tensor  # [P, 9] node-id offsets a * ny + b of the 3 x 3 stencil
    wave_rate: torch.Tensor  # [P] c_p / dx of the point's packed soil, 1/s (flip_share)


def stencil(x: torch.Tensor, node_base: torch.Tensor, ny: torch.Tensor, offsets: torch.Tensor, dx: float):
    """Node ids [P, 9], weights [P, 9] and fractional cell positions fx [P, 2] of each point.

    node_base [P] is the first node of the point's scene, ny [P] its nodes per grid column,
    offsets [P, 9] = a * ny + b for the stencil's (a, b). The node-minus-point offset of
    stencil node k is (STENCIL[k] - fx) * dx."""
    base, w, fx = stencil_2d(x * (1.0 / dx))  # the quadratic B-spline of runout.transfer; fx in [0.5, 1.5)
    cell = base + PAD
    ids = (node_base + cell[:, 0] * ny + cell[:, 1])[:, None] + offsets
    return ids, w, fx


def p2g(pts: Points, grid: Grid, dt: float):
    """Scatter mass, APIC momentum and the internal-force impulse (MLS form) to the grid."""
    ids, w, fx = stencil(pts.x, pts.node_base, pts.ny, pts.stencil_offsets, grid.dx)
    d_inv = 4.0 / grid.dx**2  # inverse of the quadratic B-spline inertia tensor D
    sxx, syy, sxy, _ = pts.stress.unbind(1)
    vol = (dt * d_inv) * pts.volume
    m = pts.mass
    # momentum: m (v + C (x_i - x_p)); impulse: -dt V D^-1 sigma (x_i - x_p)
    affine = torch.stack(
        (m[:, None, None] * pts.C,
         -vol[:, None, None] * torch.stack((sxx, sxy, sxy, syy), 1).reshape(-1, 2, 2)), dim=1,
    )  # [P, 2, 2, 2]
    # A (x_i - x_p) for the 9 nodes as one GEMM: A @ offsets^T - A @ (fx dx)
    offs = grid.offsets
    a_off = (affine.reshape(-1, 2) @ offs.T).reshape(-1, 2, 2, 9)  # [P, which, i, node]
    a_fx = torch.einsum("pwij,pj->pwi", affine, fx * grid.dx)
    shift = a_fx.clone()
    shift[:, 0] -= m[:, None] * pts.v
    node_terms = w[:, None, None, :] * (a_off - shift[..., None])  # [P, 2, 2, 9]
    flat = ids.reshape(-1)
    m_grid = torch.zeros(grid.size, dtype=pts.x.dtype, device=pts.x.device)
    p_grid = torch.zeros(grid.size, 4, dtype=pts.x.dtype, device=pts.x.device)
    m_grid.index_add_(0, flat, (m[:, None] * w).reshape(-1))
    p_grid.index_add_(0, flat, node_terms.permute(0, 3, 1, 2).reshape(-1, 4))
    return m_grid, p_grid, (ids, w, fx)


def _coulomb(v, c: Constraint):
    """Remove the velocity into a rigid surface (outward normal) and reduce the tangential
    velocity by mu times the removed normal velocity (Coulomb friction, stick if it fits).
    mu = inf is a rough surface: a node pressing on it sticks (no slip), so the soil above
    slides only by shearing on its own strength; a node moving away from it is free."""
    vn = (v * c.normal).sum(-1, keepdim=True)
    hit = vn < 0
    vt = v - vn * c.normal
    speed_t = vt.norm(dim=-1, keepdim=True)
    scale = torch.clamp(1.0 + c.finite_mu * vn / speed_t.clamp_min(1e-12), min=0.0)
    scale = torch.where(c.rough, torch.zeros_like(scale), scale)
    return torch.where(hit, vt * scale, v)


def grid_update(m_grid, p_grid, grid: Grid, dt: float, damping: float = 0.0):
    """Grid velocity with gravity and local damping, then walls (slip + Coulomb) and
    fixed-ground contact. Returns the new velocity and the velocity before this step's
    forces (for FLIP).

    Local (Cundall) damping takes `damping` times the magnitude of each component of the
    unbalanced nodal force against that component of the nodal velocity, as the reference
    MPM does: a frequency-independent loss like the hysteretic damping of soil."""
    has_mass = (m_grid > 0)[:, None]
    v_both = torch.where(has_mass, p_grid / m_grid.clamp_min(1e-30)[:, None], torch.zeros_like(p_grid))
    v_before = v_both[:, :2]  # transferred momentum only
    dv = v_both[:, 2:].clone()  # internal-force impulse per unit mass
    dv[:, 1] -= GRAVITY * dt
    if damping > 0.0:
        dv = dv - damping * dv.abs() * torch.sign(v_before)
    v = v_before + dv
    v = torch.where(has_mass, v, torch.zeros_like(v))
    for c in grid.constraints:
        v[c.ids] = _coulomb(v[c.ids], c)
    v[grid.stuck] = 0.0
    return v, v_before


def g2p(pts: Points, v_grid, v_before, cache, grid: Grid, dt: float, flip: float) -> None:
    """Gather velocity and its gradient (APIC C), move the points, clamp them inside.

    The point velocity blends FLIP (old velocity plus the grid's change) with PIC/APIC (the
    new grid velocity) by `flip`, a number or a [P, 1] tensor of shares (see flip_share)."""
    ids, w, fx = cache
    wv = w[..., None] * v_grid[ids]  # [P, 9, 2]
    v_pic = wv.sum(1)
    v_old_grid = (w[..., None] * v_before[ids]).sum(1)
    v_flip = pts.v + v_pic - v_old_grid
    # C = D^-1 sum_k w_k v_k (x_k - x_p)^T, with the stencil sum as one GEMM
    offs = grid.offsets
    wv_off = (wv.transpose(1, 2).reshape(-1, 9) @ offs).reshape(-1, 2, 2)
    pts.C = (4.0 / grid.dx**2) * (wv_off - v_pic[:, :, None] * (fx * grid.dx)[:, None, :])
    pts.v = flip * v_flip + (1.0 - flip) * v_pic
    x = pts.x + dt * v_pic  # positions follow the grid (PIC) velocity: stable and non-penetrating
    eps = 1e-4 * grid.dx
    pts.x = torch.minimum(torch.clamp(x, min=eps), pts.upper - eps)


def flip_share(pts: Points, dt: float, flip: float | str):
    """FLIP share of the point-velocity update for one substep of dt seconds.

    A number is a fixed share per substep (0: APIC, 1: pure FLIP). "wave" makes the part of a
    point's velocity that the grid cannot represent decay at a fixed rate in time: by
    exp(-dt / tau) per substep, tau = dx / c_p the time an elastic wave of the point's packed
    soil takes to cross one cell (c_p = sqrt((lambda + 2G) / rho)). A fixed share loses a
    fixed fraction of that velocity at every substep, so its dissipation grows with the
    number of substeps and the runout fell as dt was refined; a fixed rate does not depend on
    dt (docs/scene-format.md, solver version 5). Returns a float or a [P, 1] tensor."""
    if flip != FLIP_WAVE:
        return flip
    return flip_shares(pts.wave_rate, dt, flip)[:, None]


def flip_shares(wave_rate: torch.Tensor, dt: float, flip: float | str) -> torch.Tensor:
    """flip_share per point [P] from the points' c_p / dx (1/s), for every point even at a fixed
    share: what the Warp kernels read, made once per dt (in g2p the exponential was a third of its time)."""
    if flip == FLIP_WAVE:
        return torch.exp(-dt * wave_rate).contiguous()
    return torch.full_like(wave_rate, float(flip))


LOOSE = 1.16  # volume ratio beyond which a point has no contact network: random close / loose packing 0.64 / 0.55
DILUTE = 2.0  # volume ratio beyond which a point is dilute (no contacts, no stress)


def nodal_volumetric_rate(pts: Points, m_grid: torch.Tensor, cache) -> torch.Tensor:
    """[P] the volumetric rate tr(C) averaged through the nodes: each node takes the
    mass-weighted mean of its points' tr(C) (the p2g weights), each point the weighted mean of
    its nodes (the g2p weights). 1/s."""
    ids, w, _ = cache
    tr = pts.C[:, 0, 0] + pts.C[:, 1, 1]
    node = torch.zeros_like(m_grid).index_add_(0, ids.reshape(-1), ((pts.mass * tr)[:, None] * w).reshape(-1))
    node = torch.where(m_grid > 0, node / m_grid.clamp_min(1e-30), torch.zeros_like(node))
    return (w * node[ids]).sum(1)


def velocity_gradient(pts: Points, m_grid: torch.Tensor, cache) -> torch.Tensor:
    """[P, 2, 2] the velocity gradient the stress and volume updates use: the APIC C with its
    volumetric part moved towards the nodal average by the mobilised strength w,
    L = C + w (tr_avg - tr C) / 2 I.

    With psi = 0 the plastic flow is isochoric; asking tr(L) = 0 at every point is more
    constraints than the grid has velocity modes (volumetric locking), so the flow stiffens and
    dissipates more the coarser the grid. Averaging through the nodes removes the excess
    constraints (B-bar-like); weighting by the mobilised strength leaves unloaded, elastic
    soil (a standing cut's face) its own rate, and nothing switches on and off between
    substeps (docs/scene-format.md, solver version 6)."""
    C = pts.C
    tr = C[:, 0, 0] + C[:, 1, 1]
    shift = 0.5 * mobilised(pts.stress, pts.mat) * (nodal_volumetric_rate(pts, m_grid, cache) - tr)
    return C + shift[:, None, None] * torch.eye(2, dtype=C.dtype, device=C.device)


def substep(pts: Points, grid: Grid, dt: float, flip: float | str = FLIP_WAVE, damping: float = 0.0) -> None:
    """Advance every point by dt seconds in place: p2g, grid_update, g2p, then stress and volume."""
    m_grid, p_grid, cache = p2g(pts, grid, dt)
    v_grid, v_before = grid_update(m_grid, p_grid, grid, dt, damping)
    g2p(pts, v_grid, v_before, cache, grid, dt, flip_share(pts, dt, flip))
    grad_v = velocity_gradient(pts, m_grid, cache)
    pts.stress = update_stress(pts.stress, grad_v, dt, pts.mat)
    j = (1 + dt * grad_v[:, 0, 0]) * (1 + dt * grad_v[:, 1, 1]) - dt * dt * grad_v[:, 0, 1] * grad_v[:, 1, 0]
    pts.volume = pts.volume * j  # det(I + dt L)
    # dilute soil carries no stress: a point spread over more than DILUTE times its packed area
    # has lost its contacts (and its cohesion); it takes stress again, from zero, once packed
    loose = pts.volume > DILUTE * pts.rest_volume
    pts.stress = torch.where(loose[:, None], torch.zeros_like(pts.stress), pts.stress)
    # a point spread beyond the loosest packing that keeps a contact network is a loose clod:
    # it takes no part in the continuum's velocity field, so it keeps no affine velocity and its
    # momentum meets its neighbours' on the grid as a lump, a perfectly inelastic collision
    # (soil clods do not bounce). Without this a thin sheet of opened, stress-free points kept
    # the shear profile it carried over the base nodes and glided on (docs/scene-format.md)
    unpacked = pts.volume > LOOSE * pts.rest_volume
    pts.C = torch.where(unpacked[:, None, None], torch.zeros_like(pts.C), pts.C)

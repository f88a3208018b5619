"""MPM set-up: scenes in, the Batch that solver.substep advances out, all made once per run.

    batch = build_batch([scene_a, scene_b], torch.device("cpu"), torch.float64)

Here live the points (seeded, with mass and overburden), the flat grid of all scenes with
its walls, the fixed-ground contact, the time step, and the per-point material constants
with their two rules that follow phi: the K0 start (K0 = 1 - sin phi unless a material gives
k0) and the tension cut-off cap (T = min(T_given, c / tan phi)). Both the batched run
(runout.mpm.simulate) and the differentiable run (runout.mpm.differentiable) build their
materials with MaterialTable.arrays and their start with MaterialTable.start_stress.
Units: m, s, kg per metre of thickness, Pa; compression negative.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from runout.mpm.geostatic import GRAVITY, initial_stress, vertical_stress
from runout.mpm.mohr_coulomb import MaterialArrays
from runout.mpm.solver import PAD, STENCIL, Constraint, Grid, Points, stencil
from runout.scene import Material, Scene, SeedPoints, fill_points, points_in_polygon

CONTACT_SHARE = 0.4  # a node is in contact with fixed ground from this share of a full node's fixed mass


def material_table(scene: Scene) -> np.ndarray:
    """[M, 2] (phi in degrees, c in kPa) per material, in scene.material_names order."""
    return np.array([[m.friction_angle, m.cohesion] for m in scene.materials.values()], dtype=np.float64)


@dataclass
class Strengths:
    """The per-material terms that follow phi and c (tensors [M], float64)."""

    phi: torch.Tensor  # radians
    sin_phi: torch.Tensor
    cos_phi: torch.Tensor
    tan_phi: torch.Tensor  # tan phi where phi > 0; tan 1 elsewhere (never used there, keeps gradients finite)
    cohesion: torch.Tensor  # Pa

    @classmethod
    def of(cls, phi_deg: torch.Tensor, c_kpa: torch.Tensor) -> Strengths:
        """From tensors of phi (degrees) and c (kPa); differentiable."""
        rad = torch.deg2rad(phi_deg)
        tan = torch.tan(torch.where(rad > 0, rad, torch.ones_like(rad)))
        return cls(rad, torch.sin(rad), torch.cos(rad), tan, c_kpa * 1e3)

    @classmethod
    def of_materials(cls, materials: list[Material], device: torch.device) -> Strengths:
        """The materials' own, through libm (math), so the batched run keeps the bits it has
        always had: torch's sin, cos and tan differ from libm's by an ulp at 57, 16 and 73 of
        26,000 angles (0-60 degrees, torch 2.13 on CPU)."""
        rad = [math.radians(m.friction_angle) for m in materials]
        columns = (rad, [math.sin(r) for r in rad], [math.cos(r) for r in rad],
                   [math.tan(r if r > 0 else 1.0) for r in rad], [m.cohesion * 1e3 for m in materials])
        return cls(*(torch.tensor(v, dtype=torch.float64, device=device) for v in columns))


@dataclass
class MaterialTable:
    """The constants that do not follow phi or c (tensors [M], float64) and each moving
    point's row in them."""

    lam: torch.Tensor  # Lame lambda, Pa
    shear: torch.Tensor  # G, Pa
    plastic: torch.Tensor  # bool: Mohr-Coulomb (True) or linear elastic
    tension: torch.Tensor  # the tension cut-off given, Pa (before the cap)
    k0: torch.Tensor  # K0 given (elastic: nu / (1 - nu)); NaN: 1 - sin phi, which follows phi
    point: torch.Tensor  # [P] row of each moving point

    @classmethod
    def of_materials(cls, materials: list[Material], point: np.ndarray, device: torch.device) -> MaterialTable:
        e = [m.youngs_modulus * 1e6 for m in materials]
        nu = [m.poisson_ratio for m in materials]
        k0 = [n / (1 - n) if m.model == "elastic" else (math.nan if m.k0 is None else m.k0)
              for m, n in zip(materials, nu)]
        f64 = dict(dtype=torch.float64, device=device)
        return cls(
            lam=torch.tensor([a * n / ((1 + n) * (1 - 2 * n)) for a, n in zip(e, nu)], **f64),
            shear=torch.tensor([a / (2 * (1 + n)) for a, n in zip(e, nu)], **f64),
            plastic=torch.tensor([m.model == "mohr-coulomb" for m in materials], device=device),
            tension=torch.tensor([m.tension_cutoff * 1e3 for m in materials], **f64),
            k0=torch.tensor(k0, **f64),
            point=torch.as_tensor(point, device=device),
        )

    def arrays(self, s: Strengths, dtype: torch.dtype) -> MaterialArrays:
        """Per-point constants, the tension cut-off capped at c / tan phi where phi > 0."""
        cut = torch.where(s.phi > 0, torch.minimum(self.tension, s.cohesion / s.tan_phi), self.tension)
        p = self.point
        return MaterialArrays(
            lam=self.lam[p].to(dtype), shear=self.shear[p].to(dtype), sin_phi=s.sin_phi[p].to(dtype),
            cos_phi=s.cos_phi[p].to(dtype), cohesion=s.cohesion[p].to(dtype), tension=cut[p].to(dtype),
            plastic=self.plastic[p],
        )

    def start_stress(self, sigma_v: torch.Tensor, s: Strengths, dtype: torch.dtype) -> torch.Tensor:
        """[P, 4] the K0 start from the overburden sigma_v [P] (Pa), compression negative."""
        k0 = torch.where(torch.isnan(self.k0), 1 - s.sin_phi, self.k0)[self.point]
        return initial_stress(sigma_v, k0).to(dtype)


@dataclass
class Batch:
    scenes: list[Scene]
    grid: Grid
    pts: Points
    n_sub: int
    dt: float
    flip: float | str  # FLIP share: "wave" or a fixed share per substep
    damping: float
    materials: MaterialTable  # all scenes' materials, one after another
    sigma_v: torch.Tensor  # [P] float64, Pa: the overburden of each moving point (the K0 start)
    moving_index: list[np.ndarray]  # per scene: indices of its moving points in its output order
    fixed_xy: list[np.ndarray]  # per scene: fixed point positions
    order: list[tuple[np.ndarray, np.ndarray, np.ndarray]]  # per scene: (moving mask, ptype, material id)


def build_batch(scenes: list[Scene], device: torch.device, dtype: torch.dtype) -> Batch:
    """Scenes that share cell size and time settings as one flat problem (runout.mpm.simulate groups them)."""
    seeds = [fill_points(s) for s in scenes]
    densities = [_density(s, p) for s, p in zip(scenes, seeds)]
    grid = _grid(scenes, device, dtype)
    _add_fixed_ground(grid, scenes, seeds, densities, dtype)
    per_scene = [[s.materials[n] for n in s.material_names] for s in scenes]
    materials = [m for mats in per_scene for m in mats]
    first_row = np.cumsum([0] + [len(mats) for mats in per_scene[:-1]])
    rows = np.concatenate([p.material_id[~p.fixed] + r for p, r in zip(seeds, first_row)])
    table = MaterialTable.of_materials(materials, rows, device)
    strengths = Strengths.of_materials(materials, device)
    sigma_v = torch.as_tensor(np.concatenate([
        vertical_stress(p.position, rho, p.fixed, s.domain.point_spacing)[~p.fixed]
        for s, p, rho in zip(scenes, seeds, densities)
    ]), device=device)
    mat = table.arrays(strengths, dtype)
    pts = _points(scenes, seeds, densities, grid, mat, table.start_stress(sigma_v, strengths, dtype), dtype)
    n_sub = substeps_per_frame(scenes[0])
    time = scenes[0].time
    return Batch(
        scenes, grid, pts, n_sub, time.frame_dt / n_sub, time.flip, time.damping, table, sigma_v,
        moving_index=[np.flatnonzero(~p.fixed) for p in seeds],
        fixed_xy=[p.position[p.fixed] for p in seeds],
        order=[(~p.fixed, p.particle_type, p.material_id) for p in seeds],
    )


def _density(scene: Scene, p: SeedPoints) -> np.ndarray:
    """[N] kg/m^3 of each point's material."""
    mats = [scene.materials[n] for n in scene.material_names]
    return np.array([mats[m].density for m in p.material_id])


def _points(scenes, seeds, densities, grid: Grid, mat: MaterialArrays, stress, dtype) -> Points:
    """The moving points of all scenes, scene after scene, at rest in their K0 state."""
    device = grid.node_offset.device

    def cat(arrays, kind=dtype):
        return torch.as_tensor(np.concatenate(arrays), device=device, dtype=kind)

    moving = [~p.fixed for p in seeds]
    volume = cat([np.full(m.sum(), p.volume) for p, m in zip(seeds, moving)])
    mass = cat([(rho * p.volume)[m] for p, rho, m in zip(seeds, densities, moving)])
    scene = cat([np.full(m.sum(), k) for k, m in enumerate(moving)], torch.long)
    ny = grid.ny_nodes[scene]
    return Points(
        x=cat([p.position[m] for p, m in zip(seeds, moving)]), v=cat([p.velocity[m] for p, m in zip(seeds, moving)]),
        C=torch.zeros(len(volume), 2, 2, dtype=dtype, device=device),
        stress=stress, volume=volume, rest_volume=volume.clone(), mass=mass, scene=scene,
        upper=cat([np.tile([s.domain.width, s.domain.height], (m.sum(), 1)) for s, m in zip(scenes, moving)]),
        mat=mat, node_base=grid.node_offset[scene], ny=ny, stencil_offsets=stencil_offsets(ny),
        wave_rate=torch.sqrt(mat.k * volume / mass) / grid.dx,
    )


def substeps_per_frame(scene: Scene) -> int:
    """Substeps per output frame from the CFL condition on dx / (c_p + v_max), where v_max
    bounds the speed by energy: sqrt(v0^2 + 2 g H) for the tallest possible fall."""
    moving = {r.material for r in scene.regions if not r.fixed}
    c_p = max(
        p_wave_speed(m.youngs_modulus * 1e6, m.poisson_ratio, m.density)
        for name, m in scene.materials.items()
        if name in moving
    ) if moving else 1.0
    v0 = max((math.hypot(*r.velocity) for r in scene.regions), default=0.0)
    v_max = math.sqrt(v0**2 + 2 * GRAVITY * scene.domain.height)
    dt = stable_dt(scene.domain.cell_size, c_p, v_max, scene.time.cfl)
    return max(1, math.ceil(scene.time.frame_dt / dt - 1e-9))


def stable_dt(dx: float, p_wave_speed: float, max_speed: float, cfl: float) -> float:
    """CFL time step dx / (c_p + v_max) times the Courant number (s)."""
    return cfl * dx / (p_wave_speed + max_speed)


def p_wave_speed(youngs_pa: float, nu: float, density: float) -> float:
    m = youngs_pa * (1 - nu) / ((1 + nu) * (1 - 2 * nu))  # constrained modulus, Pa
    return math.sqrt(m / density)


def grid_shape(scene: Scene) -> tuple[int, int]:
    """Nodes per direction including padding; a domain that is not a whole number of cells
    gets a grid up to the next whole cell, its right and top walls acting there."""
    nx = math.ceil(scene.domain.width / scene.domain.cell_size - 1e-9)
    ny = math.ceil(scene.domain.height / scene.domain.cell_size - 1e-9)
    return nx + 1 + 2 * PAD, ny + 1 + 2 * PAD


def _grid(scenes: list[Scene], device: torch.device, dtype: torch.dtype) -> Grid:
    """Every scene's block of nodes, one after another, with its walls (no fixed ground yet)."""
    dx = scenes[0].domain.cell_size
    shapes = [grid_shape(s) for s in scenes]
    sizes = [a * b for a, b in shapes]
    offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    walls = _wall_constraints(scenes, shapes, offsets)

    def t(a, kind):
        return torch.as_tensor(a, device=device, dtype=kind)

    return Grid(
        size=int(sum(sizes)), dx=dx, node_offset=t(offsets, torch.long),
        ny_nodes=t(np.array([b for _, b in shapes]), torch.long),
        constraints=[Constraint(t(i, torch.long), t(n, dtype), t(m, dtype)) for i, n, m in walls],
        stuck=torch.zeros(0, dtype=torch.long, device=device),
        offsets=torch.tensor(STENCIL, dtype=dtype, device=device) * dx,
    )


def stencil_offsets(ny: torch.Tensor) -> torch.Tensor:
    """[P, 9] node-id offsets a * ny + b of the 3 x 3 stencil for points with ny nodes per column."""
    a = torch.tensor([a for a, _ in STENCIL], device=ny.device)
    b = torch.tensor([b for _, b in STENCIL], device=ny.device)
    return a[None, :] * ny[:, None] + b[None, :]


def _wall_constraints(scenes, shapes, offsets) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Node lists of the side walls (left and right, with wall friction), then of the base
    (base friction) and top (wall friction): every node on or beyond a wall."""
    sides, floors = [], []
    for s, (nxn, nyn), off in zip(scenes, shapes, offsets):
        i, j = np.meshgrid(np.arange(nxn) - PAD, np.arange(nyn) - PAD, indexing="ij")
        ids = off + np.arange(nxn * nyn).reshape(nxn, nyn)
        nx, ny = nxn - 1 - 2 * PAD, nyn - 1 - 2 * PAD
        for mask, normal, mu, group in (
            (i <= 0, (1.0, 0.0), s.domain.wall_friction, sides),
            (i >= nx, (-1.0, 0.0), s.domain.wall_friction, sides),
            (j <= 0, (0.0, 1.0), s.domain.base_friction, floors),
            (j >= ny, (0.0, -1.0), s.domain.wall_friction, floors),
        ):
            k = int(mask.sum())
            group.append((ids[mask], np.tile(normal, (k, 1)), np.full(k, mu)))
    return [tuple(np.concatenate(parts) for parts in zip(*g)) for g in (sides, floors)]


def _add_fixed_ground(grid: Grid, scenes, seeds, densities, dtype) -> None:
    """The fixed-ground contact (base friction) and stuck nodes, added to the grid."""
    device = grid.node_offset.device
    fixed_mass = np.concatenate([(rho * p.volume)[p.fixed] for p, rho in zip(seeds, densities)])
    if not len(fixed_mass):
        return
    scene = torch.as_tensor(np.concatenate([np.full(p.fixed.sum(), k) for k, p in enumerate(seeds)]), device=device)
    ny = grid.ny_nodes[scene]
    position = torch.as_tensor(np.concatenate([p.position[p.fixed] for p in seeds]), device=device, dtype=dtype)
    ids, w, _ = stencil(position, grid.node_offset[scene], ny, stencil_offsets(ny), grid.dx)
    full = float(np.max(fixed_mass)) / scenes[0].domain.point_spacing**2 * grid.dx**2
    offsets = grid.node_offset.cpu().numpy()
    surface, normal, grid.stuck = fixed_ground_contact(
        torch.as_tensor(fixed_mass, device=device, dtype=dtype), ids, w, grid.size, full,
        [grid_shape(s) for s in scenes], offsets, [_ground_edges(s) for s in scenes], grid.dx,
    )
    mu = torch.as_tensor(
        [scenes[k].domain.base_friction for k in np.searchsorted(offsets, surface.cpu().numpy(), "right") - 1],
        dtype=dtype, device=device,
    )
    grid.constraints.append(Constraint(surface, normal, mu))


def _ground_edges(scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exposed edges of the scene's fixed polygons: (a [E, 2], b [E, 2], outward normal [E, 2]),
    m. An edge is exposed unless it lies on a wall or another fixed polygon lies just beyond it."""
    fixed = [np.asarray(r.polygon, dtype=float) for r in scene.regions if r.fixed]
    w, h = scene.domain.width, scene.domain.height
    tol = 1e-6 * max(w, h)
    out_a, out_b, out_n = [], [], []
    for k, poly in enumerate(fixed):
        x, y = poly[:, 0], poly[:, 1]
        orient = 1.0 if np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y) > 0 else -1.0  # CCW: +1
        for p, q in zip(poly, np.roll(poly, -1, axis=0)):
            d = q - p
            length = float(np.hypot(*d))
            if length <= tol:
                continue
            n = orient * np.array([d[1], -d[0]]) / length
            on_wall = any(abs(p[i] - v) < tol and abs(q[i] - v) < tol for i, v in ((0, 0.0), (0, w), (1, 0.0), (1, h)))
            probe = (0.5 * (p + q) + 1e-3 * max(w, h) * n)[None]
            shared = any(points_in_polygon(probe, other)[0] for j, other in enumerate(fixed) if j != k)
            if not on_wall and not shared:
                out_a.append(p), out_b.append(q), out_n.append(n)
    empty = np.zeros((0, 2))
    return tuple(np.array(v) if v else empty for v in (out_a, out_b, out_n))


def fixed_ground_contact(mass, ids, w, size: int, full_node_mass: float, shapes, offsets, edges, dx: float):
    """Contact constraint and stuck nodes of the fixed ground (computed once: it never moves).

    A node is in contact when the fixed points give it at least CONTACT_SHARE of a full node's
    mass. Its outward normal is that of the nearest exposed edge of the fixed polygons (edges
    not shared with other fixed ground nor lying on a wall): the exact surface, where a normal
    from the staircase of fixed points leaned 1 degree off a 30 degree plane and let a block
    sink into it and slide 5 % too far. Nodes more than 2.5 cells inside the ground, which no
    moving point's stencil (1.5 cells) reaches, are held still. shapes [(nx, ny)], offsets and
    edges [(a [E, 2], b [E, 2], normal [E, 2]) in metres] describe each scene."""
    m_fix = torch.zeros(size, dtype=w.dtype, device=w.device)
    m_fix.index_add_(0, ids.reshape(-1), (mass[:, None] * w).reshape(-1))
    contact = torch.nonzero(m_fix >= CONTACT_SHARE * full_node_mass).squeeze(1)
    normal = torch.zeros(len(contact), 2, dtype=w.dtype, device=w.device)
    depth = torch.full((len(contact),), math.inf, dtype=w.dtype, device=w.device)
    for (nx, ny), off, (a, b, n) in zip(shapes, offsets, edges):
        mine = (contact >= off) & (contact < off + nx * ny)
        if not mine.any() or len(a) == 0:
            continue
        local = contact[mine] - off
        pos = torch.stack(((local // ny - PAD) * dx, (local % ny - PAD) * dx), 1).to(w.dtype)
        a, b, n = (torch.as_tensor(v, dtype=w.dtype, device=w.device) for v in (a, b, n))
        ab = b - a
        t = (((pos[:, None, :] - a[None]) * ab[None]).sum(-1) / (ab * ab).sum(-1)[None]).clamp(0.0, 1.0)
        dist = (pos[:, None, :] - (a[None] + t[..., None] * ab[None])).norm(dim=-1)  # [K, E]
        nearest = dist.argmin(1)
        normal[mine] = n[nearest]
        depth[mine] = dist.gather(1, nearest[:, None]).squeeze(1)
    deep = depth > 2.5 * dx
    return contact[~deep], normal[~deep], contact[deep]

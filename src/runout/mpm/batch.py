"""Turn scenes into one batched MPM problem and run it frame by frame."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import torch
from tqdm.auto import tqdm

from runout.mpm.geostatic import GRAVITY, initial_stress, vertical_stress
from runout.mpm.mohr_coulomb import MaterialArrays, return_map
from runout.mpm.solver import (
    PAD, Constraint, Grid, Points, energies, fixed_ground_contact, node_offsets, p_wave_speed,
    stable_dt, stencil, stencil_offsets, substep,
)
from runout.scene import Scene, fill_points
from runout.trajectory import Trajectory, trajectory_for_scene

RELAX_CFL = 1.5  # relaxation step as a share of the scene CFL step on the wave speed alone
RELAX_PERIODS = 3.0  # length of the geostatic relaxation in periods of the slowest mode
RELAX_DAMPING = 0.8  # local damping share during the relaxation (FLAC's default for static equilibrium)


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


@dataclass
class Batch:
    scenes: list[Scene]
    grid: Grid
    pts: Points
    n_sub: int
    dt: float
    flip: float | str  # FLIP share: "wave" or a fixed share per substep
    damping: float
    moving_index: list[np.ndarray]  # per scene: indices of its moving points in its output order
    fixed_xy: list[np.ndarray]  # per scene: fixed point positions
    order: list[tuple[np.ndarray, np.ndarray, np.ndarray]]  # per scene: (moving mask, ptype, material id)


def _scene_grid_shape(scene: Scene) -> tuple[int, int]:
    """Nodes per direction including padding; a domain that is not a whole number of cells
    gets a grid up to the next whole cell, its right and top walls acting there."""
    nx = math.ceil(scene.domain.width / scene.domain.cell_size - 1e-9)
    ny = math.ceil(scene.domain.height / scene.domain.cell_size - 1e-9)
    return nx + 1 + 2 * PAD, ny + 1 + 2 * PAD


def build_batch(scenes: list[Scene], device: torch.device, dtype: torch.dtype) -> Batch:
    dx = scenes[0].domain.cell_size
    shapes = [_scene_grid_shape(s) for s in scenes]
    sizes = [a * b for a, b in shapes]
    offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    t = lambda a, dt=None: torch.as_tensor(a, device=device, dtype=dt)  # noqa: E731
    size = int(sum(sizes))
    walls = _wall_constraints(scenes, shapes, offsets)

    xs, vs, stress, vol, mass, scene_id, upper, mat_rows = [], [], [], [], [], [], [], []
    fx, fmass, fscene = [], [], []
    moving_index, fixed_xy, order = [], [], []
    for k, s in enumerate(scenes):
        p = fill_points(s)
        mats = [s.materials[n] for n in s.material_names]
        rho = np.array([mats[m].density for m in p.material_id])
        pmass = rho * p.volume
        moving = ~p.fixed
        order.append((moving, p.particle_type, p.material_id))
        moving_index.append(np.flatnonzero(moving))
        fixed_xy.append(p.position[p.fixed])
        sig_v = vertical_stress(p.position, rho, p.fixed, s.domain.point_spacing)
        k0 = np.array([
            mats[m].poisson_ratio / (1 - mats[m].poisson_ratio) if mats[m].model == "elastic" else mats[m].k0_value
            for m in p.material_id
        ])
        xs.append(p.position[moving])
        vs.append(p.velocity[moving])
        stress.append(initial_stress(sig_v, k0)[moving])
        vol.append(np.full(moving.sum(), p.volume))
        mass.append(pmass[moving])
        scene_id.append(np.full(moving.sum(), k))
        upper.append(np.tile([s.domain.width, s.domain.height], (moving.sum(), 1)))
        mat_rows.append(_material_rows(mats, p.material_id[moving]))
        fx.append(p.position[p.fixed])
        fmass.append(pmass[p.fixed])
        fscene.append(np.full(p.fixed.sum(), k))

    grid = Grid(
        size=size, dx=dx, node_offset=t(offsets, torch.long), ny_nodes=t(np.array([b for _, b in shapes]), torch.long),
        constraints=[Constraint(t(i, torch.long), t(n, dtype), t(m, dtype)) for i, n, m in walls],
        stuck=torch.zeros(0, dtype=torch.long, device=device),
        offsets=node_offsets(dx, torch.zeros(0, dtype=dtype, device=device)),
    )
    fixed_pos = np.concatenate(fx)
    if len(fixed_pos):
        fscene_t = t(np.concatenate(fscene), torch.long)
        fny = grid.ny_nodes[fscene_t]
        ids, w, _ = stencil(t(fixed_pos, dtype), grid.node_offset[fscene_t], fny, stencil_offsets(fny), dx)
        spacing = scenes[0].domain.point_spacing
        full = float(np.max(np.concatenate(fmass))) / spacing**2 * dx**2
        surface, normal, grid.stuck = fixed_ground_contact(
            t(np.concatenate(fmass), dtype), ids, w, size, full, shapes, offsets,
            [_ground_edges(s) for s in scenes], dx,
        )
        mu = torch.as_tensor(
            [scenes[k].domain.base_friction for k in np.searchsorted(offsets, surface.cpu().numpy(), "right") - 1],
            dtype=dtype, device=device,
        )
        grid.constraints.append(Constraint(surface, normal, mu))
    rows = np.concatenate(mat_rows)
    mat = MaterialArrays(
        lam=t(rows[:, 0], dtype), shear=t(rows[:, 1], dtype), sin_phi=t(rows[:, 2], dtype),
        cos_phi=t(rows[:, 3], dtype), cohesion=t(rows[:, 4], dtype), tension=t(rows[:, 5], dtype),
        plastic=t(rows[:, 6] > 0.5),
    )
    n = int(sum(len(a) for a in xs))
    scene_t = t(np.concatenate(scene_id), torch.long)
    ny_p = grid.ny_nodes[scene_t]
    pts = Points(
        x=t(np.concatenate(xs), dtype), v=t(np.concatenate(vs), dtype),
        C=torch.zeros(n, 2, 2, dtype=dtype, device=device),
        stress=t(np.concatenate(stress), dtype), volume=t(np.concatenate(vol), dtype),
        rest_volume=t(np.concatenate(vol), dtype),
        mass=t(np.concatenate(mass), dtype), scene=scene_t,
        upper=t(np.concatenate(upper), dtype), mat=mat,
        node_base=grid.node_offset[scene_t], ny=ny_p, stencil_offsets=stencil_offsets(ny_p),
        wave_rate=torch.sqrt(mat.k * t(np.concatenate(vol), dtype) / t(np.concatenate(mass), dtype)) / grid.dx,
    )
    n_sub = substeps_per_frame(scenes[0])
    time = scenes[0].time
    return Batch(scenes, grid, pts, n_sub, time.frame_dt / n_sub, time.flip, time.damping, moving_index, fixed_xy, order)


def _ground_edges(scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exposed edges of the scene's fixed polygons: (a [E, 2], b [E, 2], outward normal [E, 2]),
    m. An edge is exposed unless it lies on a wall or another fixed polygon lies just beyond it."""
    from runout.scene import points_in_polygon

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


def _material_rows(mats, material_id: np.ndarray) -> np.ndarray:
    """[P, 7] = (lambda, G, sin phi, cos phi, c, tension cut-off, plastic) in Pa."""
    table = []
    for m in mats:
        e = m.youngs_modulus * 1e6
        nu = m.poisson_ratio
        lam = e * nu / ((1 + nu) * (1 - 2 * nu))
        g = e / (2 * (1 + nu))
        phi = math.radians(m.friction_angle)
        c = m.cohesion * 1e3
        t_cut = m.tension_cutoff * 1e3
        if phi > 0:
            t_cut = min(t_cut, c / math.tan(phi))
        table.append((lam, g, math.sin(phi), math.cos(phi), c, t_cut, float(m.model == "mohr-coulomb")))
    return np.asarray(table, dtype=float)[material_id]


def relax_geostatic(batch: Batch, step=substep) -> int:
    """Bring the K0 stresses into the discrete equilibrium of this grid before release.

    Damped elastic-plastic dynamics with the points held in place: stresses absorb the strain
    the grid would impose, through the materials' own yield and tension cut-off, until grid
    forces balance gravity; then the velocities are reset. The start is so statically and
    plastically admissible wherever the scene can stand: a cut whose crest cracks in tension
    has cracked before release, instead of opening (and being counted as moving) after it.
    A scene that cannot stand still fails on release. The damping is local (Cundall's, as in
    FLAC's static solutions): RELAX_DAMPING of each component of the unbalanced nodal force,
    which damps every mode alike. Viscous damping tuned to the slowest mode left the opening
    at a cut's face (soil held at the tension cut-off, which has no stiffness against opening)
    still moving at 0.05 m/s after three periods, and an opened face coasts on that speed after
    release (docs/scene-format.md, solver version 5). RELAX_PERIODS periods of the slowest
    vertical mode (4 H / c_p for the scene's tallest body H) are run at the wave-speed CFL step;
    a scene that has finished holds its stresses while others go on, so a batch relaxes each
    scene exactly as it would alone. Returns the substeps run."""
    pts, grid = batch.pts, batch.grid
    if len(pts.x) == 0:
        return 0
    n_scenes = len(batch.scenes)
    height = torch.zeros(n_scenes, dtype=pts.x.dtype, device=pts.x.device)
    height.scatter_reduce_(0, pts.scene, pts.x[:, 1], reduce="amax")
    c_p = torch.zeros_like(height)
    c_p.scatter_reduce_(0, pts.scene, torch.sqrt((pts.mat.lam + 2 * pts.mat.shear) * pts.volume / pts.mass),
                        reduce="amax")
    period = 4 * height / c_p  # s, per scene
    # points are held, so only the wave speed limits the step (no fall speed as in batch.dt)
    dt = max(batch.dt, RELAX_CFL * batch.scenes[0].time.cfl * grid.dx / float(c_p.max()))
    steps = torch.ceil(RELAX_PERIODS * period / dt).long()  # per scene
    steps_p = steps[pts.scene]
    x0, v0 = pts.x.clone(), pts.v.clone()
    pts.v = torch.zeros_like(v0)
    total = int(steps.max())
    for k in range(total):
        stress = pts.stress
        step(pts, grid, dt, batch.flip, RELAX_DAMPING)
        pts.stress = torch.where((k < steps_p)[:, None], pts.stress, stress)
        pts.x = x0
    pts.x, pts.v = x0, v0
    pts.C = torch.zeros_like(pts.C)
    pts.volume = torch.full_like(pts.volume, float(batch.scenes[0].domain.point_spacing) ** 2)
    pts.stress = return_map(pts.stress, pts.mat)
    return total


def run_batch(batch: Batch, frames: int, progress: bool = True, compile: bool = False) -> list[Trajectory]:
    """Advance every scene of the batch through `frames` output frames (frame 0 = start).

    compile=True fuses the substep with torch.compile: about 2.5x faster per substep on CPU
    but it costs a minute or more of compilation first, so it pays off only on long runs."""
    pts, grid = batch.pts, batch.grid
    n_scenes = len(batch.scenes)
    step = torch.compile(substep, dynamic=True) if compile else substep
    with torch.no_grad():
        relax_steps = relax_geostatic(batch, step)
    record = [pts.x.detach().to("cpu", torch.float32)]
    ke0, pe0 = energies(pts, n_scenes)
    kinetic, potential = [ke0.cpu()], [pe0.cpu()]
    start = time.perf_counter()
    with torch.no_grad():
        for _ in tqdm(range(frames - 1), desc=f"MPM {n_scenes} scene(s)", unit="frame", disable=not progress):
            for _ in range(batch.n_sub):
                step(pts, grid, batch.dt, batch.flip, batch.damping)
            record.append(pts.x.to("cpu", torch.float32))
            ke, pe = energies(pts, n_scenes)
            kinetic.append(ke.cpu())
            potential.append(pe.cpu())
    wall = time.perf_counter() - start
    moving_all = torch.stack(record).numpy()  # [T, P, 2]
    kinetic = torch.stack(kinetic).numpy()
    potential = torch.stack(potential).numpy()
    scene_of = pts.scene.cpu().numpy()
    out = []
    for k, s in enumerate(batch.scenes):
        moving, ptype, mid = batch.order[k]
        positions = np.empty((frames, len(moving), 2), dtype=np.float32)
        positions[:, moving] = moving_all[:, scene_of == k]
        positions[:, ~moving] = batch.fixed_xy[k][None].astype(np.float32)
        traj = trajectory_for_scene(s, positions, ptype, mid)
        traj.info = {
            "engine": "mpm",
            "substeps_per_frame": batch.n_sub,
            "relaxation_substeps": relax_steps,
            "dt": batch.dt,
            "wall_time_s": wall,
            "batch_size": n_scenes,
            "kinetic_energy": kinetic[:, k].tolist(),
            "potential_energy": potential[:, k].tolist(),
        }
        out.append(traj)
    return out

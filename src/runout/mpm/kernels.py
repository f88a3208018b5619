"""Solver 6's substep as fused NVIDIA Warp kernels: the physics of runout.mpm.solver and
runout.mpm.mohr_coulomb, one thread per point or per grid node, on CPU or CUDA from one source.

    step = WarpSubstep(batch.grid, batch.pts)   # once per batch
    step(pts, grid, dt, flip, damping)           # in place; what solver.substep does

A substep is six launches: clear_grid; p2g (mass, APIC momentum and the MLS internal-force
impulse, scattered with atomic adds); grid_update (gravity, local damping, then each node's
walls and fixed-ground contact in the order of grid.constraints, then the stuck nodes); g2p
(velocity and its gradient C, the FLIP blend with each point's share made once per dt, the
move and clamp, and the scatter of m tr(C) for the nodal volumetric average); nodal_rate (that
sum over the node's mass); update_points (the averaged volumetric rate weighted by the
mobilised strength, Jaumann rotation, elastic trial, Mohr-Coulomb return with tension cut-off,
volume, dilute and loose points). Same formulas as the torch solver, in float64 as its default;
results agree to rounding (the sums run in another order). The kernels read and write the
tensors of solver.Points in place (wp.from_torch: no copies), so everything around the substep
(relaxation schedule, frames, energies) stays in torch.

g2p and update_points read the old state (PointArrays) and write the new one (NewState): the
plain run points both at the same tensors (each thread reads its point before writing it), the
differentiable run (runout.mpm.kernels_ad) at new arrays, since Warp's adjoint of a kernel needs
its inputs unchanged. For the same reason the loops have fixed bounds and the functions' kinks
(sqrt at 0, the caps) are branches whose slopes are torch's (the slope at a cap itself passes,
as torch.clamp's does): values are unchanged, and the adjoints are those of torch autograd.

Warp compiles the module once per source version and caches the binary on disk in
warp.config.kernel_cache_dir (default ~/.cache/warp/<warp version>/); a later process loads it in
0.04 s. The first compile (CPU backend, forward and adjoint code) took 5.5 s on one core of a
loaded 2-core machine; without the adjoints it would take 3.7 s. CUDA builds its own binary in
the same cache on first use. Units: m, s, kg per metre of thickness, Pa; tension positive.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import torch
import warp as wp

from runout.defaults import FLIP_WAVE
from runout.mpm.geostatic import GRAVITY
from runout.mpm.mohr_coulomb import MaterialArrays
from runout.mpm.solver import DILUTE, LOOSE, PAD, Grid, Points, flip_shares
from runout.mpm.warp_runtime import start_warp

Real = wp.float64  # every real number of the substep; literals must carry it (Warp does not mix widths)
NODE = wp.constant(wp.vec3d(0.0, 1.0, 2.0))  # stencil node index a as a real: NODE[a] (Real(a) would retype the loop index)
FREE = 2**31 - 1  # a point's last stress-updating relaxation step when it has none (a normal run)
UPDATE_STEP = 5  # index of update_points' `step` argument
MAX_RULES = 4  # constraints on one node (a side wall, the base or top, the fixed ground): a fixed loop bound


# ---------------------------------------------------------------- state as Warp structs


@wp.struct
class PointArrays:
    """solver.Points as Warp arrays, sharing the torch tensors' memory."""

    x: wp.array(dtype=wp.vec2d)  # m
    v: wp.array(dtype=wp.vec2d)  # m/s
    C: wp.array(dtype=wp.mat22d)  # APIC affine velocity, 1/s
    stress: wp.array(dtype=wp.vec4d)  # (sxx, syy, sxy, szz) Pa
    volume: wp.array(dtype=Real)  # m^2
    rest_volume: wp.array(dtype=Real)
    mass: wp.array(dtype=Real)  # kg/m
    upper: wp.array(dtype=wp.vec2d)  # domain size, m
    node_base: wp.array(dtype=wp.int32)  # first grid node of the point's scene
    ny: wp.array(dtype=wp.int32)  # nodes per grid column of the point's scene
    last_stress_step: wp.array(dtype=wp.int32)  # relaxation: the point's stress is updated while k < this


@wp.struct
class NewState:
    """Where a substep writes the points' new state: PointArrays' own arrays for the plain run."""

    x_moved: wp.array(dtype=wp.vec2d)  # m: g2p's move, taken by update_points (it needs the old x)
    C_grid: wp.array(dtype=wp.mat22d)  # g2p's C, read by update_points
    x: wp.array(dtype=wp.vec2d)
    v: wp.array(dtype=wp.vec2d)
    C: wp.array(dtype=wp.mat22d)  # C_grid, zero for loose clods
    stress: wp.array(dtype=wp.vec4d)
    volume: wp.array(dtype=Real)


@wp.struct
class MaterialConstants:
    """mohr_coulomb.MaterialArrays per point."""

    lam: wp.array(dtype=Real)
    shear: wp.array(dtype=Real)
    sin_phi: wp.array(dtype=Real)
    cohesion: wp.array(dtype=Real)
    tension: wp.array(dtype=Real)
    plastic: wp.array(dtype=wp.int32)
    c_cos: wp.array(dtype=Real)
    k: wp.array(dtype=Real)
    ratio: wp.array(dtype=Real)
    corner3: wp.array(dtype=Real)
    inv_k: wp.array(dtype=Real)  # the apex rows
    inv_lam: wp.array(dtype=Real)


@wp.struct
class NodeArrays:
    """The flat grid of all scenes: transfers and each node's boundary rules in order."""

    mass: wp.array(dtype=Real)
    momentum: wp.array(dtype=wp.vec2d)
    impulse: wp.array(dtype=wp.vec2d)  # internal-force impulse dt f_int
    volumetric: wp.array(dtype=Real)  # sum of m tr(C) w
    rate: wp.array(dtype=Real)  # volumetric / mass, 1/s (0 on a node without mass): what update_points averages
    velocity: wp.array(dtype=wp.vec2d)
    velocity_before: wp.array(dtype=wp.vec2d)  # transferred momentum only (FLIP)
    rules: wp.array(dtype=wp.int32)  # how many constraints act on the node
    normal: wp.array2d(dtype=wp.vec2d)  # [node, rule] outward unit normal
    mu: wp.array2d(dtype=Real)  # [node, rule] Coulomb mu, inf: rough
    stuck: wp.array(dtype=wp.int32)  # 1: deep inside fixed ground, velocity zero


# ---------------------------------------------------------------- shared functions


@wp.func
def bspline(f: Real):
    """Quadratic B-spline weights of the three nodes for fractional position f in [0.5, 1.5)."""
    a = Real(1.5) - f
    b = f - Real(1.0)
    c = f - Real(0.5)
    return wp.vec3d(Real(0.5) * a * a, Real(0.75) - b * b, Real(0.5) * c * c)


@wp.func
def stencil_origin(x: wp.vec2d, inv_dx: Real, node_base: int, ny: int):
    """First node id of the point's 3 x 3 stencil and its fractional cell position fx (solver.stencil)."""
    xg = x * inv_dx
    bx = wp.floor(xg[0] - Real(0.5))
    by = wp.floor(xg[1] - Real(0.5))
    first = node_base + (int(bx) + PAD) * ny + int(by) + PAD
    return first, wp.vec2d(xg[0] - bx, xg[1] - by)


@wp.func
def sign0(a: Real):
    """torch.sign: 0 at 0 (wp.sign gives 1 there)."""
    if a > Real(0.0):
        return Real(1.0)
    if a < Real(0.0):
        return Real(-1.0)
    return Real(0.0)


@wp.func
def magnitude(a: Real):
    """|a| with torch's slope 0 at 0 (wp.abs has slope 1 there)."""
    return sign0(a) * a


@wp.func
def radius(a: Real, b: Real):
    """sqrt(a^2 + b^2), with slope 0 where it is 0 (sqrt's is infinite): torch's vector norm,
    and mohr_coulomb.mohr_radius under autograd."""
    r2 = a * a + b * b
    r = Real(0.0)
    if r2 > Real(0.0):
        r = wp.sqrt(r2)
    return r


@wp.func
def coulomb(v: wp.vec2d, n: wp.vec2d, mu: Real):
    """solver._coulomb for one node: remove the velocity into the surface, then reduce the
    tangential velocity by mu times the removed normal velocity; mu = inf sticks."""
    vn = v[0] * n[0] + v[1] * n[1]
    if vn >= Real(0.0):
        return v
    vt = v - vn * n
    if wp.isinf(mu):
        return wp.vec2d(Real(0.0), Real(0.0))
    speed = radius(vt[0], vt[1])
    if speed < Real(1e-12):
        speed = Real(1e-12)
    scale = Real(1.0) + mu * vn / speed
    if scale < Real(0.0):
        scale = Real(0.0)
    return vt * scale


@wp.func
def mobilised(s: wp.vec4d, mat: MaterialConstants, p: int):
    """mohr_coulomb.mobilised: t / (c cos phi - s sin phi) capped at 1; 1 at or beyond the apex; 0 elastic."""
    if mat.plastic[p] == 0:
        return Real(0.0)
    t = radius(Real(0.5) * (s[0] - s[1]), s[2])
    t_a = mat.c_cos[p] - Real(0.5) * (s[0] + s[1]) * mat.sin_phi[p]
    if t_a > Real(0.0):
        share = t / t_a
        if share > Real(1.0):
            share = Real(1.0)
        return share
    return Real(1.0)


@wp.func
def return_map(st: wp.vec4d, mat: MaterialConstants, p: int):
    """mohr_coulomb.return_map for one point: the multi-surface return (shear, tension, their
    corner, the tension apex) in the in-plane principal stresses, directions kept; szz kept
    between them. See mohr_coulomb.return_map for the flow rules."""
    if mat.plastic[p] == 0:
        return st
    s = Real(0.5) * (st[0] + st[1])
    d = Real(0.5) * (st[0] - st[1])
    t = radius(d, st[2])
    s1 = s + t
    s3 = s - t
    sin = mat.sin_phi[p]
    cut = mat.tension[p]
    lam = mat.lam[p]
    g = mat.shear[p]
    k = mat.k[p]
    t_a = mat.c_cos[p] - s * sin
    f_s = t - t_a
    f_t = s1 - cut
    ok_a = f_s > Real(0.0) and t_a >= Real(0.0) and s + t_a <= cut  # shear alone
    drop = f_t * mat.ratio[p]  # tension alone: s1 -> T, s3 and szz follow through lambda
    b3 = s3 - drop
    ok_b = f_t > Real(0.0) and b3 <= cut and Real(0.5) * (cut - b3) + Real(0.5) * (cut + b3) * sin <= mat.c_cos[p]
    if ok_a and ok_b:  # both admissible: the closer in complementary energy
        if f_s * f_s * k <= f_t * f_t * g:
            ok_b = False
        else:
            ok_a = False
    c3 = mat.corner3[p]
    l_t = (f_t - (c3 - s3)) / (k + lam)
    l_s = f_t - k * l_t  # times G
    p1 = cut  # tension apex: s1 = s3 = T
    p3 = cut
    dz = lam * ((mat.inv_k[p] - mat.inv_lam[p]) * (f_t + s3 - cut))
    if f_s <= Real(0.0) and f_t <= Real(0.0):  # elastic: the principal stresses stay (szz is still kept between them)
        p1 = s1
        p3 = s3
        dz = Real(0.0)
    elif ok_a:
        p1 = s + t_a
        p3 = s - t_a
        dz = Real(0.0)
    elif ok_b:
        p3 = b3
        dz = drop
    elif l_s >= Real(0.0) and l_t >= Real(0.0) and f_t > Real(0.0):  # corner
        p3 = c3
        dz = lam * l_t
    s_new = Real(0.5) * (p1 + p3)
    t_new = Real(0.5) * (p1 - p3)
    cos2 = Real(1.0)
    sin2 = Real(0.0)
    if t > Real(1e-9) * (wp.abs(s) + mat.cohesion[p] + Real(1.0)):  # principal directions defined
        cos2 = d / wp.max(t, Real(1e-30))
        sin2 = st[2] / wp.max(t, Real(1e-30))
    z = wp.min(wp.max(st[3] - dz, p3), p1)
    return wp.vec4d(s_new + t_new * cos2, s_new - t_new * cos2, t_new * sin2, z)


@wp.func
def update_stress(st: wp.vec4d, L: wp.mat22d, dt: Real, mat: MaterialConstants, p: int):
    """mohr_coulomb.update_stress: Jaumann rotation, plane-strain elastic trial, return."""
    exx = L[0, 0] * dt
    eyy = L[1, 1] * dt
    exy = Real(0.5) * (L[0, 1] + L[1, 0]) * dt
    spin = Real(0.5) * (L[0, 1] - L[1, 0]) * dt
    sxx = st[0] + Real(2.0) * spin * st[2]
    syy = st[1] - Real(2.0) * spin * st[2]
    sxy = st[2] + spin * (st[1] - st[0])
    g2 = Real(2.0) * mat.shear[p]
    vol = mat.lam[p] * (exx + eyy)
    trial = wp.vec4d(sxx + (vol + g2 * exx), syy + (vol + g2 * eyy), sxy + g2 * exy, st[3] + vol)
    return return_map(trial, mat, p)


# ---------------------------------------------------------------- the substep's kernels


@wp.kernel
def clear_grid(nodes: NodeArrays):
    n = wp.tid()
    nodes.mass[n] = Real(0.0)
    nodes.momentum[n] = wp.vec2d(Real(0.0), Real(0.0))
    nodes.impulse[n] = wp.vec2d(Real(0.0), Real(0.0))
    nodes.volumetric[n] = Real(0.0)


@wp.kernel
def p2g(pts: PointArrays, nodes: NodeArrays, dx: Real, dt_d_inv: Real):
    """Mass, APIC momentum m (v + C (x_i - x_p)) and impulse -dt V D^-1 sigma (x_i - x_p) to the 9 nodes."""
    p = wp.tid()
    first, fx = stencil_origin(pts.x[p], Real(1.0) / dx, pts.node_base[p], pts.ny[p])
    wx = bspline(fx[0])
    wy = bspline(fx[1])
    m = pts.mass[p]
    s = pts.stress[p]
    affine = m * pts.C[p]
    force = -(dt_d_inv * pts.volume[p]) * wp.mat22d(s[0], s[2], s[2], s[1])
    fxdx = fx * dx
    shift_m = affine @ fxdx - m * pts.v[p]
    shift_f = force @ fxdx
    for a in range(3):
        for b in range(3):
            w = wx[a] * wy[b]
            offset = wp.vec2d(NODE[a] * dx, NODE[b] * dx)
            node = first + a * pts.ny[p] + b
            wp.atomic_add(nodes.mass, node, m * w)
            wp.atomic_add(nodes.momentum, node, w * (affine @ offset - shift_m))
            wp.atomic_add(nodes.impulse, node, w * (force @ offset - shift_f))


@wp.kernel
def grid_update(nodes: NodeArrays, gravity_dt: Real, damping: Real):
    """Velocity with gravity and local (Cundall) damping, then the node's walls and fixed-ground
    contact in grid.constraints order, then stuck nodes (solver.grid_update)."""
    n = wp.tid()
    m = nodes.mass[n]
    if m <= Real(0.0):  # no points: every rule leaves a zero velocity zero
        nodes.velocity[n] = wp.vec2d(Real(0.0), Real(0.0))
        nodes.velocity_before[n] = wp.vec2d(Real(0.0), Real(0.0))
        return
    before = wp.vec2d(Real(0.0), Real(0.0))
    dv = wp.vec2d(Real(0.0), Real(0.0))
    if m > Real(0.0):
        before = nodes.momentum[n] / m
        dv = nodes.impulse[n] / m
    dv = wp.vec2d(dv[0], dv[1] - gravity_dt)
    if damping > Real(0.0):
        dv = wp.vec2d(dv[0] - damping * magnitude(dv[0]) * sign0(before[0]),
                      dv[1] - damping * magnitude(dv[1]) * sign0(before[1]))
    v = wp.vec2d(Real(0.0), Real(0.0))
    if m > Real(0.0):
        v = before + dv
    for r in range(MAX_RULES):
        if r < nodes.rules[n]:
            v = coulomb(v, nodes.normal[n, r], nodes.mu[n, r])
    if nodes.stuck[n] != 0:
        v = wp.vec2d(Real(0.0), Real(0.0))
    nodes.velocity[n] = v
    nodes.velocity_before[n] = before


@wp.func
def clamp(a: Real, low: Real, high: Real):
    """a within [low, high], its slope passing at the bounds themselves (torch.clamp)."""
    if a < low:
        return low
    if a > high:
        return high
    return a


@wp.kernel
def g2p(pts: PointArrays, nodes: NodeArrays, dx: Real, dt: Real, flip_share: wp.array(dtype=Real), out: NewState):
    """Velocity, APIC C, FLIP blend and the clamped move (solver.g2p); then m tr(C) to the nodes.
    flip_share: each point's FLIP share of this substep (flip_shares)."""
    p = wp.tid()
    first, fx = stencil_origin(pts.x[p], Real(1.0) / dx, pts.node_base[p], pts.ny[p])
    wx = bspline(fx[0])
    wy = bspline(fx[1])
    v_pic = wp.vec2d(Real(0.0), Real(0.0))
    v_old = wp.vec2d(Real(0.0), Real(0.0))
    moment = wp.mat22d(Real(0.0), Real(0.0), Real(0.0), Real(0.0))  # sum w v (x_i - origin)^T
    for a in range(3):
        for b in range(3):
            w = wx[a] * wy[b]
            node = first + a * pts.ny[p] + b
            wv = w * nodes.velocity[node]
            v_pic += wv
            v_old += w * nodes.velocity_before[node]
            moment += wp.outer(wv, wp.vec2d(NODE[a] * dx, NODE[b] * dx))
    C = (Real(4.0) / (dx * dx)) * (moment - wp.outer(v_pic, fx * dx))
    share = flip_share[p]
    out.v[p] = share * (pts.v[p] + v_pic - v_old) + (Real(1.0) - share) * v_pic
    out.C_grid[p] = C
    eps = Real(1e-4) * dx
    x = pts.x[p] + dt * v_pic  # positions follow the grid (PIC) velocity
    upper = pts.upper[p]
    out.x_moved[p] = wp.vec2d(clamp(x[0], eps, upper[0] - eps), clamp(x[1], eps, upper[1] - eps))
    m_tr = pts.mass[p] * (C[0, 0] + C[1, 1])
    for a in range(3):
        for b in range(3):
            wp.atomic_add(nodes.volumetric, first + a * pts.ny[p] + b, m_tr * (wx[a] * wy[b]))


@wp.kernel
def nodal_rate(nodes: NodeArrays):
    """Each node's volumetric rate, sum m tr(C) w / sum m w, once per node rather than once per
    point and stencil node in update_points."""
    n = wp.tid()
    m = nodes.mass[n]
    r = Real(0.0)
    if m > Real(0.0):
        r = nodes.volumetric[n] / m
    nodes.rate[n] = r


@wp.kernel
def update_points(pts: PointArrays, mat: MaterialConstants, nodes: NodeArrays, dx: Real, dt: Real,
                  step: int, hold: int, out: NewState):
    """Stress and volume from L = C + w (tr_avg - tr C) / 2 I (solver.velocity_gradient), then
    dilute points lose their stress and loose clods their C. hold (geostatic relaxation): the
    point stays where it was, and its stress changes only while step < last_stress_step."""
    p = wp.tid()
    first, fx = stencil_origin(pts.x[p], Real(1.0) / dx, pts.node_base[p], pts.ny[p])
    wx = bspline(fx[0])
    wy = bspline(fx[1])
    tr_avg = Real(0.0)  # the volumetric rate averaged through the nodes, 1/s
    for a in range(3):
        for b in range(3):
            tr_avg += (wx[a] * wy[b]) * nodes.rate[first + a * pts.ny[p] + b]
    C = out.C_grid[p]
    s = pts.stress[p]
    shift = Real(0.5) * mobilised(s, mat, p) * (tr_avg - (C[0, 0] + C[1, 1]))
    L = C + wp.mat22d(shift, Real(0.0), Real(0.0), shift)
    s = update_stress(s, L, dt, mat, p)
    j = (Real(1.0) + dt * L[0, 0]) * (Real(1.0) + dt * L[1, 1]) - dt * dt * L[0, 1] * L[1, 0]  # det(I + dt L)
    volume = pts.volume[p] * j
    rest = pts.rest_volume[p]
    if volume > Real(DILUTE) * rest:  # dilute: no contacts, no stress
        s = wp.vec4d(Real(0.0), Real(0.0), Real(0.0), Real(0.0))
    if volume > Real(LOOSE) * rest:  # loose clod: no affine velocity
        C = wp.mat22d(Real(0.0), Real(0.0), Real(0.0), Real(0.0))
    if step >= pts.last_stress_step[p]:
        s = pts.stress[p]
    x = pts.x[p]
    if hold == 0:
        x = out.x_moved[p]
    out.volume[p] = volume
    out.C[p] = C
    out.stress[p] = s
    out.x[p] = x


# ---------------------------------------------------------------- the launcher


def material_constants(mat: MaterialArrays) -> MaterialConstants:
    """The per-point constants as Warp views (wp.from_torch keeps each tensor alive)."""
    out = MaterialConstants()
    tensors = {
        "lam": mat.lam, "shear": mat.shear, "sin_phi": mat.sin_phi, "cohesion": mat.cohesion,
        "tension": mat.tension, "c_cos": mat.c_cos, "k": mat.k, "ratio": mat.ratio, "corner3": mat.corner3,
        "inv_k": mat.apex[0], "inv_lam": mat.apex[1], "plastic": mat.plastic.to(torch.int32),
    }
    for name, t in tensors.items():
        setattr(out, name, wp.from_torch(t.detach().contiguous()))
    return out


class WarpSubstep:
    """solver.substep through the kernels above, in place on a batch's Points (torch tensors on
    CPU or CUDA, float64, contiguous). Made once per batch: the node rules come from the grid's
    Constraint lists and stuck nodes, the per-point constants from pts.mat.

    On the CPU, Warp runs a launch on one thread; `advance` and `relax` run the batch's scenes
    in up to `threads` groups at once (default torch.get_num_threads()), each group on its own
    thread through all the substeps asked for (scenes share no points and no nodes, and Warp
    lets go of the GIL while a kernel runs). Each scene's arithmetic is unchanged, in the same
    order, so results are bit for bit those of one thread."""

    def __init__(self, grid: Grid, pts: Points, threads: int | None = None):
        if pts.x.dtype != torch.float64:
            raise ValueError(f"the Warp MPM kernels run in float64; got points in {pts.x.dtype} "
                             "(build the batch with dtype=torch.float64)")
        start_warp()
        self.device = wp.device_from_torch(pts.x.device)
        self.stream = wp.stream_from_torch(pts.x.device) if pts.x.is_cuda else None  # torch's, so no race with it
        self.n_points = len(pts.x)
        self.n_nodes = grid.size
        self.nodes = node_arrays(grid, self.device)
        self.mat = material_constants(pts.mat)
        self._ints = {name: getattr(pts, name).to(torch.int32).contiguous() for name in ("node_base", "ny")}
        self._last_step = torch.full((self.n_points,), FREE, dtype=torch.int32, device=pts.x.device)
        self._x_next = torch.empty_like(pts.x)
        self._wave_rate = pts.wave_rate.contiguous()
        self._shares: dict[tuple, torch.Tensor] = {}  # FLIP shares by (dt, flip)
        self._bound: tuple | None = None
        self.arrays = PointArrays()
        self.new = NewState()
        self.threads = threads if threads is not None else (torch.get_num_threads() if self.device.is_cpu else 1)
        self.groups = scene_groups(pts.scene, grid.node_offset, grid.size, self.threads)
        self._views: list[tuple] = []
        self._plans: dict[tuple, list] = {}  # packed launches by (arrays, settings)
        self._pool: ThreadPoolExecutor | None = None

    def __call__(self, pts: Points, grid: Grid, dt: float, flip: float | str = FLIP_WAVE, damping: float = 0.0) -> None:
        """One substep of dt seconds, in place (solver.substep's signature)."""
        self._launch(pts, grid.dx, dt, flip, damping, step=0, hold=0)

    def relax(self, pts: Points, grid: Grid, dt: float, flip: float | str, damping: float,
              steps: torch.Tensor, total: int) -> None:
        """`total` substeps with the points held in place, point p's stress updated only in its
        first steps[p] of them (batch.relax_geostatic's loop)."""
        self._last_step.copy_(steps.to(torch.int32))
        self._in_groups(pts, grid.dx, dt, flip, damping, total, hold=1)
        self._last_step.fill_(FREE)

    def advance(self, pts: Points, grid: Grid, dt: float, flip: float | str, damping: float, substeps: int) -> None:
        """`substeps` substeps of dt seconds in place (a frame of batch.run_batch), the scene
        groups side by side."""
        self._in_groups(pts, grid.dx, dt, flip, damping, substeps, hold=0)

    def _in_groups(self, pts: Points, dx: float, dt: float, flip, damping: float, substeps: int, hold: int) -> None:
        if self.n_points == 0:
            return
        self._bind(pts)
        plans = [self._plan(view, dx, dt, flip, damping, hold) for view in self._group_views()]

        def run(plan) -> None:
            for k in range(substeps):
                self._replay(plan, k)

        if len(plans) == 1:
            run(plans[0])
            return
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=len(plans) - 1, thread_name_prefix="runout-mpm")
        pending = [self._pool.submit(run, plan) for plan in plans[1:]]
        run(plans[0])
        for job in pending:
            job.result()

    def _launch(self, pts: Points, dx: float, dt: float, flip, damping: float, step: int, hold: int) -> None:
        if self.n_points == 0:
            return
        arrays = self._bind(pts)
        view = (arrays, self.new, self.mat, self.nodes, self.nodes, 0, self.n_points)
        self._replay(self._plan(view, dx, dt, flip, damping, hold), step)

    def _plan(self, view: tuple, dx: float, dt: float, flip, damping: float, hold: int) -> list:
        """One substep of the points in view's arrays on its own nodes (the nodes of their scenes,
        a view of all nodes, which the point kernels index globally): the six launches, packed
        once (wp.Launch) for these arrays and settings and replayed every substep."""
        key = (id(view[0]), dx, dt, str(flip), damping, hold)
        if key not in self._plans:
            arrays, new, mat, nodes, own_nodes, p0, p1 = view
            n, p = own_nodes.mass.shape[0], arrays.x.shape[0]
            if (dt, str(flip)) not in self._shares:  # kept alive here: the launches hold only a view
                self._shares[dt, str(flip)] = flip_shares(self._wave_rate, dt, flip)
            share = wp.from_torch(self._shares[dt, str(flip)][p0:p1])
            self._plans[key] = [
                self._record(clear_grid, n, own_nodes),
                self._record(p2g, p, arrays, nodes, dx, dt * (4.0 / dx**2)),
                self._record(grid_update, n, own_nodes, GRAVITY * dt, float(damping)),
                self._record(g2p, p, arrays, nodes, dx, dt, share, new),
                self._record(nodal_rate, n, own_nodes),
                self._record(update_points, p, arrays, mat, nodes, dx, dt, 0, hold, new),
            ]
        return self._plans[key]

    def _record(self, kernel, dim: int, *inputs) -> wp.Launch:
        return wp.launch(kernel, dim=dim, inputs=list(inputs), device=self.device, record_cmd=True)

    def _replay(self, launches: list, step: int) -> None:
        """Run packed launches, update_points told it is substep `step` (the relaxation's count)."""
        for launch in launches:
            if launch.kernel is update_points:
                launch.set_param_at_index(UPDATE_STEP, step)
            launch.launch(self.stream)

    def _bind(self, pts: Points) -> PointArrays:
        """The point arrays as Warp views of pts's tensors, remade only when a tensor was replaced."""
        state = (pts.x, pts.v, pts.C, pts.stress, pts.volume)
        key = tuple(t.data_ptr() for t in state)
        if key == self._bound:
            return self.arrays
        for t in state:
            if not t.is_contiguous():
                raise ValueError("the Warp MPM kernels need contiguous point tensors")
        a = self.arrays
        a.x = wp.from_torch(pts.x, dtype=wp.vec2d)
        a.v = wp.from_torch(pts.v, dtype=wp.vec2d)
        a.C = wp.from_torch(pts.C, dtype=wp.mat22d)
        a.stress = wp.from_torch(pts.stress, dtype=wp.vec4d)
        a.volume = wp.from_torch(pts.volume)
        a.rest_volume = wp.from_torch(pts.rest_volume.contiguous())
        a.mass = wp.from_torch(pts.mass.contiguous())
        a.upper = wp.from_torch(pts.upper.contiguous(), dtype=wp.vec2d)
        a.node_base = wp.from_torch(self._ints["node_base"])
        a.ny = wp.from_torch(self._ints["ny"])
        self._wave_rate = pts.wave_rate.contiguous()
        self._shares = {}
        a.last_stress_step = wp.from_torch(self._last_step)
        new = self.new  # in place: the new state overwrites the old, point by point
        new.x_moved = wp.from_torch(self._x_next, dtype=wp.vec2d)
        new.C_grid = new.C = a.C
        new.x, new.v, new.stress, new.volume = a.x, a.v, a.stress, a.volume
        self._bound = key
        self._views = []
        self._plans = {}
        return a

    def _group_views(self) -> list[tuple]:
        """Per scene group: its points' arrays, new state and constants, all nodes, and its own
        nodes, as Warp views (no copies) of the bound arrays; then its points' range."""
        if not self._views:
            for p0, p1, n0, n1 in self.groups:
                self._views.append((sliced(self.arrays, PointArrays(), p0, p1), sliced(self.new, NewState(), p0, p1),
                                    sliced(self.mat, MaterialConstants(), p0, p1), self.nodes,
                                    sliced(self.nodes, NodeArrays(), n0, n1), p0, p1))
        return self._views

    def __del__(self):
        if getattr(self, "_pool", None) is not None:
            self._pool.shutdown(wait=False)


def sliced(struct, out, start: int, stop: int):
    """`out` (a new struct of struct's type) with every array field viewing rows start:stop."""
    for name in struct._cls.vars:
        setattr(out, name, getattr(struct, name)[start:stop])
    return out


def scene_groups(scene: torch.Tensor, node_offset: torch.Tensor, n_nodes: int, threads: int) -> list[tuple[int, int, int, int]]:
    """Split a batch (points ordered by scene, each scene's nodes a contiguous run from
    node_offset) into at most `threads` groups of whole scenes with about equal points:
    (first point, end point, first node, end node) each."""
    counts = torch.bincount(scene.cpu(), minlength=len(node_offset)).tolist()
    offsets = node_offset.cpu().tolist() + [n_nodes]
    groups = max(1, min(threads, sum(c > 0 for c in counts)))
    total = sum(counts)
    out, p0, s0, done = [], 0, 0, 0
    for g in range(groups):
        if g == groups - 1:
            s1 = len(counts)
        else:  # whole scenes until this group holds its share of the points
            s1, target = s0, total * (g + 1) / groups
            while s1 < len(counts) and (done + counts[s1] <= target or s1 == s0):
                done += counts[s1]
                s1 += 1
        p1 = p0 + sum(counts[s0:s1]) if g < groups - 1 else total
        out.append((p0, p1, offsets[s0], offsets[s1]))
        p0, s0 = p1, s1
    return [g for g in out if g[1] > g[0]]


def node_arrays(grid: Grid, device) -> NodeArrays:
    """Each node's constraints in the order solver.grid_update applies them, the stuck nodes, and
    the transfer arrays."""
    count = np.zeros(grid.size, dtype=np.int32)
    for c in grid.constraints:
        count[c.ids.cpu().numpy()] += 1
    if count.max(initial=0) > MAX_RULES:
        raise ValueError(f"a grid node is under {count.max()} constraints; the Warp kernels take at most {MAX_RULES}")
    normal = np.zeros((grid.size, MAX_RULES, 2))
    mu = np.zeros((grid.size, MAX_RULES))
    slot = np.zeros(grid.size, dtype=np.int32)
    for c in grid.constraints:
        ids = c.ids.cpu().numpy()
        normal[ids, slot[ids]] = c.normal.cpu().numpy()
        mu[ids, slot[ids]] = c.mu.cpu().numpy()
        slot[ids] += 1
    stuck = np.zeros(grid.size, dtype=np.int32)
    stuck[grid.stuck.cpu().numpy()] = 1
    out = NodeArrays()
    out.rules = wp.array(count, dtype=wp.int32, device=device)
    out.normal = wp.array(normal, dtype=wp.vec2d, device=device)
    out.mu = wp.array(mu, dtype=Real, device=device)
    out.stuck = wp.array(stuck, dtype=wp.int32, device=device)
    return with_transfers(out, requires_grad=False)


def with_transfers(rules: NodeArrays, requires_grad: bool) -> NodeArrays:
    """New transfer arrays (mass, momentum, ...) on the node rules of `rules`."""
    out = NodeArrays()
    out.rules, out.normal, out.mu, out.stuck = rules.rules, rules.normal, rules.mu, rules.stuck
    size, device = rules.rules.shape[0], rules.rules.device
    for name, dtype in (("mass", Real), ("volumetric", Real), ("rate", Real), ("momentum", wp.vec2d), ("impulse", wp.vec2d),
                        ("velocity", wp.vec2d), ("velocity_before", wp.vec2d)):
        setattr(out, name, wp.zeros(size, dtype=dtype, device=device, requires_grad=requires_grad))
    return out

"""Stress update: Jaumann-rotated elastic trial, then Mohr-Coulomb (psi = 0) with a tension cut-off.

Sign convention: tension positive, compression negative (so at rest sigma_yy = -rho g depth).
Stresses in Pa. Plane strain: the out-of-plane stress sigma_zz is carried and kept between
the in-plane principal stresses.

For psi = 0 the plastic flow is purely deviatoric in the plane, so the exact return keeps the
in-plane mean stress s = (sxx + syy) / 2 and scales the Mohr-circle radius
t = sqrt(((sxx - syy) / 2)^2 + sxy^2) down to the yield radius c cos(phi) - s sin(phi);
beyond the apex (s > c / tan phi) the state returns to the apex. phi = 0 is Tresca with
s_u = c. The tension cut-off caps the principal stresses at T <= c / tan(phi), with its own
(associated, Rankine) flow rule: see return_map.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch


@dataclass
class MaterialArrays:
    """Per-point constitutive constants (tensors [P]); the return's derived constants are
    made once here rather than at every substep."""

    lam: torch.Tensor  # Lame lambda, Pa
    shear: torch.Tensor  # shear modulus G, Pa
    sin_phi: torch.Tensor
    cos_phi: torch.Tensor
    cohesion: torch.Tensor  # Pa
    tension: torch.Tensor  # tension cut-off, Pa (already capped at c / tan phi)
    plastic: torch.Tensor  # bool: Mohr-Coulomb (True) or linear elastic (False)
    c_cos: torch.Tensor = field(init=False)  # c cos(phi), Pa
    k: torch.Tensor = field(init=False)  # constrained modulus lambda + 2G, Pa
    ratio: torch.Tensor = field(init=False)  # lambda / (lambda + 2G)
    corner3: torch.Tensor = field(init=False)  # s3 at the corner of the shear line and s1 = T, Pa
    apex: torch.Tensor = field(init=False)  # [2, P] rows of the inverse of [[k, lam], [lam, k]] times det

    def __post_init__(self) -> None:
        self.c_cos = self.cohesion * self.cos_phi
        self.k = self.lam + 2 * self.shear
        self.ratio = self.lam / self.k
        self.corner3 = (self.tension * (1 + self.sin_phi) - 2 * self.c_cos) / (1 - self.sin_phi).clamp_min(1e-12)
        det = self.k * self.k - self.lam * self.lam
        self.apex = torch.stack((self.k / det, self.lam / det))


def jaumann_rotate(stress: torch.Tensor, spin: torch.Tensor) -> torch.Tensor:
    """Objective rotation of the in-plane stress by the spin increment w = 0.5 (L_xy - L_yx) dt.

    stress [P, 4] = (sxx, syy, sxy, szz); spin [P]."""
    sxx, syy, sxy, szz = stress.unbind(1)
    return torch.stack(
        (sxx + 2 * spin * sxy, syy - 2 * spin * sxy, sxy + spin * (syy - sxx), szz), dim=1
    )


def elastic_trial(stress: torch.Tensor, strain: torch.Tensor, mat: MaterialArrays) -> torch.Tensor:
    """Add the plane-strain elastic increment of strain [P, 3] = (exx, eyy, exy) (tensor shear)."""
    exx, eyy, exy = strain.unbind(1)
    vol = mat.lam * (exx + eyy)
    return stress + torch.stack(
        (vol + 2 * mat.shear * exx, vol + 2 * mat.shear * eyy, 2 * mat.shear * exy, vol), dim=1
    )


def mohr_radius(d: torch.Tensor, sxy: torch.Tensor) -> torch.Tensor:
    """Mohr-circle radius sqrt(d^2 + sxy^2). Under autograd (runout.mpm.differentiable) an
    isotropic state (radius 0, where sqrt has an infinite slope) gets a zero gradient instead
    of NaN, with the same values (the double-where trick); the default path is untouched."""
    r2 = d * d + sxy * sxy
    if not r2.requires_grad:
        return torch.sqrt(r2)
    round_ = r2 > 0
    return torch.where(round_, torch.sqrt(torch.where(round_, r2, torch.ones_like(r2))), torch.zeros_like(r2))


def yield_radius(s: torch.Tensor, mat: MaterialArrays) -> torch.Tensor:
    """Mohr-circle radius at yield for in-plane mean stress s: c cos(phi) - s sin(phi), Pa."""
    return mat.c_cos - s * mat.sin_phi


def mobilised(stress: torch.Tensor, mat: MaterialArrays) -> torch.Tensor:
    """[P] share of the shear strength a point's stress mobilises, t / (c cos(phi) - s sin(phi)),
    capped at 1; 1 where the yield radius is zero or negative (at or beyond the apex), 0 for
    elastic materials. Safe under autograd at isotropic stress (t = 0) and at the apex."""
    sxx, syy, sxy, _ = stress.unbind(1)
    t = mohr_radius(0.5 * (sxx - syy), sxy)
    t_a = yield_radius(0.5 * (sxx + syy), mat)
    open_ = t_a > 0
    share = torch.clamp(t / torch.where(open_, t_a, torch.ones_like(t_a)), max=1.0)
    share = torch.where(open_, share, torch.ones_like(share))
    return torch.where(mat.plastic, share, torch.zeros_like(share))


def return_map(stress: torch.Tensor, mat: MaterialArrays) -> torch.Tensor:
    """Project the trial stress onto the Mohr-Coulomb (psi = 0) / tension cut-off surface.

    A multi-surface return in the in-plane principal stresses (s1 >= s3, directions kept),
    each surface with its own flow rule and the plane-strain elastic law (lambda, G):
    - shear, f_s = t + s sin(phi) - c cos(phi), potential t (psi = 0): the plastic strain is
      deviatoric in the plane, so s stays and the radius t falls to c cos(phi) - s sin(phi);
    - tension, f_t = s1 - T, associated (Rankine): the plastic strain is an opening along the
      major principal direction only, so s1 falls to T and s3, szz fall by lambda / (lambda + 2G)
      of that drop. Keeping s3 instead (the old return) hides a plastic shortening across the
      crack in that step, through which gravity creeps a no-tension face down and out;
    - their corner (s1 = T, s3 on the shear line) and the tension apex (s1 = s3 = T).
    The first active set whose multipliers are non-negative and whose result is admissible is
    taken (shear or tension alone, the closer in energy when both are; then the corner; then
    the apex). szz is then kept between the in-plane principal stresses."""
    sxx, syy, sxy, szz = stress.unbind(1)
    s = 0.5 * (sxx + syy)
    d = 0.5 * (sxx - syy)
    t = mohr_radius(d, sxy)
    s1, s3 = s + t, s - t
    sin, cut, lam, g, k = mat.sin_phi, mat.tension, mat.lam, mat.shear, mat.k
    t_a = yield_radius(s, mat)
    f_s = t - t_a
    f_t = s1 - cut

    # shear alone: radius to the yield radius at constant s (needs a non-negative yield radius)
    ok_a = (f_s > 0) & (t_a >= 0) & (s + t_a <= cut)
    a1, a3 = s + t_a, s - t_a
    # tension alone: s1 -> T; s3 and szz follow through lambda
    drop = f_t * mat.ratio
    b3 = s3 - drop
    ok_b = (f_t > 0) & (b3 <= cut) & (0.5 * (cut - b3) + 0.5 * (cut + b3) * sin <= mat.c_cos)
    both = ok_a & ok_b
    closer_a = f_s * f_s * k <= f_t * f_t * g  # complementary energy of each return
    ok_b = ok_b & ~(both & closer_a)
    ok_a = ok_a & ~(both & ~closer_a)
    # corner: s1 = T, s3 on the shear line; G l_s + k l_t = s1 - T, G l_s - lambda l_t = s3c - s3
    c3 = mat.corner3
    l_t = (f_t - (c3 - s3)) / (k + lam)
    l_s = f_t - k * l_t  # times G
    ok_c = ~ok_a & ~ok_b & (l_s >= 0) & (l_t >= 0) & (f_t > 0)
    # tension apex: s1 = s3 = T; [k lam; lam k] [l1; l3] = [s1 - T; s3 - T]
    inv_k, inv_lam = mat.apex
    l13 = (inv_k - inv_lam) * (f_t + s3 - cut)  # l1 + l3

    elastic = (f_s <= 0) & (f_t <= 0)
    p1 = torch.where(ok_a, a1, cut.expand_as(s1))
    p3 = torch.where(ok_a, a3, torch.where(ok_b, b3, torch.where(ok_c, c3, cut.expand_as(s3))))
    dz = torch.where(ok_a, torch.zeros_like(s), torch.where(ok_b, drop, lam * torch.where(ok_c, l_t, l13)))
    p1 = torch.where(elastic, s1, p1)
    p3 = torch.where(elastic, s3, p3)
    dz = torch.where(elastic, torch.zeros_like(dz), dz)

    s_new = 0.5 * (p1 + p3)
    t_new = 0.5 * (p1 - p3)
    round_ = t > 1e-9 * (s.abs() + mat.cohesion + 1.0)  # principal directions defined
    cos2 = torch.where(round_, d / t.clamp_min(1e-30), torch.ones_like(t))
    sin2 = torch.where(round_, sxy / t.clamp_min(1e-30), torch.zeros_like(t))
    z = torch.minimum(torch.maximum(szz - dz, p3), p1)
    returned = torch.stack((s_new + t_new * cos2, s_new - t_new * cos2, t_new * sin2, z), dim=1)
    return torch.where(mat.plastic[:, None], returned, stress)


def update_stress(stress, grad_v, dt, mat: MaterialArrays) -> torch.Tensor:
    """Objective stress update for velocity gradient grad_v [P, 2, 2] (L_ij = dv_i/dx_j)."""
    exx = grad_v[:, 0, 0] * dt
    eyy = grad_v[:, 1, 1] * dt
    exy = 0.5 * (grad_v[:, 0, 1] + grad_v[:, 1, 0]) * dt
    spin = 0.5 * (grad_v[:, 0, 1] - grad_v[:, 1, 0]) * dt
    stress = jaumann_rotate(stress, spin)
    stress = elastic_trial(stress, torch.stack((exx, eyy, exy), dim=1), mat)
    return return_map(stress, mat)

"""Stress update: Jaumann-rotated elastic trial, then Mohr-Coulomb (psi = 0) with a tension cut-off.

Sign convention: tension positive, compression negative (so at rest sigma_yy = -rho g depth).
Stresses in Pa. Plane strain: the out-of-plane stress sigma_zz is carried and kept between
the in-plane principal stresses.

For psi = 0 the plastic flow is purely deviatoric in the plane, so the exact return keeps the
in-plane mean stress s = (sxx + syy) / 2 and scales the Mohr-circle radius
t = sqrt(((sxx - syy) / 2)^2 + sxy^2) down to the yield radius c cos(phi) - s sin(phi);
beyond the apex (s > c / tan phi) the state returns to the apex. phi = 0 is Tresca with
s_u = c. The tension cut-off caps the major principal stress at T <= c / tan(phi).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class MaterialArrays:
    """Per-point constitutive constants (tensors [P])."""

    lam: torch.Tensor  # Lame lambda, Pa
    shear: torch.Tensor  # shear modulus G, Pa
    sin_phi: torch.Tensor
    cos_phi: torch.Tensor
    cohesion: torch.Tensor  # Pa
    tension: torch.Tensor  # tension cut-off, Pa (already capped at c / tan phi)
    plastic: torch.Tensor  # bool: Mohr-Coulomb (True) or linear elastic (False)


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


def return_map(stress: torch.Tensor, mat: MaterialArrays) -> torch.Tensor:
    """Project the trial stress onto the Mohr-Coulomb / tension cut-off surface (psi = 0)."""
    sxx, syy, sxy, szz = stress.unbind(1)
    s = 0.5 * (sxx + syy)
    dx = 0.5 * (sxx - syy)
    t = torch.sqrt(dx * dx + sxy * sxy)
    # shear surface: t <= c cos(phi) - s sin(phi); the apex when that radius is negative
    t_yield = mat.cohesion * mat.cos_phi - s * mat.sin_phi
    apex = t_yield < 0
    s = torch.where(apex, mat.cohesion * mat.cos_phi / mat.sin_phi.clamp_min(1e-12), s)
    t_new = torch.minimum(t, t_yield.clamp_min(0.0))
    # tension cut-off on the major principal stress s + t <= T, keeping the minor one
    sigma3 = s - t_new
    over = s + t_new > mat.tension
    s_cut = 0.5 * (mat.tension + torch.minimum(sigma3, mat.tension))
    t_cut = 0.5 * (mat.tension - torch.minimum(sigma3, mat.tension))
    s = torch.where(over, s_cut, s)
    t_new = torch.where(over, t_cut, t_new)
    scale = torch.where(t > 0, t_new / t.clamp_min(1e-30), torch.zeros_like(t))
    szz = torch.minimum(torch.maximum(szz, s - t_new), s + t_new)
    returned = torch.stack((s + scale * dx, s - scale * dx, scale * sxy, szz), dim=1)
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

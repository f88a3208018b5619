"""The realisations' strengths: a seeded Latin hypercube or scrambled Sobol sample of the unit
cube, a Gaussian copula for each material's φ-c correlation, then each marginal's truncated
inverse CDF. Realisation k depends only on the spec (sampler, seed, count, distributions),
so a resumed or sharded run draws the same strengths.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from scipy import stats
from scipy.stats import qmc

from runout.hazard.spec import Distribution, HazardSpec

TINY = 1e-12  # keeps u away from 0 and 1, where a normal quantile is infinite


def unit_sample(sampler: str, dimensions: int, count: int, seed: int) -> np.ndarray:
    """[count, dimensions] points in (0, 1)^d, stratified (lhs) or low-discrepancy (sobol)."""
    engine = qmc.LatinHypercube(d=dimensions, rng=seed) if sampler == "lhs" else qmc.Sobol(d=dimensions, rng=seed)
    with warnings.catch_warnings():  # Sobol's balance is best at powers of 2; other counts are still valid
        warnings.simplefilter("ignore", UserWarning)
        u = engine.random(count)
    return np.clip(u, TINY, 1 - TINY)


def correlate(u_phi: np.ndarray, u_c: np.ndarray, rho: float) -> np.ndarray:
    """u_c moved so that (u_phi, u_c) follow a Gaussian copula of correlation rho."""
    z_phi, z_c = stats.norm.ppf(u_phi), stats.norm.ppf(u_c)
    return stats.norm.cdf(rho * z_phi + math.sqrt(1 - rho * rho) * z_c)


def quantile(d: Distribution, u: np.ndarray) -> np.ndarray:
    """The values at probabilities u of the distribution truncated to [lower, upper]."""
    if d.std == 0 or d.lower == d.upper:
        return np.full_like(u, d.mean if d.kind != "uniform" else d.lower)
    base = _frozen(d)
    lo, hi = base.cdf(d.lower), base.cdf(d.upper)
    return np.clip(base.ppf(lo + u * (hi - lo)), d.lower, d.upper)


def _frozen(d: Distribution):
    if d.kind == "normal":
        return stats.norm(d.mean, d.std)
    if d.kind == "lognormal":  # mean and std of the value itself
        s2 = math.log1p((d.std / d.mean) ** 2)
        return stats.lognorm(math.sqrt(s2), scale=d.mean * math.exp(-s2 / 2))
    return stats.uniform(d.lower, d.upper - d.lower)


def draw_inputs(spec: HazardSpec) -> np.ndarray:
    """[realisations, inputs] strengths in spec.inputs() order (φ in degrees, c in kPa)."""
    names = spec.inputs()
    u = unit_sample(spec.sampler, len(names), spec.realisations, spec.seed)
    column = {name: u[:, k] for k, name in enumerate(names)}
    for material, m in spec.materials.items():
        if m.phi and m.c and m.correlation:
            column[(material, "c")] = correlate(column[(material, "phi")], column[(material, "c")], m.correlation)
    return np.stack([quantile(getattr(spec.materials[mat], prop), column[(mat, prop)]) for mat, prop in names], axis=1)

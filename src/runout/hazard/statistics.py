"""The statistics of a finished study: exceedance probabilities along the ground, each front's
runout quantiles with the bootstrap standard error of its P95, and the rank correlation of
every input with every front.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

QUANTILES = (0.05, 0.50, 0.95)
BOOTSTRAP_RESAMPLES = 1000
STABLE_SHARE = 0.01  # the P95 counts as settled when its standard error is at most 1 % of it


def exceedance(thickness: np.ndarray, thresholds) -> np.ndarray:
    """[H, J] P(t(x_j) > h) over the realisations of thickness [R, J] (m), for each h (m)."""
    return np.stack([(thickness > h).mean(axis=0) for h in thresholds])


def p95_standard_error(runouts: np.ndarray, seed: int) -> float:
    """Bootstrap standard error (m) of the 95th percentile of runouts [R] (m)."""
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, len(runouts), size=(BOOTSTRAP_RESAMPLES, len(runouts)))
    return float(np.quantile(runouts[picks], 0.95, axis=1).std(ddof=1))


def front_summary(runouts: np.ndarray, seed: int) -> dict:
    """P5, P50, P95 (m), mean and std (m) of one front's runouts, the P95's bootstrap standard
    error, whether it is settled to 1 %, and about how many realisations would settle it."""
    p5, p50, p95 = (float(v) for v in np.quantile(runouts, QUANTILES))
    se = p95_standard_error(runouts, seed) if len(runouts) > 1 else float("nan")
    scale = STABLE_SHARE * max(abs(p95), 1e-9)
    needed = int(np.ceil(len(runouts) * (se / scale) ** 2)) if np.isfinite(se) else None
    return {"p5_m": p5, "p50_m": p50, "p95_m": p95, "mean_m": float(runouts.mean()), "std_m": float(runouts.std()),
            "p95_standard_error_m": se, "p95_settled_to_1_percent": bool(np.isfinite(se) and se <= scale),
            "realisations_to_settle_p95": needed}


def rank_correlations(inputs: np.ndarray, runouts: np.ndarray) -> np.ndarray:
    """[inputs, fronts] Spearman rank correlation of each input with each front's runout;
    NaN where either does not vary."""
    out = np.full((inputs.shape[1], runouts.shape[1]), np.nan)
    for i in range(inputs.shape[1]):
        for f in range(runouts.shape[1]):
            if np.ptp(inputs[:, i]) > 0 and np.ptp(runouts[:, f]) > 0:
                out[i, f] = stats.spearmanr(inputs[:, i], runouts[:, f]).statistic
    return out


def empirical_cdf(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sorted values, P(X <= value)) of a sample."""
    x = np.sort(values)
    return x, np.arange(1, len(x) + 1) / len(x)

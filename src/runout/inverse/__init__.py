"""Inverse analysis: back-calculate material strengths from an observed runout.

A differentiable GNS rollout (reverse-mode AD, each step recomputed in the backward pass)
gives the data loss and its gradient for every free parameter in one pass; L-BFGS-B with a
box per parameter searches a normalised space. See docs/inverse-format.md.

    from runout.inverse import invert
    result = invert("examples/dam_inverse.toml", "out/dam", model="models/gns.pt")
    result.best.values          # free parameters in degrees / kPa, in spec order
"""

from runout.inverse.observation import Observation, load_observation
from runout.inverse.optimise import StartResult, minimise, run_starts, starting_points
from runout.inverse.loss import weighted_mse
from runout.inverse.problem import Evaluation, InverseProblem
from runout.inverse.run import ENGINES, InversionResult, invert, summary_lines
from runout.inverse.spec import FreeParameter, InverseSpec, load_inverse_spec

__all__ = [
    "ENGINES", "Evaluation", "FreeParameter", "InverseProblem", "InverseSpec", "InversionResult",
    "Observation", "StartResult", "invert", "load_inverse_spec", "load_observation", "minimise",
    "run_starts", "starting_points", "summary_lines", "weighted_mse",
]

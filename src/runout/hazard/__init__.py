"""`runout hazard`: runout as a probability. Monte Carlo over uncertain φ and c on the batched
MPM: `spec` (the TOML study), `sampling` (Latin hypercube or Sobol, copula, truncated
marginals), `run` (resumable, shardable batches), `deposit` (thickness and fronts of one
realisation), `statistics`, `results` and `figures`. docs/hazard.md describes the spec and
every output file.
"""

from __future__ import annotations

from pathlib import Path

from runout.hazard.results import RESULT_FILES, write_results
from runout.hazard.run import gather, run_study
from runout.hazard.spec import HazardSpec, load_spec

STUDY_FILES = ("hazard.json", "parts", *RESULT_FILES)

__all__ = ["HazardSpec", "STUDY_FILES", "load_spec", "merge_study", "run_hazard"]


def run_hazard(spec: HazardSpec, out: str | Path, shard: tuple[int, int] = (0, 1), device: str = "cpu",
               simulate=None, progress: bool = True) -> dict | None:
    """Run this shard's batches; an unsharded run then writes the results and returns the summary."""
    out = Path(out)
    run_study(spec, out, shard, device, simulate, progress)
    if shard[1] > 1:
        return None
    return write_results(spec, gather(spec, [out]), out)


def merge_study(spec: HazardSpec, dirs: list[str | Path], out: str | Path) -> dict:
    """Join the parts of a sharded study's folders and write the results into out."""
    from runout.hazard.run import claim_study

    out = Path(out)
    claim_study(out, spec)
    return write_results(spec, gather(spec, [Path(d) for d in dirs]), out)

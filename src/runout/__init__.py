"""runout: forward and inverse slope-runout analysis.

Three engines share one data model (:class:`runout.trajectory.Trajectory`):
a batched MPM solver (:mod:`runout.mpm`), a Graph Network Simulator (:mod:`runout.gns`)
and a differentiable inverse analysis (:mod:`runout.inverse`).
"""

__version__ = "0.1.0"

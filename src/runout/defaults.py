"""Physical and file-format defaults shared by scenes, datasets and the GNS: one place each.

Scene files that leave a value out get it from here (runout.scene.files reads them), and
the dataclasses in runout.scene.model use the same numbers.
"""

from __future__ import annotations

import math
from pathlib import Path

GRAVITY = 9.81  # m/s^2, downwards (-y); the MPM imports it from here

# Particle types of the GNS format (geoelements/gns).
PARTICLE_TYPE_KINEMATIC = 3  # stationary points (ground, foundation): positions prescribed
PARTICLE_TYPE_SOIL = 6

FRAME_DT = 0.0375  # s between output frames (375 steps of 1e-4 s in the reference MPM)
# m/s: a point that covers more than this over a trajectory's first frame was moving at frame 0
# (a region's initial `velocity`, such as family a's thrown blocks) rather than starting from rest.
# From rest the fastest point of every solver-6 slope averages at most 1.04 m/s over the first
# frame (data/ft8, data/base8), and the thrown blocks of data/base8 at least 1.6 m/s.
START_SPEED = 2.0
FRAMES = 480
CFL = 0.4  # Courant number on dx / (c_p + v_max)
FLIP_WAVE = "wave"  # the FLIP share exp(-dt c_p / dx) per substep: a fixed rate in time (runout.mpm.solver.flip_share)
FLIP = FLIP_WAVE  # FLIP share of the point-velocity update: FLIP_WAVE, or a fixed share per substep in [0, 1]

CELL_SIZE = 4.0  # m, square background-grid cells
POINTS_PER_CELL = 2  # per direction: 2 -> 4 points per cell
ROUGH = math.inf  # base_friction "rough": no slip; the soil above shears on its own strength
BASE_FRICTION = ROUGH  # on the base and on fixed ground (a number: Coulomb coefficient); docs/scene-format.md
WALL_FRICTION = 0.38  # on the side walls (and top); 0 = free slip

# Mohr-Coulomb soil.
FRICTION_ANGLE = 30.0  # degrees
COHESION = 0.0  # kPa
YOUNGS_MODULUS = 40.0  # MPa
POISSON_RATIO = 0.3
DENSITY = 1800.0  # kg/m^3
TENSION_CUTOFF = 0.1  # kPa, capped at c / tan(phi)

MPM_CACHE = Path.home() / ".cache" / "runout" / "mpm"  # where MPM runs are cached by scene (runout.mpm.cache)

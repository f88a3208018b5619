"""The allowed ranges of scene values, torch-free and free of the scene types, so that options
and checks of other files (runout.checks, the command line) read them without the scene model."""

import sys

# Physical upper bounds of scene values (beyond them a run is meaningless or cannot finish).
MAX_DOMAIN = 20_000.0  # m, width and height
MAX_LATTICE_POINTS = 2_000_000  # candidate points (domain / point spacing, both ways)
MAX_FRAMES = 1_000_000
MAX_SPEED = 100.0  # m/s, the speed (length of the vector) of an initial velocity (fast rock avalanches)
MAX_YOUNGS_MODULUS = 1e5  # MPa (100 GPa, stiffer than intact granite)
MAX_STRENGTH = 1e4  # kPa, cohesion and tension cut-off (10 MPa, soft rock)
MAX_DENSITY = 1e4  # kg/m^3
SMALLEST_SIZE = sys.float_info.min  # 2.2e-308: below it a float is subnormal and a size divided by it overflows


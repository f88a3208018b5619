"""Small scenes shared by more than one test file."""

# a cohesive column (c 5 kPa, phi 30) beside a lower frictional block (phi 20, c 10 kPa) on
# fixed ground: 160 moving points at the default 4 m cells, 13 frames
COLUMN_BESIDE_BLOCK = {
    "domain": {"width": 60.0, "height": 40.0},
    "time": {"frames": 13},
    "materials": {
        "column": {"friction_angle": 30.0, "cohesion": 5.0},
        "block": {"friction_angle": 20.0, "cohesion": 10.0},
        "ground": {"model": "elastic"},
    },
    "regions": [
        {"material": "ground", "polygon": [[0, 0], [60, 0], [60, 2], [0, 2]], "fixed": True},
        {"material": "column", "polygon": [[10, 2], [26, 2], [26, 30], [10, 30]]},
        {"material": "block", "polygon": [[26, 2], [50, 2], [50, 10], [26, 10]]},
    ],
}

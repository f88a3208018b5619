"""Scenes: domain, materials and polygonal regions; scene files; filling regions with points.

    runout.scene.model       Scene, Domain, TimeSpec, Material, Region; check_scene, lattice_points
    runout.scene.limits      the allowed ranges (MAX_*)
    runout.scene.files       scene_from_dict, load_scene, scene_to_dict, scene_to_toml, save_scene;
                             EXAMPLES, the example scene files (package data)
    runout.scene.geometry    polygon area, self-intersection, containment, overlap
    runout.scene.seeding     fill_points -> SeedPoints

The names are re-exported here: `from runout.scene import Scene, load_scene, fill_points`.
"""

from runout.scene.files import EXAMPLES, load_scene, save_scene, scene_from_dict, scene_to_dict, scene_to_toml
from runout.scene.geometry import edges_cross, points_in_polygon, polygon_area, polygon_self_intersects, polygons_overlap
from runout.scene.limits import (
    MAX_DENSITY, MAX_DOMAIN, MAX_FRAMES, MAX_LATTICE_POINTS, MAX_SPEED, MAX_STRENGTH, MAX_YOUNGS_MODULUS,
)
from runout.scene.model import Domain, Material, Region, Scene, TimeSpec, check_scene, lattice_points
from runout.scene.seeding import SeedPoints, fill_points

__all__ = [
    "EXAMPLES", "MAX_DENSITY", "MAX_DOMAIN", "MAX_FRAMES", "MAX_LATTICE_POINTS", "MAX_SPEED", "MAX_STRENGTH",
    "MAX_YOUNGS_MODULUS", "Domain", "Material", "Region", "Scene", "SeedPoints", "TimeSpec",
    "check_scene", "edges_cross", "fill_points", "lattice_points", "load_scene", "points_in_polygon", "polygon_area",
    "polygon_self_intersects", "polygons_overlap", "save_scene", "scene_from_dict", "scene_to_dict",
    "scene_to_toml",
]

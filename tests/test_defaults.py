"""The shared defaults are the values the scene parser, the MPM and the GNS use."""

from runout import defaults
from runout.contract import HISTORY, WindowSchema, decode_material, encode_material
from runout.mpm import batch, geostatic
from runout.scene import scene_from_dict


def test_the_mpm_falls_under_the_default_gravity():
    assert geostatic.GRAVITY == batch.GRAVITY == defaults.GRAVITY


def test_a_scene_without_optional_values_takes_the_defaults():
    scene = scene_from_dict({
        "domain": {"width": 20.0, "height": 10.0},
        "materials": {"sand": {}},
        "regions": [{"material": "sand", "polygon": [[0, 0], [8, 0], [8, 4], [0, 4]]}],
    })
    assert scene.time.frame_dt == defaults.FRAME_DT
    assert scene.domain.wall_friction == defaults.WALL_FRICTION
    assert scene.domain.base_friction == defaults.BASE_FRICTION
    assert scene.materials["sand"].friction_angle == defaults.FRICTION_ANGLE


def test_the_material_codec_round_trips_degrees_and_kpa():
    phi, c = decode_material(encode_material(33.0, 25.0))
    assert abs(phi - 33.0) < 1e-9 and abs(c - 25.0) < 1e-9
    assert WindowSchema().history == HISTORY == 6

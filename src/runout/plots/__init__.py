"""Pictures: one package for every figure and animation of scenes and trajectories.

    runout.plots.frames     draw_materials, draw_displacement, save_frame, save_comparison,
                            save_side_by_side, draw_scene
    runout.plots.rollout    draw_points, save_snapshots, save_error_plot (learned-engine rollouts)
    runout.plots.families   draw_grid (random scene families)
    runout.plots.animation  write_animation (the one writer: .mp4 or .gif), save_animation,
                            save_rollout_animation, save_side_by_side_animation, animation_name

Figures are matplotlib Figure objects, never pyplot, so no backend is chosen at import;
saving a picture renders it with Agg whatever the session's backend is.
"""

from runout.plots.animation import (
    animation_name, save_animation, save_rollout_animation, save_side_by_side_animation, write_animation,
)
from runout.plots.frames import (
    GROUND_COLOUR, draw_displacement, draw_materials, draw_scene, material_colour, save_comparison, save_frame,
    save_side_by_side,
)
from runout.plots.rollout import draw_points, save_error_plot, save_snapshots

__all__ = [
    "GROUND_COLOUR", "animation_name", "draw_displacement", "draw_materials", "draw_points", "draw_scene",
    "material_colour", "save_animation", "save_comparison", "save_error_plot", "save_frame", "save_rollout_animation",
    "save_side_by_side", "save_side_by_side_animation", "save_snapshots", "write_animation",
]

"""One MPM run as `runout mpm` makes it: checks first, the run, then its files (the engine
itself is runout.mpm).

simulate and save_trajectory are looked up on their modules at call time, so a test can
replace them there."""

from __future__ import annotations

from pathlib import Path

from runout import mpm, trajectory
from runout.errors import RunFailed
from runout.mpm.budget import check_budget
from runout.outputs import check_folder, claim
from runout.plots import save_animation, save_frame
from runout.scene import load_scene
from runout.trajectory import Trajectory

MPM_FILES = ("trajectory.npz", "metadata.json", "initial.png", "final.png")


def run_mpm(
    scene: Path, out: Path, frames: int | None = None, device: str = "cpu", animate: bool = True,
    vtk: bool = False, force: bool = False,
) -> tuple[Trajectory, tuple[str, ...]]:
    """Run the MPM on SCENE and write OUT/trajectory.npz + metadata.json, initial.png,
    final.png (and animation.gif, vtk/); OUT and the cost are checked before the run.
    Returns the trajectory and the names written. RunFailed when the run diverges."""
    sc = load_scene(scene)
    if frames is not None:
        sc = sc.with_frames(frames)
    writes = MPM_FILES + (("animation.gif",) if animate else ()) + (("vtk",) if vtk else ())
    folder = check_folder(out, "mpm", writes, force=force, inputs={"the scene": scene})
    check_budget([sc], device=device, source=str(scene))
    traj = mpm.simulate([sc], device=device)[0]
    bad = traj.first_nonfinite_frame()
    if bad is not None:
        raise RunFailed(f"the MPM run of {scene} diverged (positions are not finite from frame {bad}); "
                        "lower time.cfl or check the materials.")
    claim(folder)
    trajectory.save_trajectory(traj, out)
    save_frame(traj, 0, out / "initial.png")
    save_frame(traj, traj.n_frames - 1, out / "final.png")
    if animate:
        save_animation([traj], out / "animation.gif", labels=["MPM"])
    if vtk:
        from runout.vtk import write_vtk  # meshio loads only when asked for

        write_vtk(traj, out / "vtk")
    return traj, writes

"""`runout mpm` and `runout show`."""

from __future__ import annotations

from pathlib import Path

import typer

from runout.cli.app import app

FORCE = typer.Option(False, "--force", help="Replace another command's results in --out (removing, and naming, the files that command wrote and this run does not rewrite; files runout did not write stay).")


@app.command()
def mpm(
    scene: Path = typer.Argument(..., help="Scene file (TOML or JSON), see docs/scene-format.md."),
    out: Path = typer.Option(..., "--out", help="Output directory (created)."),
    device: str = typer.Option("cpu", help="cpu or cuda."),
    frames: int = typer.Option(None, help="Output frames including frame 0 (default: the scene's [time] frames)."),
    animate: bool = typer.Option(True, help="Write animation.gif."),
    vtk: bool = typer.Option(False, "--vtk", help="Also write ParaView files: vtk/frame_*.vtu and vtk/trajectory.pvd."),
    force: bool = FORCE,
) -> None:
    """Run the MPM on a scene: writes trajectory.npz + metadata.json (GNS layout, material
    features [tan phi, c/100 kPa]), initial.png, final.png and animation.gif."""
    from runout import checks
    from runout.mpm_run import run_mpm

    checks.device(device)
    traj, writes = run_mpm(scene, out, frames, device, animate, vtk, force)
    info = traj.info
    typer.echo(
        f"{traj.n_points} points, {traj.n_frames} frames, {info['substeps_per_frame']} substeps/frame, "
        f"{info['wall_time_s']:.1f} s; wrote {out}/" + ", ".join(writes)
    )


@app.command()
def show(
    scene: Path = typer.Argument(..., help="Scene file (TOML or JSON)."),
    out: Path = typer.Option(Path("scene.png"), "--out", help="Picture to write (.png, .pdf or .svg)."),
) -> None:
    """Draw a scene's regions and materials without simulating."""
    from runout.outputs import check_picture
    from runout.plots import draw_scene
    from runout.scene import fill_points, load_scene

    sc = load_scene(scene)
    check_picture(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    written = draw_scene(sc, out)
    typer.echo(f"{len(fill_points(sc))} points; wrote {written}")

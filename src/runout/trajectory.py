"""Trajectory: the one result type made by the MPM and the GNS alike.

A trajectory holds positions [T, N, 2] (m) at frames frame_dt (s) apart, the particle
type of each point (3 = kinematic/stationary, 6 = soil), each point's material index into
a material table, and the domain bounds. On disk a trajectory is the public GNS layout
(geoelements/gns): ``trajectory.npz`` with one simulation ``simulation_0 =
(positions, particle_type, material_features)`` and a ``metadata.json`` beside it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from runout import checks
from runout.contract import MATERIAL_FEATURE_NAMES, decode_material
from runout.defaults import FRAME_DT, GRAVITY, PARTICLE_TYPE_KINEMATIC, START_SPEED
from runout.errors import InputError
from runout.scene import Material, Scene
from runout.simfiles import exchange_material, read_simulations, statistics


@dataclass
class Trajectory:
    positions: np.ndarray  # [T, N, 2] float32, m
    particle_type: np.ndarray  # [N] int64
    material_id: np.ndarray  # [N] int64, index into materials
    materials: list[Material]
    frame_dt: float  # s
    bounds: np.ndarray  # [[x_lo, x_hi], [y_lo, y_hi]] m
    name: str = "trajectory"
    info: dict = field(default_factory=dict)  # engine, wall time, ... (free-form)
    material_width: int | None = None  # material features of the GNS tuple it was read from (0: none); None: not read from one
    initial_velocity: np.ndarray | None = None  # [N, 2] m/s at frame 0 (a scene's region velocities); None: unknown

    def start_velocity(self) -> np.ndarray:
        """[N, 2] m/s: each point's velocity at frame 0, where a GNS rollout starts: the
        scene's (initial_velocity) when known, else estimated from the first frame
        (first_frame_velocity; zero for a single frame)."""
        if self.initial_velocity is not None:
            return np.asarray(self.initial_velocity, dtype=np.float64)
        if self.n_frames < 2:
            return np.zeros((self.n_points, 2))
        return first_frame_velocity(self.positions[0], self.positions[1], self.particle_type, self.frame_dt)

    @property
    def n_frames(self) -> int:
        return self.positions.shape[0]

    @property
    def n_points(self) -> int:
        return self.positions.shape[1]

    @property
    def soil(self) -> np.ndarray:
        """Mask of the points that move (not kinematic)."""
        return self.particle_type != PARTICLE_TYPE_KINEMATIC

    def every(self, stride: int) -> "Trajectory":
        """Frames 0, stride, 2 stride, ... (frame_dt x stride; the positions are a view): e.g.
        an MPM run at the times a GNS of frame stride `stride` steps through."""
        if stride == 1:
            return self
        return replace(self, positions=self.positions[::stride], frame_dt=self.frame_dt * stride, info=dict(self.info))

    def mirrored(self) -> "Trajectory":
        """The same run reflected left-right about its domain's centre, x -> x_lo + x_hi - x
        (start velocities with it): the run the physics gives for the mirrored scene."""
        positions = self.positions.copy()
        positions[..., 0] = self.bounds[0][0] + self.bounds[0][1] - positions[..., 0]
        velocity = None if self.initial_velocity is None else self.initial_velocity * np.array([-1.0, 1.0])
        return replace(self, positions=positions, initial_velocity=velocity, name=f"{self.name} mirrored", info=dict(self.info))

    def first_nonfinite_frame(self) -> int | None:
        """The first frame holding a NaN or infinite position (a diverged run), or None."""
        bad = ~np.isfinite(self.positions).all(axis=(1, 2))
        return int(np.argmax(bad)) if bad.any() else None

    def material_features(self, width: int = 2) -> np.ndarray:
        """[N, width] float32 GNS features: [tan phi] (width 1) or [tan phi, c / 100 kPa]."""
        table = np.array([m.features()[:width] for m in self.materials], dtype=np.float32)
        return table[self.material_id]


def trajectory_from_features(
    positions: np.ndarray,
    particle_type: np.ndarray,
    features: np.ndarray | None,
    frame_dt: float,
    bounds,
    name: str = "trajectory",
) -> Trajectory:
    """Rebuild a Trajectory from the GNS tuple: materials are the distinct feature rows
    (tan phi -> phi in degrees, second column x 100 -> c in kPa); material_width is the
    number of feature columns (0 for none)."""
    n = positions.shape[1]
    width = 0 if features is None else np.asarray(features).reshape(n, -1).shape[1]
    if features is None:
        features = np.zeros((n, 1), dtype=np.float32)
    features = np.asarray(features, dtype=np.float32).reshape(n, -1)
    rows, material_id = np.unique(features, axis=0, return_inverse=True)
    materials = []
    for k, row in enumerate(rows):
        phi, c = decode_material(row)
        materials.append(Material(name=f"material_{k}", friction_angle=phi, cohesion=c))
    return Trajectory(
        positions=np.asarray(positions, dtype=np.float32),
        particle_type=np.broadcast_to(np.asarray(particle_type, dtype=np.int64), (n,)).copy(),
        material_id=material_id.reshape(-1).astype(np.int64),
        materials=materials,
        frame_dt=float(frame_dt),
        bounds=np.asarray(bounds, dtype=float),
        name=name,
        material_width=width,
    )


def gns_tuple(traj: Trajectory, feature_width: int = 2) -> np.ndarray:
    """The (positions, particle_type, material) tuple as the 1-D object array the GNS reads;
    one material feature is stored as (N,), two as (N, 2)."""
    out = np.empty(3, dtype=object)
    out[0] = traj.positions.astype(np.float32)
    out[1] = traj.particle_type.astype(np.int64)
    out[2] = exchange_material(traj.material_features(feature_width))
    return out


def save_trajectory(traj: Trajectory, out_dir: str | Path, feature_width: int = 2) -> Path:
    """Write DIR/trajectory.npz (one simulation, GNS dict layout) and DIR/metadata.json."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "trajectory.npz"
    tmp = out_dir / "trajectory.tmp.npz"
    np.savez_compressed(tmp, simulation_0=gns_tuple(traj, feature_width))
    tmp.replace(path)
    meta = statistics([(traj.positions,)], bounds=traj.bounds, dt=traj.frame_dt)
    meta.update(
        {
            "name": traj.name,
            "materials": [_material_dict(m) for m in traj.materials],
            "material_features": list(MATERIAL_FEATURE_NAMES[:feature_width]),
            "info": traj.info,
        }
    )
    (out_dir / "metadata.json").write_text(json.dumps(meta, indent=2))
    return path


def _material_dict(m: Material) -> dict:
    return {
        "name": m.name, "model": m.model, "friction_angle": m.friction_angle, "cohesion": m.cohesion,
        "youngs_modulus": m.youngs_modulus, "poisson_ratio": m.poisson_ratio, "density": m.density,
    }


def load_trajectory(path: str | Path) -> Trajectory:
    """Read a trajectory written by save_trajectory (a directory or its trajectory.npz)."""
    path = Path(path)
    npz = path / "trajectory.npz" if path.is_dir() else path
    meta_path = npz.parent / "metadata.json"
    if not npz.is_file():
        raise InputError(f"{npz}: no such trajectory file.")
    if not meta_path.is_file():
        raise InputError(f"{meta_path}: missing; a trajectory needs its metadata.json beside it.")
    meta = checks.json_table(meta_path, "trajectory metadata file")
    checks.trajectory_metadata(meta, meta_path)
    sims = read_simulations(npz)
    if len(sims) != 1:
        raise InputError(f"{npz}: holds {len(sims)} simulations; a trajectory file holds exactly one.")
    positions, ptype, feats = sims[0]
    traj = trajectory_from_features(
        positions, ptype, feats, meta.get("dt", FRAME_DT), meta["bounds"], meta.get("name", npz.stem)
    )
    if "materials" in meta:
        traj = _attach_material_table(traj, feats, meta["materials"], meta_path)
    traj.info = meta.get("info", {})
    return traj


def _attach_material_table(traj: Trajectory, feats, table: list[dict], source: Path) -> Trajectory:
    """Map each point to the named material whose features match its feature row."""
    width = np.asarray(feats).reshape(traj.n_points, -1).shape[1]
    try:
        mats = [Material(**m) for m in table]
        rows = np.array([m.features()[:width] for m in mats], dtype=np.float32).reshape(len(mats), width)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{source}: the materials table does not describe materials ({exc}).") from None
    f = np.asarray(feats, dtype=np.float32).reshape(traj.n_points, -1)
    match = np.all(np.isclose(f[:, None, :], rows[None, :, :], atol=1e-6), axis=2)
    if not match.any(axis=1).all():
        return traj
    traj.material_id = match.argmax(axis=1).astype(np.int64)
    traj.materials = mats
    return traj


def first_frame_velocity(x0: np.ndarray, x1: np.ndarray, particle_type: np.ndarray, frame_dt: float) -> np.ndarray:
    """[N, 2] m/s: the velocity at frame 0 of the points that were moving then, estimated from
    frames 0 and 1 (positions [N, 2] m, frame_dt s apart) as a throw under gravity,
    (x1 - x0) / dt + g dt / 2 upwards; zero for kinematic points and for points that cover at
    most START_SPEED x dt over the frame, which started from rest (a failing slope). On data/base8
    it is within 0.03 m/s (median) of the thrown blocks' scene velocities of up to 15 m/s."""
    step = np.asarray(x1, dtype=np.float64) - np.asarray(x0, dtype=np.float64)
    velocity = step / frame_dt
    velocity[:, 1] += 0.5 * GRAVITY * frame_dt
    still = (np.linalg.norm(step, axis=1) <= START_SPEED * frame_dt) | (np.asarray(particle_type) == PARTICLE_TYPE_KINEMATIC)
    velocity[still] = 0.0
    return velocity


def trajectory_for_scene(scene: Scene, positions: np.ndarray, particle_type, material_id) -> Trajectory:
    return Trajectory(
        positions=np.asarray(positions, dtype=np.float32),
        particle_type=np.asarray(particle_type, dtype=np.int64),
        material_id=np.asarray(material_id, dtype=np.int64),
        materials=[scene.materials[n] for n in scene.material_names],
        frame_dt=scene.time.frame_dt,
        bounds=np.array([[0.0, scene.domain.width], [0.0, scene.domain.height]]),
        name=scene.name,
    )

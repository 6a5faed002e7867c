"""Simulated recording sessions of a free-moving, motion-captured camera (the recorded-data path).

The set-up is that of the paper's Panda recordings (Miseikis et al. 2019, section III): an
operator walks around the robot with a handheld RealSense; an OptiTrack system tracks a rigid
body of markers (the *rig*) fixed to the camera; a rig calibration gives the fixed rig-to-optical-
frame offset. Meanwhile the robot moves smoothly through its joint range.

Frames (``T_a_b`` maps points in frame b to frame a; metres, radians; quaternions xyzw):

- ``base``: the robot base link frame, z up; PyBullet's origin, as in :mod:`armpose.sim.render`;
- ``world``: the mocap frame, z up; the robot stands at ``T_world_base``, a random pose;
- ``rig``: the mocap rigid body on the camera; ``cam``: the OpenCV optical frame (x right,
  y down, z forward).

One session (:func:`record_session`), everything drawn from the job's seed:

1. scene: one domain-randomised background, lighting, robot colour and exposure for the whole
   session (:class:`~armpose.sim.scene.SceneRandomizer`); sensor noise and blur per frame;
2. robot: minimum-jerk segments between collision-free waypoints
   (:func:`~armpose.sessions.motion.robot_motion`);
3. camera: a smooth handheld orbit ``T_base_cam_true(t)`` (:func:`~armpose.sessions.motion.handheld_camera`), at which
   the frames are rendered;
4. rig: ``T_rig_cam_true`` from :func:`~armpose.calib.simulate.random_rig_offset`, never shown to
   the pipeline; a ChArUco session filmed with that rig
   (:func:`~armpose.calib.simulate.simulate_session`) and :func:`~armpose.calib.rig.calibrate_rig`
   give ``T_rig_cam_est``. Every session has its own rig mounting and calibration (the camera is
   re-mounted between sessions), so the calibration error differs between recordings;
5. mocap: ``T_world_rig_meas(t)``, the true rig pose with :class:`~armpose.calib.MocapNoise` per
   frame; the robot base is measured once, with the same noise;
6. written camera poses ``T_base_cam = inv(T_world_base_meas) @ T_world_rig_meas(t) @ T_rig_cam_est``,
   so the labels carry calibration and mocap error as those of real recordings do.

Two session kinds (``SessionJob.kind``): ``handheld`` (above) and ``tripod``, the calibration-free
use case: the camera stands still on a tripod (:func:`~armpose.sessions.motion.tripod_camera`: one
pose, no walk, drift or shake) while the robot moves. A tripod session still has its rig,
calibration and mocap, but the rig is measured once for the whole session, as the robot base is,
so its written camera pose is static too (one pose, repeated per frame) and carries one constant
calibration-and-mocap error.

``recording.json`` says ``source: recorded`` and ``simulated: true`` and holds the calibration
residuals and the errors against the truth; ``camera_poses_true.csv`` holds the true camera poses
(simulation only; no pipeline stage reads it).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pybullet as pb

from armpose.calib.rig import (
    RigCalibration,
    RigSettings,
    calibrate_rig,
    pose_error,
    rotation_angle_deg,
)
from armpose.calib.simulate import perturb_pose, random_rig_offset, simulate_session
from armpose.calib.solve import MocapNoise
from armpose.geometry import (
    Camera,
    invert,
    matrix_to_quat,
    pose_to_matrix,
    transform_points,
)
from armpose.io import atomic_write_text
from armpose.recording import (
    POSE_COLUMNS,
    RecordingMeta,
    read_joints,
    read_meta,
    read_poses,
    write_frame,
    write_tables,
)
from armpose.robots.kinematics import Kinematics
from armpose.robots.registry import get_robot
from armpose.sim.background import (
    composite,
    depth_from_buffer,
    pixel_rays,
    render_planes,
)
from armpose.sim.body import RobotBody
from armpose.sim.camera import FAR, NEAR, projection_matrix, view_matrix
from armpose.sessions.motion import handheld_camera, robot_motion, tripod_camera
from armpose.sim.render import jittered_color, load_other_robot, place_other_robot
from armpose.sim.scene import SceneRandomizer, camera_effects, lookalike_colors

log = logging.getLogger(__name__)

VERSION = 1  # bump when a change of this module changes its output: finished sessions are redone
PLAN_KEYS = ("recordings_dir", "sessions_per_robot", "tripod_sessions_per_robot")  # params['record'] keys that do not shape a session
TRUE_POSES = "camera_poses_true.csv"
KINDS = ("handheld", "tripod")


@dataclasses.dataclass(frozen=True)
class SessionJob:
    """One simulated session: robot type, frame count, seed, output folder, camera (a
    ``base.camera`` dict), ``params['record']``, the robot types (for background robots) and the
    session kind (:data:`KINDS`: a ``handheld`` or a static ``tripod`` camera)."""

    robot: str
    num_frames: int
    seed: tuple[int, ...]
    out_dir: Path
    camera: dict
    cfg: dict
    robot_types: tuple[str, ...]
    kind: str = "handheld"

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"session kind must be one of {KINDS}, got {self.kind!r} ({self.out_dir})")

    def signature(self) -> str:
        """A hash of everything that determines the output (for resuming)."""
        cfg = {k: v for k, v in self.cfg.items() if k not in PLAN_KEYS}
        parts = [VERSION, self.robot, self.num_frames, list(self.seed), self.camera, cfg, list(self.robot_types)]
        if self.kind != "handheld":  # handheld signatures stay those of earlier runs
            parts.append(self.kind)
        blob = json.dumps(parts, sort_keys=True)
        return hashlib.sha1(blob.encode()).hexdigest()[:16]

    def is_done(self) -> bool:
        """True if ``out_dir`` holds a finished recording of this very job."""
        meta = self.out_dir / "recording.json"
        if not meta.exists():
            return False
        return json.loads(meta.read_text()).get("generator", {}).get("signature") == self.signature()


# --------------------------------------------------------------------------- rig and mocap

def robot_in_world(rng: np.random.Generator, floor_z: float) -> np.ndarray:
    """``T_world_base``: the robot somewhere in the mocap volume (z up, origin on the floor), random yaw."""
    yaw = rng.uniform(-np.pi, np.pi)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = [*rng.uniform(-1.5, 1.5, 2), -floor_z]
    return T


def calibrate_rig_offset(T_rig_cam: np.ndarray, camera: Camera, noise: MocapNoise, views: int,
                         seed: int) -> RigCalibration:
    """Film a ChArUco board with the rig ``T_rig_cam`` (a simulated calibration session of ``views``
    views, mocap ``noise``) and estimate ``T_rig_cam`` from it as a user would, blind to the truth."""
    calib = simulate_session(seed, num_views=views, camera=camera, noise=noise, T_rig_cam=T_rig_cam)
    return calibrate_rig(calib.rig_views(), camera, calib.board.center, RigSettings(mocap_noise=noise))


def recorded_poses(T_world_base_meas: np.ndarray, T_world_rig_meas: np.ndarray, T_rig_cam_est: np.ndarray) -> np.ndarray:
    """The camera poses a recording holds: ``inv(T_world_base) @ T_world_rig @ T_rig_cam`` ``(n, 4, 4)``."""
    return invert(T_world_base_meas) @ T_world_rig_meas @ T_rig_cam_est


def label_errors(T_written: np.ndarray, T_true: np.ndarray, points_base: np.ndarray, camera: Camera) -> dict:
    """Per frame ``(n,)``: camera translation error (mm), rotation error (deg) and the largest shift
    (px, full camera image) of the base and joints ``points_base (n, K, 3)`` projected with the
    written instead of the true pose: the label error that calibration and mocap cause."""
    rot = rotation_angle_deg(np.swapaxes(T_written[:, :3, :3], -1, -2) @ T_true[:, :3, :3])
    trans = 1000.0 * np.linalg.norm(T_written[:, :3, 3] - T_true[:, :3, 3], axis=1)
    uv_w = camera.project(transform_points(invert(T_written), points_base))
    uv_t = camera.project(transform_points(invert(T_true), points_base))
    px = np.linalg.norm(uv_w - uv_t, axis=-1).max(axis=1)
    return {"camera_translation_mm": trans, "camera_rotation_deg": rot, "joint_reprojection_px": px}


def _stats(values: np.ndarray) -> dict:
    return {"median": float(np.median(values)), "p95": float(np.percentile(values, 95)), "max": float(np.max(values))}


# --------------------------------------------------------------------------- scene and rendering

def _session_camera_noise(cfg: dict, rng: np.random.Generator) -> dict:
    """``camera_noise`` settings with exposure (gain, offset) drawn once: it holds for a session."""
    if not cfg["enabled"]:
        return cfg
    gain, offset = rng.uniform(*cfg.get("gain", [0.8, 1.2])), rng.uniform(*cfg.get("offset", [-15, 15]))
    return {**cfg, "gain": [gain, gain], "offset": [offset, offset]}


def _color_robot(body: RobotBody, rcfg: dict, rng: np.random.Generator) -> None:
    app = body.spec.appearance
    jitter = rcfg["robot_appearance"]["color_jitter"] if rcfg["robot_appearance"]["enabled"] else 0.0
    body.set_colors(jittered_color(app.default_color, rng, jitter),
                    {k: jittered_color(v, rng, jitter) for k, v in app.link_colors.items()})


def _aabb(client: int, body: int) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounding box (lower, upper corner; metres) of a body over all its links."""
    boxes = [pb.getAABB(body, link, physicsClientId=client)
             for link in range(-1, pb.getNumJoints(body, physicsClientId=client))]
    return np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)


def _blocks_view(lo: np.ndarray, hi: np.ndarray, eyes: np.ndarray, points: np.ndarray, margin: float = 0.1) -> bool:
    """True if the box ``[lo, hi]`` (grown by ``margin`` m) meets a sight line from eye ``eyes[i]``
    to a robot point ``points[i, k]``, i.e. would hide part of the robot or hold the camera."""
    lo, hi = lo - margin, hi + margin
    a = np.repeat(eyes, points.shape[1], axis=0)
    d = points.reshape(-1, 3) - a
    d = np.where(np.abs(d) < 1e-12, 1e-12, d)
    t1, t2 = (lo - a) / d, (hi - a) / d
    enter, leave = np.minimum(t1, t2).max(axis=1), np.maximum(t1, t2).min(axis=1)
    return bool(np.any((leave >= np.maximum(enter, 0.0)) & (enter <= 1.0)))


def _clear_view(client: int, scene: SceneRandomizer, other: RobotBody | None, eyes: np.ndarray,
                points: np.ndarray, rng: np.random.Generator, reach: float) -> RobotBody | None:
    """Keep the operator's view of the robot clear, as a real recording would: remove distractors
    that would block a sight line from the camera to the robot's base or joints (or that the camera
    would pass through), and re-place the background robot until it blocks none, or remove it."""
    floor = scene.bodies[0]  # SceneRandomizer.new_scene adds the floor first
    for body in list(scene.bodies):
        if body not in (floor, scene.support) and _blocks_view(*_aabb(client, body), eyes, points):
            pb.removeBody(body, physicsClientId=client)
            scene.bodies.remove(body)
    if other is None:
        return None
    for _ in range(20):
        place_other_robot(other, rng, reach, scene.floor_z)
        if not _blocks_view(*_aabb(client, other.id), eyes, points, margin=0.2):
            return other
    other.remove()
    return None


def _render_frame(client: int, camera: Camera, proj, rays: np.ndarray, T_base_cam: np.ndarray,
                  scene: SceneRandomizer, light: dict) -> np.ndarray:
    """RGB uint8 ``(H, W, 3)``: the PyBullet bodies (TinyRenderer) composited over the ray-cast planes."""
    _, _, rgba, buf, _ = pb.getCameraImage(
        camera.width, camera.height, view_matrix(T_base_cam), proj, renderer=pb.ER_TINY_RENDERER,
        flags=pb.ER_NO_SEGMENTATION_MASK, physicsClientId=client, **light)
    fg = np.asarray(rgba, dtype=np.uint8).reshape(camera.height, camera.width, 4)[..., :3]
    fg_depth = depth_from_buffer(np.asarray(buf, np.float32).reshape(camera.height, camera.width), NEAR, FAR)
    bg, bg_depth = render_planes(scene.planes, scene.sky, camera, rays, T_base_cam, light)
    return composite(fg, fg_depth, bg, bg_depth)


def _pose_rows(T: np.ndarray) -> np.ndarray:
    return np.concatenate([T[:, :3, 3], matrix_to_quat(T[:, :3, :3])], axis=1)


def _write_true_poses(rec_dir: Path, T: np.ndarray) -> None:
    rows = [",".join(["frame", *POSE_COLUMNS])]
    rows += [",".join([str(i)] + [repr(float(v)) for v in r]) for i, r in enumerate(_pose_rows(T))]
    atomic_write_text(rec_dir / TRUE_POSES, "\n".join(rows) + "\n")


def read_true_poses(rec_dir: Path) -> np.ndarray:
    """The true camera poses ``T_base_cam (n, 4, 4)`` of a simulated session (``camera_poses_true.csv``)."""
    rows = np.loadtxt(Path(rec_dir) / TRUE_POSES, delimiter=",", skiprows=1, ndmin=2)
    return pose_to_matrix(rows[:, 1:4], rows[:, 4:8])


# --------------------------------------------------------------------------- one session

def _simulate_rig(job: SessionJob, rng: np.random.Generator, camera: Camera, T_true: np.ndarray,
                  floor_z: float) -> tuple[np.ndarray, dict]:
    """Rig, calibration and mocap for camera poses ``T_true``: the poses to write and the
    ``recording.json`` entries on calibration and truth. A ``tripod`` session's rig is measured
    once (from its first frame; the camera is static) and that one measurement holds for every frame."""
    rig = job.cfg["rig"]
    noise = MocapNoise(**rig["mocap_noise"])
    X = random_rig_offset(rng, rig["offset_translation_m"], rig["offset_rotation_deg"])
    cal = calibrate_rig_offset(X, camera, noise, int(rig["calibration_views"]), int(rng.integers(2**31)))
    T_world_base = robot_in_world(rng, floor_z)
    T_world_base_meas = perturb_pose(T_world_base, rng, noise)
    T_world_rig = T_world_base @ T_true @ invert(X)
    if job.kind == "tripod":
        T_world_rig_meas = np.repeat(perturb_pose(T_world_rig[0], rng, noise)[None], len(T_true), axis=0)
    else:
        T_world_rig_meas = np.stack([perturb_pose(T, rng, noise) for T in T_world_rig])
    T_written = recorded_poses(T_world_base_meas, T_world_rig_meas, cal.T_rig_cam)
    deg, mm = pose_error(cal.T_rig_cam, X)
    base_deg, base_mm = pose_error(T_world_base_meas, T_world_base)
    info = {"rig_calibration": cal.to_dict(), "simulation": {
        "note": "simulated session: the truth below is never used by the pipeline",
        "rig_offset_error": {"translation_mm": mm, "rotation_deg": deg},
        "base_pose_error": {"translation_mm": base_mm, "rotation_deg": base_deg},
        "mocap_noise": dataclasses.asdict(noise),
        "T_rig_cam_true": X.tolist(),
        "T_world_base_true": T_world_base.tolist(),
        "true_camera_poses": TRUE_POSES}}
    return T_written, info


def record_session(job: SessionJob) -> int:
    """Simulate ``job`` into ``job.out_dir`` atomically (a hidden temporary folder, then a rename).

    Returns the number of frames. Deterministic for a given ``job.seed``.
    """
    rng = np.random.default_rng(list(job.seed))
    spec, camera, cfg = get_robot(job.robot), Camera.from_dict(job.camera), job.cfg
    kin, rcfg, fps, n = Kinematics(spec), cfg["randomize"], float(cfg["fps"]), job.num_frames
    client = pb.connect(pb.DIRECT)
    tmp = Path(tempfile.mkdtemp(prefix=f".{job.out_dir.name}.", dir=job.out_dir.parent))
    try:
        body = RobotBody(client, spec, kin, self_collision=True)
        scene = SceneRandomizer(client, rng, rcfg, spec.reach, max(cfg["camera"]["distance"]),
                                lookalike_colors(spec.appearance))
        other = load_other_robot(client, job, rng)
        support = scene.new_scene()
        _color_robot(body, rcfg, rng)
        light, noise_cfg = scene.lighting(), _session_camera_noise(rcfg["camera_noise"], rng)
        q = robot_motion(body, support, rng, n, fps, cfg["robot"])
        points = np.concatenate([np.zeros((n, 1, 3)), kin.joint_positions(q)], axis=1)
        if job.kind == "tripod":
            T_true, frac = tripod_camera(points, camera, cfg["camera"], rng, scene.floor_z)
        else:
            T_true, frac = handheld_camera(points, camera, cfg["camera"], rng, fps, scene.floor_z)
        _clear_view(client, scene, other, T_true[:, :3, 3], points, rng, spec.reach)
        T_written, info = _simulate_rig(job, rng, camera, T_true, scene.floor_z)
        proj, rays = projection_matrix(camera), pixel_rays(camera)
        for i in range(n):
            body.set_joints(q[i])
            rgb = _render_frame(client, camera, proj, rays, T_true[i], scene, light)
            write_frame(tmp, i, camera_effects(rgb, rng, noise_cfg))
        errors = label_errors(T_written, T_true, points, camera)
        info["simulation"]["label_error"] = {k: _stats(v) for k, v in errors.items()}
        _write_true_poses(tmp, T_true)
        meta = RecordingMeta(job.robot, camera, "recorded",
                             notes=f"SIMULATED {job.kind}-camera session with a mocap rig (armpose record, "
                                   f"PyBullet TinyRenderer), seed {list(job.seed)}")
        extra = {"simulated": True, "generator": {"name": "armpose.record", "signature": job.signature()},
                 "session": {"kind": job.kind, "fps": fps, "duration_s": n / fps, "robot_in_view_fraction": frac},
                 **info}
        write_tables(tmp, meta, spec, np.arange(n), q, _pose_rows(T_written), extra=extra)
        if job.out_dir.exists():
            shutil.rmtree(job.out_dir)
        tmp.rename(job.out_dir)
    finally:
        pb.disconnect(client)
        if tmp.exists():
            shutil.rmtree(tmp)
    log.info("%s: %d frames, rig offset error %.2f mm / %.3f deg", job.out_dir.name, n,
             info["simulation"]["rig_offset_error"]["translation_mm"], info["simulation"]["rig_offset_error"]["rotation_deg"])
    return n


def session_errors(rec_dir: Path) -> dict:
    """:func:`label_errors` of a written simulated session, recomputed from its files."""
    meta, spec = read_meta(rec_dir)
    _, q, _ = read_joints(rec_dir, spec)
    _, poses, _ = read_poses(rec_dir)
    points = np.concatenate([np.zeros((len(q), 1, 3)), Kinematics(spec).joint_positions(q)], axis=1)
    return label_errors(pose_to_matrix(poses[:, :3], poses[:, 3:]), read_true_poses(rec_dir), points, meta.camera)

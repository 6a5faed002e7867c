"""Render one synthetic recording with PyBullet's TinyRenderer (CPU only).

The renderer writes a recording (frames, joint angles, camera poses) and no labels:
labels come from the recording alone, exactly as for real data.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pybullet as pb

from armpose.geometry import Camera, matrix_to_quat
from armpose.recording import RecordingMeta, write_frame, write_tables
from armpose.robots.kinematics import Kinematics
from armpose.robots.registry import get_robot
from armpose.sim.body import RobotBody
from armpose.sim.background import composite, depth_from_buffer, pixel_rays, render_planes
from armpose.sim.camera import FAR, NEAR, projection_matrix, view_matrix
from armpose.sim.sampling import collision_free_configuration, sample_camera_pose
from armpose.sim.scene import SceneRandomizer, camera_effects, lookalike_colors


@dataclasses.dataclass(frozen=True)
class RenderJob:
    """One synthetic recording to render: robot type, frame count, seed and output folder."""

    robot: str
    num_frames: int
    seed: tuple[int, ...]
    out_dir: Path
    camera: dict
    cfg: dict  # params['render']
    robot_types: tuple[str, ...]

    def signature(self) -> str:
        """A hash of everything that determines the output (for resuming)."""
        blob = json.dumps([self.robot, self.num_frames, list(self.seed), self.camera, self.cfg,
                           list(self.robot_types)], sort_keys=True)
        return hashlib.sha1(blob.encode()).hexdigest()[:16]

    def is_done(self) -> bool:
        """True if ``out_dir`` holds a finished recording of this very job."""
        meta = self.out_dir / "recording.json"
        if not meta.exists():
            return False
        return json.loads(meta.read_text()).get("generator", {}).get("signature") == self.signature()


def jittered_color(color, rng: np.random.Generator, amount: float):
    """RGBA ``color`` (0-1) with Gaussian noise of std ``amount`` on R, G and B; None stays None."""
    if color is None:
        return None
    rgb = np.clip(np.asarray(color[:3]) + rng.normal(0, amount, 3), 0, 1)
    return [*rgb.tolist(), color[3]]


def load_other_robot(client: int, job: RenderJob, rng: np.random.Generator):
    """Maybe load another robot type to appear, unlabelled, in the background."""
    prob = job.cfg["randomize"]["background"].get("other_robot_prob", 0.0)
    others = [r for r in job.robot_types if r != job.robot]
    if not others or rng.uniform() >= prob:
        return None
    spec = get_robot(others[rng.integers(len(others))])
    body = RobotBody(client, spec)
    body.set_colors(spec.appearance.default_color, spec.appearance.link_colors)
    return body


def place_other_robot(body: RobotBody | None, rng: np.random.Generator, reach: float, floor_z: float) -> None:
    """Stand the background robot on the floor, clear of the main robot, in a random pose."""
    if body is None:
        return
    ang, dist = rng.uniform(0, 2 * np.pi), reach + body.spec.reach + rng.uniform(0.4, 1.5)
    T = np.eye(4)
    T[:3, :3] = np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0], [0, 0, 1]])
    T[:3, 3] = [dist * np.cos(ang), dist * np.sin(ang), floor_z]
    body.place(T)
    lim = np.array(body.spec.joint_limits)
    body.set_joints(rng.uniform(lim[:, 0], lim[:, 1]))


def render_recording(job: RenderJob) -> int:
    """Render ``job`` into ``job.out_dir`` atomically (a temporary folder, then a rename).

    Returns the number of frames. Deterministic for a given ``job.seed``.
    """
    rng = np.random.default_rng(list(job.seed))
    spec = get_robot(job.robot)
    kin = Kinematics(spec)
    camera = Camera.from_dict(job.camera)
    rcfg = job.cfg["randomize"]
    client = pb.connect(pb.DIRECT)
    tmp = Path(tempfile.mkdtemp(prefix=f".{job.out_dir.name}.", dir=job.out_dir.parent))
    try:
        body = RobotBody(client, spec, kin, self_collision=True)
        scene = SceneRandomizer(client, rng, rcfg, spec.reach, max(job.cfg["camera"]["distance"]),
                                lookalike_colors(spec.appearance))
        other = load_other_robot(client, job, rng)
        proj = projection_matrix(camera)
        rays = pixel_rays(camera)
        joints, poses = np.zeros((job.num_frames, spec.num_joints)), np.zeros((job.num_frames, 7))
        support = None
        for i in range(job.num_frames):
            if i % job.cfg["frames_per_scene"] == 0:
                support = scene.new_scene()
                place_other_robot(other, rng, spec.reach, scene.floor_z)
                jitter = rcfg["robot_appearance"]["color_jitter"] if rcfg["robot_appearance"]["enabled"] else 0.0
                app = spec.appearance
                body.set_colors(jittered_color(app.default_color, rng, jitter),
                                {k: jittered_color(v, rng, jitter) for k, v in app.link_colors.items()})
            q = collision_free_configuration(body, support, rng)
            points = np.vstack([np.zeros((1, 3)), kin.joint_positions(q[None])[0]])
            T_base_cam = sample_camera_pose(points, camera, job.cfg["camera"], rng)
            light = scene.lighting()
            _, _, rgba, buf, _ = pb.getCameraImage(
                camera.width, camera.height, view_matrix(T_base_cam), proj, renderer=pb.ER_TINY_RENDERER,
                flags=pb.ER_NO_SEGMENTATION_MASK, physicsClientId=client, **light)
            fg = np.asarray(rgba, dtype=np.uint8).reshape(camera.height, camera.width, 4)[..., :3]
            fg_depth = depth_from_buffer(np.asarray(buf, np.float32).reshape(camera.height, camera.width), NEAR, FAR)
            bg, bg_depth = render_planes(scene.planes, scene.sky, camera, rays, T_base_cam, light)
            rgb = composite(fg, fg_depth, bg, bg_depth)
            write_frame(tmp, i, camera_effects(rgb, rng, rcfg["camera_noise"]))
            joints[i] = q
            poses[i, :3], poses[i, 3:] = T_base_cam[:3, 3], matrix_to_quat(T_base_cam[:3, :3])
        meta = RecordingMeta(job.robot, camera, "synthetic",
                             notes=f"armpose render, PyBullet TinyRenderer, seed {list(job.seed)}")
        write_tables(tmp, meta, spec, np.arange(job.num_frames), joints, poses,
                     extra={"generator": {"name": "armpose.render", "signature": job.signature()}})
        if job.out_dir.exists():
            shutil.rmtree(job.out_dir)
        tmp.rename(job.out_dir)
    finally:
        pb.disconnect(client)
        if tmp.exists():
            shutil.rmtree(tmp)
    return job.num_frames

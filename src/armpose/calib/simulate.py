"""Simulated rig-calibration sessions: a handheld camera with a mocap rig, filming a ChArUco board.

PyBullet (DIRECT, TinyRenderer, explicit matrices from :mod:`armpose.sim.camera`) renders the
board (a textured quad with the :meth:`BoardSpec.image` texture) in front of a procedural backdrop
(:func:`armpose.sim.textures.procedural_texture`), 2x supersampled then area-downsampled, with
pixel noise. The camera follows a smooth handheld sweep (:func:`handheld_trajectory`). The true
``T_rig_cam`` is drawn at random (3-8 cm, 5-20 deg); the solver never sees it. The mocap poses
of rig and board get noise (:class:`MocapNoise`; RMS 0.5 mm and 0.1 deg by default).

Frames as in :mod:`armpose.calib.rig`: world = mocap frame; camera optical frame OpenCV
(x right, y down, z forward); metres; quaternions xyzw.
"""
from __future__ import annotations

import dataclasses
import logging
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pybullet as pb

from armpose.calib.board import BoardSpec, detect_board
from armpose.calib.rig import RigView
from armpose.calib.solve import MocapNoise
from armpose.geometry import Camera, invert, look_at
from armpose.sim.camera import projection_matrix, view_matrix
from armpose.sim.textures import procedural_texture

log = logging.getLogger(__name__)

DEFAULT_CAMERA = Camera(480, 360, 525.0, 525.0, 239.5, 179.5)  # the repository's canonical camera
DEFAULT_BOARD = BoardSpec(7, 5, 0.07, 0.054, "DICT_4X4_50")  # 0.49 m x 0.35 m
SUPERSAMPLE = 2  # render at 2x and downsample: TinyRenderer does no anti-aliasing
PX_PER_SQUARE = 120  # board texture resolution
DEFAULT_NOISE = MocapNoise()  # 0.5 mm, 0.1 deg RMS per mocap pose


@dataclasses.dataclass
class CalibrationSession:
    """One simulated session. ``T_world_rig`` and ``T_world_board`` ``(N, 4, 4)`` are the noisy mocap
    measurements per view; ``T_rig_cam``, ``T_world_cam`` and ``T_world_board_true`` are the truth."""

    names: list[str]
    images: list[np.ndarray]  # RGB uint8 (H, W, 3)
    camera: Camera
    board: BoardSpec
    T_world_rig: np.ndarray
    T_world_board: np.ndarray
    T_rig_cam: np.ndarray
    T_world_cam: np.ndarray
    T_world_board_true: np.ndarray

    def rig_views(self) -> list[RigView]:
        """Detect the board in every image: the solver's input (no ground truth)."""
        return [RigView(n, r, b, detect_board(img, self.board, self.camera))
                for n, img, r, b in zip(self.names, self.images, self.T_world_rig, self.T_world_board)]


def _rotation(rotvec) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(rotvec, np.float64).reshape(3))[0]


def random_rig_offset(rng: np.random.Generator, translation_m=(0.03, 0.08), rotation_deg=(5.0, 20.0)) -> np.ndarray:
    """A random ``T_rig_cam``: random direction and length of translation, random axis and angle."""
    def direction() -> np.ndarray:
        v = rng.normal(size=3)
        return v / np.linalg.norm(v)
    T = np.eye(4)
    T[:3, :3] = _rotation(direction() * np.radians(rng.uniform(*rotation_deg)))
    T[:3, 3] = direction() * rng.uniform(*translation_m)
    return T


def perturb_pose(T: np.ndarray, rng: np.random.Generator, noise: MocapNoise) -> np.ndarray:
    """``T`` with isotropic Gaussian noise whose RMS magnitudes are ``noise`` (world-frame translation,
    body-frame rotation)."""
    out = np.array(T, dtype=np.float64)
    out[:3, 3] += rng.normal(scale=noise.translation_mm / 1000.0 / np.sqrt(3), size=3)
    out[:3, :3] = out[:3, :3] @ _rotation(rng.normal(scale=np.radians(noise.rotation_deg) / np.sqrt(3), size=3))
    return out


def board_in_world(rng: np.random.Generator) -> np.ndarray:
    """``T_world_board`` of a board standing upright (z-up world), facing -x, with a random yaw and tilt."""
    R0 = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # columns: board x, y, z in world
    T = np.eye(4)
    T[:3, :3] = _rotation([0, 0, rng.uniform(-0.5, 0.5)]) @ R0 @ _rotation([rng.uniform(-0.2, 0.2), 0, 0])
    T[:3, 3] = [rng.uniform(1.5, 2.5), rng.uniform(-0.5, 0.5), rng.uniform(1.0, 1.5)]
    return T


def handheld_trajectory(rng: np.random.Generator, n: int, T_world_target: np.ndarray, center: np.ndarray,
                        distance=(0.7, 1.4), max_angle_deg: float = 40.0, max_roll_deg: float = 15.0) -> np.ndarray:
    """``T_world_cam`` ``(n, 4, 4)`` of a smooth handheld sweep looking at ``center`` (target frame).

    The camera stays on the target frame's -z side (the side a ChArUco board faces), within
    ``max_angle_deg`` of the -z axis, ``distance`` metres from ``center``, and has image-down along
    the target's +y up to ``max_roll_deg``. Angles, distance, aim point and roll are slow sinusoids
    of time with random phases and rates, so consecutive views are close, as with a handheld camera.
    """
    s = np.linspace(0.0, 1.0, n)

    def wave(amplitude: float) -> np.ndarray:
        return amplitude * np.sin(2 * np.pi * rng.uniform(0.6, 1.2) * s + rng.uniform(0, 2 * np.pi))

    amax = np.radians(max_angle_deg) / np.sqrt(2)
    yaw, pitch = wave(amax * rng.uniform(0.8, 1.0)), wave(amax * rng.uniform(0.8, 1.0))
    dist = 0.5 * (distance[0] + distance[1]) + wave(0.5 * (distance[1] - distance[0]))
    aim = np.stack([wave(0.04), wave(0.04), np.zeros(n)], axis=1)
    roll = wave(np.radians(max_roll_deg))
    out = np.empty((n, 4, 4))
    for i in range(n):
        direction = _rotation([0, yaw[i], 0]) @ _rotation([pitch[i], 0, 0]) @ np.array([0.0, 0.0, -1.0])
        eye = center + dist[i] * direction
        out[i] = T_world_target @ look_at(eye, center + aim[i], up=(0.0, -1.0, 0.0), roll=roll[i])
    return out


def _quad(client: int, corners: np.ndarray, texture: int) -> int:
    """A textured quad, visible from the side its corners (board frame, TL TR BR BL) wind clockwise on."""
    vis = pb.createVisualShape(pb.GEOM_MESH, vertices=corners.tolist(), indices=[0, 2, 1, 0, 3, 2],
                               uvs=[[0, 1], [1, 1], [1, 0], [0, 0]],  # TinyRenderer's v runs bottom-up
                               normals=[[0.0, 0.0, -1.0]] * 4, physicsClientId=client)
    body = pb.createMultiBody(0, -1, vis, [0, 0, 0], [0, 0, 0, 1], physicsClientId=client)
    pb.changeVisualShape(body, -1, textureUniqueId=texture, rgbaColor=[1, 1, 1, 1], physicsClientId=client)
    return body


class BoardScene:
    """A PyBullet DIRECT client holding the board (and a backdrop) placed at ``T_world_board``.

    Use as a context manager; :meth:`render` draws the view of a camera at ``T_world_cam``.
    """

    def __init__(self, board: BoardSpec, T_world_board: np.ndarray, rng: np.random.Generator):
        self.board, self.rng = board, rng
        self.client = pb.connect(pb.DIRECT)
        try:
            self._build(T_world_board)
        except BaseException:
            pb.disconnect(self.client)
            raise
        self.light = {"lightDirection": (T_world_board[:3, :3] @ [rng.uniform(-0.5, 0.5), -0.5, -1.0]).tolist(),
                      "lightAmbientCoeff": rng.uniform(0.6, 0.8), "lightDiffuseCoeff": rng.uniform(0.3, 0.5),
                      "lightSpecularCoeff": 0.0, "shadow": 0}

    def _build(self, T_world_board: np.ndarray) -> None:
        w, h = self.board.size
        px_margin = PX_PER_SQUARE // 4  # white margin around the chessboard
        image, px = self.board.image(PX_PER_SQUARE, px_margin)
        m = px_margin / px * self.board.square_length
        with tempfile.TemporaryDirectory(prefix="armpose-calib-") as folder:  # PyBullet copies the pixels;
            board_png, back_png = Path(folder) / "board.png", Path(folder) / "backdrop.png"  # unique names:
            cv2.imwrite(str(board_png), image)  # it caches textures by path
            cv2.imwrite(str(back_png), procedural_texture(self.rng, 256)[..., ::-1])
            board_tex = pb.loadTexture(str(board_png), physicsClientId=self.client)
            back_tex = pb.loadTexture(str(back_png), physicsClientId=self.client)

        def to_world(pts) -> np.ndarray:
            pts = np.asarray(pts, dtype=np.float64)
            return pts @ T_world_board[:3, :3].T + T_world_board[:3, 3]

        _quad(self.client, to_world([[-m, -m, 0], [w + m, -m, 0], [w + m, h + m, 0], [-m, h + m, 0]]), board_tex)
        b, z = 1.2, 0.03  # backdrop: 1.2 m beyond the board's edges, 3 cm behind it
        _quad(self.client, to_world([[-b, -b, z], [w + b, -b, z], [w + b, h + b, z], [-b, h + b, z]]), back_tex)

    def render(self, T_world_cam: np.ndarray, camera: Camera, pixel_noise: float = 2.0) -> np.ndarray:
        """RGB uint8 ``(H, W, 3)`` seen by ``camera`` at ``T_world_cam``: supersampled, then Gaussian
        pixel noise of ``pixel_noise`` grey levels."""
        big = camera.scale_crop(camera.width * SUPERSAMPLE, camera.height * SUPERSAMPLE)[0]
        _, _, rgba, _, _ = pb.getCameraImage(big.width, big.height, view_matrix(T_world_cam), projection_matrix(big),
                                             renderer=pb.ER_TINY_RENDERER, flags=pb.ER_NO_SEGMENTATION_MASK,
                                             physicsClientId=self.client, **self.light)
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(big.height, big.width, 4)[..., :3]
        rgb = cv2.resize(rgb, (camera.width, camera.height), interpolation=cv2.INTER_AREA).astype(np.float32)
        rgb += self.rng.normal(scale=pixel_noise, size=rgb.shape).astype(np.float32)
        return np.clip(np.rint(rgb), 0, 255).astype(np.uint8)

    def close(self) -> None:
        pb.disconnect(self.client)

    def __enter__(self) -> BoardScene:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def simulate_session(seed: int, num_views: int = 16, camera: Camera = DEFAULT_CAMERA,
                     board: BoardSpec = DEFAULT_BOARD, noise: MocapNoise = DEFAULT_NOISE,
                     T_rig_cam: np.ndarray | None = None, distance=(0.7, 1.4)) -> CalibrationSession:
    """A simulated calibration session from ``seed``: images, noisy mocap poses of rig and board per
    view, and the truth. ``T_rig_cam`` defaults to :func:`random_rig_offset`."""
    rng = np.random.default_rng(seed)
    X = random_rig_offset(rng) if T_rig_cam is None else np.asarray(T_rig_cam, dtype=np.float64)
    T_world_board = board_in_world(rng)
    T_world_cam = handheld_trajectory(rng, num_views, T_world_board, board.center, distance)
    T_world_rig_true = T_world_cam @ invert(X)
    with BoardScene(board, T_world_board, rng) as scene:
        images = [scene.render(T, camera) for T in T_world_cam]
    return CalibrationSession(
        names=[f"view_{i:03d}.png" for i in range(num_views)], images=images, camera=camera, board=board,
        T_world_rig=np.stack([perturb_pose(T, rng, noise) for T in T_world_rig_true]),
        T_world_board=np.stack([perturb_pose(T_world_board, rng, noise) for _ in range(num_views)]),
        T_rig_cam=X, T_world_cam=T_world_cam, T_world_board_true=T_world_board)

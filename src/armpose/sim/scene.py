"""Domain-randomised PyBullet scenes around a robot whose base frame is the world origin.

Each scene re-draws floor, walls, table, distractor objects and, sometimes, another
robot in the background; each frame re-draws the lighting. Every draw comes from
the ``numpy`` generator passed in, so a seed fixes the scene.
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import cv2
import numpy as np
import pybullet as pb

from armpose.sim.background import Plane
from armpose.sim.textures import procedural_texture


def _uniform(rng: np.random.Generator, lo_hi) -> float:
    lo, hi = lo_hi
    return float(rng.uniform(lo, hi))


def lookalike_colors(appearance) -> list[tuple[float, ...]]:
    """The distinct RGBA colours of a robot description's ``appearance`` (its default colour, when
    it sets one, and its per-link colours): what :class:`SceneRandomizer` paints look-alikes in."""
    colors = ([appearance.default_color] if appearance.default_color else []) + list(appearance.link_colors.values())
    return list(dict.fromkeys(tuple(float(v) for v in c) for c in colors))


class SceneRandomizer:
    """Builds and re-builds the background of one PyBullet client.

    Floor and walls are :class:`~armpose.sim.background.Plane` records (``self.planes``,
    ray-cast in numpy); table, distractors and other robots are PyBullet bodies.

    ``cfg`` is ``params['render']['randomize']``; ``reach`` is the robot's reach in metres.
    ``lookalike_colors`` (RGBA in [0, 1], the robot's own link colours: :func:`lookalike_colors`)
    are hard negatives: with probability ``background.lookalike_prob`` (0 by default: no draw
    at all, so scenes stay exactly as before) a table or distractor is plain-coloured in one of
    them (brightness jittered by +-15 %) instead of a random colour or texture, so the network
    must tell the robot from scene surfaces that look like its links by shape.
    """

    def __init__(self, client: int, rng: np.random.Generator, cfg: dict, reach: float, max_camera_distance: float,
                 lookalike_colors: list[tuple[float, ...]] | None = None):
        self.client, self.rng, self.cfg, self.reach = client, rng, cfg, reach
        self.lookalike_colors = [tuple(c) for c in (lookalike_colors or [])]
        self.lookalike_prob = float(cfg["background"].get("lookalike_prob", 0.0)) if self.lookalike_colors else 0.0
        self.wall_distance = max_camera_distance + reach + 0.5  # walls never stand between camera and robot
        self.bodies: list[int] = []
        self.support: int | None = None
        self.floor_z = 0.0
        self.planes: list[Plane] = []
        self.sky = np.full(3, 200.0)
        self.images, self.textures = self._make_textures(int(cfg["background"].get("textures", 8)))

    def _make_textures(self, n: int) -> tuple[list[np.ndarray], list[int]]:
        """``n`` procedural textures: float32 RGB arrays (for planes) and PyBullet texture ids."""
        if not self.cfg["background"]["enabled"]:
            return [np.full((8, 8, 3), 160.0, np.float32)], []
        images, ids = [], []
        with tempfile.TemporaryDirectory(prefix="armpose-tex-") as folder:  # PyBullet copies the pixels
            for i in range(n):
                path = Path(folder) / f"tex{i}.png"
                img = procedural_texture(self.rng)
                cv2.imwrite(str(path), img[..., ::-1])
                images.append(img.astype(np.float32))
                ids.append(pb.loadTexture(str(path), physicsClientId=self.client))
        return images, ids

    def _plane(self, normal, offset: float, axes, z_max: float = np.inf) -> Plane:
        tex = self.images[self.rng.integers(len(self.images))] * self.rng.uniform(0.6, 1.2, 3).astype(np.float32)
        return Plane(np.asarray(normal, float), float(offset), tuple(np.asarray(a, float) for a in axes),
                     tex, float(self.rng.uniform(0.3, 3.0)), z_max)

    def _color(self) -> list[float]:
        return [*self.rng.uniform(0.05, 1.0, 3).tolist(), 1.0]

    def _surface(self) -> tuple[list[float], bool]:
        """``(rgba, lookalike)``: one of the robot's colours with probability ``lookalike_prob``
        (never drawn when it is 0), else a random colour."""
        if self.lookalike_prob > 0 and self.rng.uniform() < self.lookalike_prob:
            base = np.asarray(self.lookalike_colors[self.rng.integers(len(self.lookalike_colors))][:3])
            return [*np.clip(base * self.rng.uniform(0.85, 1.15), 0, 1).tolist(), 1.0], True
        return self._color(), False

    def _box(self, half, pos, collide: bool = False, yaw: float = 0.0) -> int:
        c = self.client
        color, lookalike = self._surface()
        vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=half, rgbaColor=color, physicsClientId=c)
        col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=c) if collide else -1
        body = pb.createMultiBody(0, col, vis, pos, pb.getQuaternionFromEuler([0, 0, yaw]), physicsClientId=c)
        if not lookalike and self.textures and self.rng.uniform() < 0.7:
            tex = self.textures[self.rng.integers(len(self.textures))]
            pb.changeVisualShape(body, -1, textureUniqueId=tex, rgbaColor=[1, 1, 1, 1], physicsClientId=c)
        self.bodies.append(body)
        return body

    def _distractor(self, pos) -> None:
        c, kind = self.client, self.rng.integers(3)
        size = self.rng.uniform(0.04, 0.25)
        if kind == 0:
            vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=self.rng.uniform(0.03, 0.25, 3).tolist(),
                                       rgbaColor=self._surface()[0], physicsClientId=c)
        elif kind == 1:
            vis = pb.createVisualShape(pb.GEOM_SPHERE, radius=size, rgbaColor=self._surface()[0], physicsClientId=c)
        else:
            vis = pb.createVisualShape(pb.GEOM_CYLINDER, radius=size, length=self.rng.uniform(0.1, 0.8),
                                       rgbaColor=self._surface()[0], physicsClientId=c)
        orn = pb.getQuaternionFromEuler(self.rng.uniform(-np.pi, np.pi, 3).tolist())
        self.bodies.append(pb.createMultiBody(0, -1, vis, pos, orn, physicsClientId=c))

    def _ring_position(self, r_min: float, r_max: float, z: float) -> list[float]:
        ang, r = self.rng.uniform(0, 2 * np.pi), self.rng.uniform(r_min, r_max)
        return [r * np.cos(ang), r * np.sin(ang), z]

    def new_scene(self) -> int:
        """Replace the background; returns the support body (table or floor) the robot stands on."""
        for body in self.bodies:
            pb.removeBody(body, physicsClientId=self.client)
        self.bodies = []
        bg = self.cfg["background"]
        table = bg["enabled"] and self.rng.uniform() < bg.get("table_prob", 0.5)
        floor_z = -_uniform(self.rng, bg.get("table_height", [0.6, 0.9])) if table else 0.0
        self.floor_z = floor_z
        # collision only: the floor is drawn as a Plane; a tiny far-away visual keeps PyBullet from
        # drawing the collision box (which it does for bodies without a visual shape)
        hidden = pb.createVisualShape(pb.GEOM_SPHERE, radius=1e-4, visualFramePosition=[0, 0, -100],
                                      physicsClientId=self.client)
        floor = pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[15, 15, 0.05],
                                                              physicsClientId=self.client),
                                   hidden, [0, 0, floor_z - 0.05], physicsClientId=self.client)
        self.bodies.append(floor)
        self.support = floor
        self.planes = [self._plane([0, 0, 1], floor_z, ([1, 0, 0], [0, 1, 0]))]
        self.sky = self.rng.uniform(60, 255, 3)
        if table:
            hx, hy = self.rng.uniform(0.3, 0.9, 2)
            off = self.rng.uniform(-0.2, 0.2, 2)
            self.support = self._box([hx, hy, -floor_z / 2], [off[0], off[1], floor_z / 2], collide=True)
        if not bg["enabled"]:
            return self.support
        for _ in range(int(self.rng.integers(bg["walls"][0], bg["walls"][1] + 1))):
            ang = self.rng.uniform(0, 2 * np.pi)
            dist = self.wall_distance + self.rng.uniform(0.0, 4.0)
            inward = -np.array([np.cos(ang), np.sin(ang), 0.0])
            self.planes.append(self._plane(inward, -dist, ([-np.sin(ang), np.cos(ang), 0], [0, 0, 1]),
                                           z_max=floor_z + self.rng.uniform(2.0, 8.0)))
        for _ in range(int(self.rng.integers(bg["distractors"][0], bg["distractors"][1] + 1))):
            self._distractor(self._ring_position(0.4 + 0.5 * self.reach, self.wall_distance,
                                                 floor_z + self.rng.uniform(0, 1.8)))
        return self.support

    def lighting(self) -> dict:
        """Keyword arguments for ``getCameraImage``: light direction, colour and coefficients."""
        cfg = self.cfg["lighting"]
        if not cfg["enabled"]:
            return {"lightDirection": [1, 1, 2], "lightAmbientCoeff": 0.6, "lightDiffuseCoeff": 0.6,
                    "lightSpecularCoeff": 0.1, "shadow": 0}
        az, el = self.rng.uniform(0, 2 * np.pi), self.rng.uniform(0.2, 1.4)
        jitter = cfg.get("color_jitter", 0.2)
        return {
            "lightDirection": [np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)],
            "lightColor": np.clip(1.0 - self.rng.uniform(0, jitter, 3), 0, 1).tolist(),
            "lightAmbientCoeff": _uniform(self.rng, cfg["ambient"]),
            "lightDiffuseCoeff": _uniform(self.rng, cfg["diffuse"]),
            "lightSpecularCoeff": _uniform(self.rng, cfg["specular"]),
            "shadow": int(self.rng.uniform() < cfg.get("shadow_prob", 0.0)),
        }


def camera_effects(img: np.ndarray, rng: np.random.Generator, cfg: dict) -> np.ndarray:
    """Exposure (gain, offset), blur and Gaussian sensor noise on an RGB uint8 image
    (``cfg`` is ``params['render']['randomize']['camera_noise']``)."""
    if not cfg["enabled"]:
        return img
    out = cv2.convertScaleAbs(img, alpha=rng.uniform(*cfg.get("gain", [0.8, 1.2])),
                              beta=rng.uniform(*cfg.get("offset", [-15, 15])))
    if rng.uniform() < cfg.get("blur_prob", 0.3):
        out = cv2.GaussianBlur(out, (0, 0), _uniform(rng, cfg.get("blur_sigma", [0.5, 1.5])))
    std = _uniform(rng, cfg.get("gaussian_std", [0, 6]))
    if std > 0:
        cv2.setRNGSeed(int(rng.integers(2**31)))  # OpenCV's generator, seeded from ours: deterministic
        noise = np.empty(out.shape, np.int16)
        cv2.randn(noise, 0.0, std)
        out = cv2.add(out, noise, dtype=cv2.CV_8U)
    return out

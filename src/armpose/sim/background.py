"""Floor and walls as textured planes, ray-cast with numpy and composited behind TinyRenderer.

PyBullet's TinyRenderer costs about 250 ns per covered pixel, so a floor and walls filling
the frame cost more than a (simplified) robot. Planes are cheap to ray-cast exactly: each
pixel's ray meets the floor ``z = floor_z`` or a vertical wall, the hit point indexes a tiling
texture, and a Lambert term shades it. Planes are ray-cast at a reduced resolution (a soft
background is one more randomisation) and carry metric depth along the optical axis, so they
composite correctly with the depth buffer of the TinyRenderer layer (robot, table, objects).
"""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from armpose.geometry import Camera


@dataclasses.dataclass
class Plane:
    """A textured plane ``normal . p = offset`` (world frame, metres), facing the robot.

    ``axes``: two in-plane unit vectors for texture coordinates; ``scale``: metres per texture
    tile; ``z_max``: walls end at this height (inf for the floor)."""

    normal: np.ndarray
    offset: float
    axes: tuple[np.ndarray, np.ndarray]
    texture: np.ndarray  # (h, w, 3) float32 RGB in [0, 255]
    scale: float
    z_max: float = np.inf


def pixel_rays(camera: Camera, factor: int = 3) -> np.ndarray:
    """Ray directions ``(H/f * W/f, 3)`` (unit z, camera optical frame) through the centres of
    ``factor x factor`` pixel blocks."""
    h, w = camera.height // factor, camera.width // factor
    u, v = np.meshgrid((np.arange(w) + 0.5) * factor - 0.5, (np.arange(h) + 0.5) * factor - 0.5)
    rays = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], -1)
    return rays.reshape(-1, 3).astype(np.float32)


def render_planes(planes: list[Plane], sky, camera: Camera, rays: np.ndarray, T_world_cam: np.ndarray,
                  light: dict) -> tuple[np.ndarray, np.ndarray]:
    """RGB ``(H, W, 3)`` float32 and depth ``(H, W)`` (metres along the optical axis; inf for
    sky) of ``planes`` seen from pose ``T_world_cam``, lit by PyBullet-style ``light`` kwargs.
    ``rays`` come from :func:`pixel_rays`; the result is upsampled to the camera's size."""
    h = int(round(np.sqrt(rays.shape[0] * camera.height / camera.width)))
    w = rays.shape[0] // h
    dirs = rays @ T_world_cam[:3, :3].T.astype(np.float32)
    origin = T_world_cam[:3, 3].astype(np.float32)
    depth = np.full(len(rays), np.inf, np.float32)
    rgb = np.empty((len(rays), 3), np.float32)
    rgb[:] = np.asarray(sky, np.float32)
    ldir = np.asarray(light["lightDirection"], np.float32)
    ldir /= np.linalg.norm(ldir)
    lcol = np.asarray(light.get("lightColor", [1, 1, 1]), np.float32)
    for plane in planes:
        n = plane.normal.astype(np.float32)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (plane.offset - origin @ n) / (dirs @ n)
        ok = (t > 0) & (t < depth)
        idx = np.nonzero(ok)[0]
        hit = origin + dirs[idx] * t[idx, None]
        below = hit[:, 2] <= plane.z_max
        idx, hit = idx[below], hit[below]
        if not len(idx):
            continue
        th, tw = plane.texture.shape[:2]
        s = np.mod(hit @ plane.axes[0].astype(np.float32) / plane.scale, 1.0) * (tw - 1)
        q = np.mod(hit @ plane.axes[1].astype(np.float32) / plane.scale, 1.0) * (th - 1)
        color = plane.texture[q.astype(np.int32), s.astype(np.int32)]
        shade = light["lightAmbientCoeff"] + light["lightDiffuseCoeff"] * max(0.0, float(n @ ldir))
        rgb[idx] = color * (shade * lcol)
        depth[idx] = t[idx]
    size = (camera.width, camera.height)
    rgb = cv2.resize(rgb.reshape(h, w, 3), size, interpolation=cv2.INTER_LINEAR)
    depth = cv2.resize(depth.reshape(h, w), size, interpolation=cv2.INTER_NEAREST)
    return rgb, depth


def depth_from_buffer(buffer: np.ndarray, near: float, far: float) -> np.ndarray:
    """Metric depth (metres along the optical axis) from an OpenGL depth buffer in [0, 1];
    inf where nothing was drawn."""
    with np.errstate(divide="ignore"):
        z = far * near / (far - (far - near) * buffer)
    return np.where(buffer < 1.0, z, np.inf).astype(np.float32)


def composite(fg_rgb: np.ndarray, fg_depth: np.ndarray, bg_rgb: np.ndarray, bg_depth: np.ndarray) -> np.ndarray:
    """Per pixel, the nearer of the TinyRenderer layer and the planes, as uint8 RGB."""
    out = np.where((fg_depth < bg_depth)[..., None], fg_rgb, np.clip(bg_rgb, 0, 255).astype(np.uint8))
    return out.astype(np.uint8)

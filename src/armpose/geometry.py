"""Rigid transforms, quaternions and the pinhole camera.

Conventions (used everywhere in armpose):
- quaternions are ``(qx, qy, qz, qw)``, unit norm;
- ``T_a_b`` is a 4x4 homogeneous matrix mapping points in frame b to frame a;
- the camera optical frame is OpenCV's: x right, y down, z forward; metres.
"""
from __future__ import annotations

import dataclasses

import numpy as np


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` from unit quaternions ``(..., 4)`` in xyzw order."""
    q = np.asarray(q, dtype=np.float64)
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` (xyzw, qw >= 0) from rotation matrices ``(..., 3, 3)``."""
    R = np.asarray(R, dtype=np.float64)
    flat = R.reshape(-1, 3, 3)
    out = np.empty((flat.shape[0], 4))
    for i, m in enumerate(flat):
        tr = np.trace(m)
        if tr > 0:
            s = 2.0 * np.sqrt(tr + 1.0)
            out[i] = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
        else:
            k = int(np.argmax(np.diag(m)))
            a, b = (k + 1) % 3, (k + 2) % 3
            s = 2.0 * np.sqrt(1.0 + m[k, k] - m[a, a] - m[b, b])
            v = np.empty(4)
            v[k] = s / 4
            v[a] = (m[a, k] + m[k, a]) / s
            v[b] = (m[b, k] + m[k, b]) / s
            v[3] = (m[b, a] - m[a, b]) / s
            out[i] = v
    out *= np.where(out[:, 3:4] < 0, -1.0, 1.0)
    return out.reshape(R.shape[:-2] + (4,))


def pose_to_matrix(xyz: np.ndarray, quat: np.ndarray) -> np.ndarray:
    """4x4 transforms ``(..., 4, 4)`` from translations ``(..., 3)`` and xyzw quaternions."""
    xyz = np.asarray(xyz, dtype=np.float64)
    T = np.zeros(xyz.shape[:-1] + (4, 4))
    T[..., :3, :3] = quat_to_matrix(quat)
    T[..., :3, 3] = xyz
    T[..., 3, 3] = 1.0
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms ``(..., 4, 4)``."""
    T = np.asarray(T, dtype=np.float64)
    R = T[..., :3, :3]
    Rt = np.swapaxes(R, -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def transform_points(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Apply ``T (..., 4, 4)`` to points ``(..., K, 3)``."""
    return np.einsum("...ij,...kj->...ki", T[..., :3, :3], p) + T[..., None, :3, 3]


def look_at(eye: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0), roll: float = 0.0) -> np.ndarray:
    """``T_world_cam`` of an OpenCV-convention camera at ``eye`` looking at ``target``.

    ``roll`` (radians) turns the camera about its optical axis.
    """
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=1)
    c, s = np.cos(roll), np.sin(roll)
    R = R @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = eye
    return T


@dataclasses.dataclass(frozen=True)
class Camera:
    """A rectified pinhole camera: image size in pixels, focal lengths and principal point in pixels."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_dict(cls, d: dict) -> "Camera":
        return cls(int(d["width"]), int(d["height"]), float(d["fx"]), float(d["fy"]),
                   float(d["cx"]), float(d["cy"]))

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    def project(self, p_cam: np.ndarray) -> np.ndarray:
        """Pixel coordinates ``(..., 2)`` of camera-frame points ``(..., 3)``; OpenCV convention,
        the centre of pixel (i, j) is at (u, v) = (i, j)."""
        p = np.asarray(p_cam, dtype=np.float64)
        z = np.clip(p[..., 2], 1e-6, None)
        return np.stack([self.fx * p[..., 0] / z + self.cx, self.fy * p[..., 1] / z + self.cy], -1)

    def scale_crop(self, width: int, height: int) -> tuple["Camera", tuple[int, int], tuple[int, int]]:
        """The camera after resizing to cover ``width x height`` and centre-cropping to it.

        Returns the new camera, the resized size ``(W', H')`` for ``cv2.resize`` and the integer crop
        offset ``(x0, y0)``. Pixel centres map as ``u' + 0.5 = (u + 0.5) * W'/W``, then ``u'' = u' - x0``.
        """
        scale = max(width / self.width, height / self.height)
        rw, rh = max(width, round(self.width * scale)), max(height, round(self.height * scale))
        sx, sy = rw / self.width, rh / self.height
        x0, y0 = (rw - width) // 2, (rh - height) // 2
        cam = Camera(width, height, self.fx * sx, self.fy * sy,
                     (self.cx + 0.5) * sx - 0.5 - x0, (self.cy + 0.5) * sy - 0.5 - y0)
        return cam, (rw, rh), (x0, y0)


CAMERA_KEYS = ("width", "height", "fx", "fy", "cx", "cy")


def camera_problem(raw: dict) -> tuple[object, str] | None:
    """``(value, problem)`` for the first bad entry of a camera dict (pixels), or None if it is a
    valid pinhole camera: ``width`` and ``height`` whole numbers > 0, ``fx`` and ``fy`` finite and
    > 0, ``cx`` and ``cy`` finite and >= 0. ``recording.json`` is checked with it too."""
    for k in CAMERA_KEYS:
        if k not in raw:
            return sorted(raw), f"camera needs {', '.join(CAMERA_KEYS)}; missing {k!r}"
        v = raw[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0 \
                or (k in ("width", "height", "fx", "fy") and v <= 0):
            return v, f"{k} must be a positive number"
        if k in ("width", "height") and not float(v).is_integer():
            return v, f"{k} must be a whole number of pixels"
    return None

"""Camera intrinsics from JSON: the one reader behind every ``--intrinsics`` option.

``armpose predict``, ``armpose calibrate``, ``armpose import`` and ``armpose calibrate-rig`` all
read the same file: ``{"width", "height", "fx", "fy", "cx", "cy"}`` in pixels (a rectified
pinhole camera), optionally ``"distortion"``: OpenCV coefficients ``[k1, k2, p1, p2, k3, ...]``
(4, 5, 8, 12 or 14 of them). A ``recording.json`` works too: its ``"camera"`` object is read.
Every problem raises :class:`IntrinsicsError` naming the file, the line (for bad JSON) and the value.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from armpose.geometry import CAMERA_KEYS, Camera, camera_problem
from armpose.io import InputFileError, read_json_input

DISTORTION_LENGTHS = (4, 5, 8, 12, 14)


class IntrinsicsError(InputFileError):
    """A bad intrinsics file: ``file``, ``row`` (None for the whole file) and ``value`` say where and what."""


def _distortion(path: Path, dist) -> np.ndarray | None:
    if dist is None:
        return None
    if not isinstance(dist, list) or len(dist) not in DISTORTION_LENGTHS or \
            not all(isinstance(d, (int, float)) and not isinstance(d, bool) and np.isfinite(d) for d in dist):
        raise IntrinsicsError(path, None, dist, f"distortion must be a list of {DISTORTION_LENGTHS} numbers")
    return np.asarray(dist, dtype=np.float64)


def read_intrinsics(path: Path | str) -> tuple[Camera, np.ndarray | None]:
    """The pinhole camera (pixels) and the distortion coefficients (None when absent) of ``path``."""
    path = Path(path)
    raw = read_json_input(path, IntrinsicsError)
    if isinstance(raw, dict) and isinstance(raw.get("camera"), dict):
        raw = raw["camera"]
    if not isinstance(raw, dict) or any(k not in raw for k in CAMERA_KEYS):
        raise IntrinsicsError(path, None, sorted(raw) if isinstance(raw, dict) else raw,
                              f"intrinsics need {', '.join(CAMERA_KEYS)}")
    problem = camera_problem(raw)
    if problem:
        raise IntrinsicsError(path, None, *problem)
    return Camera.from_dict(raw), _distortion(path, raw.get("distortion"))


def load_intrinsics(path: Path | str) -> Camera:
    """The camera of :func:`read_intrinsics` for rectified images: an :class:`IntrinsicsError` if
    the file gives non-zero distortion (undistort the images first, or drop the coefficients)."""
    camera, dist = read_intrinsics(path)
    if dist is not None and np.any(dist != 0):
        raise IntrinsicsError(path, None, dist.tolist(), "images must be rectified: distortion must be absent or zero")
    return camera

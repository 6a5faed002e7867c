"""Camera intrinsics from JSON: the one reader behind every ``--intrinsics`` option.

``armpose predict``, ``armpose calibrate``, ``armpose import`` and ``armpose calibrate-rig`` all
read the same file: ``{"width", "height", "fx", "fy", "cx", "cy"}`` in pixels (a rectified
pinhole camera), optionally ``"distortion"``: OpenCV coefficients ``[k1, k2, p1, p2, k3, ...]``
(4, 5, 8, 12 or 14 of them). A ``recording.json`` works too: its ``"camera"`` object is read.
Every problem raises :class:`IntrinsicsError` naming the file, the line (for bad JSON) and the value.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from armpose.geometry import Camera

KEYS = ("width", "height", "fx", "fy", "cx", "cy")
DISTORTION_LENGTHS = (4, 5, 8, 12, 14)


class IntrinsicsError(ValueError):
    """A bad intrinsics file: ``file``, ``row`` (None for the whole file) and ``value`` say where and what."""

    def __init__(self, file: Path | str, row: int | None, value, problem: str):
        self.file, self.row, self.value, self.problem = str(file), row, value, problem
        where = f"{file}:{row}" if row is not None else f"{file}"
        super().__init__(f"{where}: {problem} (value: {value!r})")


def _read_json(path: Path):
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise IntrinsicsError(path, None, None, "missing file") from None
    except json.JSONDecodeError as err:
        raise IntrinsicsError(path, err.lineno, err.msg, "not valid JSON") from err
    except (OSError, UnicodeDecodeError) as err:
        raise IntrinsicsError(path, None, str(err), "not readable") from err


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
    raw = _read_json(path)
    if isinstance(raw, dict) and isinstance(raw.get("camera"), dict):
        raw = raw["camera"]
    if not isinstance(raw, dict) or any(k not in raw for k in KEYS):
        raise IntrinsicsError(path, None, sorted(raw) if isinstance(raw, dict) else raw,
                              f"intrinsics need {', '.join(KEYS)}")
    for k in KEYS:
        v = raw[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0 \
                or (k in ("width", "height", "fx", "fy") and v <= 0):
            raise IntrinsicsError(path, None, v, f"{k} must be a positive number")
    return Camera.from_dict(raw), _distortion(path, raw.get("distortion"))


def load_intrinsics(path: Path | str) -> Camera:
    """The camera of :func:`read_intrinsics` for rectified images: an :class:`IntrinsicsError` if
    the file gives non-zero distortion (undistort the images first, or drop the coefficients)."""
    camera, dist = read_intrinsics(path)
    if dist is not None and np.any(dist != 0):
        raise IntrinsicsError(path, None, dist.tolist(), "images must be rectified: distortion must be absent or zero")
    return camera

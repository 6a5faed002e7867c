"""Shared pieces of the importers: error locations, timestamped streams, matching, transforms.

Units and frames: timestamps are integer nanoseconds; positions in metres; quaternions
``(qx, qy, qz, qw)``; ``T_a_b`` maps points in frame b to frame a; the camera frame is the
OpenCV optical frame (x right, y down, z forward).
"""
from __future__ import annotations

import dataclasses
import math
import xml.etree.ElementTree as ET
from decimal import Decimal, InvalidOperation
from functools import cache
from pathlib import Path

import numpy as np

from armpose.geometry import invert, matrix_to_quat, pose_to_matrix
from armpose.io import read_json_input
from armpose.recording import QUAT_TOLERANCE, RecordingError
from armpose.robots.registry import RobotSpec

TIME_UNITS = {"s": 9, "ms": 6, "us": 3, "ns": 0}  # power of ten to nanoseconds


@dataclasses.dataclass(frozen=True)
class Where:
    """Where a sample came from: a CSV line (header = 1), or a bag topic and message index."""

    file: str
    row: int | None = None
    topic: str | None = None
    index: int | None = None
    stamp_ns: int | None = None

    def __str__(self) -> str:
        if self.topic is None:
            return f"{self.file}:{self.row}" if self.row is not None else self.file
        parts = [f"topic {self.topic}"]
        if self.index is not None:
            parts.append(f"message {self.index}")
        if self.stamp_ns is not None:
            parts.append(f"stamp {format_stamp(self.stamp_ns)} s")
        return f"{self.file} [{', '.join(parts)}]"

    def error(self, value, problem: str) -> SourceError:
        return SourceError(self, value, problem)


class SourceError(RecordingError):
    """Bad input to an importer. ``where`` names the file and the CSV row or bag topic and message."""

    def __init__(self, where: Where, value, problem: str):
        super().__init__(where.file, where.row, value, problem)
        self.where = where
        self.args = (f"{where}: {problem} (value: {value!r})",)


class NothingKeptError(ValueError):
    """No frame survived matching and checks; ``summary`` says why."""

    def __init__(self, summary: dict):
        self.summary = summary
        super().__init__(f"no frame kept out of {summary['images']} images; dropped: {summary['dropped']}")


def format_stamp(stamp_ns: int) -> str:
    """Seconds with nanosecond digits, e.g. ``1700000000.100000000``."""
    sign = "-" if stamp_ns < 0 else ""
    sec, nsec = divmod(abs(int(stamp_ns)), 10**9)
    return f"{sign}{sec}.{nsec:09d}"


def parse_stamp(text: str, unit: str, where: Where) -> int:
    """Integer nanoseconds from a decimal string in ``unit`` (s, ms, us, ns), without float rounding."""
    try:
        value = Decimal(text.strip())
    except InvalidOperation:
        raise where.error(text, f"timestamp is not a number (unit {unit})") from None
    if not value.is_finite():
        raise where.error(text, "timestamp is not finite")
    return int(value.scaleb(TIME_UNITS[unit]).to_integral_value())


class StreamBuilder:
    """Collects timestamped samples of one kind, aborting when a timestamp goes backwards."""

    def __init__(self, name: str, width: int):
        self.name, self.width = name, width
        self.stamps: list[int] = []
        self.values: list[np.ndarray] = []
        self.wheres: list[Where] = []

    def check_order(self, stamp_ns: int, where: Where) -> None:
        """Raise :class:`SourceError` if ``stamp_ns`` is earlier than the previous sample's."""
        if self.stamps and stamp_ns < self.stamps[-1]:
            raise where.error(format_stamp(stamp_ns), f"{self.name} timestamp goes backwards "
                              f"(previous {format_stamp(self.stamps[-1])} s at {self.wheres[-1]})")

    def add(self, stamp_ns: int, values, where: Where) -> None:
        self.check_order(stamp_ns, where)
        self.stamps.append(int(stamp_ns))
        self.values.append(np.asarray(values, dtype=np.float64).reshape(self.width))
        self.wheres.append(where)

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Timestamps ``(N,)`` int64 ns and values ``(N, width)``."""
        return np.array(self.stamps, dtype=np.int64), np.array(self.values).reshape(-1, self.width)


def match_nearest(queries: np.ndarray, stamps: np.ndarray, tolerance_ns: int) -> np.ndarray:
    """Index into sorted ``stamps`` of the sample nearest to each query, -1 where none lies
    within ``tolerance_ns`` (ties go to the earlier sample)."""
    queries = np.asarray(queries, dtype=np.int64)
    out = np.full(len(queries), -1, dtype=np.int64)
    if len(stamps) == 0:
        return out
    right = np.clip(np.searchsorted(stamps, queries, side="left"), 0, len(stamps) - 1)
    left = np.clip(right - 1, 0, len(stamps) - 1)
    d_left, d_right = np.abs(queries - stamps[left]), np.abs(stamps[right] - queries)
    best = np.where(d_left <= d_right, left, right)
    dist = np.minimum(d_left, d_right)
    out[dist <= tolerance_ns] = best[dist <= tolerance_ns]
    return out


def pose_problem(pose: np.ndarray) -> str | None:
    """Why a pose ``(x, y, z, qx, qy, qz, qw)`` is unusable, or None."""
    if not np.all(np.isfinite(pose)):
        return "pose has a non-finite value"
    norm = float(np.linalg.norm(pose[3:]))
    if abs(norm - 1.0) > QUAT_TOLERANCE:
        return f"quaternion is not unit (norm {norm:.6f})"
    return None


def parse_pose_text(text: str, what: str) -> np.ndarray:
    """``(7,)`` pose from ``"x,y,z,qx,qy,qz,qw"`` (metres; quaternion unit within 1e-3, returned
    normalised); ValueError names ``what``."""
    try:
        pose = np.array([float(v) for v in text.split(",")])
    except ValueError:
        raise ValueError(f"{what}: expected x,y,z,qx,qy,qz,qw as numbers, got {text!r}") from None
    if pose.shape != (7,):
        raise ValueError(f"{what}: expected 7 comma-separated numbers x,y,z,qx,qy,qz,qw, got {text!r}")
    problem = pose_problem(pose)
    if problem:
        raise ValueError(f"{what}: {problem}: {text!r}")
    pose[3:] /= np.linalg.norm(pose[3:])
    return pose


def load_transform(spec: str | Path, what: str, key: str | None = None) -> np.ndarray:
    """A 4x4 rigid transform from inline ``x,y,z,qx,qy,qz,qw`` or a JSON file (metres, xyzw).

    The JSON is, or holds under ``key`` (e.g. ``T_rig_cam``, as ``armpose calibrate-rig`` writes it)
    or under its only key: a 4x4 row-major list; ``{"matrix": 4x4}``; ``{"translation": [x, y, z],
    "quaternion_xyzw": [...]}``; or ``{"x", "y", "z", "qx", "qy", "qz", "qw"}``.
    """
    text = str(spec)
    if not text.endswith(".json"):
        pose = parse_pose_text(text, what)
        return pose_to_matrix(pose[:3], pose[3:])
    path = Path(text)
    raw = read_json_input(path)
    if isinstance(raw, dict) and key in raw:
        raw = raw[key]
    elif isinstance(raw, dict) and len(raw) == 1 and isinstance(next(iter(raw.values())), (dict, list)):
        raw = next(iter(raw.values()))
    return _transform_from_json(raw, f"{path}: {what}")


def _transform_from_json(raw, what: str) -> np.ndarray:
    if isinstance(raw, dict) and "matrix" in raw:
        raw = raw["matrix"]
    if isinstance(raw, list):
        T = np.asarray(raw, dtype=np.float64)
        if T.shape != (4, 4) or not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-4) \
                or not np.allclose(T[3], [0, 0, 0, 1]) or abs(np.linalg.det(T[:3, :3]) - 1) > 1e-4:
            raise ValueError(f"{what}: not a 4x4 rigid transform: {raw!r}")
        return T
    keys = ["x", "y", "z", "qx", "qy", "qz", "qw"]
    if isinstance(raw, dict) and "translation" in raw and "quaternion_xyzw" in raw:
        raw = dict(zip(keys, [*raw["translation"], *raw["quaternion_xyzw"]]))
    if not isinstance(raw, dict) or any(k not in raw for k in keys):
        raise ValueError(f"{what} needs a 4x4 matrix, translation + quaternion_xyzw, or keys {keys}; got {raw!r}")
    pose = parse_pose_text(",".join(str(raw[k]) for k in keys), what)
    return pose_to_matrix(pose[:3], pose[3:])


def compose_poses(poses: np.ndarray, T_left: np.ndarray | None, T_right: np.ndarray | None) -> np.ndarray:
    """``T_left @ T(pose) @ T_right`` for poses ``(N, 7)``; returns ``(N, 7)`` with qw >= 0."""
    T = pose_to_matrix(poses[:, :3], poses[:, 3:] / np.linalg.norm(poses[:, 3:], axis=1, keepdims=True))
    if T_left is not None:
        T = T_left @ T
    if T_right is not None:
        T = T @ T_right
    return np.concatenate([T[:, :3, 3], matrix_to_quat(T[:, :3, :3])], axis=1)


def base_from_world(T_world_base: np.ndarray | None) -> np.ndarray | None:
    """``T_base_world`` for composing mocap poses, or None."""
    return None if T_world_base is None else invert(T_world_base)


def pose_steps(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translation (metres) and rotation (degrees) between consecutive poses ``(N, 7)``: ``(N-1,)`` each."""
    if len(poses) < 2:
        return np.zeros(0), np.zeros(0)
    dist = np.linalg.norm(np.diff(poses[:, :3], axis=0), axis=1)
    q = poses[:, 3:] / np.linalg.norm(poses[:, 3:], axis=1, keepdims=True)
    dot = np.clip(np.abs(np.sum(q[1:] * q[:-1], axis=1)), 0.0, 1.0)
    return dist, np.degrees(2.0 * np.arccos(dot))


@cache
def _urdf_joint_names(urdf: str) -> frozenset[str]:
    return frozenset(j.get("name") for j in ET.parse(urdf).getroot().findall("joint"))


def urdf_joint_names(spec: RobotSpec) -> frozenset[str]:
    """Every joint named in the robot's URDF (movable and fixed)."""
    return _urdf_joint_names(str(spec.urdf_path()))


def check_joint_names(names: list[str], spec: RobotSpec, where: Where, ignore=()) -> list[str]:
    """Validate joint names against the robot; returns the names that are not estimated joints.

    Raises :class:`SourceError` for a name neither the URDF nor ``ignore`` has, a duplicate, or a
    missing estimated joint.
    """
    known = urdf_joint_names(spec) | set(spec.joints) | set(ignore)
    unknown = [n for n in names if n not in known]
    if unknown:
        raise where.error(unknown[0], f"joint name not in robot {spec.name!r}'s URDF "
                          f"(expected {', '.join(spec.joints)})")
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise where.error(dupes[0], "joint name appears twice")
    missing = [j for j in spec.joints if j not in names]
    if missing:
        raise where.error(missing, f"missing joints of robot {spec.name!r}")
    return [n for n in names if n not in spec.joints]


def finite_or_raise(values: np.ndarray, names, where: Where) -> None:
    """Raise :class:`SourceError` naming the first non-finite value."""
    for name, v in zip(names, values):
        if not math.isfinite(v):
            raise where.error(float(v), f"joint {name} is not a finite number (radians)")

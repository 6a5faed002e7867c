"""The recording format, shared by synthetic renders and real recordings.

A recording is a directory::

    recording.json      robot type, camera (width, height, fx, fy, cx, cy), source, notes
    frames/000000.png   RGB frames, rectified, of the camera in recording.json
    joints.csv          frame, then one column per estimated joint (radians)
    camera_poses.csv    frame, x, y, z, qx, qy, qz, qw: the camera optical frame in the robot
                        base frame (metres; OpenCV optical axes, x right, y down, z forward)

Readers validate strictly: every problem raises :class:`RecordingError` naming the file,
the row (line number, header = 1) and the offending value.
"""
from __future__ import annotations

import csv
import dataclasses
import math
from pathlib import Path

import cv2
import numpy as np

from armpose.geometry import Camera, camera_problem
from armpose.io import InputFileError, atomic_write_json, atomic_write_text, read_json_input
from armpose.robots.registry import RobotSpec, UnknownRobotError, get_robot

SOURCES = ("synthetic", "recorded")
POSE_COLUMNS = ["x", "y", "z", "qx", "qy", "qz", "qw"]
QUAT_TOLERANCE = 1e-3


class RecordingError(InputFileError):
    """A bad recording: ``file``, ``row`` (None for the whole file) and ``value`` say where and what."""


@dataclasses.dataclass(frozen=True)
class RecordingMeta:
    """Contents of ``recording.json``."""

    robot: str
    camera: Camera
    source: str
    notes: str = ""

    def to_dict(self) -> dict:
        return {"robot": self.robot, "camera": self.camera.to_dict(), "source": self.source, "notes": self.notes}


def frame_path(rec_dir: Path, frame: int) -> Path:
    return Path(rec_dir) / "frames" / f"{frame:06d}.png"


def read_meta(rec_dir: Path) -> tuple[RecordingMeta, RobotSpec]:
    """Read and validate ``recording.json``; returns it with the robot's description."""
    path = Path(rec_dir) / "recording.json"
    raw = read_json_input(path, RecordingError)
    if not isinstance(raw, dict):
        raise RecordingError(path, None, raw, "expected a JSON object")
    for key in ("robot", "camera", "source"):
        if key not in raw:
            raise RecordingError(path, None, sorted(raw), f"missing key {key!r}")
    if not isinstance(raw["robot"], str):
        raise RecordingError(path, None, raw["robot"], "robot must be a robot type name (a string)")
    try:
        spec = get_robot(raw["robot"])
    except UnknownRobotError as err:
        raise RecordingError(path, None, raw["robot"], f"unknown robot type; {err.args[0]}") from err
    if raw["source"] not in SOURCES:
        raise RecordingError(path, None, raw["source"], f"source must be one of {SOURCES}")
    problem = (raw["camera"], "camera must be an object") if not isinstance(raw["camera"], dict) \
        else camera_problem(raw["camera"])
    if problem:
        raise RecordingError(path, None, *problem)
    camera = Camera.from_dict(raw["camera"])
    return RecordingMeta(raw["robot"], camera, raw["source"], raw.get("notes", "")), spec


def _read_table(path: Path, columns: list[str], check=None) -> tuple[np.ndarray, np.ndarray, list[RecordingError]]:
    """Frames ``(N,)``, values ``(N, C)`` and per-row errors of a ``frame,<columns>`` CSV.

    A header that differs from ``columns`` is a file-level error and raises. Rows with a
    missing, non-numeric or non-finite value, or for which ``check(values)`` returns a
    ``(value, problem)`` pair, are returned as errors (values NaN in the table); so are rows whose
    frame index is not an integer or repeats an earlier row's (those rows are left out). Blank
    lines are ignored; errors name the line in the file.
    """
    if not path.exists():
        raise RecordingError(path, None, None, "missing file")
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except UnicodeDecodeError as err:
        raise RecordingError(path, None, f"byte {err.start}", "not a UTF-8 text CSV file") from None
    except csv.Error as err:
        raise RecordingError(path, None, None, f"not a readable CSV file ({err})") from None
    except OSError as err:
        raise RecordingError(path, None, None, f"cannot read ({err.strerror or err})") from None
    if not rows:
        raise RecordingError(path, 1, None, "empty file, expected a header")
    header = [h.strip() for h in rows[0]]
    if header[:1] != ["frame"] or header[1:] != columns:
        missing = [c for c in columns if c not in header]
        extra = [c for c in header[1:] if c not in columns]
        raise RecordingError(path, 1, header, f"header must be frame,{','.join(columns)}"
                             + (f"; missing {missing}" if missing else "") + (f"; unexpected {extra}" if extra else ""))
    frames, values, errors = [], [], []
    first_line: dict[int, int] = {}
    for line, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        try:
            frame = int(row[0])
        except ValueError:
            errors.append(RecordingError(path, line, row[0], "frame index is not an integer"))
            continue
        vals = np.full(len(columns), np.nan)
        if frame in first_line:
            errors.append(RecordingError(path, line, frame, f"frame listed twice (first on line {first_line[frame]})"))
            continue
        first_line[frame] = line
        if len(row) != len(columns) + 1:
            errors.append(RecordingError(path, line, row, f"expected {len(columns) + 1} columns, got {len(row)}"))
        else:
            for i, (name, cell) in enumerate(zip(columns, row[1:])):
                try:
                    vals[i] = float(cell)
                except ValueError:
                    vals[i] = np.nan
                if not math.isfinite(vals[i]):
                    errors.append(RecordingError(path, line, cell, f"{name} is missing or not a finite number"))
                    vals[:] = np.nan
                    break
            else:
                problem = check(vals) if check else None
                if problem:
                    errors.append(RecordingError(path, line, *problem))
                    vals[:] = np.nan
        frames.append(frame)
        values.append(vals)
    return np.array(frames, dtype=np.int64), np.array(values).reshape(-1, len(columns)), errors


def read_joints(rec_dir: Path, spec: RobotSpec):
    """Joint angles from ``joints.csv``: frames ``(N,)``, radians ``(N, J)``, row errors."""
    return _read_table(Path(rec_dir) / "joints.csv", list(spec.joints))


def read_poses(rec_dir: Path):
    """Camera poses from ``camera_poses.csv``: frames ``(N,)``, ``(N, 7)`` x..qw, row errors.

    Quaternions must be unit length within 1e-3; rows that are not are returned as errors
    (values NaN in the table).
    """
    def unit_quaternion(vals: np.ndarray):
        norm = float(np.linalg.norm(vals[3:]))
        if abs(norm - 1.0) > QUAT_TOLERANCE:
            return [float(v) for v in vals[3:]], f"quaternion is not unit (norm {norm:.6f})"
        return None

    return _read_table(Path(rec_dir) / "camera_poses.csv", POSE_COLUMNS, unit_quaternion)


def read_frame(rec_dir: Path, frame: int, camera: Camera) -> np.ndarray:
    """Frame ``frame`` as RGB uint8 ``(H, W, 3)``; raises :class:`RecordingError` if missing,
    unreadable or not the camera's size."""
    path = frame_path(rec_dir, frame)
    if not path.exists():
        raise RecordingError(path, None, frame, "frame image is missing")
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise RecordingError(path, None, path.stat().st_size, "frame image is corrupt or not an image (bytes)")
    h, w = img.shape[:2]
    if (w, h) != (camera.width, camera.height):
        raise RecordingError(path, None, f"{w}x{h}", f"image size differs from the camera's {camera.width}x{camera.height}")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def write_frame(rec_dir: Path, frame: int, rgb: np.ndarray) -> None:
    """Write an RGB uint8 frame as PNG (fast settings: zlib level 1, run-length strategy, SUB filter)."""
    path = frame_path(rec_dir, frame)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR),
                [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE,
                 cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB])


def _csv_text(header: list[str], frames: np.ndarray, values: np.ndarray) -> str:
    lines = [",".join(header)]
    lines += [",".join([str(int(f))] + [repr(float(v)) for v in row]) for f, row in zip(frames, values)]
    return "\n".join(lines) + "\n"


def write_tables(rec_dir: Path, meta: RecordingMeta, spec: RobotSpec, frames: np.ndarray,
                 joints: np.ndarray, poses: np.ndarray, extra: dict | None = None) -> None:
    """Write ``joints.csv``, ``camera_poses.csv`` and, last, ``recording.json`` (plus ``extra`` keys)."""
    rec_dir = Path(rec_dir)
    atomic_write_text(rec_dir / "joints.csv", _csv_text(["frame", *spec.joints], frames, joints))
    atomic_write_text(rec_dir / "camera_poses.csv", _csv_text(["frame", *POSE_COLUMNS], frames, poses))
    atomic_write_json(rec_dir / "recording.json", {**meta.to_dict(), **(extra or {})})


def find_recordings(folder: Path) -> list[Path]:
    """Every recording (a folder holding ``recording.json``) below ``folder``, sorted."""
    folder = Path(folder)
    if not folder.exists():
        return []
    return sorted(p.parent for p in folder.rglob("recording.json") if not p.parent.name.startswith("."))


def static_camera(rec_dir: Path, tol_m: float = 0.005, tol_deg: float = 0.5) -> bool:
    """True if every valid camera pose of ``camera_poses.csv`` lies within ``tol_m`` metres and
    ``tol_deg`` degrees of the first one (a camera on a tripod), for at least two frames.

    The rule needs no metadata, so real recordings linked in are classified the same way as
    simulated tripod sessions (whose written pose is exactly static).
    """
    _, poses, _ = read_poses(rec_dir)
    poses = poses[np.isfinite(poses).all(axis=1)]
    if len(poses) < 2:
        return False
    shift = np.linalg.norm(poses[:, :3] - poses[0, :3], axis=1).max()
    dots = np.clip(np.abs(poses[:, 3:] @ poses[0, 3:]) / np.linalg.norm(poses[:, 3:], axis=1), 0.0, 1.0)
    turn = np.degrees(2 * np.arccos(dots)).max()
    return bool(shift <= tol_m and turn <= tol_deg)

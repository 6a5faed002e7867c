"""On-disk input of ``armpose calibrate-rig``: a views folder, the intrinsics and the board.

Layout::

    views/
      view_000.png ...    the images (any format OpenCV reads; RGB or grey), named in the CSVs
      rig_poses.csv       image,x,y,z,qx,qy,qz,qw   T_world_rig: the mocap rig body in the mocap world
      board_poses.csv     image,x,y,z,qx,qy,qz,qw   T_world_board: one row per image (the board streamed
                          with the rig), or one row with image "*" (the board measured once)
    cam.json              {"width", "height", "fx", "fy", "cx", "cy"} in pixels, optionally
                          "distortion": OpenCV coefficients [k1, k2, p1, p2, k3, ...]; or a
                          recording.json (its "camera" object); read by armpose.intrinsics
    board.json            {"squares_x", "squares_y", "square_length", "marker_length"} (metres), optionally
                          "dictionary" (default "DICT_4X4_50") and "legacy_pattern" (default false)

Positions in metres, quaternions xyzw and unit (within 1e-3). The board pose is that of the
ChArUco board frame (:mod:`armpose.calib.board`). Every problem raises :class:`CalibInputError`
naming the file, the row (line number, header = 1) and the value.
"""
from __future__ import annotations

import csv
import logging
from pathlib import Path

import cv2
import numpy as np

from armpose.calib.board import BoardSpec, detect_board
from armpose.calib.rig import RigView
from armpose.geometry import Camera, matrix_to_quat, pose_to_matrix
from armpose.io import InputFileError, atomic_write_json, atomic_write_text, read_json_input

log = logging.getLogger(__name__)

POSE_HEADER = ["image", "x", "y", "z", "qx", "qy", "qz", "qw"]
RIG_POSES, BOARD_POSES = "rig_poses.csv", "board_poses.csv"
ALL_IMAGES = "*"  # board_poses.csv: one pose for every image
QUAT_TOLERANCE = 1e-3


class CalibInputError(InputFileError):
    """Bad calibration input: ``file``, ``row`` (None for the whole file) and ``value`` say where and what."""


def _parse_pose(path: Path, line: int, row: list[str]) -> np.ndarray:
    """4x4 ``T`` from one CSV row ``image,x,y,z,qx,qy,qz,qw``."""
    if len(row) != len(POSE_HEADER):
        raise CalibInputError(path, line, row, f"expected {len(POSE_HEADER)} fields {','.join(POSE_HEADER)}")
    vals = []
    for name, text in zip(POSE_HEADER[1:], row[1:]):
        try:
            v = float(text)
        except ValueError:
            raise CalibInputError(path, line, text, f"{name} is not a number") from None
        if not np.isfinite(v):
            raise CalibInputError(path, line, text, f"{name} is not finite")
        vals.append(v)
    q = np.array(vals[3:])
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > QUAT_TOLERANCE:
        raise CalibInputError(path, line, vals[3:], f"quaternion is not unit (norm {norm:.6f})")
    return pose_to_matrix(np.array(vals[:3]), q / norm)


def read_pose_csv(path: Path) -> dict[str, np.ndarray]:
    """Poses by image name, in file order, from a CSV with header ``image,x,y,z,qx,qy,qz,qw``."""
    path = Path(path)
    if not path.is_file():
        raise CalibInputError(path, None, None, "missing file")
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows or [c.strip() for c in rows[0]] != POSE_HEADER:
        raise CalibInputError(path, 1, rows[0] if rows else None, f"header must be {','.join(POSE_HEADER)}")
    poses: dict[str, np.ndarray] = {}
    for line, row in enumerate(rows[1:], start=2):
        if not row or all(not c.strip() for c in row):
            continue
        name = row[0].strip()
        if not name:
            raise CalibInputError(path, line, row, "empty image name")
        if name in poses:
            raise CalibInputError(path, line, name, "image listed twice")
        poses[name] = _parse_pose(path, line, row)
    if not poses:
        raise CalibInputError(path, None, None, "no pose rows")
    return poses


def read_board(path: Path) -> BoardSpec:
    """The board description from ``board.json``."""
    path = Path(path)
    raw = read_json_input(path, CalibInputError)
    try:
        return BoardSpec.from_dict(raw)
    except ValueError as err:
        raise CalibInputError(path, None, raw, str(err)) from None


def _read_image(path: Path, csv_path: Path, line: int, camera: Camera) -> np.ndarray:
    if not path.is_file():
        raise CalibInputError(csv_path, line, path.name, f"image file {path} is missing")
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise CalibInputError(path, None, path.stat().st_size, "not a readable image (bytes)")
    h, w = img.shape[:2]
    if (w, h) != (camera.width, camera.height):
        raise CalibInputError(path, None, f"{w}x{h}", f"image size differs from the camera's "
                                                      f"{camera.width}x{camera.height}")
    return img[..., ::-1]


def load_views(folder: Path, camera: Camera, board: BoardSpec, distortion: np.ndarray | None = None) -> list[RigView]:
    """Read the views folder and detect the board in every image listed in ``rig_poses.csv``."""
    folder = Path(folder)
    if not folder.is_dir():
        raise CalibInputError(folder, None, None, "views folder does not exist")
    rig_csv, board_csv = folder / RIG_POSES, folder / BOARD_POSES
    rig, boards = read_pose_csv(rig_csv), read_pose_csv(board_csv)
    if ALL_IMAGES in boards and len(boards) > 1:
        raise CalibInputError(board_csv, None, sorted(boards), f"a {ALL_IMAGES!r} row must be the only row")
    for line, name in enumerate(boards, start=2):
        if name != ALL_IMAGES and name not in rig:
            raise CalibInputError(board_csv, line, name, f"image has no row in {RIG_POSES}")
    views = []
    for line, (name, T_world_rig) in enumerate(rig.items(), start=2):
        if ALL_IMAGES not in boards and name not in boards:
            raise CalibInputError(board_csv, None, name, f"no board pose for this image of {RIG_POSES}")
        image = _read_image(folder / name, rig_csv, line, camera)
        obs = detect_board(image, board, camera, distortion)
        if obs is None:
            log.warning("%s: board not detected", name)
        views.append(RigView(name, T_world_rig, boards.get(ALL_IMAGES, boards.get(name)), obs))
    return views


def _pose_rows(names: list[str], Ts: np.ndarray) -> str:
    lines = [",".join(POSE_HEADER)]
    for name, T in zip(names, Ts):
        vals = [*T[:3, 3], *matrix_to_quat(T[:3, :3])]
        lines.append(",".join([name, *(f"{v:.9f}" for v in vals)]))
    return "\n".join(lines) + "\n"


def write_session(session, root: Path, truth: bool = True) -> dict[str, Path]:
    """Write a :class:`armpose.calib.simulate.CalibrationSession` in this layout under ``root``:
    ``views/``, ``cam.json``, ``board.json`` and (``truth``) ``truth.json``; returns their paths."""
    root = Path(root)
    views = root / "views"
    views.mkdir(parents=True, exist_ok=True)
    for name, img in zip(session.names, session.images):
        cv2.imwrite(str(views / name), img[..., ::-1])
    atomic_write_text(views / RIG_POSES, _pose_rows(session.names, session.T_world_rig))
    atomic_write_text(views / BOARD_POSES, _pose_rows(session.names, session.T_world_board))
    paths = {"views": views, "intrinsics": root / "cam.json", "board": root / "board.json"}
    atomic_write_json(paths["intrinsics"], session.camera.to_dict())
    atomic_write_json(paths["board"], session.board.to_dict())
    if truth:
        paths["truth"] = root / "truth.json"
        atomic_write_json(paths["truth"], {"T_rig_cam": session.T_rig_cam.tolist(),
                                           "T_world_board": session.T_world_board_true.tolist(),
                                           "T_world_cam": session.T_world_cam.tolist()})
    return paths

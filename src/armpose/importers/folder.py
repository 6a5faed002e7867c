"""Import a folder of images plus CSV files.

Layout (timestamps are decimal numbers in ``time_unit``, default seconds, e.g. ``1700000000.1``)::

    raw_session/
      images/<timestamp>.png        one image per capture; the file stem is its timestamp
                                    (.png, .jpg or .jpeg; colour, any bit depth OpenCV reads as 8-bit)
      images.csv                    optional: timestamp,file (file relative to raw_session/);
                                    when present it lists the images instead of their names
      joint_states.csv              timestamp, then one column per joint name (radians); columns in
                                    any order; extra URDF joints (e.g. fingers) are ignored
      camera_poses.csv              timestamp,x,y,z,qx,qy,qz,qw: camera optical frame (OpenCV) in
                                    the robot base frame, metres; optional with a fixed ``camera_pose``
                                    (with ``T_rig_cam`` / ``T_world_base`` these are mocap rig poses)

Rows are matched to images by nearest timestamp (see :mod:`armpose.importers.assemble`).
"""
from __future__ import annotations

import csv
import logging
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from armpose.importers.assemble import ImageRef, ImportOptions, RawRecording, assemble, check_output
from armpose.importers.common import (TIME_UNITS, SourceError, StreamBuilder, Where, check_joint_names, finite_or_raise,
                                      parse_stamp, pose_problem)
from armpose.recording import POSE_COLUMNS
from armpose.robots.registry import RobotSpec, get_robot

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def _rows(path: Path) -> Iterator[tuple[Where, list[str]]]:
    """``(where, cells)`` of every non-blank CSV line, header first (line numbers from 1)."""
    if not path.exists():
        raise Where(str(path)).error(None, "missing file")
    with open(path, newline="") as fh:
        for line, row in enumerate(csv.reader(fh), start=1):
            if row and any(c.strip() for c in row):
                yield Where(str(path), line), [c.strip() for c in row]


def _table(path: Path) -> tuple[list[str], list[tuple[Where, list[str]]]]:
    rows = list(_rows(path))
    if not rows:
        raise Where(str(path), 1).error(None, "empty file, expected a header")
    header_where, header = rows[0]
    if header[0] != "timestamp":
        raise header_where.error(header, "the first column must be 'timestamp'")
    for where, cells in rows[1:]:
        if len(cells) != len(header):
            raise where.error(cells, f"expected {len(header)} columns, got {len(cells)}")
    return header, rows[1:]


def _numbers(cells: list[str], names: list[str], where: Where) -> np.ndarray:
    try:
        return np.array([float(c) for c in cells])
    except ValueError:
        bad = next(i for i, c in enumerate(cells) if not _is_float(c))
        raise where.error(cells[bad], f"{names[bad]} is not a number") from None


def _is_float(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def read_images(folder: Path, unit: str) -> list[ImageRef]:
    """Images from ``images.csv`` (file order, timestamps must not go backwards) or ``images/``."""
    listing = folder / "images.csv"
    order = StreamBuilder("image", 0)
    refs = []
    if listing.exists():
        header, rows = _table(listing)
        if header != ["timestamp", "file"]:
            raise Where(str(listing), 1).error(header, "header must be timestamp,file")
        for where, (stamp, name) in rows:
            t = parse_stamp(stamp, unit, where)
            order.add(t, (), where)
            refs.append(ImageRef(t, where, folder / name))
        return refs
    files = sorted(p for p in (folder / "images").glob("*") if p.suffix.lower() in IMAGE_SUFFIXES)
    for path in files:
        where = Where(str(path))
        try:
            refs.append(ImageRef(parse_stamp(path.stem, unit, where), where, path))
        except SourceError:
            raise where.error(path.name, f"image name is not a timestamp in {unit}; "
                              "name images <timestamp>.png or list them in images.csv") from None
    if not refs:
        raise Where(str(folder)).error(None, "no images: expected images/<timestamp>.png or images.csv")
    return sorted(refs, key=lambda r: r.stamp_ns)


def read_joint_table(path: Path, spec: RobotSpec, unit: str,
                     ignore: tuple[str, ...] = ()) -> tuple[StreamBuilder, list[str]]:
    """Joint samples in the robot's joint order (radians) and the ignored extra joint columns."""
    header, rows = _table(path)
    extra = check_joint_names(header[1:], spec, Where(str(path), 1), ignore)
    cols = [header.index(j) for j in spec.joints]
    stream = StreamBuilder("joint_states", spec.num_joints)
    for where, cells in rows:
        values = _numbers([cells[c] for c in cols], list(spec.joints), where)
        finite_or_raise(values, spec.joints, where)
        stream.add(parse_stamp(cells[0], unit, where), values, where)
    return stream, extra


def read_pose_table(path: Path, unit: str) -> tuple[StreamBuilder, int]:
    """Pose samples ``(x, y, z, qx, qy, qz, qw)`` and the number of unusable rows (dropped, logged)."""
    header, rows = _table(path)
    if header[1:] != POSE_COLUMNS:
        raise Where(str(path), 1).error(header, f"header must be timestamp,{','.join(POSE_COLUMNS)}")
    stream, invalid = StreamBuilder("camera pose", 7), 0
    for where, cells in rows:
        stamp = parse_stamp(cells[0], unit, where)
        values = _numbers(cells[1:], POSE_COLUMNS, where)
        problem = pose_problem(values)
        if problem:
            stream.check_order(stamp, where)
            log.warning("%s: %s; pose sample dropped", where, problem)
            invalid += 1
            continue
        stream.add(stamp, values, where)
    return stream, invalid


def _decode(refs: list[ImageRef]) -> Iterator[np.ndarray]:
    for ref in refs:
        path = Path(ref.key)
        if not path.exists():
            raise ref.where.error(str(path), "image file is missing")
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ref.where.error(str(path), "image file is corrupt or not an image")
        yield ref, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def read_folder(folder: Path, opts: ImportOptions, time_unit: str = "s") -> RawRecording:
    """Read and validate a folder source (layout in the module docstring)."""
    folder = Path(folder)
    if time_unit not in TIME_UNITS:
        raise ValueError(f"time unit must be one of {sorted(TIME_UNITS)}, got {time_unit!r}")
    spec = get_robot(opts.robot)
    images = read_images(folder, time_unit)
    joints, extra = read_joint_table(folder / "joint_states.csv", spec, time_unit, opts.ignore_joints)
    ignored = {"extra_joints": extra}
    pose_csv = folder / "camera_poses.csv"
    if opts.camera_pose is not None:
        if pose_csv.exists():
            raise ValueError(f"{pose_csv} exists and a fixed camera pose was given: use one of them")
        poses, pose_from = None, "fixed camera pose"
    else:
        poses, ignored["invalid_pose_samples"] = read_pose_table(pose_csv, time_unit)
        pose_from = str(pose_csv)
    return RawRecording(str(folder), "folder", images, joints, poses, _decode, None, "", pose_from, ignored)


def import_folder(folder: str | Path, out: str | Path, robot: str, *, time_unit: str = "s", **options) -> dict:
    """Import a folder of images and CSVs into the recording ``out``; returns the summary dict.

    ``options`` are :class:`~armpose.importers.assemble.ImportOptions` fields (``camera`` is required
    here: a folder has no CameraInfo). Raises :class:`~armpose.importers.common.SourceError` (a
    ``RecordingError``) for bad input, naming the file, row and value.
    """
    opts = ImportOptions(robot=robot, **options)
    check_output(Path(out), opts.overwrite)
    return assemble(read_folder(Path(folder), opts, time_unit), Path(out), opts)

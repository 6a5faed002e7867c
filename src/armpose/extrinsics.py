"""Eye-to-Hand extrinsics of a static camera from network predictions and joint encoder readings.

For each image the network predicts the base and joint positions in the camera optical frame
(OpenCV: x right, y down, z forward; metres). Forward kinematics of the encoder readings
(radians) gives the same points in the robot base frame (base = origin). The rigid transform
mapping the second set onto the first is ``T_cam_base`` (4x4, metres; ``T_a_b`` maps points in
frame b to frame a, see :mod:`armpose.geometry`); its inverse ``T_base_cam`` is the camera
pose in the base frame, the Eye-to-Hand transform.

- :func:`read_joint_csv`: the encoder table (``frame`` or ``image`` first column, then one
  column per joint, radians), validated strictly: errors name the file, the line and the value;
- :func:`match_rows`: the table's rows for a list of images (in order, or by image name);
- :func:`estimate_extrinsics`: one pose from many images (robust fit of all correspondences
  at once, or the average of per-image fits), optionally refined on the predicted points'
  rays and depths or on the 2D reprojection error, with a residual report per image and per point.
"""
from __future__ import annotations

import csv
import dataclasses
import logging
import math
from collections.abc import Sequence
from functools import cache
from pathlib import Path

import numpy as np

from armpose.camera_pose import (pool_poses, refine_rays, refine_reprojection, reprojection_errors_px, robust_rigid,
                                 rotation_error_deg, to_matrix, translation_error_m)
from armpose.geometry import Camera, invert, matrix_to_quat, quat_to_matrix, transform_points
from armpose.recording import RecordingError
from armpose.robots.kinematics import Kinematics
from armpose.robots.registry import get_robot

log = logging.getLogger(__name__)

KEY_COLUMNS = ("frame", "image")


@dataclasses.dataclass(frozen=True)
class JointTable:
    """A validated encoder CSV: ``key`` is ``"frame"`` or ``"image"``, ``keys`` that column per row,
    ``columns`` the joint names in file order, ``values`` ``(N, C)`` radians, ``lines`` the line
    number of each row in the file (header = 1)."""

    path: str
    key: str
    keys: list[str]
    columns: list[str]
    values: np.ndarray
    lines: list[int]

    def angles_for(self, joints: Sequence[str]) -> np.ndarray:
        """Values ``(N, J)`` in the order of ``joints``; a :class:`RecordingError` naming the header
        when the columns are not exactly those joints."""
        missing = [j for j in joints if j not in self.columns]
        extra = [c for c in self.columns if c not in joints]
        if missing or extra:
            raise RecordingError(self.path, 1, self.columns,
                                 f"joint columns must be {list(joints)} (any order)"
                                 + (f"; missing {missing}" if missing else "")
                                 + (f"; unexpected {extra}" if extra else ""))
        return self.values[:, [self.columns.index(j) for j in joints]]


def read_joint_csv(path: Path | str) -> JointTable:
    """Read an encoder table; every problem raises :class:`RecordingError` (file, line, value).

    Header: ``frame`` or ``image``, then joint names (radians). With ``frame`` (the recording
    format's ``joints.csv``) rows go with the images in order and frame indices must increase;
    with ``image`` each row names its image (a path as given on the command line, or its file
    name; ``clip.avi#12`` for frame 12 of a video). Blank lines are ignored.
    """
    path = Path(path)
    if not path.is_file():
        raise RecordingError(path, None, str(path), "no such file")
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows or not rows[0]:
        raise RecordingError(path, 1, None, "empty file, expected a header 'frame,<joint names>'")
    header = [h.strip() for h in rows[0]]
    if header[0] not in KEY_COLUMNS:
        raise RecordingError(path, 1, header[0], f"first column must be one of {KEY_COLUMNS}")
    columns = header[1:]
    dup = sorted({c for c in columns if columns.count(c) > 1})
    if not columns or dup or "" in columns:
        raise RecordingError(path, 1, header, "expected distinct, non-empty joint column names"
                             + (f"; repeated {dup}" if dup else ""))
    keys, values, lines = [], [], []
    for line, row in enumerate(rows[1:], start=2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(header):
            raise RecordingError(path, line, row, f"expected {len(header)} columns, got {len(row)}")
        keys.append(_key(path, line, header[0], row[0].strip(), keys))
        values.append([_angle(path, line, name, cell) for name, cell in zip(columns, row[1:])])
        lines.append(line)
    if not keys:
        raise RecordingError(path, None, None, "no data rows")
    return JointTable(str(path), header[0], keys, columns, np.array(values, dtype=np.float64), lines)


def _key(path: Path, line: int, kind: str, cell: str, previous: list[str]) -> str:
    """The row's frame index or image name, checked (frames increase, images are unique)."""
    if kind == "frame":
        try:
            frame = int(cell)
        except ValueError:
            raise RecordingError(path, line, cell, "frame index is not an integer") from None
        if previous and frame <= int(previous[-1]):
            raise RecordingError(path, line, cell, f"frame indices must increase (previous {previous[-1]})")
        return str(frame)
    if not cell:
        raise RecordingError(path, line, cell, "image name is empty")
    if cell in previous:
        raise RecordingError(path, line, cell, "image named twice")
    return cell


def _angle(path: Path, line: int, name: str, cell: str) -> float:
    """``cell`` as a finite float (radians) or a :class:`RecordingError` naming the column."""
    try:
        v = float(cell)
    except ValueError:
        v = math.nan
    if not math.isfinite(v):
        raise RecordingError(path, line, cell, f"{name} is missing or not a finite number (radians)")
    return v


def match_rows(table: JointTable, images: Sequence[str]) -> list[int]:
    """For each image name, the index of its row in ``table``.

    ``frame`` tables: row k goes with image k, and the counts must be equal. ``image`` tables:
    a row matches an image by its full name as given or by its file name; every image needs
    exactly one row and every row an image.
    """
    images = [str(i) for i in images]
    if table.key == "frame":
        if len(table.keys) != len(images):
            raise RecordingError(table.path, None, len(table.keys),
                                 f"{len(table.keys)} rows of joint angles but {len(images)} images; rows are "
                                 "matched to images in order (or give an 'image' column)")
        return list(range(len(images)))
    by_name = {k: i for i, k in enumerate(table.keys)}
    out, used = [], set()
    for name in images:
        i = by_name.get(name, by_name.get(Path(name).name))
        if i is None:
            raise RecordingError(table.path, None, name, "no row for this image (match by path as given or file name)")
        if i in used:
            raise RecordingError(table.path, table.lines[i], table.keys[i], "row matches more than one image")
        used.add(i)
        out.append(i)
    unused = [i for i in range(len(table.keys)) if i not in used]
    if unused:
        i = unused[0]
        raise RecordingError(table.path, table.lines[i], table.keys[i],
                             f"row names no input image ({len(unused)} such rows)")
    return out


@cache
def kinematics(robot: str) -> Kinematics:
    """The cached forward kinematics of robot type ``robot``."""
    return Kinematics(get_robot(robot))


def correspondences(prediction: dict, fk_joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(points_base, points_cam)``, each ``(1 + J, 3)``: base then joints.

    The prediction's joints are cut or padded with NaN to the J joints of ``fk_joints``
    (the network puts a robot with fewer joints in the first slots).
    """
    J = len(fk_joints)
    cam = np.full((1 + J, 3), np.nan)
    cam[0] = np.asarray(prediction["base_xyz"], dtype=np.float64)
    joints = np.asarray(prediction["joints_xyz"], dtype=np.float64).reshape(-1, 3)[:J]
    cam[1:1 + len(joints)] = joints
    return np.vstack([np.zeros(3), fk_joints]), cam


def pose_json(T: np.ndarray, prefix: str = "") -> dict:
    """JSON of a 4x4 pose: ``{prefix}quaternion_xyzw`` (qw >= 0) and ``{prefix}translation_m`` (metres)."""
    return {f"{prefix}quaternion_xyzw": matrix_to_quat(T[:3, :3]).tolist(), f"{prefix}translation_m": T[:3, 3].tolist()}


def average_pose(poses: Sequence[np.ndarray]) -> np.ndarray:
    """The mean of rigid poses ``(4, 4)``: mean translation, chordal-L2 mean rotation (principal
    eigenvector of the summed quaternion outer products)."""
    q = matrix_to_quat(np.asarray(poses)[:, :3, :3])
    _, v = np.linalg.eigh(q.T @ q)
    return to_matrix(quat_to_matrix(v[:, -1]), np.mean(np.asarray(poses)[:, :3, 3], axis=0))


def _fit(samples: list[tuple], pooled: bool, method: str, threshold_m: float) -> tuple[np.ndarray, list, list]:
    """The pose, per-image inlier masks and per-image single-image poses (None where unsolvable)."""
    alone = []
    for src, dst, _ in samples:
        try:
            alone.append(robust_rigid(src, dst, method=method, threshold_m=threshold_m))
        except ValueError as err:
            log.warning("single-image fit failed: %s", err)
            alone.append(None)
    if pooled:
        est = pool_poses(samples, method=method, threshold_m=threshold_m)
        splits = np.cumsum([len(s[0]) for s in samples])[:-1]
        return est.T, np.split(est.inliers, splits), alone
    good = [a for a in alone if a is not None]
    if not good:
        raise ValueError("no image has 3 usable points; cannot estimate the pose")
    inliers = [a.inliers if a is not None else np.zeros(len(s[0]), bool) for a, s in zip(alone, samples)]
    return average_pose([a.T for a in good]), inliers, alone


def _round(x, digits: int = 6):
    """A float rounded for JSON; None for NaN or infinity."""
    return round(float(x), digits) if np.isfinite(x) else None


def _image_report(name: str, T: np.ndarray, src, dst, inl, uv, camera, alone, names) -> dict:
    """Residuals (m, and px with a camera) of one image under pose ``T``."""
    r = np.linalg.norm(transform_points(T, src) - dst, axis=1)
    rep = {"image": name, "points": int(np.isfinite(r).sum()), "inliers": int(inl.sum()),
           "rmse_m": _round(np.sqrt(np.mean(r[inl] ** 2))) if inl.any() else None,
           "residuals_m": {n: _round(v) for n, v in zip(names, r)},
           "outliers": [n for n, v, i in zip(names, r, inl) if np.isfinite(v) and not i]}
    if camera is not None:
        ok = np.isfinite(uv).all(1) & np.isfinite(src).all(1)
        px = np.full(len(src), np.nan)
        px[ok] = reprojection_errors_px(T, src[ok], uv[ok], camera.K)
        rep["reprojection_px"] = {n: _round(v, 3) for n, v in zip(names, px)}
    rep["alone"] = None if alone is None else {
        "rotation_deg_from_result": _round(rotation_error_deg(alone.T, T), 4),
        "translation_m_from_result": _round(translation_error_m(alone.T, T)), "rmse_m": _round(alone.rmse_m)}
    return rep


def _uv(prediction: dict, points_cam: np.ndarray, camera: Camera | None) -> np.ndarray:
    """Pixels ``(1 + J, 2)`` of base and joints: the prediction's ``joints_uv``, the base projected."""
    uv = np.full((len(points_cam), 2), np.nan)
    if camera is None:
        return uv
    if np.isfinite(points_cam[0]).all() and points_cam[0, 2] > 0:
        uv[0] = camera.project(points_cam[0])
    given = np.asarray(prediction.get("joints_uv", []), dtype=np.float64).reshape(-1, 2)[:len(uv) - 1]
    uv[1:1 + len(given)] = given
    return uv


def estimate_extrinsics(predictions: Sequence[dict], joint_angles, robot: str, pooled: bool = True,
                        method: str = "huber", threshold_m: float = 0.05, refine_2d: bool = False,
                        camera: Camera | None = None, refine_rays_depth: bool = False) -> dict:
    """``T_cam_base`` of a static camera from ``predictions`` (dicts of :func:`armpose.predict.predict`)
    and the encoder readings ``joint_angles`` ``(N, J)`` (radians, ``robot``'s joint order) at
    the same instants.

    ``pooled=True`` fits all correspondences of all images at once with
    :func:`~armpose.camera_pose.pool_poses`; ``False`` averages the per-image fits.
    ``method`` and ``threshold_m`` are those of :func:`~armpose.camera_pose.robust_rigid`.
    ``refine_2d`` polishes the pose on the reprojection error of the inlier points (needs
    ``camera``, the images' intrinsics; pixels: ``joints_uv`` and the projected base).
    ``refine_rays_depth`` refines it instead on each inlier point's predicted ray and depth,
    weighted by the network's typical errors (:func:`~armpose.camera_pose.refine_rays`; no
    intrinsics needed). Either refinement fits all images' inlier points at once, also when
    ``pooled`` is False; the inliers, ``rmse_m`` and the per-point residuals stay those of the
    robust 3D fit, measured at the final pose. ``camera`` also adds reprojection errors (px) to
    the report. Images with fewer than 3 finite
    points are skipped and listed. Returns a JSON-ready dict (see the CLI ``armpose calibrate``).
    """
    spec = get_robot(robot)
    q = np.asarray(joint_angles, dtype=np.float64)
    if q.shape != (len(predictions), spec.num_joints):
        raise ValueError(f"joint_angles must have shape ({len(predictions)}, {spec.num_joints}) for "
                         f"{len(predictions)} predictions of {robot}, got {q.shape}")
    if refine_2d and camera is None:
        raise ValueError("refine_2d needs the camera intrinsics")
    if refine_2d and refine_rays_depth:
        raise ValueError("refine_2d and refine_rays_depth are two refinements of the same pose; choose one")
    names = ["base", *spec.joints]
    fk = kinematics(robot).joint_positions(q) if len(q) else np.zeros((0, spec.num_joints, 3))
    samples, used, skipped = [], [], []
    for i, pred in enumerate(predictions):
        src, dst = correspondences(pred, fk[i])
        name = str(pred.get("image", i))
        if pred.get("robot_type", robot) != robot:
            log.warning("%s: predicted type %s, calibrating as %s", name, pred.get("robot_type"), robot)
        if np.isfinite(dst).all(1).sum() < 3:
            skipped.append({"image": name, "reason": "fewer than 3 finite predicted points"})
            continue
        samples.append((src, dst, None))
        used.append((name, _uv(pred, dst, camera)))
    if not samples:
        raise ValueError(f"none of the {len(predictions)} images has 3 usable points; cannot estimate the pose")
    T, inliers, alone = _fit(samples, pooled, method, threshold_m)
    if refine_2d:
        src_all = np.concatenate([s[0] for s in samples])
        uv_all = np.concatenate([u for _, u in used])
        T = refine_reprojection(T, src_all, uv_all, camera.K, valid=np.concatenate(inliers))
    if refine_rays_depth:
        T = refine_rays(T, np.concatenate([s[0] for s in samples]), np.concatenate([s[1] for s in samples]),
                        valid=np.concatenate(inliers))
    per_image = [_image_report(n, T, s[0], s[1], inl, u, camera, a, names)
                 for (n, u), s, inl, a in zip(used, samples, inliers, alone)]
    return _result(T, per_image, skipped, names, robot, pooled, method, threshold_m, refine_2d, refine_rays_depth,
                   sum(p.get("robot_type", robot) != robot for p in predictions))


def _result(T, per_image, skipped, names, robot, pooled, method, threshold_m, refine_2d, refine_rays_depth,
            mismatched) -> dict:
    """The JSON-ready result: pose, inverse, summary and residual report."""
    res = np.array([[r["residuals_m"][n] if r["residuals_m"][n] is not None else np.nan for n in names]
                    for r in per_image])
    inl = np.array([[n not in r["outliers"] and r["residuals_m"][n] is not None for n in names] for r in per_image])
    per_point = {n: {"median_m": _round(np.nanmedian(res[:, j])) if np.isfinite(res[:, j]).any() else None,
                     "inlier_fraction": _round(inl[:, j].mean(), 4)} for j, n in enumerate(names)}
    out = {"robot": robot, "method": method, "threshold_m": threshold_m, "pooled": pooled, "refine_2d": refine_2d,
           "refine_rays": refine_rays_depth,
           "T_cam_base": T.tolist(), **pose_json(T), "T_base_cam": invert(T).tolist(),
           **pose_json(invert(T), "T_base_cam_")}
    out.update({"rmse_m": _round(np.sqrt(np.mean(res[inl] ** 2))) if inl.any() else None,
                "images_used": len(per_image), "images_skipped": skipped, "points_used": int(inl.sum()),
                "points_total": int(np.isfinite(res).sum()), "type_mismatch_images": int(mismatched)})
    if per_image and "reprojection_px" in per_image[0]:
        px = np.array([[r["reprojection_px"][n] if r["reprojection_px"][n] is not None else np.nan for n in names]
                       for r in per_image])
        out["reprojection_rmse_px"] = _round(np.sqrt(np.mean(px[inl & np.isfinite(px)] ** 2)), 3) \
            if (inl & np.isfinite(px)).any() else None
    out["per_point"] = per_point
    out["per_image"] = per_image
    log.info("T_cam_base from %d images: translation %s m, rmse %s m", len(per_image), out["translation_m"],
             out["rmse_m"])
    return out

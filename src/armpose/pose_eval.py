"""Camera-to-robot pose from one image, evaluated on the test split (beyond the paper).

For every test frame, the network's 3D base and joints (camera optical frame, metres) are
aligned with the same points from forward kinematics of that frame's joint angles (robot base
frame) by a robust rigid fit (:func:`armpose.camera_pose.robust_rigid`), giving the pose of the
robot base in the camera frame, ``T_cam_base``, without any calibration. The truth is the
inverse of the recording's camera pose (``camera_poses.csv``: the optical frame in the base frame).

Reported per family: median rotation error (deg), median translation error (cm), median ADD
(cm; the mean distance between the robot's joints placed by the estimated and by the true
pose) and the ADD AUC at 10 cm. Only single images: pooling several images needs a static
camera, which the synthetic recordings do not have (each frame has its own camera).
"""
from __future__ import annotations

import logging
from functools import lru_cache
from pathlib import Path

import numpy as np

from armpose.camera_pose import add_auc, add_m, robust_rigid, rotation_error_deg, translation_error_m
from armpose.geometry import invert, pose_to_matrix
from armpose.recording import read_joints, read_meta, read_poses

log = logging.getLogger(__name__)


@lru_cache(maxsize=None)
def _kinematics(robot: str):
    from armpose.robots import get_robot
    from armpose.robots.kinematics import Kinematics
    return Kinematics(get_robot(robot))


@lru_cache(maxsize=256)
def _recording_tables(path: str) -> tuple[str, dict, dict]:
    """(robot, frame -> joint angles, frame -> T_base_cam) of one recording."""
    rec = Path(path)
    meta, spec = read_meta(rec)
    frames, angles, _ = read_joints(rec, spec)
    pframes, poses, _ = read_poses(rec)
    return (meta.robot, {int(f): a for f, a in zip(frames, angles)},
            {int(f): pose_to_matrix(p[:3], p[3:]) for f, p in zip(pframes, poses)})


def frame_pose_errors(pred: dict, truth: dict, index: dict, arrays: dict, root: Path,
                      threshold_m: float = 0.05) -> dict[str, np.ndarray]:
    """Per test frame: ``rot_deg``, ``trans_m``, ``add_m`` of the single-image pose estimate
    (NaN where the recording cannot be read)."""
    n = len(truth["row"])
    out = {k: np.full(n, np.nan) for k in ("rot_deg", "trans_m", "add_m")}
    recordings = index["recordings"]
    for i, row in enumerate(truth["row"]):
        rec = recordings[int(arrays["recording"][row])]
        try:
            robot, angles, poses = _recording_tables(str(Path(root) / rec["name"]))
        except (OSError, ValueError) as err:
            log.warning("pose evaluation skips %s: %s", rec["name"], err)
            continue
        frame = int(arrays["frame"][row])
        kin = _kinematics(robot)
        joints_base = kin.joint_positions(np.asarray(angles[frame])[None])[0]
        src = np.vstack([np.zeros(3), joints_base])
        dst = np.vstack([pred["base"][i], pred["joints"][i][: len(joints_base)]])
        est = robust_rigid(src, dst, method="huber", threshold_m=threshold_m)
        T_true = invert(poses[frame])
        out["rot_deg"][i] = rotation_error_deg(est.T[:3, :3], T_true[:3, :3])
        out["trans_m"][i] = translation_error_m(est.T[:3, 3], T_true[:3, 3])
        out["add_m"][i] = add_m(est.T, T_true, src)
    return out


def summarise_poses(errors: dict[str, np.ndarray], rows: np.ndarray) -> dict:
    """Medians and ADD AUC over ``rows``."""
    rows = np.asarray(rows, np.int64)
    ok = rows[np.isfinite(errors["add_m"][rows])]
    if ok.size == 0:
        return {"frames": 0}
    return {"frames": int(ok.size), "images_pooled": 1,
            "rotation_median_deg": float(np.median(errors["rot_deg"][ok])),
            "translation_median_cm": float(100 * np.median(errors["trans_m"][ok])),
            "add_median_cm": float(100 * np.median(errors["add_m"][ok])),
            "add_auc_10cm": add_auc(errors["add_m"][ok], 0.1)}

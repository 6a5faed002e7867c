"""Camera-to-robot pose from one image, evaluated on the test split (beyond the paper).

For every test frame, the network's 3D base and joints (camera optical frame, metres) are
aligned with the same points from forward kinematics of that frame's joint angles (robot base
frame) by a robust rigid fit (:func:`armpose.camera_pose.robust_rigid`), giving the pose of the
robot base in the camera frame, ``T_cam_base``, without any calibration; with ``rays`` the fit
is refined on each point's ray and, weakly, its depth (:func:`armpose.camera_pose.refine_rays`),
since the network's rays are far better than its depths. The truth is the
inverse of the recording's camera pose (``camera_poses.csv``: the optical frame in the base frame).

Reported per family: median rotation error (deg), median translation error (cm), median ADD
(cm; the mean distance between the robot's joints placed by the estimated and by the true
pose) and the ADD AUC at 10 cm.

Pooling several images needs a static camera, which the synthetic recordings do not have (each
frame has its own camera); the recorded static-camera (tripod) test recordings have one.
:func:`pooled_pose_errors` fits one pose to the points of ``images`` frames of such a recording
at once (:func:`fit_pose` of all their points), the frames spread over the recording
(:func:`spread_chunks`); :func:`camera_pose_metrics` reports, per family, single images on the
synthetic test set, and single images and pooled images on the same tripod frames.
"""
from __future__ import annotations

import logging
from functools import lru_cache
from pathlib import Path

import numpy as np

from armpose.camera_pose import (add_auc, add_m, refine_rays, robust_rigid, rotation_error_deg,
                                 translation_error_m)
from armpose.geometry import invert, pose_to_matrix
from armpose.labels.dataset import SOURCE_CODES
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


def frame_points(root: Path, rec_name: str, frame: int) -> tuple[np.ndarray, np.ndarray]:
    """``(points_base (J+1, 3), T_cam_base (4, 4))`` of one frame: the base origin and the joints
    from forward kinematics (robot base frame, metres) and the recorded pose of the base in the
    camera optical frame. Raises ``OSError``/``ValueError`` for an unreadable recording and
    ``KeyError`` naming the recording for a frame it lacks."""
    robot, angles, poses = _recording_tables(str(Path(root) / rec_name))
    if frame not in angles or frame not in poses:
        raise KeyError(f"{rec_name}: frame {frame} has no joint angles or camera pose")
    joints_base = _kinematics(robot).joint_positions(np.asarray(angles[frame])[None])[0]
    return np.vstack([np.zeros(3), joints_base]), invert(poses[frame])


def predicted_points(pred: dict, i: int, count: int) -> np.ndarray:
    """The predicted base and first ``count - 1`` joints of test frame ``i`` ``(count, 3)`` (camera frame, m)."""
    return np.vstack([pred["base"][i], pred["joints"][i][: count - 1]])


def pose_errors(T_est: np.ndarray, T_true: np.ndarray, points_base: np.ndarray) -> tuple[float, float, float]:
    """``(rotation deg, translation m, ADD m over points_base)`` of ``T_est`` against ``T_true`` (``T_cam_base``)."""
    return (float(rotation_error_deg(T_est[:3, :3], T_true[:3, :3])),
            float(translation_error_m(T_est[:3, 3], T_true[:3, 3])), float(add_m(T_est, T_true, points_base)))


def fit_pose(src: np.ndarray, dst: np.ndarray, threshold_m: float = 0.05, rays: bool = False) -> np.ndarray:
    """``T_cam_base`` mapping FK points ``src`` onto predicted points ``dst`` (rows of one or more
    images of one camera): the robust rigid fit (Huber), then with ``rays`` refined on its inliers'
    rays and depths (:func:`~armpose.camera_pose.refine_rays`)."""
    est = robust_rigid(src, dst, method="huber", threshold_m=threshold_m)
    return refine_rays(est.T, src, dst, valid=est.inliers) if rays else est.T


def frame_pose_errors(pred: dict, truth: dict, index: dict, arrays: dict, root: Path,
                      threshold_m: float = 0.05, rays: bool = False) -> dict[str, np.ndarray]:
    """Per test frame: ``rot_deg``, ``trans_m``, ``add_m`` of the single-image pose estimate
    (:func:`fit_pose`; NaN where the recording cannot be read)."""
    n = len(truth["row"])
    out = {k: np.full(n, np.nan) for k in ("rot_deg", "trans_m", "add_m")}
    recordings = index["recordings"]
    for i, row in enumerate(truth["row"]):
        rec = recordings[int(arrays["recording"][row])]
        try:
            src, T_true = frame_points(root, rec["name"], int(arrays["frame"][row]))
        except (OSError, ValueError, KeyError) as err:
            log.warning("pose evaluation skips %s: %s", rec["name"], err)
            continue
        T = fit_pose(src, predicted_points(pred, i, len(src)), threshold_m, rays)
        out["rot_deg"][i], out["trans_m"][i], out["add_m"][i] = pose_errors(T, T_true, src)
    return out


def spread_chunks(n: int, images: int) -> list[np.ndarray]:
    """Positions ``0..n-1`` (frames in time order) in groups of ``images`` spread over the sequence:
    with ``m = n // images`` groups, group c holds ``c, c + m, c + 2m, ...`` (so the frames of one
    group are ``m`` frames apart and see the robot in different configurations). Fewer than
    ``images`` positions give one group of them all; none give no group."""
    m = n // images
    if m == 0:
        return [np.arange(n)] if n else []
    return [np.arange(c, m * images, m) for c in range(m)]


def pooled_errors(points_base: list[np.ndarray], points_cam: list[np.ndarray], T_true: np.ndarray, images: int,
                  threshold_m: float = 0.05, rays: bool = False) -> dict[str, np.ndarray]:
    """Per group of :func:`spread_chunks`: ``rot_deg``, ``trans_m``, ``add_m`` of one pose pooled
    over the group's frames of a static camera (all their points in one :func:`fit_pose`).

    ``points_base[k]`` ``(J+1, 3)`` (base frame) and ``points_cam[k]`` ``(J+1, 3)`` (predictions,
    camera frame) are frame k's points in time order; ``T_true`` is the one ``T_cam_base``. ADD
    averages over all the group's base-frame points."""
    out = {k: [] for k in ("rot_deg", "trans_m", "add_m")}
    for group in spread_chunks(len(points_base), images):
        src = np.concatenate([points_base[k] for k in group])
        T = fit_pose(src, np.concatenate([points_cam[k] for k in group]), threshold_m, rays)
        errs = pose_errors(T, T_true, src)
        for key, value in zip(out, errs):
            out[key].append(value)
    return {k: np.asarray(v, np.float64) for k, v in out.items()}


def static_recordings(truth: dict, arrays: dict, index: dict) -> dict[int, np.ndarray]:
    """Static-camera test recordings (``index.json`` ``static_camera``): recording index ->
    positions into ``truth`` sorted by frame."""
    out = {}
    for r in np.unique(truth["recording"]):
        if index["recordings"][int(r)].get("static_camera"):
            pos = np.flatnonzero(truth["recording"] == r)
            out[int(r)] = pos[np.argsort(arrays["frame"][truth["row"][pos]], kind="stable")]
    return out


def pooled_pose_errors(pred: dict, truth: dict, index: dict, arrays: dict, root: Path, images: int,
                       threshold_m: float = 0.05, rays: bool = False) -> dict[int, dict[str, np.ndarray]]:
    """:func:`pooled_errors` of every static-camera test recording (recording index -> errors)."""
    out = {}
    for r, pos in static_recordings(truth, arrays, index).items():
        name = index["recordings"][r]["name"]
        try:
            pts = [frame_points(root, name, int(arrays["frame"][truth["row"][i]])) for i in pos]
        except (OSError, ValueError, KeyError) as err:
            log.warning("pooled pose evaluation skips %s: %s", name, err)
            continue
        src = [p[0] for p in pts]
        dst = [predicted_points(pred, i, len(s)) for i, s in zip(pos, src)]
        out[r] = pooled_errors(src, dst, pts[0][1], images, threshold_m, rays)
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


def summarise_pooled(errors: list[dict[str, np.ndarray]], images: int) -> dict:
    """Medians and ADD AUC over the pooled estimates of ``errors`` (one dict per recording)."""
    cat = {k: np.concatenate([e[k] for e in errors]) if errors else np.zeros(0) for k in ("rot_deg", "trans_m", "add_m")}
    ok = np.isfinite(cat["add_m"])
    if not ok.any():
        return {"estimates": 0}
    return {"estimates": int(ok.sum()), "recordings": len(errors), "images_pooled": images,
            "rotation_median_deg": float(np.median(cat["rot_deg"][ok])),
            "translation_median_cm": float(100 * np.median(cat["trans_m"][ok])),
            "add_median_cm": float(100 * np.median(cat["add_m"][ok])),
            "add_auc_10cm": add_auc(cat["add_m"][ok], 0.1)}


def camera_pose_metrics(pred: dict, truth: dict, index: dict, arrays: dict, root: Path, families: list[str],
                        images: int = 10, rays: bool = False) -> dict:
    """Camera-to-robot pose per family (``families``: one per robot type index), by :func:`fit_pose`
    (``fit``: ``"rays"`` with ``rays``, else ``"rigid"``).

    ``by_family``/``all``: single images of the synthetic test frames. ``tripod``: on the
    static-camera test recordings, ``images_1`` (single images) and ``images_<images>`` (pooled
    over ``images`` spread frames, :func:`pooled_pose_errors`) on the same frames."""
    errors = frame_pose_errors(pred, truth, index, arrays, root, rays=rays)
    fams = np.array(families)[truth["type"]] if len(truth["type"]) else np.array([], str)
    synthetic = truth["source"] == SOURCE_CODES["synthetic"]
    out = {"source": "synthetic", "fit": "rays" if rays else "rigid",
           "by_family": {f: summarise_poses(errors, np.flatnonzero(synthetic & (fams == f)))
                         for f in dict.fromkeys(fams[synthetic].tolist())},
           "all": summarise_poses(errors, np.flatnonzero(synthetic))}
    static = static_recordings(truth, arrays, index)
    if not static:
        return out
    pooled = pooled_pose_errors(pred, truth, index, arrays, root, images, rays=rays)
    rec_family = {r: str(fams[pos[0]]) for r, pos in static.items()}
    tripod = {"images_pooled": images, "by_family": {}}
    for f in [*dict.fromkeys(rec_family.values()), None]:
        recs = [r for r in static if f is None or rec_family[r] == f]
        block = {"images_1": summarise_poses(errors, np.concatenate([static[r] for r in recs])),
                 f"images_{images}": summarise_pooled([pooled[r] for r in recs if r in pooled], images)}
        if f is None:
            tripod["all"] = block
        else:
            tripod["by_family"][f] = block
    out["tripod"] = tripod
    return out

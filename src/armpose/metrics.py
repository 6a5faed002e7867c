"""Evaluation metrics, pure numpy: the paper's (section VI) and what the field reports besides.

Inputs are per-frame arrays over N test frames:

- ``pred_joints``, ``true_joints`` (N, J, 3) metres, camera optical frame; ``joint_valid`` (N, J);
- ``pred_base``, ``true_base`` (N, 3) metres;
- ``pred_type``, ``true_type`` (N,) class indices;
- per-frame mask counts from :func:`mask_counts` (pixels that agree, intersection, union);
- ``intrinsics`` (N, 4) fx, fy, cx, cy of the network input, and ``pixel_scale`` the factor
  from network-input pixels to pixels of the rectified camera image (PCK is reported in the
  camera image, as DREAM does).

Definitions:

- mask accuracy: the fraction of pixels whose predicted class matches the truth (paper);
- mask IoU: intersection over union of the robot pixels, summed per frame then averaged;
- median / mean joint error: over every valid joint of every frame, Euclidean, cm;
- ADD AUC at 10 cm: per frame, ADD is the mean Euclidean error of its valid joints; the
  AUC is the area under the fraction of frames with ADD <= t for t in [0, 0.1] m, divided by
  0.1 (1.0 is perfect), as NVlabs/DREAM computes it (:func:`armpose.camera_pose.add_auc`);
- PCK@k px: the fraction of valid joints whose projected 2D error is below k pixels.

Where the 3D error comes from (ours; :func:`depth_breakdown`):

- joint median at true depth: the joint error left after sliding each predicted joint along
  its own ray to the true depth, i.e. the part that 2D (ray) errors cause, cm;
- depth error: median of ``|z_pred / z_true - 1|`` over valid joints, %;
- frame depth error: median over frames of ``|median_j(z_pred / z_true) - 1|``, the depth
  error that all joints of a frame share (a scale error), %;
- joint median at true frame scale: the joint error left after dividing each frame's
  predicted joints by that frame's ``median_j(z_pred / z_true)`` (a scaling about the camera
  centre, which keeps every ray): what remains when only the shared scale is fixed, i.e. the
  2D errors plus the errors of each joint's depth relative to the others, cm.
"""
from __future__ import annotations

import numpy as np

from armpose import camera_pose

ADD_AUC_THRESHOLD_M = 0.1
PCK_PIXELS = (5, 10)
SUMMARY_KEYS = ("mask_accuracy", "mask_iou", "type_accuracy", "joint_median_cm", "joint_mean_cm",
                "base_median_cm", "base_mean_cm", "add_auc_10cm", "joint_median_true_depth_cm",
                "depth_error_median_pct", "frame_depth_error_median_pct", "joint_median_true_frame_scale_cm")


def mask_counts(pred: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``(N, 4)`` per frame: pixels that agree, intersection, union, pixel count. Masks (N, H, W) bool."""
    pred, truth = np.asarray(pred, bool), np.asarray(truth, bool)
    agree = (pred == truth).reshape(len(pred), -1).sum(1)
    inter = (pred & truth).reshape(len(pred), -1).sum(1)
    union = (pred | truth).reshape(len(pred), -1).sum(1)
    return np.stack([agree, inter, union, np.full(len(pred), pred[0].size if len(pred) else 0)], 1).astype(np.int64)


def joint_errors(pred: np.ndarray, truth: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``(N, J)`` Euclidean errors in metres, NaN where the joint slot is not valid."""
    err = np.linalg.norm(np.asarray(pred, np.float64) - np.asarray(truth, np.float64), axis=-1)
    return np.where(np.asarray(valid, bool), err, np.nan)


def add_auc(add: np.ndarray, threshold: float = ADD_AUC_THRESHOLD_M) -> float:
    """DREAM's ADD AUC (see :func:`armpose.camera_pose.add_auc`); NaN for no frames."""
    add = np.asarray(add, np.float64)
    return camera_pose.add_auc(add, threshold) if add.size else float("nan")


def project(points: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """Pixels ``(N, J, 2)`` of camera-frame points ``(N, J, 3)`` through per-frame intrinsics ``(N, 4)``."""
    k = np.asarray(intrinsics, np.float64)[:, None, :]
    p = np.asarray(points, np.float64)
    z = np.clip(p[..., 2], 1e-6, None)
    return np.stack([k[..., 0] * p[..., 0] / z + k[..., 2], k[..., 1] * p[..., 1] / z + k[..., 3]], -1)


def _median_cm(values: np.ndarray) -> float:
    v = values[np.isfinite(values)]
    return float(100 * np.median(v)) if v.size else float("nan")


def _mean_cm(values: np.ndarray) -> float:
    v = values[np.isfinite(values)]
    return float(100 * np.mean(v)) if v.size else float("nan")


def frame_depth_ratio(pred: np.ndarray, truth: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Per frame ``(N,)``, the median over its ``valid`` joints (both depths positive) of predicted
    over true depth, from ``pred`` and ``truth`` (N, J, 3, metres, camera frame); NaN for a
    frame without such a joint. One minus it is the depth error the frame's joints share."""
    pred, truth = np.asarray(pred), np.asarray(truth)
    valid = np.asarray(valid, bool) & (pred[..., 2] > 0) & (truth[..., 2] > 0)
    ratio = np.where(valid, pred[..., 2] / np.where(valid, truth[..., 2], 1.0), np.nan)
    out = np.full(len(ratio), np.nan)
    has = valid.any(1)
    out[has] = np.nanmedian(ratio[has], axis=1)
    return out


def depth_breakdown(pred: np.ndarray, truth: np.ndarray, valid: np.ndarray) -> dict:
    """Split the 3D joint error of ``pred`` against ``truth`` (N, J, 3, metres) into its ray
    and depth parts over the ``valid`` (N, J) joints; see the module docstring."""
    valid = np.asarray(valid, bool) & (np.asarray(pred)[..., 2] > 0) & (np.asarray(truth)[..., 2] > 0)
    nan = float("nan")
    if not valid.any():
        return {"joint_median_true_depth_cm": nan, "depth_error_median_pct": nan, "frame_depth_error_median_pct": nan,
                "joint_median_true_frame_scale_cm": nan}
    safe_pred = np.where(valid[..., None], pred, 1.0)
    safe_truth = np.where(valid[..., None], truth, 1.0)
    ratio = safe_pred[..., 2] / safe_truth[..., 2]                               # (N, J)
    on_true_depth = safe_pred / ratio[..., None]
    per_frame = frame_depth_ratio(pred, truth, valid)                                   # (N,), NaN: no joint
    on_true_scale = safe_pred / np.where(np.isnan(per_frame), 1.0, per_frame)[:, None, None]
    frame_ratio = per_frame[valid.any(1)]
    return {"joint_median_true_depth_cm": _median_cm(np.linalg.norm(on_true_depth - safe_truth, axis=-1)[valid]),
            "depth_error_median_pct": float(100 * np.median(np.abs(ratio[valid] - 1))),
            "frame_depth_error_median_pct": float(100 * np.median(np.abs(frame_ratio - 1))),
            "joint_median_true_frame_scale_cm": _median_cm(np.linalg.norm(on_true_scale - safe_truth, axis=-1)[valid])}


def summarise(pred: dict, truth: dict, rows: np.ndarray, pixel_scale: float | np.ndarray = 1.0) -> dict:
    """Every metric over the frames ``rows`` (indices into the per-frame arrays).

    ``pred`` keys: ``joints``, ``base``, ``type``, ``mask_counts``; ``truth`` keys: ``joints``,
    ``joint_valid``, ``base``, ``type``, ``intrinsics``. ``pixel_scale``: network-input pixels per
    PCK pixel, one number or one per frame (indexed by ``rows``). Returns a flat dict of floats.

    Mask accuracy and IoU are per frame (network-input pixels), then averaged over the frames; an
    empty union counts as IoU 1. Joint errors are those of the true type's joint slots
    (``joint_valid``), also for a frame whose type is predicted wrong; the joint median and mean
    pool every valid joint of every frame. ADD AUC: :func:`add_auc` of each frame's mean joint
    error."""
    rows = np.asarray(rows, np.int64)
    if rows.size == 0:
        nan = float("nan")
        return {"frames": 0, **{k: nan for k in SUMMARY_KEYS}, **{f"pck_{k}px": nan for k in PCK_PIXELS},
                "per_joint_median_cm": []}
    err = joint_errors(pred["joints"][rows], truth["joints"][rows], truth["joint_valid"][rows])
    per_frame_add = np.nanmean(np.where(np.isnan(err), np.nan, err), axis=1)
    base_err = np.linalg.norm(pred["base"][rows] - truth["base"][rows], axis=-1)
    counts = pred["mask_counts"][rows].astype(np.float64)
    iou = np.where(counts[:, 2] > 0, counts[:, 1] / np.maximum(counts[:, 2], 1), 1.0)
    scale = np.asarray(pixel_scale, np.float64)
    scale = scale[rows][:, None] if scale.ndim else scale
    uv_err = np.linalg.norm(project(pred["joints"][rows], truth["intrinsics"][rows])
                            - project(truth["joints"][rows], truth["intrinsics"][rows]), axis=-1) / scale
    valid = np.asarray(truth["joint_valid"][rows], bool)
    out = {
        "frames": int(rows.size),
        "mask_accuracy": float((counts[:, 0] / counts[:, 3]).mean()),
        "mask_iou": float(iou.mean()),
        "type_accuracy": float((pred["type"][rows] == truth["type"][rows]).mean()),
        "joint_median_cm": _median_cm(err),
        "joint_mean_cm": _mean_cm(err),
        "base_median_cm": _median_cm(base_err),
        "base_mean_cm": _mean_cm(base_err),
        "add_auc_10cm": add_auc(per_frame_add),
        **depth_breakdown(pred["joints"][rows], truth["joints"][rows], truth["joint_valid"][rows]),
    }
    for k in PCK_PIXELS:
        out[f"pck_{k}px"] = float((uv_err[valid] < k).mean()) if valid.any() else float("nan")
    out["per_joint_median_cm"] = [_median_cm(err[:, j]) for j in range(err.shape[1])
                                  if np.isfinite(err[:, j]).any()]
    return out


def confusion_matrix(pred_type: np.ndarray, true_type: np.ndarray, num_types: int) -> np.ndarray:
    """``(num_types, num_types)`` counts, rows = true class, columns = predicted class."""
    m = np.zeros((num_types, num_types), np.int64)
    np.add.at(m, (np.asarray(true_type, np.int64), np.asarray(pred_type, np.int64)), 1)
    return m


def error_by_distance(err: np.ndarray, distance: np.ndarray, edges: np.ndarray) -> list[dict]:
    """Median joint error (cm) per camera-distance bin; ``err`` (N, J) metres with NaN for invalid."""
    rows = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (distance >= lo) & (distance < hi)
        rows.append({"distance_lo_m": float(lo), "distance_hi_m": float(hi), "frames": int(sel.sum()),
                     "joint_median_cm": _median_cm(err[sel]) if sel.any() else float("nan")})
    return rows

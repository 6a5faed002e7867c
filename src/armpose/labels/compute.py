"""Labels for every frame of one recording.

For each frame: (a) base and joint positions in the camera optical frame (metres) from
batched forward kinematics on ``joints.csv`` and ``camera_poses.csv``; (b) the robot mask,
rendered from the robot model alone; (c) the image scaled and cropped to the network input,
with the intrinsics adjusted to match; (d) the camera-to-base distance (metres).
"""
from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np

from armpose.geometry import Camera, invert, pose_to_matrix, transform_points
from armpose.labels.mask import mask_renderer
from armpose.recording import RecordingError, read_frame, read_joints, read_meta, read_poses
from armpose.robots.kinematics import Kinematics

log = logging.getLogger(__name__)



def scale_crop_image(img: np.ndarray, camera: Camera, width: int, height: int) -> np.ndarray:
    """Resize ``img`` (of ``camera``) to cover ``width x height`` and centre-crop it.

    The result is seen by ``camera.scale_crop(width, height)[0]``."""
    _, (rw, rh), (x0, y0) = camera.scale_crop(width, height)
    interp = cv2.INTER_AREA if rw < img.shape[1] else cv2.INTER_LINEAR
    return cv2.resize(img, (rw, rh), interpolation=interp)[y0:y0 + height, x0:x0 + width]


def _aligned_rows(rec_dir: Path, spec, errors: list[RecordingError]):
    """Frames present in both CSVs, with their joint angles and poses; the rest become errors."""
    jf, q, jerr = read_joints(rec_dir, spec)
    pf, poses, perr = read_poses(rec_dir)
    errors += jerr + perr
    # the readers leave a bad row's values NaN (row indices are not line numbers: blank lines)
    jrow = {f: i for i, f in enumerate(jf) if np.isfinite(q[i]).all()}
    prow = {f: i for i, f in enumerate(pf) if np.isfinite(poses[i]).all()}
    for f in sorted(set(jf) - set(pf)):
        errors.append(RecordingError(rec_dir / "camera_poses.csv", None, int(f), "no camera pose for frame"))
    for f in sorted(set(pf) - set(jf)):
        errors.append(RecordingError(rec_dir / "joints.csv", None, int(f), "no joint reading for frame"))
    frames = sorted(set(jrow) & set(prow))
    return (np.array(frames, dtype=np.int64), q[[jrow[f] for f in frames]].reshape(-1, spec.num_joints),
            poses[[prow[f] for f in frames]].reshape(-1, 7))


def label_recording(rec_dir: Path, input_size: dict, max_joints: int, skip_bad: bool = False):
    """Label arrays for the good frames of ``rec_dir`` and the list of problems skipped.

    Without ``skip_bad`` the first problem raises :class:`RecordingError`. Arrays: images
    ``(N, h, w, 3)`` uint8, masks ``(N, h, w)`` uint8 {0, 1}, joints ``(N, max_joints, 3)`` and
    base ``(N, 3)`` float32 metres in the camera optical frame, joint_valid ``(N, max_joints)``,
    distance ``(N,)`` metres, intrinsics ``(N, 4)`` fx, fy, cx, cy of the network input, frame ``(N,)``.
    """
    rec_dir = Path(rec_dir)
    meta, spec = read_meta(rec_dir)
    errors: list[RecordingError] = []
    frames, q, poses = _aligned_rows(rec_dir, spec, errors)
    if errors and not skip_bad:
        raise errors[0]
    if not len(frames) and not errors:
        raise RecordingError(rec_dir / "joints.csv", None, 0, "no rows: a recording needs at least one frame")
    w, h = int(input_size["width"]), int(input_size["height"])
    cam_in, _, _ = meta.camera.scale_crop(w, h)
    T_base_cam = pose_to_matrix(poses[:, :3], poses[:, 3:])
    T_cam_base = invert(T_base_cam)
    joints_cam = transform_points(T_cam_base, Kinematics(spec).joint_positions(q))
    base_cam = T_cam_base[:, :3, 3]
    renderer = mask_renderer(spec)
    keep, images, masks = [], [], []
    for i, frame in enumerate(frames):
        try:
            img = read_frame(rec_dir, int(frame), meta.camera)
        except RecordingError as err:
            if not skip_bad:
                raise
            errors.append(err)
            continue
        keep.append(i)
        images.append(scale_crop_image(img, meta.camera, w, h))
        masks.append(renderer.render(q[i], T_base_cam[i], cam_in).astype(np.uint8))
    for err in errors:
        log.warning("skipped: %s", err)
    n, J = len(keep), spec.num_joints
    joints = np.zeros((n, max_joints, 3), np.float32)
    joints[:, :J] = joints_cam[keep]
    valid = np.zeros((n, max_joints), bool)
    valid[:, :J] = True
    return {
        "images": np.stack(images) if n else np.zeros((0, h, w, 3), np.uint8),
        "masks": np.stack(masks) if n else np.zeros((0, h, w), np.uint8),
        "joints": joints, "joint_valid": valid,
        "base": base_cam[keep].astype(np.float32),
        "distance": np.linalg.norm(base_cam[keep], axis=1).astype(np.float32),
        "intrinsics": np.tile(np.array([cam_in.fx, cam_in.fy, cam_in.cx, cam_in.cy], np.float32), (n, 1)),
        "frame": frames[keep],
    }, meta, [str(e) for e in errors]

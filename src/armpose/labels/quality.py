"""Label quality checks: do the projected joints fall on the rendered mask?

For recorded data this catches a wrong camera calibration or a joint-name mix-up: with good
poses every joint origin projects onto (or within a few pixels of) the robot's silhouette.
"""
from __future__ import annotations

import cv2
import numpy as np


def joints_near_mask(masks, joints, joint_valid, intrinsics, tol_px: float = 3.0) -> np.ndarray:
    """Per frame, True if every valid joint that projects inside the image lies within
    ``tol_px`` pixels of the mask. Joints (N, J, 3) are in the camera frame (metres);
    intrinsics (N, 4) are fx, fy, cx, cy of the mask's image."""
    ok = np.ones(len(masks), bool)
    for i in range(len(masks)):
        mask = np.asarray(masks[i]).astype(np.uint8)
        dist = cv2.distanceTransform(1 - mask, cv2.DIST_L2, 5)  # pixels to the nearest mask pixel
        fx, fy, cx, cy = intrinsics[i]
        pts = np.asarray(joints[i])[np.asarray(joint_valid[i])]
        pts = pts[pts[:, 2] > 1e-3]
        u, v = fx * pts[:, 0] / pts[:, 2] + cx, fy * pts[:, 1] / pts[:, 2] + cy
        inside = (u >= 0) & (u <= mask.shape[1] - 1) & (v >= 0) & (v <= mask.shape[0] - 1)
        d = dist[np.round(v[inside]).astype(int), np.round(u[inside]).astype(int)]
        ok[i] = bool((d <= tol_px).all())
    return ok

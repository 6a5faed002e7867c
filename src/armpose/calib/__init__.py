"""Mocap-rig-to-camera calibration (``armpose calibrate-rig``) and its simulation.

Modules: ``board`` (ChArUco geometry, detection, PnP), ``solve`` (estimators), ``rig`` (the
calibration with outlier rejection and residuals), ``views`` (the on-disk input layout),
``simulate`` (PyBullet sessions with known truth; imports pybullet), ``cli``.
Frames: OpenCV camera optical frame (x right, y down, z forward), metres, quaternions xyzw.
"""
from armpose.calib.board import BoardObservation, BoardSpec, board_pose, detect_board
from armpose.calib.rig import (
    MIN_VIEWS,
    NotEnoughViewsError,
    RigCalibration,
    RigSettings,
    RigView,
    ViewResidual,
    calibrate_rig,
    pose_error,
)
from armpose.calib.solve import MocapNoise

__all__ = [
    "MIN_VIEWS",
    "BoardObservation",
    "BoardSpec",
    "MocapNoise",
    "NotEnoughViewsError",
    "RigCalibration",
    "RigSettings",
    "RigView",
    "ViewResidual",
    "board_pose",
    "calibrate_rig",
    "detect_board",
    "pose_error",
]

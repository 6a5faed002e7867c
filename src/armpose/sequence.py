"""Consecutive frames through the network, smoothed causally (``armpose predict --sequence``).

Frames come, in order, from image files, folders (image files sorted by name) and video files
read with OpenCV (``cv2.VideoCapture``; frame k of ``clip.avi`` is named ``clip.avi#k``).
Frame k of the sequence is at time ``k / rate_hz`` seconds, so a frame that cannot be read or
processed leaves a gap in time that the filters bridge.

Every output uses only the frames up to its own (causal), so the same code runs live:

- ``joints_xyz`` and ``base_xyz`` (camera optical frame: x right, y down, z forward; metres)
  are the network's positions smoothed by a :mod:`armpose.tracking` filter (``kalman``,
  ``one-euro`` or ``none``); the per-frame values stay in ``raw_joints_xyz`` and
  ``raw_base_xyz``, and ``joints_uv`` (pixels) are the smoothed joints projected;
- ``robot_type`` is the sequence's type: the given robot, else the type with the largest summed
  probability so far; ``raw_robot_type`` is the frame's own. Joints the frame's type lacks
  (fewer joints than the sequence's type) are null in ``raw_joints_xyz`` and predicted by the
  filter; a value never seen yet is null;
- with known joint angles (radians, one row per frame), ``raw_T_cam_base`` is the frame's
  robust rigid fit of the raw points to forward kinematics (4x4, base frame to camera frame,
  metres), ``T_cam_base`` its smoothed value (translation filtered as a point, rotation as a
  quaternion kept on one hemisphere, then renormalised) and ``pose_rmse_m`` the fit's residual.

Other keys follow the single-image schema of :mod:`armpose.predict`, plus ``frame`` (index in
the sequence) and ``time_s``.
"""
from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence
from pathlib import Path

import cv2
import numpy as np

from armpose.camera_pose import robust_rigid, to_matrix
from armpose.extrinsics import correspondences, kinematics
from armpose.geometry import Camera, matrix_to_quat, quat_to_matrix
from armpose.intrinsics import load_intrinsics
from armpose.predict import PredictError, Predictor, expand_inputs, read_image, write_mask
from armpose.robots.registry import get_robot
from armpose.tracking import KalmanFilter3D, OneEuroFilter

log = logging.getLogger(__name__)

VIDEO_SUFFIXES = (".avi", ".mp4", ".mov", ".mkv", ".m4v", ".webm", ".mpg", ".mpeg", ".wmv")
FILTERS = ("kalman", "one-euro", "none")
DEFAULT_RATE_HZ = 30.0


def is_video(path: Path | str) -> bool:
    """Whether ``path`` is read as a video (by its suffix)."""
    return Path(path).suffix.lower() in VIDEO_SUFFIXES


def _open_video(path: Path) -> cv2.VideoCapture:
    """An opened capture, or a :class:`PredictError` naming the file."""
    if not path.is_file():
        raise PredictError(f"{path}: no such file")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise PredictError(f"{path}: cannot be opened as a video by OpenCV")
    return cap


def list_frames(inputs: Sequence[str | Path]) -> list[str]:
    """The names of all frames of ``inputs`` in order (videos are decoded once to count them)."""
    names = []
    for item in inputs:
        p = Path(item)
        if not p.is_dir() and is_video(p):
            cap = _open_video(p)
            n = 0
            while cap.grab():
                n += 1
            cap.release()
            names += [f"{p}#{i}" for i in range(n)]
        else:
            names += [str(f) for f in expand_inputs([p])]
    return names


def video_rate_hz(inputs: Sequence[str | Path]) -> float | None:
    """The frame rate of the first video among ``inputs`` (None if there is none or it is unknown)."""
    for item in inputs:
        p = Path(item)
        if p.is_file() and is_video(p):
            cap = cv2.VideoCapture(str(p))
            fps = cap.get(cv2.CAP_PROP_FPS) if cap.isOpened() else 0.0
            cap.release()
            return float(fps) if fps and np.isfinite(fps) and fps > 0 else None
    return None


def iter_images(inputs: Sequence[str | Path]) -> Iterator[tuple[str, np.ndarray | PredictError]]:
    """``(name, RGB uint8 image or the error reading it)`` for every frame, in order."""
    for item in inputs:
        p = Path(item)
        if p.is_dir() or not is_video(p):
            for f in expand_inputs([p]):
                try:
                    yield str(f), read_image(f)
                except PredictError as err:
                    yield str(f), err
            continue
        cap = _open_video(p)
        k = 0
        while True:
            ok, bgr = cap.read()
            if not ok:
                break
            yield f"{p}#{k}", cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            k += 1
        cap.release()


def frame_stem(name: str) -> str:
    """A file-name stem for frame ``name``: ``clip_000012`` for ``clip.avi#12``, else the image's stem."""
    path, _, index = name.rpartition("#")
    if path and index.isdigit() and is_video(path):
        return f"{Path(path).stem}_{int(index):06d}"
    return Path(name).stem


class Passthrough:
    """The ``none`` filter: every output is its measurement."""

    def reset(self) -> None:
        """Nothing to forget."""

    def update(self, x, t: float | None = None) -> np.ndarray:
        """``x`` as float64."""
        return np.array(x, dtype=np.float64)


def make_filter(name: str, rate_hz: float):
    """A fresh causal filter by name (:data:`FILTERS`) with its default tuning at ``rate_hz``."""
    if name == "kalman":
        return KalmanFilter3D(rate_hz=rate_hz)
    if name == "one-euro":
        return OneEuroFilter(rate_hz=rate_hz)
    if name == "none":
        return Passthrough()
    raise ValueError(f"filter must be one of {FILTERS}, got {name!r}")


class PoseFilter:
    """Causal smoothing of ``T_cam_base`` (4x4): translation as a point; the rotation as a
    quaternion whose sign follows the previous one, renormalised after filtering."""

    def __init__(self, name: str, rate_hz: float):
        self.translation, self.rotation = make_filter(name, rate_hz), make_filter(name, rate_hz)
        self._last = None

    def update(self, T: np.ndarray | None, t: float) -> np.ndarray | None:
        """The smoothed pose after measurement ``T`` (None: missing) at ``t`` s; None until one is seen."""
        trans, quat = np.full(3, np.nan), np.full(4, np.nan)
        if T is not None:
            trans, quat = T[:3, 3], matrix_to_quat(T[:3, :3])
            if self._last is not None and quat @ self._last < 0:
                quat = -quat
            self._last = quat
        tf, qf = self.translation.update(trans, t), self.rotation.update(quat, t)
        if not (np.isfinite(tf).all() and np.isfinite(qf).all()) or np.linalg.norm(qf) < 1e-9:
            return None
        return to_matrix(quat_to_matrix(qf / np.linalg.norm(qf)), tf)


class TypeVote:
    """The causal sequence type: the largest summed type probability so far."""

    def __init__(self):
        self.mass: dict[str, float] = {}

    def add(self, probs: dict[str, float]) -> str:
        """Count one frame's probabilities; the current winner."""
        for k, v in probs.items():
            self.mass[k] = self.mass.get(k, 0.0) + float(v)
        return max(self.mass, key=self.mass.get)


def jsonable(a) -> list:
    """Nested lists of floats with None for non-finite values (valid JSON)."""
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 0:
        return float(a) if np.isfinite(a) else None
    return [jsonable(x) for x in a]


def _padded(joints, slots: int) -> np.ndarray:
    """Joints ``(k, 3)`` in ``(slots, 3)``, NaN after the k given."""
    out = np.full((slots, 3), np.nan)
    j = np.asarray(joints, dtype=np.float64).reshape(-1, 3)[:slots]
    out[:len(j)] = j
    return out


class _Tracker:
    """The causal state of one sequence: filters, type vote and, with joint angles, the poses."""

    def __init__(self, predictor: Predictor, camera: Camera, filter: str, rate_hz: float, fk, robot, method,
                 threshold_m):
        self.camera, self.fk, self.robot, self.method, self.threshold_m = camera, fk, robot, method, threshold_m
        self.slots = max(predictor.num_joints)
        self.joints, self.base = make_filter(filter, rate_hz), make_filter(filter, rate_hz)
        self.pose = PoseFilter(filter, rate_hz) if fk is not None else None
        self.vote = TypeVote()

    def step(self, k: int, t: float, res: dict) -> dict:
        """The output keys of frame ``k`` at ``t`` s from its per-frame prediction ``res``."""
        seq_type = self.robot or self.vote.add(res["type_probs"])
        J = get_robot(seq_type).num_joints
        raw_j, raw_b = _padded(res["joints_xyz"], self.slots), np.asarray(res["base_xyz"], dtype=np.float64)
        joints, base = self.joints.update(raw_j, t)[:J], self.base.update(raw_b, t)
        row = {"frame": k, "time_s": round(t, 6), "robot_type": seq_type, "raw_robot_type": res["robot_type"],
               "type_probs": res["type_probs"], "base_xyz": jsonable(base), "joints_xyz": jsonable(joints),
               "joints_uv": jsonable(self.camera.project(joints)), "raw_base_xyz": jsonable(raw_b),
               "raw_joints_xyz": jsonable(raw_j[:J]), "latency_ms": res["latency_ms"]}
        if self.pose is not None:
            row.update(self._pose(k, t, raw_b, raw_j[:J]))
        return row

    def _pose(self, k: int, t: float, raw_b: np.ndarray, raw_j: np.ndarray) -> dict:
        """``raw_T_cam_base``, ``pose_rmse_m`` and the smoothed ``T_cam_base`` of frame ``k``."""
        src, dst = correspondences({"base_xyz": raw_b, "joints_xyz": raw_j}, self.fk[k])
        try:
            est = robust_rigid(src, dst, method=self.method, threshold_m=self.threshold_m)
        except ValueError as err:
            log.warning("frame %d: no camera pose (%s)", k, err)
            est = None
        T = self.pose.update(None if est is None else est.T, t)
        return {"T_cam_base": None if T is None else T.tolist(),
                "raw_T_cam_base": None if est is None else est.T.tolist(),
                "pose_rmse_m": None if est is None else round(est.rmse_m, 6)}


def _fk_for(joint_angles, robot: str | None, frames) -> np.ndarray | None:
    """FK joint positions ``(N, J, 3)`` (base frame, m) of ``joint_angles``; None without angles."""
    if joint_angles is None:
        return None
    if robot is None:
        raise ValueError("joint_angles need robot, the robot type they belong to")
    q = np.asarray(joint_angles, dtype=np.float64)
    n, J = len(list_frames(frames)), get_robot(robot).num_joints
    if q.shape != (n, J) or not np.isfinite(q).all():
        raise ValueError(f"joint_angles must be finite with shape ({n}, {J}): one row per frame of {robot}, got {q.shape}")
    return kinematics(robot).joint_positions(q)


def iter_sequence(frames: Sequence[str | Path], checkpoint: Path | str, intrinsics: Camera | str | Path | None = None,
                  filter: str = "kalman", rate_hz: float | None = DEFAULT_RATE_HZ, model=None, device: str = "cpu",
                  joint_angles=None, robot: str | None = None, masks: Path | None = None, errors: list | None = None,
                  method: str = "huber", threshold_m: float = 0.05,
                  mirror: bool = False,
                  zoom: bool = False) -> Iterator[tuple[dict, np.ndarray, np.ndarray]]:
    """``(row, RGB image, mask)`` per processed frame, in order, as soon as each is ready.

    Arguments as :func:`predict_sequence`, plus ``mirror`` (the mirror test of
    :mod:`armpose.mirror_test` on every frame) and ``zoom`` (the zoom test of :mod:`armpose.zoom_test`); frames that fail are skipped with a warning (and
    their message appended to ``errors``), their time slot kept.
    """
    if filter not in FILTERS:
        raise ValueError(f"filter must be one of {FILTERS}, got {filter!r}")
    rate_hz = rate_hz or video_rate_hz(frames) or DEFAULT_RATE_HZ
    if robot is not None:
        get_robot(robot)
    fk = _fk_for(joint_angles, robot, frames)
    predictor = Predictor(checkpoint, device, model=model, mirror=mirror, zoom=zoom)
    camera = load_intrinsics(Path(intrinsics)) if isinstance(intrinsics, (str, Path)) else intrinsics
    tracker = _Tracker(predictor, camera or predictor.canonical, filter, rate_hz, fk, robot, method, threshold_m)
    for k, (name, image) in enumerate(iter_images(frames)):
        try:
            if isinstance(image, PredictError):
                raise image
            res = predictor(image, camera)
        except PredictError as err:
            msg = str(err) if str(err).startswith(name) else f"{name}: {err}"
            log.warning("%s", msg)
            if errors is not None:
                errors.append(msg)
            continue
        mask = res.pop("_mask")
        row = {"image": name, **tracker.step(k, k / rate_hz, res)}
        if masks is not None:
            row["mask"] = str(write_mask(mask, masks, frame_stem(name)))
        yield row, image, mask


def predict_sequence(frames: Sequence[str | Path], checkpoint: Path | str, intrinsics: Camera | str | Path | None = None,
                     filter: str = "kalman", rate_hz: float | None = DEFAULT_RATE_HZ, model=None, device: str = "cpu",
                     joint_angles=None, robot: str | None = None, masks: Path | None = None,
                     errors: list | None = None, method: str = "huber", threshold_m: float = 0.05) -> list[dict]:
    """One result dict per processed frame of the sequence ``frames`` (schema in the module docstring).

    ``frames``: image files, folders and videos, in order. ``filter``: one of :data:`FILTERS`.
    ``rate_hz``: frames per second (None: the first video's rate, else 30). ``joint_angles``
    ``(N, J)``: encoder readings (radians) for all N frames of the sequence, in order, of robot
    type ``robot`` (which then also fixes ``robot_type``); they add the camera pose per frame,
    fitted with ``method`` and ``threshold_m`` (see :func:`armpose.camera_pose.robust_rigid`).
    ``masks``: folder for mask PNGs. ``model`` replaces the checkpoint's network (tests).
    """
    rows = [row for row, _, _ in iter_sequence(frames, checkpoint, intrinsics, filter, rate_hz, model, device,
                                               joint_angles, robot, masks, errors, method, threshold_m)]
    log.info("sequence: %d frames processed, filter %s", len(rows), filter)
    return rows

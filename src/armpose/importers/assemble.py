"""From timestamped raw samples to a recording: match, check, drop, write atomically.

Every source reader (folder, bag) produces a :class:`RawRecording`; :func:`assemble` does the
rest the same way for all of them. Matching: each image takes the joint sample and the camera
pose sample nearest in time, if within the tolerance; otherwise the image is dropped and counted.
"""
from __future__ import annotations

import dataclasses
import logging
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
from tqdm import tqdm

from armpose.geometry import Camera
from armpose.importers.common import (NothingKeptError, StreamBuilder, Where, base_from_world, compose_poses,
                                      match_nearest, pose_steps)
from armpose.recording import RecordingMeta, read_joints, read_meta, read_poses, write_frame, write_tables
from armpose.robots.registry import get_robot

log = logging.getLogger(__name__)

DROP_REASONS = ("no_joints_within_tolerance", "no_pose_within_tolerance", "pose_jump")


@dataclasses.dataclass
class ImportOptions:
    """Settings shared by every source.

    ``tolerance_ms``: largest image-to-sample time difference for a match (milliseconds).
    ``max_pose_jump_m`` / ``max_pose_jump_deg``: largest camera motion between consecutive frames
    (metres, degrees) before both frames around the jump are dropped; ``inf`` disables.
    ``camera``: intrinsics (else the source's CameraInfo). ``camera_pose``: a fixed camera optical
    frame pose in the robot base frame ``(x, y, z, qx, qy, qz, qw)``, instead of a pose stream.
    ``T_rig_cam``: 4x4, the camera optical frame in the tracked rig's frame; ``T_world_base``: 4x4,
    the robot base in the mocap world frame. ``ignore_joints``: joint names not in the URDF that
    are accepted and dropped (e.g. a gripper's, published with the arm's). A pose stream sample ``T_world_rig`` becomes
    ``T_base_cam = inv(T_world_base) @ T_world_rig @ T_rig_cam`` (each factor identity if not given).
    """

    robot: str
    tolerance_ms: float = 20.0
    max_pose_jump_m: float = 0.10
    max_pose_jump_deg: float = 10.0
    camera: Camera | None = None
    camera_pose: np.ndarray | None = None
    T_rig_cam: np.ndarray | None = None
    T_world_base: np.ndarray | None = None
    ignore_joints: tuple[str, ...] = ()
    notes: str = ""
    overwrite: bool = False
    progress: bool = False

    def __post_init__(self):
        if self.tolerance_ms < 0 or self.max_pose_jump_m <= 0 or self.max_pose_jump_deg <= 0:
            raise ValueError("tolerance must be >= 0 and pose jump thresholds > 0")
        if self.camera_pose is not None and (self.T_rig_cam is not None or self.T_world_base is not None):
            raise ValueError("a fixed camera pose is already the optical frame in the base frame; "
                             "T_rig_cam and T_world_base apply to pose streams only")


@dataclasses.dataclass
class ImageRef:
    """One source image: capture time (ns), where it is, and the reader's key to decode it."""

    stamp_ns: int
    where: Where
    key: object


@dataclasses.dataclass
class RawRecording:
    """What a source reader found. ``poses`` (x..qw samples of ``T_world_rig``) is None for a
    fixed camera pose. ``decode(refs)`` yields RGB uint8 ``(H, W, 3)`` for ``refs``, in order."""

    source: str
    kind: str
    images: list[ImageRef]
    joints: StreamBuilder
    poses: StreamBuilder | None
    decode: Callable[[list[ImageRef]], Iterator[np.ndarray]]
    camera: Camera | None = None
    intrinsics_from: str = ""
    pose_from: str = ""
    ignored: dict = dataclasses.field(default_factory=dict)


def check_output(out: Path, overwrite: bool) -> None:
    """Fail early if ``out`` exists and may not be replaced."""
    if Path(out).exists() and not overwrite:
        raise FileExistsError(f"{out} exists; choose another output or pass overwrite (--overwrite)")


def _frame_poses(raw: RawRecording, opts: ImportOptions, stamps: np.ndarray, tol_ns: int):
    """Per-image pose index into the pose stream (-1 none) and camera poses ``(M, 7)`` indexed by it."""
    if raw.poses is None:
        return np.zeros(len(stamps), dtype=np.int64), np.asarray(opts.camera_pose, dtype=np.float64)[None]
    p_stamps, p_values = raw.poses.arrays()
    cam = compose_poses(p_values, base_from_world(opts.T_world_base), opts.T_rig_cam) if len(p_values) \
        else np.zeros((0, 7))
    return match_nearest(stamps, p_stamps, tol_ns), cam


def _jump_flags(raw: RawRecording, opts: ImportOptions, p_idx: np.ndarray, cam: np.ndarray) -> np.ndarray:
    """True for images whose pose jumps from the previous or next image with a pose."""
    flags = np.zeros(len(p_idx), dtype=bool)
    if raw.poses is None:  # a fixed camera pose never jumps
        return flags
    have = np.flatnonzero(p_idx >= 0)
    dist, angle = pose_steps(cam[p_idx[have]])
    for k in np.flatnonzero((dist > opts.max_pose_jump_m) | (angle > opts.max_pose_jump_deg)):
        a, b = have[k], have[k + 1]
        flags[[a, b]] = True
        log.warning("camera pose jumps %.3f m, %.1f deg between image %s (pose %s) and image %s (pose %s); "
                    "both frames dropped", dist[k], angle[k], raw.images[a].where, raw.poses.wheres[p_idx[a]],
                    raw.images[b].where, raw.poses.wheres[p_idx[b]])
    return flags


def _decide(raw: RawRecording, opts: ImportOptions):
    """Match every image; returns drop reasons (None = kept), joint and pose indices, camera poses."""
    tol_ns = round(opts.tolerance_ms * 1e6)
    stamps = np.array([im.stamp_ns for im in raw.images], dtype=np.int64)
    j_stamps, _ = raw.joints.arrays()
    j_idx = match_nearest(stamps, j_stamps, tol_ns)
    p_idx, cam = _frame_poses(raw, opts, stamps, tol_ns)
    jumps = _jump_flags(raw, opts, p_idx, cam)
    reasons = [None] * len(stamps)
    for i in range(len(stamps)):
        if j_idx[i] < 0:
            reasons[i] = DROP_REASONS[0]
        elif p_idx[i] < 0:
            reasons[i] = DROP_REASONS[1]
        elif jumps[i]:
            reasons[i] = DROP_REASONS[2]
        if reasons[i] and reasons[i] != DROP_REASONS[2]:
            log.info("dropped %s: %s", raw.images[i].where, reasons[i])
    return reasons, j_idx, p_idx, cam


def _offset_ms(stamps: np.ndarray, partner: np.ndarray) -> float:
    return float(np.max(np.abs(stamps - partner)) / 1e6) if len(stamps) else 0.0


def _summary(raw: RawRecording, opts: ImportOptions, out: Path, camera: Camera, reasons, kept, j_idx, p_idx) -> dict:
    stamps = np.array([raw.images[i].stamp_ns for i in kept], dtype=np.int64)
    j_stamps, _ = raw.joints.arrays()
    pose_offset = 0.0
    if raw.poses is not None and len(kept):
        pose_offset = _offset_ms(stamps, raw.poses.arrays()[0][p_idx[kept]])
    return {
        "source": raw.source, "kind": raw.kind, "output": str(out), "robot": opts.robot,
        "images": len(raw.images), "kept": len(kept),
        "dropped": {r: sum(1 for x in reasons if x == r) for r in DROP_REASONS},
        "ignored": dict(raw.ignored),
        "joint_samples": len(j_stamps),
        "pose_samples": None if raw.poses is None else len(raw.poses.stamps),
        "max_offset_ms": {"joints": _offset_ms(stamps, j_stamps[j_idx[kept]]) if len(kept) else 0.0,
                          "pose": pose_offset},
        "tolerance_ms": opts.tolerance_ms,
        "max_pose_jump": {"m": opts.max_pose_jump_m, "deg": opts.max_pose_jump_deg},
        "camera": camera.to_dict(), "intrinsics_from": raw.intrinsics_from, "camera_pose_from": raw.pose_from,
    }


def _write_frames(raw: RawRecording, camera: Camera, kept: np.ndarray, tmp: Path, progress: bool) -> np.ndarray:
    """Decode, size-check and write the kept images as frames 0..N-1; returns the image index of each frame."""
    position = {id(raw.images[i]): int(i) for i in kept}
    refs = [raw.images[i] for i in kept]
    written = []
    bar = tqdm(raw.decode(refs), total=len(refs), desc="import", unit="frame", disable=not progress)
    for k, (ref, rgb) in enumerate(bar):
        h, w = rgb.shape[:2]
        if (w, h) != (camera.width, camera.height):
            raise ref.where.error(f"{w}x{h}", f"image size differs from the camera's "
                                  f"{camera.width}x{camera.height} ({raw.intrinsics_from})")
        write_frame(tmp, k, rgb)
        written.append(position[id(ref)])
    if len(written) != len(refs):
        raise RuntimeError(f"{raw.source}: {len(refs)} images to write but the source gave {len(written)}")
    return np.array(written, dtype=np.int64)


def _self_check(tmp: Path) -> None:
    """Read the finished recording back with the recording readers; raise on any problem."""
    _, spec = read_meta(tmp)
    for reader in (read_joints(tmp, spec), read_poses(tmp)):
        if reader[2]:
            raise reader[2][0]


def _publish(tmp: Path, out: Path, overwrite: bool) -> None:
    """Rename the finished ``tmp`` to ``out`` (same folder, so the rename is atomic)."""
    old = None
    if out.exists():
        if not overwrite:
            raise FileExistsError(f"{out} exists; choose another output or pass overwrite (--overwrite)")
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
        os.replace(out, old / out.name)
    os.replace(tmp, out)
    if old is not None:
        shutil.rmtree(old)


def assemble(raw: RawRecording, out: Path, opts: ImportOptions) -> dict:
    """Match, check and write ``raw`` as the recording ``out``; returns the summary dict.

    The recording is built in a hidden sibling folder ``.<name>.import-*`` (which
    :func:`armpose.recording.find_recordings` skips) and renamed to ``out`` only when complete;
    on any error the partial folder is removed and ``out`` is untouched.
    """
    out = Path(out)
    spec = get_robot(opts.robot)
    camera = opts.camera or raw.camera
    if camera is None:
        raise ValueError(f"{raw.source}: no camera intrinsics: give --intrinsics cam.json"
                         + (" or a CameraInfo topic" if raw.kind == "bag" else ""))
    raw.intrinsics_from = raw.intrinsics_from if opts.camera is None else "given intrinsics"
    reasons, j_idx, p_idx, cam = _decide(raw, opts)
    kept = np.array([i for i, r in enumerate(reasons) if r is None], dtype=np.int64)
    summary = _summary(raw, opts, out, camera, reasons, kept, j_idx, p_idx)
    if not len(kept):
        raise NothingKeptError(summary)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.import-", dir=out.parent))
    try:
        frames = _write_frames(raw, camera, kept, tmp, opts.progress)
        meta = RecordingMeta(spec.name, camera, "recorded", opts.notes)
        _, joint_values = raw.joints.arrays()
        write_tables(tmp, meta, spec, np.arange(len(frames)), joint_values[j_idx[frames]], cam[p_idx[frames]],
                     extra={"import": {k: summary[k] for k in ("source", "kind", "images", "kept", "dropped",
                                                               "tolerance_ms", "camera_pose_from")}})
        _self_check(tmp)
        _publish(tmp, out, opts.overwrite)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    log.info("imported %d of %d images from %s into %s", len(kept), len(raw.images), raw.source, out)
    return summary

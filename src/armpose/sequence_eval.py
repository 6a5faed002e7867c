"""Sequence metrics on the recorded test recordings: raw per-frame output against causal filters.

Every recorded test recording is a video: its frames in order, frame k at ``k / fps`` seconds.
The network's per-frame joints (camera optical frame, metres) are compared, unfiltered and after
each causal filter of ``armpose predict --sequence`` (:func:`armpose.sequence.make_filter` with its
default tuning at ``fps``), with the labelled joints:

- ``joint_median_cm``: median Euclidean joint error over every valid joint of every frame (cm);
- ``jitter_mm``: :func:`armpose.tracking.jitter`, the mean magnitude of the second difference
  over time (mm per frame^2), averaged over the recording's valid joints and then over recordings.
  The labels' own jitter (``labels``) is what the true motion leaves: small for a static camera;
  a moving camera's labels also carry its per-frame mocap noise (about 10 mm per frame^2 at the
  default 0.1 deg RMS, 2-3 m away), so compare filters on the ``static`` block first;
- ``jitter_reduction``: unfiltered jitter over filtered jitter (x), and ``jitter_reduction_pct``
  ``100 * (1 - filtered / unfiltered)``.

Blocks are given for all recorded test recordings, per family and per camera kind (``static``:
tripod recordings, ``moving``: handheld ones). :func:`metrics_by_recording` gives the per-frame
metrics of each recording on its own.
"""
from __future__ import annotations

import logging

import numpy as np

from armpose.labels.dataset import SOURCE_CODES
from armpose.metrics import frame_depth_ratio, summarise
from armpose.sequence import make_filter
from armpose.tracking import filter_sequence, jitter

log = logging.getLogger(__name__)

RAW = "unfiltered"


def recorded_sequences(truth: dict, arrays: dict) -> dict[int, np.ndarray]:
    """Recorded test recordings: recording index -> positions into ``truth`` sorted by frame
    (at least 3 frames: fewer have no second difference)."""
    out = {}
    recorded = truth["source"] == SOURCE_CODES["recorded"]
    for r in np.unique(truth["recording"][recorded]):
        pos = np.flatnonzero(recorded & (truth["recording"] == r))
        if len(pos) >= 3:
            out[int(r)] = pos[np.argsort(arrays["frame"][truth["row"][pos]], kind="stable")]
    return out


def sequence_errors(raw: np.ndarray, labels: np.ndarray, times: np.ndarray, filters: list[str],
                    fps: float) -> dict[str, dict[str, np.ndarray | float]]:
    """One recording's errors: for ``unfiltered``, each filter in ``filters`` and ``labels``,
    ``dist_m`` (per frame and joint, metres; not for ``labels``) and ``jitter_m`` (mean over joints,
    metres per frame^2).

    ``raw`` and ``labels`` ``(T, J, 3)`` hold the valid joints only (camera frame, metres);
    ``times`` ``(T,)`` seconds (frame / fps: a dropped frame leaves a gap the filters bridge)."""
    tracks = {RAW: np.asarray(raw, np.float64)}
    for name in filters:
        tracks[name] = filter_sequence(raw, make_filter(name, fps), times)
    out = {name: {"dist_m": np.linalg.norm(v - labels, axis=-1), "jitter_m": float(np.nanmean(jitter(v)))}
           for name, v in tracks.items()}
    out["labels"] = {"jitter_m": float(np.nanmean(jitter(labels)))}
    return out


def summarise_sequences(per_rec: list[dict], frames: int, filters: list[str]) -> dict:
    """One block over recordings' :func:`sequence_errors`: errors pooled, jitter averaged, reductions."""
    if not per_rec:
        return {"recordings": 0}
    block = {"recordings": len(per_rec), "frames": frames,
             "labels": {"jitter_mm": 1000 * float(np.mean([e["labels"]["jitter_m"] for e in per_rec]))}}
    for name in (RAW, *filters):
        dist = np.concatenate([e[name]["dist_m"].ravel() for e in per_rec])
        block[name] = {"joint_median_cm": 100 * float(np.nanmedian(dist)),
                       "jitter_mm": 1000 * float(np.mean([e[name]["jitter_m"] for e in per_rec]))}
    raw = block[RAW]["jitter_mm"]
    for name in filters:
        filt = block[name]["jitter_mm"]
        block[name]["jitter_reduction"] = raw / filt if filt > 0 else float("nan")
        block[name]["jitter_reduction_pct"] = 100 * (1 - filt / raw) if raw > 0 else float("nan")
    return block


def camera_kind(recording: dict) -> str:
    """``static`` for a tripod recording of the index, ``moving`` for a handheld one."""
    return "static" if recording.get("static_camera") else "moving"


def sequence_metrics(pred: dict, truth: dict, index: dict, arrays: dict, families: list[str], fps: float,
                     filters: list[str]) -> dict:
    """Sequence metrics of every recorded test recording (:func:`recorded_sequences`):
    ``{"fps", "filters", "all", "by_family", "by_camera"}`` of :func:`summarise_sequences` blocks;
    ``{"recordings": 0}`` when there are none. ``families`` has one entry per robot type index."""
    seqs = recorded_sequences(truth, arrays)
    errs, fam, cam, frames = {}, {}, {}, {}
    for r, pos in seqs.items():
        valid = truth["joint_valid"][pos].all(axis=0)
        times = arrays["frame"][truth["row"][pos]].astype(np.float64) / fps
        errs[r] = sequence_errors(pred["joints"][pos][:, valid], truth["joints"][pos][:, valid], times, filters, fps)
        fam[r], frames[r] = families[int(truth["type"][pos[0]])], len(pos)
        cam[r] = camera_kind(index["recordings"][r])

    def block(recs: list[int]) -> dict:
        return summarise_sequences([errs[r] for r in recs], sum(frames[r] for r in recs), filters)

    out = {"fps": fps, "filters": list(filters), "all": block(list(errs))}
    if not errs:
        return out
    out["by_family"] = {f: block([r for r in errs if fam[r] == f]) for f in dict.fromkeys(fam.values())}
    out["by_camera"] = {c: block([r for r in errs if cam[r] == c]) for c in ("static", "moving")
                        if c in cam.values()}
    a = out["all"]
    log.info("sequences: %d recordings, jitter %.2f mm/frame^2 unfiltered, %s", a["recordings"], a[RAW]["jitter_mm"],
             ", ".join(f"{f} {a[f]['jitter_mm']:.2f} ({a[f]['jitter_reduction']:.1f}x less)" for f in filters))
    return out


RECORDING_KEYS = ("frames", "mask_accuracy", "type_accuracy", "joint_median_cm", "base_median_cm",
                  "joint_median_true_depth_cm")


def metrics_by_recording(pred: dict, truth: dict, index: dict, arrays: dict, pixel_scale: float | np.ndarray) -> dict:
    """Per recorded test recording, keyed by its name in ``index["recordings"]``: ``robot``,
    ``camera`` (``static``: tripod, ``moving``: handheld), the :data:`RECORDING_KEYS` of
    :func:`armpose.metrics.summarise` and ``frame_depth_ratio_median``, the median over its frames
    of :func:`armpose.metrics.frame_depth_ratio` (predicted over true depth that a frame's joints
    share; below 1: the robot placed too close). One recording is one scene, lighting and camera
    path, so a family's median can hide one recording far off the others."""
    out = {}
    for r, pos in recorded_sequences(truth, arrays).items():
        rec = index["recordings"][r]
        m = summarise(pred, truth, pos, pixel_scale)
        ratio = frame_depth_ratio(pred["joints"][pos], truth["joints"][pos], truth["joint_valid"][pos])
        out[rec["name"]] = {"robot": rec["robot"], "camera": camera_kind(rec),
                            **{k: m[k] for k in RECORDING_KEYS},
                            "frame_depth_ratio_median": float(np.nanmedian(ratio)) if np.isfinite(ratio).any()
                            else float("nan")}
    return out

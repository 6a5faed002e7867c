"""The kinematic fit's weights for one trained network, measured on training frames it never saw.

:mod:`armpose.kinematic_fit` holds the robot model to the rays of the network's points (to
``ray_sigma``) and, loosely, to their depths (``log_depth_sigma``). How good the rays and depths
are depends on the network and the robot type: on our held-out frames the transfer model's
Panda rays are twice as far off as the UR ones. So a training stage with ``fit_sigmas: true``
measures both per robot type, after training, on up to ``HELD_OUT_PER_TYPE`` frames per type of
the training split that the stage did not train on (never the test split), through the zoom test
when the network was trained for it, and stores them in its checkpoint (``extra.fit_sigmas``):

- ``ray_sigma``: the median distance between predicted and true rays (``x/z, y/z``) over the base
  and valid joints;
- ``log_depth_sigma``: the median ``|log(z_pred / z_true)|`` times the square root of the points
  per frame (a frame's depth errors are nearly one shared error; see :mod:`armpose.kinematic_fit`);
- ``depth_ratio``: over the frames the network *types* as this robot (the fit is chosen by the
  predicted type), the median of :func:`armpose.metrics.frame_depth_ratio`, predicted over true
  depth; the fit divides the points by it (``benchmarks/depth_bias.py`` checks it on the test split).

``evaluate`` and ``armpose predict --fit`` read them with :func:`checkpoint_fit_sigmas`; a type
without them (no held-out frames) uses :class:`armpose.kinematic_fit.FitSettings`' defaults.
"""
from __future__ import annotations

import io
import logging
from pathlib import Path

import numpy as np
import torch

from armpose.data import LabelledFrames, split_indices
from armpose.io import atomic_write_bytes
from armpose.labels.dataset import load_dataset
from armpose.metrics import frame_depth_ratio
from armpose.robots import get_robot
from armpose.train import load_checkpoint, load_model
from armpose.zoom_test import settings_from_config, trained_for_zoom, zoom_refine

log = logging.getLogger(__name__)
HELD_OUT_PER_TYPE = 200
FIT_SIGMAS_VERSION = 2   # 2: with depth_ratio. A checkpoint measured by another version is measured again


def held_out_rows(data_dir: Path, used: np.ndarray, types: list[int], seed: int,
                  per_type: int = HELD_OUT_PER_TYPE) -> np.ndarray:
    """Training-split rows of robot classes ``types`` outside ``used``, at most ``per_type`` of each,
    drawn with ``seed``; sorted."""
    arrays, _ = load_dataset(Path(data_dir))
    rows = np.setdiff1d(split_indices(arrays, "train"), np.asarray(used, np.int64))
    robot = np.asarray(arrays["robot"])[rows]
    rng = np.random.default_rng(int(seed))
    return np.sort(np.concatenate([rng.permutation(rows[robot == t])[:per_type] for t in types] or [np.zeros(0, np.int64)]))


def sigmas_from_predictions(pred: dict, truth: dict, robot_types: list[str]) -> dict:
    """``{robot type: {ray_sigma, log_depth_sigma, frames[, depth_ratio]}}`` from per-frame
    predictions (the keys of :func:`armpose.evaluate.predict_split`) against the truth: the sigmas
    per true robot type, ``depth_ratio`` per predicted type (``pred["type"]``; absent for a type
    no frame was typed as)."""
    p = np.concatenate([pred["base"][:, None], pred["joints"]], axis=1)
    t = np.concatenate([truth["base"][:, None], truth["joints"]], axis=1)
    valid = np.concatenate([np.ones((len(p), 1), bool), truth["joint_valid"]], axis=1) & (p[..., 2] > 1e-3)
    with np.errstate(divide="ignore", invalid="ignore"):      # unused slots, masked out below
        ray = np.linalg.norm(p[..., :2] / p[..., 2:] - t[..., :2] / t[..., 2:], axis=-1)
        depth = np.abs(np.log(p[..., 2] / t[..., 2]))
    out = {}
    for k, name in enumerate(robot_types):
        frames = truth["type"] == k
        if frames.any():
            m = valid & frames[:, None]
            out[name] = {"ray_sigma": round(float(np.median(ray[m])), 5),
                         "log_depth_sigma": round(float(np.median(depth[m]) * np.sqrt(m.sum() / frames.sum())), 5),
                         "frames": int(frames.sum())}
    for name, r in depth_ratios(pred, truth, robot_types).items():
        if name in out:
            out[name]["depth_ratio"] = round(r, 5)
    return out


def depth_ratios(pred: dict, truth: dict, robot_types: list[str]) -> dict[str, float]:
    """``{robot type: ratio}``: over the frames ``pred["type"]`` types as each robot, the median of
    :func:`armpose.metrics.frame_depth_ratio` (predicted over true depth); types no frame was typed
    as are left out."""
    ratio = frame_depth_ratio(pred["joints"], truth["joints"], truth["joint_valid"])
    out = {}
    for k, name in enumerate(robot_types):
        typed = (np.asarray(pred["type"]) == k) & np.isfinite(ratio)
        if typed.any():
            out[name] = float(np.median(ratio[typed]))
    return out


@torch.no_grad()
def held_out_points(model, config: dict, data_dir: Path, rows: np.ndarray, batch_size: int = 32) -> tuple[dict, dict]:
    """``(pred, truth)``: the network's base, joints and type on ``rows`` (through the zoom test when
    it was trained for it, as the fit will see them) and the labels, per-frame numpy arrays."""
    frames = LabelledFrames(Path(data_dir), rows)
    counts = [get_robot(t).num_joints for t in frames.robot_types]
    zoom, settings = trained_for_zoom(config), settings_from_config(config)
    threshold = float(getattr(model, "mask_threshold", 0.0))
    parts = {"joints": [], "base": [], "type": []}
    for start in range(0, len(frames), batch_size):
        items = [frames[i] for i in range(start, min(start + batch_size, len(frames)))]
        images = torch.stack([it["image"] for it in items]).contiguous(memory_format=torch.channels_last)
        out = model(images)
        if zoom:
            cams = torch.stack([it["intrinsics"] for it in items])
            out = zoom_refine(model, images, out, cams, settings, counts, threshold)
        for k in ("joints", "base"):
            parts[k].append(out[k].double().numpy())
        parts["type"].append(out["type_logits"].argmax(1).numpy())
    arrays, _ = load_dataset(Path(data_dir))
    truth = {"joints": np.asarray(arrays["joints"][rows], np.float64), "base": np.asarray(arrays["base"][rows], np.float64),
             "joint_valid": np.asarray(arrays["joint_valid"][rows], bool), "type": np.asarray(arrays["robot"][rows], np.int64)}
    return {k: np.concatenate(v) for k, v in parts.items()}, truth


def add_fit_sigmas(checkpoint: Path, data_dir: Path, used_rows: np.ndarray, seed: int) -> dict:
    """Measure the fit sigmas of ``checkpoint`` on held-out training frames of its robot types
    (outside ``used_rows``) and store them in its ``extra.fit_sigmas`` (atomically). A checkpoint
    that holds them already, measured by this :data:`FIT_SIGMAS_VERSION`, is left as it is (a
    resumed, finished stage); one measured by another version is measured again. Returns the sigmas."""
    ckpt = load_checkpoint(Path(checkpoint))
    if "fit_sigmas" in ckpt["extra"] and ckpt["extra"].get("fit_sigmas_version") == FIT_SIGMAS_VERSION:
        return ckpt["extra"]["fit_sigmas"]
    model, config = load_model(Path(checkpoint))
    types = list(config["base"]["robot_types"])
    rows = held_out_rows(data_dir, used_rows, [types.index(r) for r in config["cfg"]["robots"]], seed)
    sigmas = sigmas_from_predictions(*held_out_points(model, config, data_dir, rows), types) if len(rows) else {}
    ckpt["extra"]["fit_sigmas"], ckpt["extra"]["fit_sigmas_version"] = sigmas, FIT_SIGMAS_VERSION
    buf = io.BytesIO()
    torch.save(ckpt, buf)
    atomic_write_bytes(Path(checkpoint), buf.getvalue())
    log.info("%s: kinematic fit sigmas on %d held-out frames: %s", checkpoint, len(rows), sigmas)
    return sigmas


def checkpoint_fit_sigmas(checkpoint: Path) -> dict:
    """The per-type fit sigmas stored in ``checkpoint`` (empty when none were measured)."""
    return dict(load_checkpoint(Path(checkpoint))["extra"].get("fit_sigmas", {}))

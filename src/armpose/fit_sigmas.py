"""The kinematic fit's weights for one trained network, measured on training frames it never saw.

:mod:`armpose.kinematic_fit` holds the robot model to the rays of the network's points (to
``ray_sigma``) and, loosely, to their depths (``log_depth_sigma``). How good the rays and depths
are depends on the network and the robot type: on our held-out frames the transfer model's
Panda rays are twice as far off as the UR ones. So a training stage with ``fit_sigmas: true``
measures both per robot type, after training, on up to ``HELD_OUT_PER_TYPE`` frames per type of
the training split that the stage did not train on (never the test split), through the zoom test
when the network was trained for it, and with ``fit_sigmas_on_mirror: true`` on the mirror test's
passes (the estimates ``evaluate`` with ``zoom_on_mirror`` fits), and stores them in its
checkpoint (``extra.fit_sigmas``, with ``extra.fit_sigmas_on_mirror``):

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

from armpose.data import split_indices
from armpose.evaluate import predict_split
from armpose.io import atomic_write_bytes
from armpose.labels.dataset import load_dataset
from armpose.metrics import frame_depth_ratio
from armpose.train import load_checkpoint, load_model
from armpose.zoom_test import settings_from_config, trained_for_zoom

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


def held_out_points(model, config: dict, data_dir: Path, rows: np.ndarray, batch_size: int = 32,
                    on_mirror: bool = False) -> tuple[dict, dict]:
    """``(pred, truth)`` of :func:`armpose.evaluate.predict_split` on ``rows``: the network's base,
    joints and type as the fit will see them, i.e. through the zoom test when the network was
    trained for it, and with ``on_mirror`` on the mirror test's passes (both looks mirror-averaged,
    as ``evaluate`` with ``zoom_on_mirror`` and ``armpose predict --mirror --zoom --fit`` fit them)."""
    zoom = trained_for_zoom(config)
    pred, truth = predict_split(model, Path(data_dir), rows=rows, batch_size=batch_size, mirror=on_mirror,
                                zoom=zoom, zoom_settings=settings_from_config(config),
                                zoom_on_mirror=on_mirror and zoom)
    seen = pred["zoom"] if zoom else pred["mirror"] if on_mirror else pred
    return {k: seen[k] for k in ("joints", "base", "type")}, truth


def measure_fit_sigmas(model, config: dict, data_dir: Path, used_rows: np.ndarray, seed: int,
                       on_mirror: bool = False) -> tuple[np.ndarray, dict]:
    """``(rows, sigmas)``: the held-out training rows of the checkpoint's stage robots (outside
    ``used_rows``, :func:`held_out_rows`) and the per-type sigmas measured on them
    (:func:`sigmas_from_predictions` of :func:`held_out_points`); nothing is written."""
    types = list(config["base"]["robot_types"])
    rows = held_out_rows(data_dir, used_rows, [types.index(r) for r in config["cfg"]["robots"]], seed)
    if not len(rows):
        return rows, {}
    return rows, sigmas_from_predictions(*held_out_points(model, config, data_dir, rows, on_mirror=on_mirror), types)


def add_fit_sigmas(checkpoint: Path, data_dir: Path, used_rows: np.ndarray, seed: int,
                   on_mirror: bool = False) -> dict:
    """Measure the fit sigmas of ``checkpoint`` on held-out training frames of its robot types
    (outside ``used_rows``; on the mirror test's passes with ``on_mirror``, see
    :func:`held_out_points`) and store them in its ``extra.fit_sigmas`` (atomically), with
    ``extra.fit_sigmas_on_mirror``. A checkpoint that holds them already, measured by this
    :data:`FIT_SIGMAS_VERSION` on the same passes, is left as it is (a resumed, finished stage);
    one measured by another version or on the other passes is measured again. Returns the sigmas."""
    ckpt = load_checkpoint(Path(checkpoint))
    extra = ckpt["extra"]
    if ("fit_sigmas" in extra and extra.get("fit_sigmas_version") == FIT_SIGMAS_VERSION
            and bool(extra.get("fit_sigmas_on_mirror", False)) == bool(on_mirror)):
        return extra["fit_sigmas"]
    model, config = load_model(Path(checkpoint))
    rows, sigmas = measure_fit_sigmas(model, config, data_dir, used_rows, seed, on_mirror)
    extra["fit_sigmas"], extra["fit_sigmas_version"] = sigmas, FIT_SIGMAS_VERSION
    extra["fit_sigmas_on_mirror"] = bool(on_mirror)
    buf = io.BytesIO()
    torch.save(ckpt, buf)
    atomic_write_bytes(Path(checkpoint), buf.getvalue())
    log.info("%s: kinematic fit sigmas on %d held-out frames (%s passes): %s", checkpoint, len(rows),
             "mirror-averaged" if on_mirror else "single", sigmas)
    return sigmas


def checkpoint_fit_sigmas(checkpoint: Path) -> dict:
    """The per-type fit sigmas stored in ``checkpoint`` (empty when none were measured)."""
    return dict(load_checkpoint(Path(checkpoint))["extra"].get("fit_sigmas", {}))

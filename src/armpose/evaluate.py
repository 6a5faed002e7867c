"""Evaluate a trained checkpoint on the held-out split: predictions, then metrics per family and type.

:func:`predict_split` runs the network over the test frames of ``data/labels`` (the images
exactly as stored, no augmentation) and returns per-frame predictions and truth;
:func:`evaluate_checkpoint` adds the metrics of :mod:`armpose.metrics` per robot family (UR,
KUKA, Panda: the paper's Table II rows), per robot type, per data source (synthetic,
recorded) and the type confusion matrix. All positions are metres in the camera optical frame.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from armpose.data import LabelledFrames, split_indices
from armpose.kinematic_fit import FitSettings, fit_predictions
from armpose.labels.dataset import SOURCE_CODES, load_dataset
from armpose.metrics import confusion_matrix, mask_counts, summarise
from armpose.mirror_test import MirrorAveraged, forward_with_mirror
from armpose.model import predicted_mask
from armpose.robots import get_robot
from armpose.inference import load_inference_model
from armpose.train import load_checkpoint, to_channels_last  # noqa: F401 (load_checkpoint re-exported)
from armpose.zoom_test import settings_from_config, zoom_refine

log = logging.getLogger(__name__)


@torch.no_grad()
def predict_split(model, data_dir: Path, split: str = "test", batch_size: int = 32,
                  device: torch.device | str = "cpu", rows: np.ndarray | None = None,
                  mirror: bool = False, zoom: bool = False, zoom_settings: dict | None = None,
                  fit: FitSettings | None = None, fit_sigmas: dict | None = None,
                  keep_masks: bool = False, zoom_on_mirror: bool = False) -> tuple[dict, dict]:
    """``(pred, truth)`` dicts of per-frame numpy arrays over ``rows`` (default: every frame of
    ``split``). ``pred``: joints, base, type, type_probs, mask_counts; ``truth``: joints,
    joint_valid, base, type, intrinsics, distance, source, recording, row. With ``mirror``,
    ``pred["mirror"]`` holds the same keys for the mirror test (:mod:`armpose.mirror_test`),
    from the same forward passes; with ``zoom``, ``pred["zoom"]`` those of the zoom test
    (:mod:`armpose.zoom_test` with ``zoom_settings``: one more pass per batch; on the single
    pass, or with ``zoom_on_mirror`` (which needs ``mirror``) on the mirror test's, both looks
    mirror-averaged as in ``armpose predict --mirror --zoom``); with ``fit``, ``pred["fit"]``
    those of the kinematic fit (:mod:`armpose.kinematic_fit`) to the zoom test's outputs (the
    single pass's without ``zoom``; per-type weights ``fit_sigmas``, :mod:`armpose.fit_sigmas`),
    plus its joint angles ``q`` and poses ``T_cam_base``. With ``keep_masks``, each set also holds
    ``masks`` (N, H, W) bool, the predicted masks in network-input pixels, and ``truth["masks"]``
    the labelled ones."""
    if zoom_on_mirror and not (zoom and mirror):
        raise ValueError("zoom_on_mirror runs the zoom test on the mirror test's passes: it needs zoom and mirror")
    arrays, _ = load_dataset(Path(data_dir))
    rows = split_indices(arrays, split) if rows is None else np.asarray(rows, np.int64)
    frames = LabelledFrames(Path(data_dir), rows)
    single, averaged, zoomed = _Collected(keep_masks), _Collected(keep_masks), _Collected(keep_masks)
    true_masks = []
    if zoom:
        threshold = float(getattr(model, "mask_threshold", 0.0))
        joint_counts = [get_robot(t).num_joints for t in frames.robot_types]
    for start in tqdm(range(0, len(frames), batch_size), desc="evaluate", unit="batch", dynamic_ncols=True):
        items = [frames[i] for i in range(start, min(start + batch_size, len(frames)))]
        images = torch.stack([it["image"] for it in items]).to(device)
        masks = torch.stack([it["mask"] for it in items]).numpy() > 0.5
        if keep_masks:
            true_masks.append(masks)
        intrinsics = torch.stack([it["intrinsics"] for it in items]).to(device)
        if mirror:
            out, mean = forward_with_mirror(model, images, intrinsics[:, 0], intrinsics[:, 2])
            averaged.add(model, mean, masks)
        else:
            out = model(to_channels_last(images))
        single.add(model, out, masks)
        if zoom:
            first, forward = ((mean, MirrorAveraged(model, intrinsics[:, 0], intrinsics[:, 2])) if zoom_on_mirror
                              else (out, model))
            zoomed.add(model, zoom_refine(forward, images, first, intrinsics, zoom_settings, joint_counts, threshold),
                       masks)
    pred = single.arrays()
    if mirror:
        pred["mirror"] = averaged.arrays()
    if zoom:
        pred["zoom"] = zoomed.arrays()
    if fit is not None:
        pred["fit"] = fitted(pred["zoom"] if zoom else pred, frames.robot_types, fit, fit_sigmas)
    truth = {"joints": np.asarray(arrays["joints"][rows], np.float64),
             "joint_valid": np.asarray(arrays["joint_valid"][rows], bool),
             "base": np.asarray(arrays["base"][rows], np.float64),
             "type": np.asarray(arrays["robot"][rows], np.int64),
             "intrinsics": np.asarray(arrays["intrinsics"][rows], np.float64),
             "distance": np.asarray(arrays["distance"][rows], np.float64),
             "source": np.asarray(arrays["source"][rows], np.int64),
             "recording": np.asarray(arrays["recording"][rows], np.int64),
             "row": rows}
    if keep_masks:
        truth["masks"] = np.concatenate(true_masks) if true_masks else np.zeros((0, 0, 0), bool)
    return pred, truth


class _Collected:
    """Per-batch network outputs gathered into the per-frame arrays of :func:`predict_split`."""

    def __init__(self, keep_masks: bool = False):
        self.joints, self.base, self.probs, self.counts, self.masks = [], [], [], [], []
        self.keep_masks = keep_masks

    def add(self, model, out: dict, masks: np.ndarray) -> None:
        self.joints.append(out["joints"].float().cpu().numpy())
        self.base.append(out["base"].float().cpu().numpy())
        self.probs.append(out["type_logits"].float().softmax(-1).cpu().numpy())
        predicted = predicted_mask(model, out["mask_logits"][:, 0]).cpu().numpy()
        self.counts.append(mask_counts(predicted, masks))
        if self.keep_masks:
            self.masks.append(predicted)

    def arrays(self) -> dict:
        cat = (lambda xs, shape: np.concatenate(xs) if xs else np.zeros(shape))
        type_probs = cat(self.probs, (0, 0))
        out = {"joints": cat(self.joints, (0, 0, 3)), "base": cat(self.base, (0, 3)), "type_probs": type_probs,
               "type": type_probs.argmax(1) if len(type_probs) else np.zeros(0, np.int64),
               "mask_counts": cat(self.counts, (0, 4))}
        if self.keep_masks:
            out["masks"] = cat(self.masks, (0, 0, 0)).astype(bool)
        return out


def fitted(pred: dict, robot_types: list[str], settings: FitSettings, sigmas: dict | None = None) -> dict:
    """``pred`` (per-frame arrays of :func:`predict_split`) with its joints and base replaced by
    the kinematic fit of each frame's predicted type, plus ``q`` and ``T_cam_base``."""
    fit = fit_predictions(pred["joints"], pred["base"], pred["type"], robot_types, settings, sigmas)
    return {**{k: v for k, v in pred.items() if k in ("type_probs", "type", "mask_counts")},
            "joints": fit["joints"], "base": fit["base"], "q": fit["q"], "T_cam_base": fit["T_cam_base"]}


def family_of(robot_types: list[str]) -> list[str]:
    """The family of each robot type, from the registry (``ur3`` -> ``UR``)."""
    return [get_robot(name).family for name in robot_types]


def metrics_by_group(pred: dict, truth: dict, robot_types: list[str], pixel_scale: float) -> dict:
    """``{"all", "by_family", "by_type", "by_source", "confusion"}`` over the frames of ``truth``."""
    families = family_of(robot_types)
    fam_of_frame = np.array([families[t] for t in truth["type"]]) if len(truth["type"]) else np.array([])
    result = {"all": summarise(pred, truth, np.arange(len(truth["type"])), pixel_scale),
              "by_family": {}, "by_type": {}, "by_source": {}}
    for fam in dict.fromkeys(families):
        result["by_family"][fam] = summarise(pred, truth, np.flatnonzero(fam_of_frame == fam), pixel_scale)
    for t, name in enumerate(robot_types):
        result["by_type"][name] = summarise(pred, truth, np.flatnonzero(truth["type"] == t), pixel_scale)
    for source, code in SOURCE_CODES.items():
        rows = np.flatnonzero(truth["source"] == code)
        if rows.size:
            result["by_source"][source] = {
                "all": summarise(pred, truth, rows, pixel_scale),
                "by_family": {fam: summarise(pred, truth, rows[fam_of_frame[rows] == fam], pixel_scale)
                              for fam in dict.fromkeys(families) if (fam_of_frame[rows] == fam).any()}}
    result["confusion"] = {"labels": list(robot_types),
                           "matrix": confusion_matrix(pred["type"], truth["type"], len(robot_types)).tolist()}
    return result


def pixel_scale_of(base: dict, truth: dict) -> np.ndarray:
    """Network-input pixels per pixel of the canonical camera (``base.camera``), the unit of PCK:
    one per frame, its network-input ``fx`` (``truth["intrinsics"]``) over the canonical ``fx``, so
    that a recording from another camera is scored at the same angle per pixel (for canonical
    frames this is the factor the label stage's ``cv2.resize`` applied)."""
    return np.asarray(truth["intrinsics"], np.float64)[:, 0] / float(base["camera"]["fx"])


def evaluate_checkpoint(checkpoint: Path, data_dir: Path, base: dict, split: str = "test",
                        batch_size: int = 32, device: str = "cpu", mirror: bool = False,
                        zoom: bool = False, fit: FitSettings | None = None,
                        zoom_on_mirror: bool = False) -> tuple[dict, dict, dict]:
    """``(metrics, pred, truth)`` of one checkpoint on ``split``; with ``mirror``, also
    ``metrics["mirror_test"]``: the ``all`` and ``by_family`` metrics of the mirror test
    (:mod:`armpose.mirror_test`, with ``by_type``, ``by_source`` and ``confusion`` too), and
    ``pred["mirror"]`` its predictions; with ``zoom``,
    ``metrics["zoom_test"]`` and ``pred["zoom"]`` likewise for the zoom test (:mod:`armpose.zoom_test`,
    its settings from the checkpoint's config; on the mirror test's passes with ``zoom_on_mirror``); with ``fit``, ``metrics["kinematic_fit"]`` and
    ``pred["fit"]`` for the kinematic fit (:mod:`armpose.kinematic_fit`; its ``sigmas_on_mirror_test``
    says which passes the checkpoint's fit weights were measured on)."""
    model, config = load_inference_model(checkpoint, device)
    extra = load_checkpoint(checkpoint)["extra"] if fit is not None else {}
    pred, truth = predict_split(model, data_dir, split, batch_size, device, mirror=mirror, zoom=zoom,
                                zoom_settings=settings_from_config(config), fit=fit, zoom_on_mirror=zoom_on_mirror,
                                fit_sigmas=dict(extra.get("fit_sigmas", {})) if fit is not None else None)
    metrics = metrics_by_group(pred, truth, list(base["robot_types"]), pixel_scale_of(base, truth))
    for key, name in (("mirror", "mirror_test"), ("zoom", "zoom_test"), ("fit", "kinematic_fit")):
        if key in pred:
            both = metrics_by_group(pred[key], truth, list(base["robot_types"]), pixel_scale_of(base, truth))
            metrics[name] = {k: both[k] for k in ("all", "by_family", "by_type", "by_source", "confusion")}
    if "kinematic_fit" in metrics:   # which passes the fit's weights were measured on (armpose.fit_sigmas)
        metrics["kinematic_fit"]["sigmas_on_mirror_test"] = bool(extra.get("fit_sigmas_on_mirror", False))
    log.info("%s on %s: %s", checkpoint, split, {k: metrics["by_family"][k].get("joint_median_cm")
                                                 for k in metrics["by_family"]})
    return metrics, pred, truth

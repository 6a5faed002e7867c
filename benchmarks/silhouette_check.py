"""Does the predicted mask settle what the network's points leave open? Two post-hoc checks.

    python benchmarks/silhouette_check.py [CHECKPOINT] [--out FILE] [--threads 2]

Most of the joint error is the depth that all joints of a frame share, and most UR type errors
are a UR5 taken for a UR10 or the reverse (``results/results_table.md``). The predicted mask is
evidence the points do not carry, so both checks render a robot model (PyBullet TinyRenderer, the
network-input camera of each frame) and compare its silhouette with the zoom test's mask:

1. **Depth.** The kinematic fit of the predicted type (zoom test, per-type sigmas of the
   checkpoint) is rendered; the image scale ``s`` about the silhouette's centroid (log grid 0.75 to
   1.33, parabolic refinement) that maximises its IoU with the mask, over all 2D shifts, says the
   robot stands ``s`` times nearer or farther than fitted. The network's points are moved along
   their rays so that their median depth becomes the fit's times ``s ** -alpha``, and fitted
   again (depth ratio 1). ``alpha = 0`` is today's fit.
2. **Type.** For a frame typed UR, UR3, UR5 and UR10 are each fitted to the points with loose
   depths (log-depth sigma 1) and rendered; the type with the highest ``log p(type) + beta *
   IoU`` is chosen (``p``: the zoom test's type probabilities). ``beta = 0`` is today's choice.

``alpha`` (per family) and ``beta`` are chosen without the test split, on the held-out training
frames of ``benchmarks/ray_bone_fit.py`` (200 per robot type, outside both transfer sets), as
the grid value with the lowest joint median and the highest type accuracy (ties: the smallest).
Both sets' figures go to ``--out`` as JSON (atomically). Positions: metres, camera optical frame.
"""
from __future__ import annotations

import json
from dataclasses import replace

import cv2
import numpy as np
import pybullet as pb
from tqdm import tqdm

from armpose.config import load_params
from armpose.data import split_indices
from armpose.evaluate import family_of, predict_split
from armpose.fit_sigmas import checkpoint_fit_sigmas
from armpose.geometry import Camera, invert
from armpose.io import atomic_write_json
from armpose.kinematic_fit import FitSettings, fit_predictions, fit_robot
from armpose.robots import get_robot
from armpose.sim.body import RobotBody
from armpose.sim.camera import projection_matrix, view_matrix
from armpose.zoom_test import settings_from_config

from bone_rescale import medians
from checkpoint_cli import load_checkpoint_from_cli
from ray_bone_fit import held_out_rows

SCALES = np.exp(np.linspace(np.log(0.75), np.log(1.33), 41))
ALPHAS = (0.0, 0.25, 0.5, 1.0)
BETAS = (0.0, 1.0, 2.0, 5.0, 10.0, 20.0)
FAR_AWAY = np.array([[1.0, 0, 0, 100.0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])


class Silhouettes:
    """Robot silhouettes rendered with PyBullet's TinyRenderer, one body per robot type."""

    def __init__(self):
        self.client = pb.connect(pb.DIRECT)
        self.bodies: dict[str, RobotBody] = {}

    def render(self, robot: str, q: np.ndarray, T_cam_base: np.ndarray, camera: Camera) -> np.ndarray:
        """Bool (H, W): the pixels of ``robot`` at joint angles ``q`` (radians) and pose
        ``T_cam_base`` (4x4, metres, camera optical frame) seen by ``camera``."""
        if robot not in self.bodies:
            self.bodies[robot] = RobotBody(self.client, get_robot(robot))
        for name, body in self.bodies.items():
            body.place(np.eye(4) if name == robot else FAR_AWAY)
        self.bodies[robot].set_joints(np.asarray(q, np.float64))
        _, _, _, _, seg = pb.getCameraImage(camera.width, camera.height, view_matrix(invert(T_cam_base)),
                                            projection_matrix(camera), renderer=pb.ER_TINY_RENDERER,
                                            physicsClientId=self.client)
        return np.asarray(seg).reshape(camera.height, camera.width) == self.bodies[robot].id


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two bool masks (0 when both are empty)."""
    return float((a & b).sum() / max(1, (a | b).sum()))


def best_scale(silhouette: np.ndarray, mask: np.ndarray) -> float:
    """The image scale about the silhouette's centroid, over :data:`SCALES` with a parabolic
    refinement, that maximises its IoU with ``mask`` at the best 2D shift; 1 when either is
    (nearly) empty."""
    if silhouette.sum() < 20 or mask.sum() < 20:
        return 1.0
    ys, xs = np.nonzero(silhouette)
    cx, cy = xs.mean(), ys.mean()
    m = mask.astype(np.float32)
    fm = np.fft.rfft2(m)
    ious = []
    for s in SCALES:
        A = np.array([[s, 0, cx * (1 - s)], [0, s, cy * (1 - s)]])
        w = cv2.warpAffine(silhouette.astype(np.float32), A, (m.shape[1], m.shape[0]), flags=cv2.INTER_LINEAR)
        inter = np.fft.irfft2(fm * np.conj(np.fft.rfft2(w)), s=m.shape).max()
        ious.append(inter / (w.sum() + m.sum() - inter))
    ious = np.asarray(ious)
    j = int(np.argmax(ious))
    log_s, step = np.log(SCALES[j]), np.log(SCALES[1] / SCALES[0])
    if 0 < j < len(SCALES) - 1:
        y0, y1, y2 = ious[j - 1:j + 2]
        if y0 - 2 * y1 + y2 < 0:
            log_s += step * 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)
    return float(np.exp(log_s))


def cameras(truth: dict, width: int, height: int) -> list[Camera]:
    """Each frame's network-input camera (``truth['intrinsics']``: fx, fy, cx, cy in pixels)."""
    return [Camera(width, height, *map(float, k)) for k in truth["intrinsics"]]


def silhouette_scales(fit: dict, pred: dict, cams: list[Camera], types: list[str], sil: Silhouettes) -> np.ndarray:
    """Per frame, :func:`best_scale` of the fitted robot's silhouette against the predicted mask."""
    out = np.ones(len(cams))
    for i in tqdm(range(len(cams)), desc="depth check", unit="frame", dynamic_ncols=True):
        robot = types[pred["type"][i]]
        n = get_robot(robot).num_joints
        out[i] = best_scale(sil.render(robot, fit["q"][i, :n], fit["T_cam_base"][i], cams[i]), pred["masks"][i])
    return out


def median_depth(base: np.ndarray, joints: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Per frame, the median depth (metres) of the base and the first ``counts`` joints."""
    z = np.concatenate([base[:, None, 2], joints[..., 2]], 1)
    used = np.arange(z.shape[1])[None] <= counts[:, None]
    return np.nanmedian(np.where(used, z, np.nan), 1)


def refit_at_scale(pred: dict, fit: dict, scale: np.ndarray, alpha: float, types: list[str], sigmas: dict) -> dict:
    """The fit again, the network's points first moved along their rays so that their median depth
    is the fit's over ``scale ** alpha`` (points: base then joints, metres)."""
    counts = np.array([get_robot(types[t]).num_joints for t in pred["type"]])
    k = (median_depth(fit["base"], fit["joints"], counts) * scale ** -alpha
         / median_depth(pred["base"], pred["joints"], counts))
    unit_ratio = {t: {**v, "depth_ratio": 1.0} for t, v in sigmas.items()}
    return fit_predictions(pred["joints"] * k[:, None, None], pred["base"] * k[:, None], pred["type"], types,
                           FitSettings(), unit_ratio)


def ur_candidate_ious(pred: dict, cams: list[Camera], types: list[str], sil: Silhouettes) -> np.ndarray:
    """(N, T) silhouette IoU of each candidate type of a frame's predicted family, fitted with
    loose depths; NaN outside the family and for single-type families."""
    families = np.asarray(family_of(types))
    out = np.full((len(cams), len(types)), np.nan)
    loose = replace(FitSettings(), log_depth_sigma=1.0)
    for k, robot in enumerate(types):
        rows = np.flatnonzero(families[pred["type"]] == families[k])
        if families.tolist().count(families[k]) < 2 or not rows.size:
            continue
        n = get_robot(robot).num_joints
        points = np.concatenate([pred["base"][rows, None], pred["joints"][rows, :n]], 1)
        f = fit_robot(points, robot, loose)
        for j, i in enumerate(tqdm(rows, desc=f"type check {robot}", unit="frame", dynamic_ncols=True)):
            out[i, k] = iou(sil.render(robot, f["q"][j], f["T_cam_base"][j], cams[i]), pred["masks"][i])
    return out


def chosen_types(type_probs: np.ndarray, ious: np.ndarray, beta: float) -> np.ndarray:
    """Per frame, the type maximising ``log p + beta * IoU`` among its candidates; the network's
    type where it has none."""
    score = np.log(np.clip(type_probs, 1e-12, 1.0)) + beta * np.nan_to_num(ious, nan=0.0)
    has = np.isfinite(ious).any(1)
    return np.where(has, np.where(np.isfinite(ious), score, -np.inf).argmax(1), type_probs.argmax(1))


def type_accuracy(chosen: np.ndarray, truth: dict, types: list[str]) -> dict:
    """Per family (of the true type): the fraction of frames whose ``chosen`` type is the true one."""
    fam = np.asarray(family_of(types))[truth["type"]]
    return {f: round(float(np.mean(chosen[fam == f] == truth["type"][fam == f])), 4) for f in dict.fromkeys(fam)}


def check(model, config: dict, data_dir, rows: np.ndarray, types: list[str], sigmas: dict, sil: Silhouettes) -> dict:
    """Both checks on ``rows``: per alpha the joint and base medians per family, per beta the type
    accuracy per family, and the median silhouette IoU at scale 1."""
    families = family_of(types)
    names = list(dict.fromkeys(families))
    size = config["base"]["input_size"]
    pred, truth = predict_split(model, data_dir, rows=rows, zoom=True, zoom_settings=settings_from_config(config),
                                fit=FitSettings(), fit_sigmas=sigmas, keep_masks=True)
    zoom, fit = pred["zoom"], pred["fit"]
    cams = cameras(truth, int(size["width"]), int(size["height"]))
    scale = silhouette_scales(fit, zoom, cams, types, sil)
    depth = {}
    for a in ALPHAS:
        moved = fit if a == 0 else refit_at_scale(zoom, fit, scale, a, types, sigmas)
        depth[str(a)] = medians(moved["joints"], moved["base"], truth, families, names)
    ious = ur_candidate_ious(zoom, cams, types, sil)
    kind = {str(b): type_accuracy(chosen_types(zoom["type_probs"], ious, b), truth, types) for b in BETAS}
    fam = np.asarray(families)[truth["type"]]
    counts = truth["joint_valid"].sum(1)
    log_ratio = np.log(median_depth(fit["base"], fit["joints"], counts)
                       / median_depth(truth["base"], truth["joints"], counts))
    return {"frames": int(len(rows)), "by_alpha": depth, "by_beta": kind,
            "scale_vs_depth_error_corr": {f: round(float(np.corrcoef(np.log(scale[fam == f]), log_ratio[fam == f])[0, 1]), 3)
                                          for f in names}}


def main() -> None:
    args, root, model, config = load_checkpoint_from_cli(__doc__)
    data_dir = root / "data" / "labels"
    params = load_params(root / "params.yaml")
    types = list(params["base"]["robot_types"])
    sigmas = checkpoint_fit_sigmas(root / args.checkpoint)
    sil = Silhouettes()
    result = {"checkpoint": str(args.checkpoint), "alphas": list(ALPHAS), "betas": list(BETAS)}
    for name, rows in (("held_out", held_out_rows(data_dir, params)), ("test", split_indices(data_dir, "test"))):
        result[name] = check(model, config, data_dir, rows, types, sigmas, sil)
    held = result["held_out"]
    names = list(dict.fromkeys(family_of(types)))
    result["chosen_alpha"] = {f: min(ALPHAS, key=lambda a: (held["by_alpha"][str(a)][f]["joint_median_cm"], a))
                              for f in names}
    multi = [f for f in names if family_of(types).count(f) > 1]
    result["chosen_beta"] = max(BETAS, key=lambda b: (np.mean([held["by_beta"][str(b)][f] for f in multi]), -b))
    print(json.dumps({k: result[k] for k in ("chosen_alpha", "chosen_beta")} | {
        s: {"depth": {a: result[s]["by_alpha"][a] for a in map(str, ALPHAS)},
            "type": {b: result[s]["by_beta"][b] for b in ("0.0", str(result["chosen_beta"]))},
            "corr": result[s]["scale_vs_depth_error_corr"]} for s in ("held_out", "test")}, indent=1))
    if args.out:
        atomic_write_json(args.out, result)


if __name__ == "__main__":
    main()

"""Where the zoom test's second look samples from: the network input or the full-resolution frame.

    python benchmarks/zoom_source.py [CHECKPOINT] [--out results/zoom_source.json] [--no-fit]

:mod:`armpose.zoom_test` builds the second look by warping the 256x212 network input, so a view
zoomed by ``s`` is that image upsampled ``s`` times: no detail the first pass did not have. The
recording's own frame (480x360 in the default camera, 1.7x the network input's pixels per ray)
could fill the same view with real detail. This script runs both on the held-out training frames
of ``benchmarks/ray_bone_fit.py`` (rows outside both transfer sets, 200 per robot type; never the
test split): the same first pass and the same view (turn and scale), the second look's pixels taken
either from the network input (``input``, what the library does) or from the raw frame read
from its recording (``frame``: one homography from frame pixels to the view, after an area
downscale of the frame wherever the view has fewer pixels per ray than the frame). Scored per
family: joint and base medians (cm) and type accuracy of the zoom test, and, unless
``--no-fit``, joint and base medians after the kinematic fit (:mod:`armpose.kinematic_fit`,
the checkpoint's per-type weights). Written to ``--out`` as JSON (atomically).
"""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import torch

from armpose.augment import view_homography
from armpose.config import load_params
from armpose.data import LabelledFrames, load_dataset
from armpose.evaluate import family_of, fit_predictions
from armpose.fit_sigmas import checkpoint_fit_sigmas
from armpose.io import atomic_write_json
from armpose.kinematic_fit import FitSettings
from armpose.recording import read_frame, read_meta
from armpose.robots import get_robot
from armpose.zoom_test import second_look_views, settings_from_config, warp_images, zoom_combine

from checkpoint_cli import load_checkpoint_from_cli
from ray_bone_fit import held_out_rows

SOURCES = ("input", "frame")


class RawFrames:
    """Each labelled row's raw frame (float RGB in [0, 1]) and the homography from its pixels
    to the network input's (the labels' scale-and-crop, :meth:`armpose.geometry.Camera.scale_crop`)."""

    def __init__(self, root: Path, data_dir: Path, input_size: dict):
        arrays, index = load_dataset(data_dir)
        self.root, self.index = root, index
        self.recording, self.frame = np.asarray(arrays["recording"]), np.asarray(arrays["frame"])
        self.size = (int(input_size["width"]), int(input_size["height"]))
        self._cameras: dict[int, tuple] = {}

    def __call__(self, row: int) -> tuple[np.ndarray, np.ndarray]:
        rec = int(self.recording[row])
        rec_dir = self.root / self.index["recordings"][rec]["name"]
        if rec not in self._cameras:
            camera = read_meta(rec_dir)[0].camera
            _, (rw, rh), (x0, y0) = camera.scale_crop(*self.size)
            sx, sy = rw / camera.width, rh / camera.height
            self._cameras[rec] = (camera, np.array([[sx, 0, 0.5 * sx - 0.5 - x0], [0, sy, 0.5 * sy - 0.5 - y0], [0, 0, 1.0]]))
        camera, to_input = self._cameras[rec]
        return read_frame(rec_dir, int(self.frame[row]), camera).astype(np.float32) / 255, to_input


def frame_views(frames: list[tuple[np.ndarray, np.ndarray]], turns: np.ndarray, scales: np.ndarray,
                cameras: np.ndarray, size: tuple[int, int]) -> torch.Tensor:
    """The second look's views (B, 3, h, w) sampled from the raw frames: frame pixels -> network
    input (``to_input``) -> the turned, dollied view; the frame is area-downscaled first where the
    view has fewer pixels per ray than the frame (no aliasing)."""
    out = []
    for (img, to_input), M, s, cam in zip(frames, turns, scales, cameras):
        k = float(s) * float(to_input[0, 0])          # view pixels per frame pixel
        if k < 1:
            h, w = img.shape[:2]
            small = (max(1, round(w * k)), max(1, round(h * k)))
            fx, fy = small[0] / w, small[1] / h
            down = np.array([[fx, 0, 0.5 * fx - 0.5], [0, fy, 0.5 * fy - 0.5], [0, 0, 1.0]])
            img, to_input = cv2.resize(img, small, interpolation=cv2.INTER_AREA), to_input @ np.linalg.inv(down)
        H = view_homography(M, cam, s) @ to_input
        out.append(cv2.warpPerspective(img, H, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0))
    return torch.from_numpy(np.stack(out)).permute(0, 3, 1, 2).contiguous(memory_format=torch.channels_last)


def main() -> None:
    args, root, model, config = load_checkpoint_from_cli(
        __doc__, lambda ap: ap.add_argument("--no-fit", action="store_true", help="zoom test only, no kinematic fit"))
    fit = not args.no_fit
    params = load_params(root / "params.yaml")
    data_dir = root / "data" / "labels"
    rows = held_out_rows(data_dir, params)
    frames = LabelledFrames(data_dir, rows)
    raw = RawFrames(root, data_dir, params["base"]["input_size"])
    types = frames.robot_types
    counts = [get_robot(t).num_joints for t in types]
    settings, threshold = settings_from_config(config), float(model.mask_threshold)
    outs = {s: {"joints": [], "base": [], "type": []} for s in SOURCES}
    truth = {"joints": [], "valid": [], "base": [], "type": []}
    with torch.no_grad():
        for start in range(0, len(frames), 32):
            idx = list(range(start, min(start + 32, len(frames))))
            items = [frames[i] for i in idx]
            x = torch.stack([it["image"] for it in items]).contiguous(memory_format=torch.channels_last)
            cams = torch.stack([it["intrinsics"] for it in items])
            single = model(x)
            turns, scales, cam_rows = second_look_views(x, single, cams, settings, counts)
            views = {"input": warp_images(x, turns, scales, cam_rows).contiguous(memory_format=torch.channels_last),
                     "frame": frame_views([raw(int(rows[i])) for i in idx], turns, scales, cam_rows, (x.shape[-1], x.shape[-2]))}
            for s in SOURCES:
                o = zoom_combine(single, model(views[s]), turns, scales, cam_rows, threshold, counts, float(settings["weight"]))
                outs[s]["joints"].append(o["joints"].double().numpy())
                outs[s]["base"].append(o["base"].double().numpy())
                outs[s]["type"].append(o["type_logits"].argmax(-1).numpy())
            for k, key in (("joints", "joints"), ("valid", "joint_valid"), ("base", "base"), ("type", "robot")):
                truth[k].append(torch.stack([torch.as_tensor(it[key]) for it in items]).numpy())
    truth = {k: np.concatenate(v) for k, v in truth.items()}
    fams = np.array(family_of(types))[truth["type"]]
    sigmas = checkpoint_fit_sigmas(root / args.checkpoint) if fit else None
    result = {"checkpoint": str(args.checkpoint), "frames": int(len(rows)), "settings": settings, "by_source": {}}
    for s in SOURCES:
        o = {k: np.concatenate(v) for k, v in outs[s].items()}
        scored = {"zoom": o}
        if fit:
            scored["zoom+fit"] = fit_predictions(o["joints"], o["base"], o["type"], types, FitSettings(), sigmas)
        result["by_source"][s] = {name: _scores(p, o["type"], truth, fams) for name, p in scored.items()}
    print(json.dumps(result, indent=1))
    if args.out:
        atomic_write_json(args.out, result)


def _scores(pred: dict, types: np.ndarray, truth: dict, fams: np.ndarray) -> dict:
    """Per family: joint and base medians (cm) and type accuracy."""
    joint = np.linalg.norm(pred["joints"][:, : truth["joints"].shape[1]] - truth["joints"], axis=-1)
    base = np.linalg.norm(pred["base"] - truth["base"], axis=-1)
    return {f: {"joint_median_cm": round(100 * float(np.median(joint[fams == f][truth["valid"][fams == f]])), 2),
                "base_median_cm": round(100 * float(np.median(base[fams == f])), 2),
                "type_accuracy": round(float(np.mean(types[fams == f] == truth["type"][fams == f])), 4)}
            for f in dict.fromkeys(fams.tolist())}


if __name__ == "__main__":
    main()

"""``armpose predict``: the network on a user's own images, with their own camera.

The network was trained on one canonical camera: the rectified 480x360 camera of
``params.yaml`` (``base.camera``), scaled and centre-cropped to the 256x212 network input.
An image from another pinhole camera is warped to that network input before the network sees
it: since both are pinhole cameras with the same optical frame, the warp is an axis-aligned
scale plus shift (scale, crop or pad about the principal point), and 3D outputs in the
camera optical frame (metres; x right, y down, z forward) need no change. 2D outputs are
projected with the user's intrinsics, and the mask is warped back to the input image.

Output per image (one JSON object): ``image``, ``robot_type``, ``type_probs``, ``base_xyz``,
``joints_xyz`` (one per joint of the predicted type), ``joints_uv`` (pixels of the input
image), ``mask`` (PNG path, when a mask folder is given), ``latency_ms`` (network forward).
With ``fit`` (``--fit``), ``base_xyz``, ``joints_xyz`` and ``joints_uv`` are those of the kinematic
fit (:mod:`armpose.kinematic_fit`: the predicted type's model posed to the network's estimate),
and two keys more: ``joint_angles`` (radians, the robot description's joints) and
``camera_T_base`` (4x4, the robot base in the camera frame, metres); ``latency_ms`` includes it.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np
import torch

from armpose.geometry import Camera
from armpose.intrinsics import load_intrinsics
from armpose.mirror_test import MirrorAveraged
from armpose.io import atomic_write_bytes
from armpose.fit_sigmas import checkpoint_fit_sigmas
from armpose.kinematic_fit import fit_predictions
from armpose.model import predicted_mask
from armpose.robots import get_robot
from armpose.train import load_checkpoint
from armpose.zoom_test import settings_from_config, zoom_refine

log = logging.getLogger(__name__)
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")


class PredictError(ValueError):
    """A file that cannot be processed; the message names it."""


class SizeMismatch(PredictError):
    """An image whose size is not that of the camera it is said to come from."""


@dataclass(frozen=True)
class Warp:
    """Network-input pixel ``n`` <-> source pixel ``s``: ``s = scale * n + offset`` per axis."""

    scale: np.ndarray     # (2,) source pixels per network pixel, x and y
    offset: np.ndarray    # (2,)

    def to_source(self, uv: np.ndarray) -> np.ndarray:
        return np.asarray(uv, np.float64) * self.scale + self.offset

    def matrix(self) -> np.ndarray:
        """2x3 affine from network-input pixels to source pixels (for ``cv2.warpAffine`` with WARP_INVERSE_MAP)."""
        return np.array([[self.scale[0], 0, self.offset[0]], [0, self.scale[1], self.offset[1]]])


def network_camera(base: dict) -> Camera:
    """The network-input camera: the canonical camera of ``base`` scaled and cropped to ``input_size``."""
    size = base["input_size"]
    return Camera.from_dict(base["camera"]).scale_crop(int(size["width"]), int(size["height"]))[0]


def warp_for(source: Camera, net: Camera) -> Warp:
    """The pixel map from the network camera to ``source``: same rays, OpenCV pixel centres."""
    scale = np.array([source.fx / net.fx, source.fy / net.fy])
    offset = np.array([source.cx - scale[0] * net.cx, source.cy - scale[1] * net.cy])
    return Warp(scale, offset)


def to_network(image: np.ndarray, warp: Warp, net: Camera) -> np.ndarray:
    """``image`` (H, W, 3) RGB uint8 resampled into the network camera; outside the source is black.

    Downscaling is by area averaging first (``cv2.resize``, ``INTER_AREA``), as the label stage
    makes the training inputs (:func:`armpose.labels.compute.scale_crop_image`; ``warpAffine``
    has no area mode and would alias); what is left of the map, a shift and a scale near 1,
    is bilinear. An image of the canonical camera comes out exactly as the label stage's."""
    scale, offset = warp.scale.astype(np.float64), warp.offset.astype(np.float64)
    src = image
    if scale.max() > 1:
        h, w = image.shape[:2]
        size = (max(1, round(w / max(scale[0], 1.0))), max(1, round(h / max(scale[1], 1.0))))
        src = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        ratio = np.array([size[0] / w, size[1] / h])
        scale, offset = scale * ratio, (offset + 0.5) * ratio - 0.5   # source pixel centres in the resized image
    matrix = np.array([[scale[0], 0, offset[0]], [0, scale[1], offset[1]]])
    return cv2.warpAffine(src, matrix, (net.width, net.height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def mask_to_source(mask: np.ndarray, warp: Warp, source: Camera) -> np.ndarray:
    """A network-input mask (h, w) bool warped to the source image (H, W) bool."""
    inv = np.array([[1 / warp.scale[0], 0, -warp.offset[0] / warp.scale[0]],
                    [0, 1 / warp.scale[1], -warp.offset[1] / warp.scale[1]]])
    out = cv2.warpAffine(mask.astype(np.uint8) * 255, inv, (source.width, source.height),
                         flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderValue=0)
    return out >= 128


def read_image(path: Path) -> np.ndarray:
    """RGB uint8 (H, W, 3); :class:`PredictError` naming the file if it is not a readable image."""
    if not path.is_file():
        raise PredictError(f"{path}: no such file")
    try:
        data = np.fromfile(str(path), np.uint8)
    except OSError as err:
        raise PredictError(f"{path}: cannot read ({err.strerror or err})") from err
    img = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    if img is None:
        raise PredictError(f"{path}: not a readable image (PNG or JPEG expected, {data.size} bytes)")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


class Predictor:
    """A loaded network plus its camera, robot types and joint counts."""

    def __init__(self, checkpoint: Path | str, device: str = "cpu", model=None, mirror: bool = False,
                 zoom: bool = False, fit: bool = False):
        from armpose.inference import load_inference_model
        ckpt_path = Path(checkpoint)
        try:
            if model is None:
                model, config = load_inference_model(ckpt_path, device)
            else:
                config = load_checkpoint(ckpt_path)["config"]
            self.zoom_settings = settings_from_config(config)
            self.fit_sigmas = checkpoint_fit_sigmas(ckpt_path) if fit else {}
            self.base = config["base"]
            self.types = list(self.base["robot_types"])
            self.net = network_camera(self.base)
            self.canonical = Camera.from_dict(self.base["camera"])
        except (ValueError, KeyError, TypeError, RuntimeError) as err:
            msg = f"missing key {err.args[0]!r}" if isinstance(err, KeyError) and err.args else str(err)
            raise PredictError(msg if msg.startswith(str(ckpt_path))
                               else f"{ckpt_path}: cannot use this checkpoint ({msg})") from err
        self.model, self.device, self.mirror, self.zoom, self.fit = model, device, mirror, zoom, fit
        self.num_joints = [get_robot(t).num_joints for t in self.types]
        self._looked = MirrorAveraged(model, self.net.fx, self.net.cx) if mirror else model

    def forward(self, x: torch.Tensor) -> dict:
        """The network's outputs on the network-input batch ``x``, mirror-test averaged with ``mirror``."""
        return self._looked(x)

    @torch.no_grad()
    def __call__(self, image: np.ndarray, camera: Camera | None = None) -> dict:
        """Prediction for one RGB uint8 image from ``camera`` (default: the canonical camera)."""
        camera = camera or self.canonical
        h, w = image.shape[:2]
        if (w, h) != (camera.width, camera.height):
            raise SizeMismatch(f"image is {w}x{h} but the camera is {camera.width}x{camera.height}"
                               + ("" if camera is not self.canonical else "; pass --intrinsics for another camera"))
        warp = warp_for(camera, self.net)
        x = torch.from_numpy(to_network(image, warp, self.net)).permute(2, 0, 1).float().div(255)[None]
        x = x.to(self.device).contiguous(memory_format=torch.channels_last)
        t = time.perf_counter()
        out = self.forward(x)
        if self.zoom:
            net = (self.net.fx, self.net.fy, self.net.cx, self.net.cy)
            out = zoom_refine(self.forward, x, out, net, self.zoom_settings, self.num_joints,
                              float(getattr(self.model, "mask_threshold", 0.0)))
        probs = out["type_logits"][0].float().softmax(-1).cpu().numpy()
        k = int(probs.argmax())
        joints = out["joints"][0, : self.num_joints[k]].double().cpu().numpy()
        base = out["base"][0].double().cpu().numpy()
        if not (np.isfinite(probs).all() and np.isfinite(joints).all() and np.isfinite(base).all()):
            raise PredictError("the network's output is not finite (NaN or inf); is the checkpoint damaged?")
        extra = {}
        if self.fit:
            fitted = fit_predictions(joints[None], base[None], np.array([0]), [self.types[k]], sigmas=self.fit_sigmas)
            joints, base = fitted["joints"][0], fitted["base"][0]
            extra = {"joint_angles": fitted["q"][0].tolist(), "camera_T_base": fitted["T_cam_base"][0].tolist()}
        latency = 1000 * (time.perf_counter() - t)
        uv = camera.project(joints)
        mask = mask_to_source(predicted_mask(self.model, out["mask_logits"][0, 0]).cpu().numpy(), warp, camera)
        return {"robot_type": self.types[k], "type_probs": {t: float(p) for t, p in zip(self.types, probs)},
                "base_xyz": base.tolist(), "joints_xyz": joints.tolist(), "joints_uv": uv.tolist(),
                "latency_ms": round(latency, 3), **extra, "_mask": mask}


def expand_inputs(inputs: Sequence[str | Path], errors: list | None = None) -> list[Path]:
    """Files as given; folders expand to their image files (``IMAGE_SUFFIXES``), sorted.

    A folder without any is reported into ``errors`` (when given) with a message naming it."""
    out = []
    for item in inputs:
        p = Path(item)
        if p.is_dir():
            found = sorted(f for f in p.iterdir() if f.suffix.lower() in IMAGE_SUFFIXES)
            if not found and errors is not None:
                errors.append(f"{p}: no images in this folder ({', '.join(IMAGE_SUFFIXES)})")
            out += found
        else:
            out.append(p)
    return out


def output_stems(paths: Sequence[Path]) -> list[str]:
    """One distinct file-name stem per input, for its mask and overlay: the input's own stem, with
    ``_2``, ``_3``, ... added when an earlier input took it (``a/img.png`` and ``b/img.png``)."""
    used: set[str] = set()
    stems = []
    for path in paths:
        stem, n = Path(path).stem, 2
        name = stem
        while name in used:
            name, n = f"{stem}_{n}", n + 1
        used.add(name)
        stems.append(name)
    return stems


def write_mask(mask: np.ndarray, folder: Path, stem: str) -> Path:
    """The mask (bool, input size) as ``<folder>/<stem>_mask.png`` (255 = robot), atomically."""
    path = Path(folder) / f"{stem}_mask.png"
    ok, buf = cv2.imencode(".png", mask.astype(np.uint8) * 255)
    atomic_write_bytes(path, buf.tobytes())
    return path


def write_overlay(image: np.ndarray, mask: np.ndarray | None, joints_uv, folder: Path, stem: str) -> Path:
    """``image`` (RGB uint8) with ``mask`` (non-zero = robot, or None) and the joints (pixels; NaN
    rows left out) drawn, as ``<folder>/<stem>_overlay.png``, atomically."""
    from armpose.viz import overlay_labels
    drawn = overlay_labels(image, mask, np.asarray(joints_uv, np.float64).reshape(-1, 2))
    path = Path(folder) / f"{stem}_overlay.png"
    ok, buf = cv2.imencode(".png", cv2.cvtColor(drawn, cv2.COLOR_RGB2BGR))
    atomic_write_bytes(path, buf.tobytes())
    return path


def predict(images: Sequence[str | Path], checkpoint: Path | str, intrinsics: Camera | str | Path | None = None,
            masks: Path | None = None, device: str = "cpu", errors: list | None = None, model=None,
            mirror: bool = False, zoom: bool = False, fit: bool = False, overlays: Path | None = None) -> list[dict]:
    """One result dict per readable image (schema in the module docstring).

    ``intrinsics``: a :class:`Camera` or a JSON path; ``None`` means the canonical camera of the
    checkpoint's params. Files that fail are skipped with a warning; pass a list as ``errors``
    to collect their messages (a folder without images is one). ``model`` replaces the
    checkpoint's network (tests use an oracle).
    ``mirror``: average with the network's outputs on the mirrored image (:mod:`armpose.mirror_test`;
    two images a forward pass, included in ``latency_ms``). ``zoom``: a second look from the camera
    turned to the robot and moved closer (:mod:`armpose.zoom_test`, settings from the checkpoint;
    one more forward pass, included in ``latency_ms``). ``fit``: the kinematic fit of the predicted
    type's model (:mod:`armpose.kinematic_fit`), with ``joint_angles`` and ``camera_T_base``.
    ``masks`` and ``overlays``: folders for ``<stem>_mask.png`` and ``<stem>_overlay.png`` (the
    image with its mask and joints drawn), stems from :func:`output_stems`.
    """
    predictor = Predictor(checkpoint, device, model=model, mirror=mirror, zoom=zoom, fit=fit)
    camera = load_intrinsics(Path(intrinsics)) if isinstance(intrinsics, (str, Path)) else intrinsics
    where = f" (intrinsics {intrinsics})" if isinstance(intrinsics, (str, Path)) else ""
    problems: list[str] = []
    paths = expand_inputs(images, problems)
    for msg in problems:
        log.warning("%s", msg)
    if errors is not None:
        errors += problems
    results = []
    for path, stem in zip(paths, output_stems(paths)):
        try:
            image = read_image(path)
            res = predictor(image, camera)
        except SizeMismatch as err:
            res = None
            msg = f"{path}: {err}{where}"
        except PredictError as err:
            res = None
            msg = str(err) if str(err).startswith(str(path)) else f"{path}: {err}"
        if res is None:
            log.warning("%s", msg)
            if errors is not None:
                errors.append(msg)
            continue
        mask = res.pop("_mask")
        row = {"image": str(path), **res}
        if masks is not None:
            row["mask"] = str(write_mask(mask, masks, stem))
        if overlays is not None:
            write_overlay(image, mask, row["joints_uv"], overlays, stem)
        results.append(row)
    return results

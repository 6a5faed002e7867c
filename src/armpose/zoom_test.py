"""Zoom test: a second look at the robot, from a camera turned to it and moved closer.

The robot's box (its projected base and joints) spans a median 44 % of a 256x212 frame's width
or height, but the robot itself is thin: a median 3-8 % of the pixels (section V of the paper:
5-22 %). The zoom test takes the first pass's estimate of where the robot is, turns the
camera to look at the centre of that box (a rotation about the optical centre: an exact
homography of the image) and dollies it in until the box spans ``fill`` of the frame (image
scale ``s``, clipped to ``[1, max_zoom]``), and runs the network again on that view. It is the
view a training stage's ``augment.zoom`` draws (:mod:`armpose.augment`), so a network trained
with it reads the second look in distribution; the settings (``fill``, the middle of the
training range, and ``max_zoom``) come from the checkpoint's own config
(:func:`settings_from_config`).

Mapping back (metres, camera optical frame: x right, y down, z forward; pixels of the network
input, intrinsics ``fx, fy, cx, cy``): the second look's points are those of the dollied,
turned camera, so :func:`armpose.augment.undolly_points` with the view's scale and the mean
depth of the second look's joints (the labels' reference depth), then the transposed turn,
give them in the original camera: exactly the inverse of the training labels' transform. Its
mask logits are warped back by the inverse homography. The result is a weighted mean,
``weight`` on the second look (one half: the two looks' errors are partly independent, and their
mean beat the second look alone on held-out training frames): joints, base and type
probabilities everywhere, mask logits where the second look's view covers the pixel (the first
pass's alone elsewhere).

The mask logits of a view are offset by its robot share (the class-balanced mask loss weights
each image by its own foreground fraction, :mod:`armpose.losses`): before averaging, the second
look's logits are moved to the first pass's offset, ``log((1 - pi) / pi)`` with ``pi`` the
first pass's predicted foreground share, ``s**2`` times that in the second look's view.

``armpose predict --zoom`` uses it, and the ``evaluate`` stage reports it next to the single
pass (``evaluate.zoom_test``).
"""
from __future__ import annotations

from typing import Callable

import cv2
import numpy as np
import torch

from armpose.augment import (centring_turn, points_box, rotate_points, undolly_points, view_homography, zoom_config,
                             zoom_scale)

OUTPUT_KEYS = ("joints", "base", "type_logits", "mask_logits")
DEFAULT_SETTINGS = {"fill": 0.6, "max_zoom": 1.5, "weight": 0.5}   # a checkpoint trained without augment.zoom
TRAINED_WEIGHT = 0.5   # the second look's share for a network trained on such views: on held-out training
                       # frames of the default run the mean of both looks beat the second alone (README)


CameraLike = "tuple[float, float, float, float] | torch.Tensor"   # one (fx, fy, cx, cy), or one per frame


def camera_rows(camera, n: int) -> np.ndarray:
    """``(n, 4)`` float64 ``fx, fy, cx, cy`` from one camera or one per frame."""
    cam = np.asarray(torch.as_tensor(camera).detach().cpu(), np.float64)
    if cam.shape not in ((4,), (n, 4)):
        raise ValueError(f"camera must be (fx, fy, cx, cy) or one per frame ({n}, 4), got shape {tuple(cam.shape)}")
    return np.broadcast_to(cam, (n, 4))


def check_max_zoom(max_zoom) -> float:
    """``max_zoom`` as a float, or a ValueError naming it unless it is a number >= 1."""
    if isinstance(max_zoom, bool) or not isinstance(max_zoom, (int, float)) or not max_zoom >= 1:
        raise ValueError(f"max_zoom must be a number >= 1, got {max_zoom!r}")
    return float(max_zoom)


def trained_for_zoom(config: dict) -> bool:
    """Whether the checkpoint ``config``'s training stage drew the zoom test's views (``augment.zoom``)."""
    zoom = ((config or {}).get("cfg", {}).get("augment") or {}).get("zoom") or {}
    return bool(zoom) and float(zoom.get("p", 0.0)) > 0


def settings_from_config(config: dict) -> dict:
    """``{fill, max_zoom, weight}`` of the zoom test for a checkpoint's ``config``: the middle of
    the training stage's ``augment.zoom.fill`` and its ``max_zoom``, with the second look at
    :data:`TRAINED_WEIGHT`; :data:`DEFAULT_SETTINGS` (the mean of both looks) for a network
    trained without zoomed views."""
    if not trained_for_zoom(config):
        return dict(DEFAULT_SETTINGS)
    zcfg = zoom_config(config["cfg"]["augment"])
    return {"fill": float(np.mean(zcfg["fill"])), "max_zoom": check_max_zoom(float(zcfg["max_zoom"])),
            "weight": TRAINED_WEIGHT}


def zoom_views(points: np.ndarray, valid: np.ndarray, camera: np.ndarray, size: tuple[int, int],
               fill: float, max_zoom: float) -> tuple[np.ndarray, np.ndarray]:
    """``(turns (B, 3, 3), scales (B,))``: per frame, the camera turn that centres the box of
    ``points`` (B, N, 3) where ``valid`` (B, N), and the image scale that makes it span ``fill``
    of ``size`` = (width, height), within ``[1, max_zoom]``. ``camera`` (B, 4)."""
    turns, scales = np.zeros((len(points), 3, 3)), np.ones(len(points))
    for b, (p, ok, cam) in enumerate(zip(points, valid, camera)):
        p = p[ok]
        if not (p[:, 2] > 1e-6).any():       # nothing in front of the camera: look again unchanged
            turns[b] = np.eye(3)
            continue
        turns[b] = centring_turn(points_box(p, cam)[0], cam)
        scales[b] = zoom_scale(rotate_points(p, turns[b]), cam, size, fill, 1.0, max_zoom)
    return turns, scales


def warp_images(images: torch.Tensor, turns: np.ndarray, scales: np.ndarray, camera: np.ndarray) -> torch.Tensor:
    """``images`` (B, C, H, W) as seen from each frame's turned, dollied camera (bilinear,
    zeros outside; :func:`armpose.augment.view_homography`)."""
    arr = images.detach().float().cpu().permute(0, 2, 3, 1).numpy()
    size = (arr.shape[2], arr.shape[1])
    out = np.stack([_warp(a, view_homography(M, cam, s), size) for a, M, s, cam in zip(arr, turns, scales, camera)])
    out = out.reshape(arr.shape)
    return torch.from_numpy(out).permute(0, 3, 1, 2).to(images.device, images.dtype)


def unwarp_maps(maps: torch.Tensor, turns: np.ndarray, scales: np.ndarray,
                camera: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
    """``(maps back, covered)``: ``maps`` (B, 1, H, W) of the second look resampled at the
    original pixels (pixel ``p`` reads the view's ``H p``), and a (B, 1, H, W) bool of the
    pixels whose source lies inside the view."""
    arr = maps.detach().float().cpu()[:, 0].numpy()
    size = (arr.shape[2], arr.shape[1])
    ones = np.ones(arr.shape[1:], np.float32)
    back, covered = [], []
    for a, M, s, cam in zip(arr, turns, scales, camera):
        H = view_homography(M, cam, s)
        back.append(_warp(a, H, size, inverse=True))
        covered.append(_warp(ones, H, size, inverse=True, nearest=True) > 0.5)
    to = lambda x: torch.from_numpy(np.stack(x))[:, None].to(maps.device)   # noqa: E731
    return to(back).to(maps.dtype), to(covered)


def _warp(a: np.ndarray, H: np.ndarray, size, inverse: bool = False, nearest: bool = False) -> np.ndarray:
    flags = (cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR) | (cv2.WARP_INVERSE_MAP if inverse else 0)
    return cv2.warpPerspective(np.ascontiguousarray(a, np.float32), H, size, flags=flags,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def unzoom_points(points: torch.Tensor, turns: np.ndarray, scales: np.ndarray, z_ref: np.ndarray) -> torch.Tensor:
    """Points ``(B, N, 3)`` predicted on the second look's views, in the original camera's frame:
    un-dollied about ``z_ref`` (B,) (the view's reference depth, the mean depth of its joints)
    and turned back."""
    p = points.detach().double().cpu().numpy()
    back = np.stack([undolly_points(q, s, z) @ M for q, M, s, z in zip(p, turns, scales, z_ref)])
    return torch.from_numpy(back).to(points.device, points.dtype)


def valid_slots(type_logits: torch.Tensor, n_slots: int, joint_counts: list[int] | None) -> torch.Tensor:
    """(B, n_slots) bool: the joint slots of each frame's predicted type (all without ``joint_counts``)."""
    slots = torch.arange(n_slots, device=type_logits.device)
    if joint_counts is None:
        return torch.ones(type_logits.shape[0], n_slots, dtype=torch.bool, device=type_logits.device)
    counts = torch.as_tensor(joint_counts, device=type_logits.device)[type_logits.argmax(-1)]
    return slots[None] < counts[:, None]


def zoom_combine(single: dict, zoomed: dict, turns: np.ndarray, scales: np.ndarray, camera: np.ndarray,
                 mask_threshold: float = 0.0, joint_counts: list[int] | None = None, weight: float = 0.5) -> dict:
    """The weighted mean of ``single`` (outputs on the images) and ``zoomed`` (outputs on the
    views ``turns``, ``scales`` of cameras ``camera`` (B, 4)), ``weight`` on the second look; both
    dicts with :data:`OUTPUT_KEYS` (``mask_logits`` optional). ``mask_threshold``: the model's
    mask decision logit."""
    joints2 = zoomed["joints"].float()
    valid2 = valid_slots(zoomed["type_logits"], joints2.shape[1], joint_counts)
    z_ref = ((joints2[..., 2] * valid2).sum(1) / valid2.sum(1).clamp(min=1)).cpu().numpy()
    points = unzoom_points(torch.cat([joints2, zoomed["base"].float()[:, None]], 1), turns, scales, z_ref)
    w = float(weight)
    probs = (1 - w) * single["type_logits"].float().softmax(-1) + w * zoomed["type_logits"].float().softmax(-1)
    out = {"joints": (1 - w) * single["joints"].float() + w * points[:, :-1],
           "base": (1 - w) * single["base"].float() + w * points[:, -1],
           "type_logits": probs.clamp(min=1e-12).log()}
    if "mask_logits" in single:
        first = single["mask_logits"].float()
        back, covered = unwarp_maps(zoomed["mask_logits"].float(), turns, scales, camera)
        pi = (first > mask_threshold).float().mean((1, 2, 3)).clamp(1e-3, 0.5)
        pi2 = (pi * torch.as_tensor(scales, dtype=pi.dtype, device=pi.device) ** 2).clamp(1e-3, 0.5)
        shift = (torch.log((1 - pi) / pi) - torch.log((1 - pi2) / pi2)).reshape(-1, 1, 1, 1)
        out["mask_logits"] = torch.where(covered, (1 - w) * first + w * (back + shift), first)
    return out


def zoom_refine(forward: Callable[[torch.Tensor], dict], images: torch.Tensor, single: dict, camera: CameraLike,
                settings: dict | None = None, joint_counts: list[int] | None = None,
                mask_threshold: float = 0.0) -> dict:
    """The zoom-test result, given ``single``, the outputs of ``forward`` on ``images``
    (B, 3, H, W) in [0, 1]: ``forward`` runs once more, on the second look's views.
    ``camera``: (fx, fy, cx, cy) of the network input in pixels, or one row per frame.
    ``settings``: ``{fill, max_zoom, weight}`` (:func:`settings_from_config`; default
    :data:`DEFAULT_SETTINGS`). ``joint_counts`` (joints of each robot type, by class index):
    the box then holds only the joints of each frame's predicted type (and the base)."""
    st = {**DEFAULT_SETTINGS, **(settings or {})}
    turns, scales, cams = second_look_views(images, single, camera, st, joint_counts)
    views = warp_images(images, turns, scales, cams).contiguous(memory_format=torch.channels_last)
    return zoom_combine(single, forward(views), turns, scales, cams, mask_threshold, joint_counts, float(st["weight"]))


def second_look_views(images: torch.Tensor, single: dict, camera: CameraLike, settings: dict,
                      joint_counts: list[int] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(turns, scales, cameras)`` of the second look at ``images`` (B, 3, H, W), from the first
    pass's outputs ``single``: :func:`zoom_views` of its base and the joints of its predicted type."""
    cams = camera_rows(camera, images.shape[0])
    joints = single["joints"].float()
    valid = torch.cat([valid_slots(single["type_logits"], joints.shape[1], joint_counts),
                       torch.ones(joints.shape[0], 1, dtype=torch.bool, device=joints.device)], 1)
    points = torch.cat([joints, single["base"].float()[:, None]], 1).detach().double().cpu().numpy()
    turns, scales = zoom_views(points, valid.cpu().numpy(), cams, (images.shape[-1], images.shape[-2]),
                               float(settings["fill"]), check_max_zoom(settings["max_zoom"]))
    return turns, scales, cams


def forward_with_zoom(model, images: torch.Tensor, camera: CameraLike, settings: dict | None = None,
                      joint_counts: list[int] | None = None) -> tuple[dict, dict]:
    """``(single, zoomed)``: the model's outputs on ``images`` and the zoom-test result
    (two forward passes, the second on the second look's views)."""
    single = model(images)
    threshold = float(getattr(model, "mask_threshold", 0.0))
    return single, zoom_refine(model, images, single, camera, settings, joint_counts, threshold)

"""Zoom test: a second look at the robot, magnified, mapped back and averaged with the first.

The robot covers a median 3-8 % of a frame (section V of the paper: 5-22 %), so the network
reads its type and outline from few pixels. The zoom test takes the first pass's estimate of
where the robot is (the box of its projected joints and base, grown by ``margin`` on each
side), magnifies the network input about that box's centre by ``k = min(W / box_w, H / box_h)``
clipped to ``[1, max_zoom]``, puts the box centre on the principal point, and runs the
network again. The second pass's outputs are mapped back to the original image's camera and
averaged with the first pass's: joints, base and type probabilities everywhere, mask logits
where the magnified image covers the pixel (the first pass's alone elsewhere). ``armpose
predict --zoom`` uses it, and the ``evaluate`` stage reports it next to the single pass
(``evaluate.zoom_test``).

Geometry (pixels of the network input; network camera ``fx, fy, cx, cy``; positions in
metres, camera optical frame: x right, y down, z forward). The magnified image maps pixel
``p`` of the input to ``p' = k p + t`` with ``t = c - k m`` (``c = (cx, cy)``, ``m`` the box
centre): it is the image of a camera with focal lengths ``k fx, k fy`` and principal point
``k c + t``. The network reads it as if taken by its own camera, so a point it predicts at
``(x', y', z')`` lies on the magnified image's pixel ``(fx x'/z' + cx, fy y'/z' + cy)``,
whose true ray follows from the magnified camera; its apparent size is ``k`` times the
original's, so its depth is ``k z'`` (the depth that apparent size gives). Hence::

    z = k z',   x = (fx x'/z' + cx - k cx - t_x) z / (k fx),   y likewise.

``k = 1`` and ``t = 0`` give back the first pass exactly; where the box fills the frame, ``k``
is clipped to 1 but the frame is still shifted to centre the box. The box holds the joints of the
predicted robot type and the base, when the caller passes the types' joint counts.
"""
from __future__ import annotations

from typing import Callable

import torch
import torch.nn.functional as F

OUTPUT_KEYS = ("joints", "base", "type_logits", "mask_logits")


CameraLike = "tuple[float, float, float, float] | torch.Tensor"   # one (fx, fy, cx, cy), or one per frame


def camera_columns(camera, n: int, like: torch.Tensor) -> list[torch.Tensor]:
    """``[fx, fy, cx, cy]``, each (n,), from one camera ``(fx, fy, cx, cy)`` or one per frame (n, 4)."""
    cam = torch.as_tensor(camera, dtype=like.dtype, device=like.device)
    if cam.shape not in ((4,), (n, 4)):
        raise ValueError(f"camera must be (fx, fy, cx, cy) or one per frame ({n}, 4), got shape {tuple(cam.shape)}")
    return list(cam.expand(n, 4).unbind(-1))


def check_max_zoom(max_zoom) -> float:
    """``max_zoom`` as a float, or a ValueError naming it unless it is a number >= 1."""
    if isinstance(max_zoom, bool) or not isinstance(max_zoom, (int, float)) or not max_zoom >= 1:
        raise ValueError(f"max_zoom must be a number >= 1, got {max_zoom!r}")
    return float(max_zoom)


def zoom_for_points(points: torch.Tensor, camera: CameraLike, size: tuple[int, int], max_zoom: float = 1.5,
                    margin: float = 0.25, pad_px: float = 8.0,
                    valid: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """``(k, t)``: per frame, magnification ``k`` (B,) and offset ``t`` (B, 2) pixels that put the
    box of ``points`` (B, N, 3) (metres, camera frame, in front of the camera; only those where
    ``valid`` (B, N) is true, if given) at the principal point, magnified to fill the image
    ``size`` = (width, height) with ``margin`` (a fraction of the box size) plus ``pad_px`` on
    every side, ``1 <= k <= max_zoom``. Where ``k`` is clipped to 1 the frame is still shifted
    by ``t``, to centre the box."""
    max_zoom = check_max_zoom(max_zoom)
    fx, fy, cx, cy = (c[:, None] for c in camera_columns(camera, points.shape[0], points))
    width, height = size
    z = points[..., 2].clamp(min=1e-3)
    u, v = fx * points[..., 0] / z + cx, fy * points[..., 1] / z + cy
    if valid is not None:
        inf = torch.full_like(u, float("inf"))
        umin, umax = torch.where(valid, u, inf).amin(1), torch.where(valid, u, -inf).amax(1)
        vmin, vmax = torch.where(valid, v, inf).amin(1), torch.where(valid, v, -inf).amax(1)
    else:
        umin, umax, vmin, vmax = u.amin(1), u.amax(1), v.amin(1), v.amax(1)
    box_w = (umax - umin + 1) * (1 + 2 * margin) + 2 * pad_px
    box_h = (vmax - vmin + 1) * (1 + 2 * margin) + 2 * pad_px
    k = torch.minimum(width / box_w, height / box_h).clamp(1.0, float(max_zoom))
    centre = torch.stack([(umin + umax) / 2, (vmin + vmax) / 2], -1)
    t = torch.cat([cx, cy], 1) - k[:, None] * centre
    return k, t


def magnify(images: torch.Tensor, k: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """``images`` (B, C, H, W) resampled so that pixel ``p`` goes to ``k p + t`` (bilinear;
    pixels from outside the image are 0)."""
    return _affine_resample(images, 1.0 / k, -t / k[:, None])


def unmagnify(maps: torch.Tensor, k: torch.Tensor, t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(maps back, covered)``: ``maps`` (B, C, H, W) of a magnified image resampled to the
    original pixels (pixel ``p`` reads ``k p + t``), and a (B, 1, H, W) bool of the pixels whose
    source lies inside the magnified image."""
    back = _affine_resample(maps, k, t)
    n, _, h, w = maps.shape
    kk, tx, ty = k.reshape(n, 1, 1, 1), t[:, 0].reshape(n, 1, 1, 1), t[:, 1].reshape(n, 1, 1, 1)
    u = kk * torch.arange(w, dtype=k.dtype, device=k.device).reshape(1, 1, 1, w) + tx
    v = kk * torch.arange(h, dtype=k.dtype, device=k.device).reshape(1, 1, h, 1) + ty
    covered = (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    return back, covered


def _affine_resample(x: torch.Tensor, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Output pixel ``p`` (pixel-centre coordinates, 0 at the first pixel) reads input pixel
    ``a p + b``; ``a`` (B,), ``b`` (B, 2). Bilinear, zeros outside."""
    n, _, h, w = x.shape
    size = torch.tensor([w, h], dtype=x.dtype, device=x.device)
    a, b = a.to(x.dtype), b.to(x.dtype)
    # normalised coordinates (align_corners=False): q = (2 p + 1) / size - 1, so
    # q_in = a q_out + (a - 1) + (2 b + 1 - a) / size
    theta = torch.zeros(n, 2, 3, dtype=x.dtype, device=x.device)
    theta[:, 0, 0] = a
    theta[:, 1, 1] = a
    theta[:, :, 2] = a[:, None] - 1 + (2 * b + 1 - a[:, None]) / size
    grid = F.affine_grid(theta, list(x.shape), align_corners=False)
    return F.grid_sample(x, grid, mode="bilinear", padding_mode="zeros", align_corners=False)


def unzoom_points(points: torch.Tensor, k: torch.Tensor, t: torch.Tensor, camera: CameraLike) -> torch.Tensor:
    """Points ``(B, ..., 3)`` predicted on magnified images, in the original camera's frame
    (module docstring). ``k`` (B,), ``t`` (B, 2) as from :func:`zoom_for_points`."""
    shape = (-1,) + (1,) * (points.dim() - 2)
    fx, fy, cx, cy = (c.reshape(shape) for c in camera_columns(camera, points.shape[0], points))
    kk, tx, ty = k.to(points.dtype).reshape(shape), t[:, 0].to(points.dtype).reshape(shape), t[:, 1].to(points.dtype).reshape(shape)
    zp = points[..., 2]
    # x = (fx x'/z' + cx - k cx - t_x) z / (k fx) with z = k z', without dividing by z'
    x = points[..., 0] + ((1 - kk) * cx - tx) * zp / fx
    y = points[..., 1] + ((1 - kk) * cy - ty) * zp / fy
    return torch.stack([x, y, kk * zp], -1)


def zoom_average(single: dict, zoomed: dict, k: torch.Tensor, t: torch.Tensor, camera: CameraLike) -> dict:
    """The mean of ``single`` (outputs on the images) and ``zoomed`` (outputs on the magnified
    images), both dicts with :data:`OUTPUT_KEYS` (``mask_logits`` optional)."""
    probs = (single["type_logits"].float().softmax(-1) + zoomed["type_logits"].float().softmax(-1)) / 2
    out = {"joints": (single["joints"] + unzoom_points(zoomed["joints"], k, t, camera)) / 2,
           "base": (single["base"] + unzoom_points(zoomed["base"][:, None], k, t, camera)[:, 0]) / 2,
           "type_logits": probs.clamp(min=1e-12).log()}
    if "mask_logits" in single:
        back, covered = unmagnify(zoomed["mask_logits"].float(), k, t)
        first = single["mask_logits"].float()
        out["mask_logits"] = torch.where(covered, (first + back) / 2, first)
    return out


def zoom_refine(forward: Callable[[torch.Tensor], dict], images: torch.Tensor, single: dict, camera: CameraLike,
                max_zoom: float = 1.5, margin: float = 0.25, joint_counts: list[int] | None = None) -> dict:
    """The zoom-test average, given ``single``, the outputs of ``forward`` on ``images``
    (B, 3, H, W) in [0, 1]: ``forward`` runs once more, on the magnified images.
    ``camera``: (fx, fy, cx, cy) of the network input in pixels, or one row per frame.
    ``joint_counts`` (joints of each robot type, by class index): the box then holds only the
    joints of each frame's predicted type (and the base), not the unused slots."""
    points = torch.cat([single["joints"], single["base"][:, None]], 1).float()
    valid = None
    if joint_counts is not None:
        counts = torch.as_tensor(joint_counts, device=points.device)[single["type_logits"].argmax(-1)]
        slots = torch.arange(points.shape[1], device=points.device)
        valid = (slots[None] < counts[:, None]) | (slots[None] == points.shape[1] - 1)
    k, t = zoom_for_points(points, camera, (images.shape[-1], images.shape[-2]), max_zoom, margin, valid=valid)
    zoomed_images = magnify(images.float(), k, t).to(images.dtype).contiguous(memory_format=torch.channels_last)
    return zoom_average(single, forward(zoomed_images), k, t, camera)


def forward_with_zoom(model, images: torch.Tensor, camera: CameraLike, max_zoom: float = 1.5,
                      margin: float = 0.25, joint_counts: list[int] | None = None) -> tuple[dict, dict]:
    """``(single, averaged)``: the model's outputs on ``images`` and the zoom-test average
    (two forward passes, the second on the magnified images)."""
    single = model(images)
    return single, zoom_refine(model, images, single, camera, max_zoom, margin, joint_counts)

"""Plots and small summaries for the narrated notebooks of the ``render`` and ``labels`` stages.

Conventions (those of :mod:`armpose.geometry`):

- 3D points in the *camera optical frame* are OpenCV's: x right, y down, z forward, metres;
- pixel coordinates ``(u, v)``: u to the right, v down, the centre of pixel ``(col, row)``
  at ``(u, v) = (col, row)``; images are ``(H, W, 3)`` RGB uint8, masks ``(H, W)`` {0, 1};
- camera poses in a recording (``camera_poses.csv``) are the optical frame in the robot
  *base frame* (z up, metres);
- ``intrinsics`` are ``(fx, fy, cx, cy)`` in pixels of the image they belong to (for the
  labelled dataset: the network input, after scale and crop).

Figures are built with matplotlib's object API (:class:`matplotlib.figure.Figure`, no pyplot):
no global figure state, nothing to close, works with the Agg backend and shows inline in
Jupyter when it is a cell's last expression (after ``%matplotlib inline``).
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import cv2
import numpy as np
from matplotlib.figure import Figure

from armpose.recording import find_recordings, read_frame, read_joints, read_meta, read_poses
from armpose.geometry import quat_to_matrix

#: Fraction of the image covered by the robot in the paper's real datasets (section IV-A),
#: by robot family (:attr:`armpose.robots.registry.RobotSpec.family`).
PAPER_MASK_AREA = {"UR": (0.06, 0.17), "KUKA": (0.08, 0.18), "Panda": (0.05, 0.22)}

MASK_COLOR = (255, 40, 40)      # RGB tint of the robot mask in overlays
BASE_COLOR = (0, 255, 255)      # RGB of the base marker and of the base-to-joint-1 link
SPLIT_NAMES = {0: "train", 1: "test"}


# --------------------------------------------------------------------------- geometry helpers

def project(points_cam: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """Pixel coordinates ``(..., 2)`` of points ``(..., 3)`` in the camera optical frame (metres).

    ``u = fx * x / z + cx``, ``v = fy * y / z + cy`` with ``intrinsics = (fx, fy, cx, cy)``
    in pixels, shape ``(4,)`` or with leading dimensions matching those of ``points_cam``
    (e.g. joints ``(N, J, 3)`` with intrinsics ``(N, 4)``). Points with ``z <= 0`` (behind
    the camera) give NaN.
    """
    p = np.asarray(points_cam, dtype=np.float64)
    k = np.asarray(intrinsics, dtype=np.float64)
    if p.shape[-1] != 3 or k.shape[-1] != 4:
        raise ValueError(f"expected points (..., 3) and intrinsics (..., 4), got {p.shape} and {k.shape}")
    while k.ndim < p.ndim:
        k = k[..., None, :]
    z = p[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = k[..., 0] * p[..., 0] / z + k[..., 2]
        v = k[..., 1] * p[..., 1] / z + k[..., 3]
    uv = np.stack(np.broadcast_arrays(u, v), -1)
    uv[z <= 0] = np.nan
    return uv


def chw_to_uint8(image) -> np.ndarray:
    """A network-input image, (3, H, W) float RGB in [0, 1] (numpy, or a CPU tensor), as the
    (H, W, 3) uint8 RGB image the drawing functions take; rounded, values outside [0, 1] clipped."""
    arr = np.asarray(image, dtype=np.float32).transpose(1, 2, 0)
    return np.clip(np.rint(arr * 255), 0, 255).astype(np.uint8)


def _pt(uv, shift: int = 4) -> tuple[int, int]:
    """A sub-pixel point for cv2 drawing functions called with ``shift``."""
    return int(round(float(uv[0]) * (1 << shift))), int(round(float(uv[1]) * (1 << shift)))


def _joint_colors(n: int) -> list[tuple[int, int, int]]:
    """``n`` RGB colours along the kinematic chain, yellow (joint 1) to magenta (last joint)."""
    t = np.linspace(0.0, 1.0, max(n, 1))
    return [(255, int(230 * (1 - s)), int(255 * s)) for s in t]


def overlay_labels(image: np.ndarray, mask: np.ndarray | None, joints_uv: np.ndarray | None,
                   base_uv: np.ndarray | None = None, joint_valid: np.ndarray | None = None,
                   alpha: float = 0.45, radius: int = 3) -> np.ndarray:
    """The labels drawn onto a copy of ``image``; returns ``(H, W, 3)`` uint8 RGB.

    ``image`` is ``(H, W, 3)`` uint8 RGB; ``mask`` ``(H, W)`` (non-zero = robot) is tinted in
    :data:`MASK_COLOR` with opacity ``alpha``; ``joints_uv`` ``(J, 2)`` and ``base_uv`` ``(2,)``
    are pixel coordinates (see :func:`project`). The skeleton base -> joint 1 -> ... -> joint J
    is drawn as lines, joints as circles coloured along the chain, the base as a square.
    Joints that are not valid (``joint_valid`` False, or NaN) are left out.
    """
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"image must be (H, W, 3), got {img.shape}")
    out = np.array(img, dtype=np.uint8, order="C", copy=True)   # cv2 draws on C-contiguous arrays only
    if mask is not None:
        m = np.asarray(mask).astype(bool)
        if m.shape != out.shape[:2]:
            raise ValueError(f"mask {m.shape} does not match image {out.shape[:2]}")
        tint = np.array(MASK_COLOR, np.float32)
        out[m] = np.clip((1 - alpha) * out[m].astype(np.float32) + alpha * tint, 0, 255).astype(np.uint8)
    chain: list[tuple[np.ndarray, tuple[int, int, int]]] = []
    has_base = base_uv is not None and bool(np.all(np.isfinite(base_uv)))
    if has_base:
        chain.append((np.asarray(base_uv, np.float64).reshape(2), BASE_COLOR))
    if joints_uv is not None:
        juv = np.asarray(joints_uv, np.float64).reshape(-1, 2)
        valid = np.ones(len(juv), bool) if joint_valid is None else np.asarray(joint_valid, bool).copy()
        valid &= np.isfinite(juv).all(axis=1)
        colors = _joint_colors(int(valid.sum()))
        chain += [(uv, c) for uv, c in zip(juv[valid], colors)]
    for (a, _), (b, cb) in zip(chain[:-1], chain[1:]):
        cv2.line(out, _pt(a), _pt(b), cb, 1, cv2.LINE_AA, shift=4)
    for k, (uv, c) in enumerate(chain):
        if k == 0 and has_base:
            r = radius + 1
            x, y = _pt(uv, 0)
            cv2.rectangle(out, (x - r, y - r), (x + r, y + r), c, 1, cv2.LINE_AA)
        else:
            cv2.circle(out, _pt(uv), radius << 4, c, -1, cv2.LINE_AA, shift=4)
    return out


# --------------------------------------------------------------------------- figures

def sample_grid(images: Sequence[np.ndarray], titles: Sequence[str] | None = None, ncols: int = 4,
                cell_inches: float = 2.6, suptitle: str | None = None) -> Figure:
    """A figure showing ``images`` (each ``(H, W, 3)`` uint8 RGB) in a grid of ``ncols`` columns."""
    n = len(images)
    if n == 0:
        raise ValueError("no images to show")
    ncols = max(1, min(ncols, n))
    nrows = -(-n // ncols)
    h, w = np.asarray(images[0]).shape[:2]
    fig = Figure(figsize=(cell_inches * ncols, cell_inches * nrows * h / w + 0.35 * nrows), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False)
    for k, ax in enumerate(axes.flat):
        ax.set_axis_off()
        if k < n:
            ax.imshow(images[k], interpolation="nearest")
            if titles is not None:
                ax.set_title(titles[k], fontsize=8)
    if suptitle:
        fig.suptitle(suptitle)
    return fig


def _frame_ids(rec_dir: Path) -> list[int]:
    return sorted(int(p.stem) for p in (Path(rec_dir) / "frames").glob("*.png"))


def render_samples(render_dir: Path, robot_types: Sequence[str], per_robot: int = 4,
                   seed: int = 0) -> tuple[list[np.ndarray], list[str]]:
    """``per_robot`` random frames of each robot type's recordings under ``render_dir``
    (``render_dir/<robot>/<recording>/``), read with :func:`armpose.recording.read_frame`.

    Returns the images (full camera resolution, RGB uint8) robot by robot, and titles
    ``"<robot> <recording> #<frame>"``. Robots without recordings are left out.
    """
    rng = np.random.default_rng(seed)
    images, titles = [], []
    for robot in robot_types:
        recs = find_recordings(Path(render_dir) / robot)
        pairs = [(rec, f) for rec in recs for f in _frame_ids(rec)]
        if not pairs:
            continue
        for k in sorted(rng.choice(len(pairs), size=min(per_robot, len(pairs)), replace=False)):
            rec, frame = pairs[k]
            meta, _ = read_meta(rec)
            images.append(read_frame(rec, frame, meta.camera))
            titles.append(f"{meta.robot}  {rec.name}  #{frame}")
    return images, titles


def render_samples_figure(render_dir: Path, robot_types: Sequence[str], per_robot: int = 4,
                          seed: int = 0) -> Figure:
    """A grid of rendered frames, one row per robot type (see :func:`render_samples`)."""
    images, titles = render_samples(render_dir, robot_types, per_robot, seed)
    return sample_grid(images, titles, ncols=per_robot)


def camera_poses_figure(rec_dir: Path, axis_length: float = 0.25) -> Figure:
    """Where the camera was in one recording: a 3D view and a top-down view (x-y plane).

    Everything is in the robot base frame (metres, z up). Camera centres are coloured by frame
    index; short lines of ``axis_length`` metres show the optical axis (+z of the optical
    frame); the robot's base and joints at the first frame (forward kinematics of
    ``joints.csv``) are drawn as a grey skeleton for scale.
    """
    from armpose.robots.kinematics import Kinematics

    rec_dir = Path(rec_dir)
    meta, spec = read_meta(rec_dir)
    _, poses, _ = read_poses(rec_dir)
    _, q, _ = read_joints(rec_dir, spec)
    xyz = poses[:, :3]
    fwd = quat_to_matrix(poses[:, 3:])[:, :, 2]
    skel = np.vstack([np.zeros((1, 3)), Kinematics(spec).joint_positions(q[:1])[0]])
    frames = np.arange(len(xyz))

    fig = Figure(figsize=(12, 5), layout="constrained")
    fig.get_layout_engine().set(wspace=0.12)
    grid = fig.add_gridspec(1, 2, width_ratios=[1.15, 1])
    ax3 = fig.add_subplot(grid[0], projection="3d")
    ax2 = fig.add_subplot(grid[1])
    sc = ax3.scatter(*xyz.T, c=frames, cmap="viridis", s=18)
    tips = xyz + axis_length * fwd
    for a, b in zip(xyz, tips):
        ax3.plot(*np.stack([a, b]).T, color="0.4", lw=0.8)
        ax2.plot(*np.stack([a, b])[:, :2].T, color="0.4", lw=0.8)
    ax3.plot(*skel.T, "-o", color="0.3", ms=3, lw=2, label=f"{meta.robot}, frame 0")
    ax3.scatter([0], [0], [0], marker="s", color="k", s=30, label="base")
    ax3.set_xlabel("x [m]")
    ax3.set_ylabel("y [m]")
    ax3.set_zlabel("z [m]", labelpad=2)
    span = np.ptp(np.vstack([xyz, skel, [[0, 0, 0]]]), axis=0)
    ax3.set_box_aspect(np.maximum(span, 1e-3))
    ax3.legend(loc="upper left", fontsize=8)
    ax3.set_title("camera centres and optical axes (base frame)")
    ax2.scatter(xyz[:, 0], xyz[:, 1], c=frames, cmap="viridis", s=18)
    ax2.plot(skel[:, 0], skel[:, 1], "-o", color="0.3", ms=3, lw=2)
    ax2.plot([0], [0], "ks", ms=6)
    ax2.set_aspect("equal", adjustable="datalim")
    ax2.set_xlabel("x [m]")
    ax2.set_ylabel("y [m]")
    ax2.set_title("top-down view")
    ax2.grid(alpha=0.3)
    fig.colorbar(sc, ax=[ax3, ax2], label="frame", shrink=0.7)
    fig.suptitle(f"{rec_dir.name}: {len(xyz)} camera poses")
    return fig


# --------------------------------------------------------------------------- labelled dataset

def label_samples(arrays: dict, index: dict, per_robot: int = 3, seed: int = 0,
                  split: int | None = None) -> tuple[list[np.ndarray], list[str]]:
    """``per_robot`` random frames per robot type of a labelled dataset
    (:func:`armpose.labels.dataset.load_dataset`), with mask, joints and base drawn by
    :func:`overlay_labels` after projecting them with the frame's ``intrinsics``.

    ``split`` (0 train, 1 test) restricts the draw. Returns the overlays (network-input size,
    RGB uint8) and titles with the robot, recording, frame, camera-to-base distance (metres)
    and mask area (percent of the image).
    """
    rng = np.random.default_rng(seed)
    robot = np.asarray(arrays["robot"])
    keep = np.ones(len(robot), bool) if split is None else np.asarray(arrays["split"]) == split
    images, titles = [], []
    for r, name in enumerate(index["robot_types"]):
        idx = np.flatnonzero((robot == r) & keep)
        if idx.size == 0:
            continue
        for i in np.sort(rng.choice(idx, size=min(per_robot, idx.size), replace=False)):
            intr = np.asarray(arrays["intrinsics"][i])
            mask = np.asarray(arrays["masks"][i])
            over = overlay_labels(np.asarray(arrays["images"][i]), mask,
                                  project(arrays["joints"][i], intr), project(arrays["base"][i], intr),
                                  joint_valid=np.asarray(arrays["joint_valid"][i]))
            rec = Path(index["recordings"][int(arrays["recording"][i])]["name"]).name
            images.append(over)
            titles.append(f"{name}  {rec}  #{int(arrays['frame'][i])}\n"
                          f"d={float(arrays['distance'][i]):.2f} m, mask {100 * mask.mean():.1f} %")
    return images, titles


def label_samples_figure(arrays: dict, index: dict, per_robot: int = 3, seed: int = 0,
                         split: int | None = None) -> Figure:
    """A grid of labelled frames, one row per robot type (see :func:`label_samples`)."""
    images, titles = label_samples(arrays, index, per_robot, seed, split)
    return sample_grid(images, titles, ncols=per_robot, cell_inches=3.0)


def augmented_samples(data_dir: Path, rows: Sequence[int], augment: dict, seed: int = 0,
                      epochs: int = 3) -> tuple[list[np.ndarray], list[str]]:
    """Each dataset row in ``rows`` as stored, then as the training loader gives it in
    ``epochs`` epochs with ``augment`` (a stage's ``augment`` section), with mask, joints
    and base drawn on (:func:`overlay_labels`): the labels must sit on the robot in every
    draw. Titles give the row, the epoch and the camera-to-robot ``distance`` (metres)."""
    from armpose.data import LabelledFrames   # torch, only for this figure

    plain = LabelledFrames(Path(data_dir), np.asarray(rows, np.int64))
    moved = LabelledFrames(Path(data_dir), np.asarray(rows, np.int64), augment=augment, seed=seed)
    images, titles = [], []
    for i, row in enumerate(rows):
        for epoch in range(-1, epochs):
            item = plain[i] if epoch < 0 else moved[(i, epoch)]
            image = chw_to_uint8(item["image"].numpy())
            intr = item["intrinsics"].numpy()
            images.append(overlay_labels(image, item["mask"].numpy(), project(item["joints"].numpy(), intr),
                                         project(item["base"].numpy(), intr), item["joint_valid"].numpy()))
            what = "as stored" if epoch < 0 else f"epoch {epoch}"
            titles.append(f"row {int(row)}, {what}\nd={float(item['distance']):.2f} m")
    return images, titles


def augmentation_figure(data_dir: Path, rows: Sequence[int], augment: dict, seed: int = 0,
                        epochs: int = 3) -> Figure:
    """A grid of :func:`augmented_samples`: one row per dataset row, the stored frame first."""
    images, titles = augmented_samples(data_dir, rows, augment, seed, epochs)
    return sample_grid(images, titles, ncols=epochs + 1, cell_inches=2.6)


def mask_area_fraction(masks: np.ndarray, chunk: int = 512) -> np.ndarray:
    """Fraction ``(N,)`` of each mask's pixels that are robot (non-zero), read in chunks so
    memory-mapped masks ``(N, H, W)`` are never loaded whole."""
    n = len(masks)
    out = np.empty(n, np.float64)
    for s in range(0, n, chunk):
        m = np.asarray(masks[s:s + chunk])
        out[s:s + chunk] = (m.reshape(len(m), -1) != 0).mean(axis=1)
    return out


def mask_area_by_robot(arrays: dict, index: dict) -> dict[str, np.ndarray]:
    """Mask area fraction (0-1 of the image) of every frame, grouped by robot type name."""
    area = mask_area_fraction(arrays["masks"])
    robot = np.asarray(arrays["robot"])
    return {name: area[robot == r] for r, name in enumerate(index["robot_types"]) if (robot == r).any()}


def _family(robot: str) -> str | None:
    from armpose.robots.registry import get_robot
    try:
        return get_robot(robot).family
    except Exception:  # an unknown type: no paper range to compare with
        return None


def mask_area_summary(areas: dict[str, np.ndarray]) -> list[dict]:
    """Per robot type: frame count, 5th/50th/95th percentile and min/max of the mask area
    (fractions 0-1), the paper's range for the robot's family (:data:`PAPER_MASK_AREA`) and
    the fraction of frames inside that range."""
    rows = []
    for robot, a in areas.items():
        fam = _family(robot)
        lo, hi = PAPER_MASK_AREA.get(fam, (np.nan, np.nan))
        p5, p50, p95 = np.percentile(a, [5, 50, 95])
        rows.append({"robot": robot, "family": fam, "frames": int(a.size), "min": float(a.min()),
                     "p5": float(p5), "median": float(p50), "p95": float(p95), "max": float(a.max()),
                     "paper": (lo, hi), "in_paper_range": float(((a >= lo) & (a <= hi)).mean())})
    return rows


def format_table(rows: list[dict], percent: Sequence[str] = ()) -> str:
    """``rows`` (dicts with the same keys) as a plain-text table; keys in ``percent`` are shown
    as percentages (fractions x 100), tuples as ``lo-hi``."""
    def cell(key, v):
        if isinstance(v, tuple):
            return "-".join(cell(key, x) for x in v)
        if isinstance(v, float):
            return f"{100 * v:.1f}" if key in percent else f"{v:.3g}"
        return str(v)
    if not rows:
        return "(empty)"
    keys = list(rows[0])
    head = [k + (" %" if k in percent else "") for k in keys]
    body = [[cell(k, r[k]) for k in keys] for r in rows]
    widths = [max(len(h), *(len(b[i]) for b in body)) for i, h in enumerate(head)]
    line = lambda cells: "  ".join(c.rjust(w) for c, w in zip(cells, widths))  # noqa: E731
    return "\n".join([line(head), line(["-" * w for w in widths])] + [line(b) for b in body])


def mask_area_figure(areas: dict[str, np.ndarray]) -> Figure:
    """Box plots of the mask area (percent of the image) per robot type, with the paper's
    range for the robot's family shaded behind each box."""
    names = list(areas)
    fig = Figure(figsize=(1.4 * len(names) + 2.5, 4), layout="constrained")
    ax = fig.subplots()
    for k, robot in enumerate(names, start=1):
        rng_ = PAPER_MASK_AREA.get(_family(robot))
        if rng_:
            ax.fill_between([k - 0.4, k + 0.4], 100 * rng_[0], 100 * rng_[1], color="tab:orange", alpha=0.25,
                            label="paper range (real data)" if k == 1 else None, lw=0)
    ax.boxplot([100 * areas[n] for n in names], tick_labels=names, whis=(5, 95), showfliers=True,
               flierprops={"markersize": 3})
    ax.set_ylabel("robot mask area [% of image]")
    ax.set_title("mask area per robot type (whiskers: 5th-95th percentile)")
    ax.grid(axis="y", alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    return fig


def distance_histogram(arrays: dict, index: dict, bins: int | np.ndarray = 20) -> Figure:
    """Histograms of the camera-to-base distance (metres, ``distance`` array), one panel per
    robot type, on shared bins."""
    d = np.asarray(arrays["distance"], np.float64)
    robot = np.asarray(arrays["robot"])
    if np.isscalar(bins):
        bins = np.linspace(np.floor(d.min() * 10) / 10, np.ceil(d.max() * 10) / 10, int(bins) + 1)
    present = [(r, name) for r, name in enumerate(index["robot_types"]) if (robot == r).any()]
    fig = Figure(figsize=(2.7 * len(present) + 0.5, 3.2), layout="constrained")
    axes = fig.subplots(1, len(present), sharex=True, sharey=True, squeeze=False)[0]
    for ax, (r, name) in zip(axes, present):
        sel = d[robot == r]
        ax.hist(sel, bins=bins, color=f"C{r}", alpha=0.8)
        ax.axvline(np.median(sel), color="k", lw=1, ls="--")
        ax.set_title(f"{name}: n={sel.size}, median {np.median(sel):.2f} m", fontsize=9)
        ax.set_xlabel("distance [m]")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("frames")
    fig.suptitle("camera-to-base distance per robot type (dashed: median)")
    return fig


def split_counts(arrays: dict, index: dict) -> list[dict]:
    """Frames per robot type in the train (0) and test (1) split, plus a total row."""
    robot, split = np.asarray(arrays["robot"]), np.asarray(arrays["split"])
    rows = []
    for r, name in enumerate(index["robot_types"]):
        sel = robot == r
        n_tr, n_te = int((sel & (split == 0)).sum()), int((sel & (split == 1)).sum())
        rows.append({"robot": name, "train": n_tr, "test": n_te,
                     "test_fraction": n_te / max(n_tr + n_te, 1)})
    tr, te = int((split == 0).sum()), int((split == 1).sum())
    rows.append({"robot": "all", "train": tr, "test": te, "test_fraction": te / max(tr + te, 1)})
    return rows

"""Plots for the narrated notebook of the ``record`` stage: rig calibration residuals, the errors a
simulated session's labels carry, and label overlays on frames of the moving camera.

Units: residuals and errors in millimetres, degrees and pixels, as named; poses in the robot base
frame (metres). Figures use matplotlib's object API, as in :mod:`armpose.viz`.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from armpose import viz
from armpose.labels.compute import label_recording
from armpose.sessions.session import session_errors

STATUS_COLORS = {"used": "tab:blue", "rejected": "tab:red", "no_board": "0.7"}


def _meta(rec_dir: Path) -> dict:
    return json.loads((Path(rec_dir) / "recording.json").read_text())


def calibration_residuals_figure(rec_dir: Path) -> Figure:
    """Per-view residuals of a session's rig calibration (``recording.json``'s ``rig_calibration``):
    board-centre translation (mm), rotation (deg) and RMS reprojection (px) of the board pose that
    the fitted ``T_rig_cam`` and the mocap predict, against the board seen in the image. Bars are
    coloured by view status (used, rejected as outlier, board not found); the title gives the
    error against the truth for a simulated session."""
    meta = _meta(rec_dir)
    cal = meta.get("rig_calibration")
    if cal is None:
        raise ValueError(f"{rec_dir}/recording.json holds no rig_calibration")
    views = cal["views"]
    x = np.arange(len(views))
    colors = [STATUS_COLORS.get(v["status"], "k") for v in views]
    fig = Figure(figsize=(11, 3.4), layout="constrained")
    axes = fig.subplots(1, 3, sharex=True)
    for ax, key, label in zip(axes, ("translation_mm", "rotation_deg", "reprojection_px"),
                              ("board-centre residual [mm]", "rotation residual [deg]", "RMS reprojection [px]")):
        vals = [np.nan if v[key] is None else v[key] for v in views]
        ax.bar(x, vals, color=colors)
        ax.set_ylabel(label)
        ax.set_xlabel("calibration view")
        ax.grid(axis="y", alpha=0.3)
    title = (f"{Path(rec_dir).name}: T_rig_cam from {cal['views_used']} of {cal['views_given']} views, "
             f"RMS reprojection {cal['rms_reprojection_px']:.2f} px")
    err = meta.get("simulation", {}).get("rig_offset_error")
    if err:
        title += f"; error vs truth {err['translation_mm']:.2f} mm, {err['rotation_deg']:.3f} deg"
    fig.suptitle(title, fontsize=10)
    return fig


def calibration_errors_figure(summary: dict) -> Figure:
    """The rig calibration's error against the truth (mm and deg) of every simulated session in a
    ``data/record/summary.json``, one bar per session."""
    rows = [s for s in summary["sessions"] if s.get("rig_offset_error")]
    if not rows:
        raise ValueError("no session with a known rig offset error (real recordings have no truth)")
    names = [s["name"].split("/")[-1] for s in rows]
    fig = Figure(figsize=(max(6.0, 0.55 * len(rows) + 3), 3.2), layout="constrained")
    axes = fig.subplots(1, 2)
    for ax, key, label in zip(axes, ("translation_mm", "rotation_deg"), ("translation error [mm]", "rotation error [deg]")):
        ax.bar(names, [s["rig_offset_error"][key] for s in rows], color="tab:purple")
        ax.set_ylabel(label)
        ax.tick_params(axis="x", rotation=60, labelsize=8)
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle("estimated vs true T_rig_cam, per session")
    return fig


def session_errors_figure(rec_dir: Path) -> Figure:
    """Per frame of a simulated session: how far the written camera pose is from the true one
    (translation mm, rotation deg) and the largest shift (px, full image) of the base and joints
    projected with it: the label error from rig calibration, mocap noise and the base measurement."""
    err = session_errors(rec_dir)
    frames = np.arange(len(err["camera_translation_mm"]))
    fig = Figure(figsize=(11, 3.0), layout="constrained")
    axes = fig.subplots(1, 3, sharex=True)
    for ax, (key, label) in zip(axes, (("camera_translation_mm", "camera position error [mm]"),
                                       ("camera_rotation_deg", "camera rotation error [deg]"),
                                       ("joint_reprojection_px", "largest joint shift [px]"))):
        ax.plot(frames, err[key], color="tab:green")
        ax.set_ylim(bottom=0)
        ax.set_xlabel("frame")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    fig.suptitle(f"{Path(rec_dir).name}: written vs true camera poses")
    return fig


def label_overlays_figure(rec_dir: Path, input_size: dict, max_joints: int, count: int = 6) -> Figure:
    """``count`` evenly spaced frames of a recording with their labels (mask, joints, base; from
    :func:`armpose.labels.compute.label_recording`, i.e. from the written camera poses) drawn at
    the network input size."""
    arrays, meta, _ = label_recording(Path(rec_dir), input_size, max_joints)
    picks = np.unique(np.linspace(0, len(arrays["frame"]) - 1, count).round().astype(int))
    images, titles = [], []
    for i in picks:
        intr = arrays["intrinsics"][i]
        images.append(viz.overlay_labels(arrays["images"][i], arrays["masks"][i], viz.project(arrays["joints"][i], intr),
                                         viz.project(arrays["base"][i], intr), joint_valid=arrays["joint_valid"][i]))
        titles.append(f"{meta.robot} #{int(arrays['frame'][i])}, d={float(arrays['distance'][i]):.2f} m")
    return viz.sample_grid(images, titles, ncols=min(3, len(images)), cell_inches=3.2)

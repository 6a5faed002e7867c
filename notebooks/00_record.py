# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
#       format_version: '1.3'
#       jupytext_version: 1.19.6
#   kernelspec:
#     display_name: Python 3 (ipykernel)
#     language: python
#     name: python3
# ---

# %% [markdown]
# # 00 · Record: a free-moving camera tracked by motion capture
#
# **Stage `record`** of the pipeline (`dvc.yaml` runs the same function, `armpose.stages.record.run`).
#
# Miseikis et al. (2019, section III) recorded the Franka Panda with a *free-moving* Intel RealSense:
# an operator walked around the robot holding the camera, an OptiTrack motion-capture (mocap) system
# tracked a rigid body of markers (the *rig*) fixed to the camera, and the fixed transform from the rig
# to the camera's optical frame came from a calibration. Every sample is a rectified colour image, the
# joint encoder readings, and the camera pose *as the mocap and the calibration say it was*. Labels
# computed from such a recording carry the errors of both.
#
# This stage makes recordings of that kind. With `record.recordings_dir: null` it **simulates** them;
# pointing `record.recordings_dir` at a folder of real recordings (the format of README, *Recording
# format*) validates and links those instead, with no code change. Everything below is about the
# simulated path, and every number on this page is from simulated sessions, not from real hardware.
#
# One simulated session (`armpose.sessions.session.record_session`), each drawn from the stage's seed:
#
# | part | how | stands in for |
# |---|---|---|
# | scene | one domain-randomised background, lighting, robot colour and exposure for the whole session (as `render`, but fixed: a session is one recording in one room); sensor noise and blur per frame | a lab |
# | robot | minimum-jerk moves between collision-free waypoints, peak joint speed `record.robot.max_joint_speed` | the programmed motion through the joint range |
# | camera | a smooth handheld walk around the robot: distance, elevation, aim and roll drift slowly, the aim follows the robot, a little hand shake | the operator with the RealSense |
# | rig | a true rig-to-camera offset `T_rig_cam` (3-8 cm, 5-20 deg), drawn per session and never shown to the pipeline | a rig glued onto the camera |
# | calibration | a simulated ChArUco session with that rig, solved by `armpose.calib.rig.calibrate_rig` (the `armpose calibrate-rig` solver) | the rig calibration |
# | mocap | the rig's true pose plus noise every frame (0.5 mm, 0.1 deg RMS), the robot base measured once with the same noise | OptiTrack |
#
# Two kinds of session: **handheld** (`record.sessions_per_robot`, named `<robot>_sNN`), as in the
# paper, and **tripod** (`record.tripod_sessions_per_robot`, `<robot>_tNN`): the camera stands still
# on a tripod while the robot moves, the calibration-free use case this project adds: one static
# camera whose pose to the robot should follow from the images alone (and improves when pooled over
# many frames, notebook 06). A tripod session has the same scene, robot motion, rig and calibration;
# its camera pose is drawn once (distance, elevation, azimuth as above; no walk, drift or shake) and
# the mocap measures the rig once, so the written pose is static too, with one constant error.
#
# Frames are rendered at the **true** camera pose; the recording stores
# `T_base_cam = inv(T_world_base_measured) @ T_world_rig_measured @ T_rig_cam_estimated`.
# Each session has its own rig mounting and calibration, so calibration errors differ between
# recordings. The stage `labels` then treats these recordings exactly like real ones (split per
# recording, not per frame): every static-camera recording is test data, and of each robot type's
# moving-camera recordings `ceil(labels.test_fraction x n)` are (a seeded draw), so every robot type
# has recorded test recordings.

# %% tags=["parameters"]
profile = "default"
root = ""

# %% [markdown]
# The two parameters above are papermill's: `profile` names a file in `profiles/` (`""` reads the
# project's `params.yaml`, which is what `dvc repro` uses); `root` is where `data/` is written
# (`""` = the project root). No path depends on the kernel's working directory.

# %%
# %matplotlib inline
import logging
from pathlib import Path

from armpose import viz, viz_record
from armpose.config import load_params, profile_params, project_root
from armpose.recording import find_recordings, static_camera
from armpose.stages import record

logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s", force=True)
params = profile_params(profile) if profile else load_params()
root = Path(root) if root else project_root()
record_dir = root / "data" / "record"
cfg = params["record"]
print(f"profile {profile or 'params.yaml'!r}; data under {root / 'data'}")

# %% [markdown]
# ## Settings
#
# Sessions per robot type, their length, and how the operator, the robot, the rig and the mocap behave:

# %%
print("recordings_dir:", cfg["recordings_dir"], "(null: simulate)")
print("handheld sessions per robot:", cfg["sessions_per_robot"])
print("tripod sessions per robot:", cfg.get("tripod_sessions_per_robot", {}))
print(f"frames per session: {cfg['frames_per_session']} at {cfg['fps']} Hz "
      f"= {cfg['frames_per_session'] / cfg['fps']:.1f} s")
print("camera:", cfg["camera"])
print("robot:", cfg["robot"])
print("rig:", cfg["rig"])

# %% [markdown]
# ## Record
#
# Finished sessions of an identical job are kept, so running this again only simulates what is
# missing; recordings no longer planned are removed. Each session is written into a hidden folder
# and renamed into place when complete. `base.num_workers` processes share the sessions.

# %%
result = record.run(params, root)
summary = result["summary"]
print(f"{summary['mode']}: {result['frames']} frames in {len(result['recordings'])} recordings under "
      f"{result['out']} ({result['new']} new)")

# %% [markdown]
# ## The rig calibration
#
# Each session's calibration films a ChArUco board with the rig on the camera while the mocap
# measures rig and board. For every view, the fitted `T_rig_cam` and the mocap poses predict where the
# board should be; the bars show how far that is from the board found in the image (board-centre
# distance, rotation, reprojection). Views whose residuals stand out would be rejected as outliers
# (red). The title gives the error of the estimate against the simulation's true offset.

# %%
sessions = find_recordings(record_dir)
first = sessions[0]
print(f"{len(sessions)} recordings; showing {first.relative_to(root)}")
viz_record.calibration_residuals_figure(first)

# %% [markdown]
# Across all sessions, the estimated offset is within about a millimetre and a tenth of a degree of
# the truth (the calibration's own tests require 2 mm and 0.2 deg):

# %%
print(viz.format_table([{"session": s["name"], "kind": s["kind"], "frames": s["frames"],
                         "error_mm": s["rig_offset_error"]["translation_mm"],
                         "error_deg": s["rig_offset_error"]["rotation_deg"],
                         "rms_px": s["calibration"]["rms_reprojection_px"],
                         "label_shift_px_median": s["label_error"]["joint_reprojection_px"]["median"]}
                        for s in summary["sessions"] if s["simulated"]]))
viz_record.calibration_errors_figure(summary)

# %% [markdown]
# ## The camera's path
#
# `camera_poses.csv` holds the camera's optical frame in the robot base frame, as the mocap and the
# calibration give it. Unlike the `render` stage, where every frame is an independent draw, the
# camera moves smoothly: the operator walks part of the way around the robot, keeping it in view.

# %%
viz.camera_poses_figure(first)

# %% [markdown]
# ## A tripod session
#
# The same plot for a tripod session: one camera pose for every frame (the path is a single point),
# while the robot moves through its joint range. `armpose.recording.static_camera` recognises such a
# recording from its camera poses alone, so real tripod recordings linked in are treated alike.

# %%
tripods = [r for r in sessions if static_camera(r)]
print("static-camera recordings:", [str(r.relative_to(record_dir)) for r in tripods])
tripod = tripods[0] if tripods else first   # a profile without tripod sessions shows the handheld one again
viz.camera_poses_figure(tripod)

# %% [markdown]
# Its labels on evenly spaced frames: the background and the camera stay put, the robot moves.

# %%
viz_record.label_overlays_figure(tripod, params["base"]["input_size"], params["base"]["max_joints"])

# %% [markdown]
# ## What the labels inherit
#
# The written poses differ from the true ones (at which the frames were rendered) by the
# calibration error, the mocap's per-frame noise and the error of the robot base's mocap pose. The
# right panel turns that into what matters for the labels: the largest shift, in pixels of the
# 480 x 360 image, of the base and joints projected with the written instead of the true pose.

# %%
viz_record.session_errors_figure(first)

# %% [markdown]
# ## Labels on frames of the moving camera
#
# The labels of the stage `labels` (mask, joints, base), computed from the recording alone and drawn
# on evenly spaced frames at the network input size: they should sit on the robot in every frame,
# within the pixel or two shown above.

# %%
viz_record.label_overlays_figure(first, params["base"]["input_size"], params["base"]["max_joints"])

# %% [markdown]
# ## Real recordings instead
#
# Set `record.recordings_dir` to a folder of recordings (relative to the project root, or absolute)
# and run `dvc repro` (or this notebook): the stage checks every recording completely
# (`recording.json`, every row of `joints.csv` and `camera_poses.csv`, every frame), stops at the first
# problem with an error naming the file, the row and the value, and otherwise hard-links (or copies)
# the recordings into `data/record/<robot>/`. The sections above then show them; real recordings carry
# no truth, so the error plots apply to simulated sessions only.
#
# Next: notebook 01 renders the synthetic data; notebook 02 labels both.

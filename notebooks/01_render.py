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
# # 01 · Render: synthetic recordings of five robot types
#
# **Stage `render`** of the pipeline (`dvc.yaml` runs the same function, `armpose.stages.render.run`).
#
# Miseikis et al. (2019, section III) trained on *real* recordings: a Kinect V2 or a free-moving
# RealSense R200 watching UR3/UR5/UR10, a KUKA LBR iiwa 7 R800 and a Franka Emika Panda, with the
# camera-to-robot transform from eye-to-hand calibration or an OptiTrack motion-capture rig. Each
# sample saved the colour image (rectified, 480 x 360), the joint encoder readings and the camera pose;
# ground truth was computed from those. Table I: 4350 UR, 1837 KUKA and 2513 Panda samples.
#
# We have neither the robots nor the cameras, so this stage **synthesises the same kind of recording**:
#
# * **Renderer.** PyBullet's CPU *TinyRenderer* draws the manufacturers' URDF meshes (from
#   `example-robot-data`) through the paper's canonical rectified camera (480 x 360, pinhole, no
#   distortion). No GPU or display is needed.
# * **Robot motion.** Joint angles are drawn uniformly over each joint's limits and rejected if the
#   arm collides with itself or with the table or floor it stands on, like the paper's programmed
#   "full range of motion ... taking into account self-collision and table collision avoidance".
# * **Camera motion.** The camera is placed around the robot at a random distance, elevation,
#   azimuth and roll, aimed near the robot's centroid (the paper moved its camera between
#   recordings, and the Panda camera freely); a pose is kept only if the base and all joints are
#   inside the image.
#
# What is **randomised** (domain randomisation), and why: a network trained on clean renders
# learns the renderer, not the robot. Everything that is *not* the robot is therefore made
# arbitrary, so that the only stable cue left is the robot's shape:
#
# | randomised | how | what it stands in for |
# |---|---|---|
# | floor, walls, table, distractor objects | procedural textures (noise, checkers, stripes, blobs) and random colours; a random number of walls, sometimes a table of random height and size under the robot, random boxes, spheres and cylinders around it; redrawn every `frames_per_scene` frames | the varied lab backgrounds of the paper's recordings |
# | another robot in the background | sometimes a different robot type, unlabelled, in a random pose | "in some cases, even other robots in the background were present" (caption of the paper's sample-images figure) |
# | lighting | per frame: light direction, colour, ambient/diffuse/specular coefficients | the paper's varied illumination |
# | camera noise | per frame: gain/offset (exposure), Gaussian noise, sometimes a Gaussian blur | sensor noise and motion blur of a real RGB camera |
# | robot colour | per scene, a small jitter around the real colour scheme (UR silver-blue, KUKA silver-orange, Panda white-black) | paint, wear and white balance |
#
# A recording is written in the **same format as a real one** (`recording.json`, `frames/*.png`,
# `joints.csv`, `camera_poses.csv`) and carries **no labels**: stage `labels` (notebook 02) computes
# them from the recording alone, exactly as it would for data recorded on a real robot.

# %% tags=["parameters"]
profile = "default"
root = ""

# %% [markdown]
# The two parameters above are papermill's: `profile` names a file in `profiles/` (`""` reads the
# project's `params.yaml`, which is what `dvc repro` uses); `root` is where `data/` is written
# (`""` = the project root). Settings always come from the project's `profiles/` or `params.yaml`,
# whatever `root` is, and no path depends on the kernel's working directory.

# %%
# %matplotlib inline
import logging
from pathlib import Path

from armpose import viz
from armpose.config import load_params, profile_params, project_root
from armpose.recording import find_recordings
from armpose.stages import render

logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s", force=True)
params = profile_params(profile) if profile else load_params()
root = Path(root) if root else project_root()
render_dir = root / "data" / "render"
robot_types = params["base"]["robot_types"]
print(f"profile {profile or 'params.yaml'!r}; data under {root / 'data'}")

# %% [markdown]
# ## Settings
#
# Frames per robot type, recordings of `frames_per_recording` frames (one worker job each, each with
# its own seed derived from `base.seed`), and a new background every `frames_per_scene` frames:

# %%
cfg = params["render"]
print("frames per robot:", cfg["frames_per_robot"])
print("frames per recording:", cfg["frames_per_recording"], "| frames per scene:", cfg["frames_per_scene"])
print("camera:", params["base"]["camera"])
print("camera placement:", cfg["camera"])
print("randomised:", {k: v.get("enabled", True) for k, v in cfg["randomize"].items()})

# %% [markdown]
# ## Render
#
# Finished recordings of an identical job are kept, so running this again only renders what is
# missing; recordings no longer planned are removed. `base.num_workers` processes share the work.

# %%
result = render.run(params, root)
print(f"{result['frames']} frames in {len(result['recordings'])} recordings under {result['out']} "
      f"({result['rendered']} newly rendered)")

# %% [markdown]
# ## Sample frames
#
# Random frames of every robot type (one row each), as the network's data source sees them: full
# camera resolution, after the simulated camera noise.

# %%
viz.render_samples_figure(render_dir, robot_types, per_robot=4, seed=params["base"]["seed"])

# %% [markdown]
# ## Camera poses of one recording
#
# `camera_poses.csv` holds the camera's optical frame in the robot base frame. The camera jumps
# around the robot from frame to frame (every frame is an independent draw), at the distances and
# elevations set in `render.camera`; the grey line is the robot at the recording's first frame.

# %%
recordings = find_recordings(render_dir)
print(f"{len(recordings)} recordings; showing {recordings[0].relative_to(root)}")
viz.camera_poses_figure(recordings[0])

# %% [markdown]
# Next: notebook 02 turns these recordings into labels (mask, joint and base positions in the camera
# frame, distance) and the train/test split.

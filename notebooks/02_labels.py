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
# # 02 · Labels: ground truth for every frame, and the dataset
#
# **Stage `labels`** of the pipeline (`dvc.yaml` runs the same function, `armpose.stages.labels.run`).
#
# In the paper (section III) the ground truth was computed automatically with ROS and **MoveIt**:
# the robot's URDF model, posed with the live joint-encoder readings, was transformed into the
# camera frame (eye-to-hand calibration or OptiTrack) and rendered into a **robot mask**; the 3D
# positions of the **joints** and of the **base** in the camera frame came from the same model. The
# network is trained on four objectives: mask, robot type, 3D base position and 3D joint positions.
#
# This stage redoes that step without ROS, from a recording alone (`joints.csv`,
# `camera_poses.csv`, `recording.json`, `frames/`), so real recordings in the same format are
# labelled exactly like the synthetic ones of notebook 01:
#
# 1. **Forward kinematics** with `pytorch-kinematics`, batched over all frames: joint *i*'s position
#    is the origin of the child link of the *i*-th actuated joint, the base position the origin of the
#    base link; both are moved from the robot base frame into the **camera optical frame** (OpenCV:
#    x right, y down, z forward, metres) with the inverse of the recorded camera pose.
# 2. **Mask** by rendering the robot model *alone* (no background, no other robot) at the recorded
#    joint angles and camera pose with PyBullet's TinyRenderer, the counterpart of MoveIt's model
#    rendering. Anything else in the image, including a second robot, is background.
# 3. **Scale and crop** to the network input: the 480 x 360 image is resized to cover 256 x 212 and
#    centre-cropped; the intrinsics (fx, fy, cx, cy) are adjusted to match, and the mask is rendered
#    directly with those adjusted intrinsics, so mask, image and projected joints line up.
# 4. **Distance**: the camera-to-base distance, the norm of the base position in the camera frame
#    (the paper plots its joint-position errors against this distance).
#
# Frames are split into train and test at random, a fraction `labels.test_fraction` to test (the
# paper: 80 % / 20 % by random sampling); per frame for synthetic recordings, per
# recording for recorded ones, so that one real scene never lands in both; seeded by `base.seed`.

# %% tags=["parameters"]
profile = "default"
root = ""

# %% [markdown]
# Papermill parameters, as in notebook 01: `profile` is a file in `profiles/` (`""` = the project's
# `params.yaml`), `root` is the folder holding `data/` (`""` = the project root).

# %%
# %matplotlib inline
import logging
from pathlib import Path

from armpose import viz
from armpose.config import load_params, profile_params, project_root
from armpose.geometry import Camera
from armpose.labels.dataset import load_dataset
from armpose.stages import labels

logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s", force=True)
params = profile_params(profile) if profile else load_params()
root = Path(root) if root else project_root()
print(f"profile {profile or 'params.yaml'!r}; data under {root / 'data'}")

# %% [markdown]
# ## Scale and crop: how the intrinsics change
#
# The image is scaled by the larger of the two ratios so that it covers the input, then the excess
# is cropped symmetrically. Pixel centres map as u' + 0.5 = (u + 0.5) * W'/W, then u'' = u' - x0,
# hence the new principal point; the focal lengths scale with the resize.

# %%
camera = Camera.from_dict(params["base"]["camera"])
size = params["base"]["input_size"]
cam_in, resized, offset = camera.scale_crop(size["width"], size["height"])
print("recorded camera:", camera)
print(f"resized to {resized[0]} x {resized[1]}, cropped at x0, y0 = {offset}")
print("network input camera:", cam_in)

# %% [markdown]
# ## Label every recording
#
# Results are cached per recording by content (`data/.cache/labels`), so a re-run only labels new or
# changed recordings; the dataset is then written to `data/labels/` as one memory-mappable `.npy`
# per field plus `index.json`.

# %%
result = labels.run(params, root)
print(f"{result['frames']} labelled frames in {result['out']}; {result['skipped']} bad frames skipped")

# %%
arrays, index = load_dataset(root / "data" / "labels")
print({name: tuple(a.shape) for name, a in arrays.items()})

# %% [markdown]
# ## Labelled samples
#
# Each frame at network-input size with its labels: the mask tinted red, the base as a cyan square,
# the joints as dots from yellow (joint 1) to magenta (last joint), joined base to tip. The 3D labels
# are projected with the frame's own intrinsics, u = fx x/z + cx, v = fy y/z + cy.

# %%
viz.label_samples_figure(arrays, index, per_robot=3, seed=params["base"]["seed"])

# %% [markdown]
# ## Mask area
#
# The paper motivates its foreground-weighted mask loss with how little of the image the robot
# covers: 6-17 % for UR, 8-18 % for KUKA, 5-22 % for Panda. The table compares our masks (in percent
# of the image) with those ranges; the last column is the share of frames inside the paper's range.

# %%
areas = viz.mask_area_by_robot(arrays, index)
print(viz.format_table(viz.mask_area_summary(areas),
                       percent=("min", "p5", "median", "p95", "max", "paper", "in_paper_range")))

# %%
viz.mask_area_figure(areas)

# %% [markdown]
# How much of the image the robot fills is set by the camera placement (`render.camera.distance`,
# measured from the look-at point near the robot's centroid) and the robot's size: a small UR3 seen
# from 3 m covers far less than a UR10. If the synthetic masks are systematically smaller than the
# paper's, the synthetic camera is further away than the paper's cameras were.
#
# ## Camera distance

# %%
viz.distance_histogram(arrays, index)

# %% [markdown]
# ## Train / test split

# %%
print(viz.format_table(viz.split_counts(arrays, index), percent=("test_fraction",)))
print(f"index.json: {index['num_train']} train, {index['num_test']} test, {index['num_skipped']} skipped")

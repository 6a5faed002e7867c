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
# # 03 · Pretrain: the multi-objective CNN, trained from scratch on the UR robots
#
# **Stage `pretrain`** of the pipeline (`dvc.yaml` runs the same function, `armpose.stages.pretrain.run`).
#
# Miseikis et al. (2019, section IV) use one **multi-objective CNN** that takes a single RGB image
# and learns four objectives at once: the **robot mask**, the **3D positions of the joints** and of
# the **base** in the camera frame, and the **robot type**. Some convolutional layers are shared;
# the network then branches off, one branch per objective (the paper's Fig. 4). Its starting point
# (section V) is a network *fully trained on the UR robots* (UR3, UR5, UR10); notebooks 04 and 05
# then add the KUKA iiwa and the Franka Panda by two-stage transfer learning. This notebook is that
# starting point.
#
# ## The losses (paper eq. 1-8)
#
# * **Mask** (eq. 1-4). The robot covers only 5-22 % of an image, so a plain per-pixel
#   cross-entropy is minimised by calling everything background. The paper weights each class by
#   its inverse frequency in the ground-truth mask, $w_{fg} = 1/P(Z{=}fg)$, $w_{bg} = 1/P(Z{=}bg)$,
#   takes the per-pixel loss
#   $l^n = -w_{fg}\, i_{gt} \log i_{est} - w_{bg} (1 - i_{gt}) \log(1 - i_{est})$
#   and normalises by the pixel count $\mathcal N$: $\mathcal L_{mask} = \frac{1}{\mathcal N}\sum_n l^n$.
# * **Joints** (eq. 5): mean Euclidean distance over the robot's $N_j$ joints,
#   $\mathcal L_{Jcoords} = \frac{1}{N_j}\sum_i \lVert J_i - E_i \rVert_2$ (metres; a 6-joint UR
#   leaves the 7th output slot out of the loss).
# * **Base** (eq. 6): $\mathcal L_{Bcoords} = \lVert B_{xyz} - E_{xyz} \rVert_2$.
# * **Type** (eq. 7): categorical cross-entropy over the robot types, $-\sum_c p(c) \log q(c)$.
# * **Total** (eq. 8): $\mathcal L_{final} = W_{mask}\mathcal L_{mask} + W_{Jcoords}\mathcal L_{Jcoords}
#   + W_{Bcoords}\mathcal L_{Bcoords} + W_{type}\mathcal L_{type}$ with the paper's weights
#   **1.2, 1.2, 1.2 and 0.6** (`base.loss_weights`), chosen by the authors "by trial and error".
#
# `armpose.losses` implements these from logits (numerically stable), with P(fg) clamped so an
# image without robot pixels stays finite.
#
# ## Our network, and why it looks like this
#
# The paper does not spell out its layers, and it trained on a GPU. This pipeline must train on a
# 2-core CPU, so `armpose.model.ArmPoseNet` keeps the paper's *structure* (a shared trunk, then one
# branch per objective, the same inputs, outputs and losses) and chooses its layers for cost:
#
# * **Trunk** (ResNet-style, width 32): `trunk.early` (stride 4 and 8, generic low-level
#   features) and `trunk.late` (stride 16 and 32, object-level features). The split is the one
#   the transfer stages need: "first convolutional layers tend to learn general visual features,
#   while further layers figure out specific visual cues" (section V).
# * **Mask decoder**: a light FPN over the four trunk levels, one separable 3x3 at stride 4, one
#   logit per pixel upsampled to the input size.
# * **Joint and base heads**: instead of dense layers regressing coordinates, one spatial-softmax
#   attention map per point (soft-argmax), a log-depth, and a learned pinhole back-projection; only
#   3D labels are needed. They read trunk features (stride 16, plus x/y CoordConv channels) only.
# * **Type head**: average and max pooling of the stride-32 features, then a small MLP.
#
# About 0.27 GMAC per 212 x 256 frame and 1.9 M parameters; it runs in `channels_last` on CPU.
# The paper's input size (256 x 212, pixel values in [0, 1]) and learning-rate range (1e-3
# decreasing to 1e-6) are kept; the decrease is a cosine schedule after a short warm-up. A stage
# may start on smaller frames (`low_res`, progressive resizing, `armpose.resolution`); it is off,
# because on our budget it did not pay (results/experiments/README.md, "Progressive resizing").

# %% tags=["parameters"]
profile = "default"
root = ""

# %% [markdown]
# Papermill parameters, as in notebooks 01 and 02: `profile` is a file in `profiles/` (`""` = the
# project's `params.yaml`), `root` is the folder holding `data/` and `models/` (`""` = the project
# root).

# %%
# %matplotlib inline
import logging
from pathlib import Path

from armpose import viz, viz_train
from armpose.config import load_params, profile_params, project_root
from armpose.model import build_model
from armpose.stages import pretrain

logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s", force=True)
params = profile_params(profile) if profile else load_params()
root = Path(root) if root else project_root()
model = build_model(params["base"].get("model", {}))
print(f"profile {profile or 'params.yaml'!r}; data under {root / 'data'}, models under {root / 'models'}")

# %% [markdown]
# ## The architecture
#
# The layer groups are named in `armpose.model.GROUPS` and are what the freeze lists of
# `params.yaml` refer to. The colours follow the paper's Fig. 4, read from this profile's
# `transfer_stage1.trainable` (blue: learns from transfer stage 1 on) and `transfer_stage2.trainable`
# (red: learns in stage 2 only); grey groups stay frozen during transfer. Pretraining trains every
# group.

# %%
viz_train.architecture_figure(params, model)

# %%
stages = {"stage 1": params["transfer_stage1"]["trainable"], "stage 2": params["transfer_stage2"]["trainable"]}
print(viz.format_table(viz_train.group_table(model, stages), percent=("share",)))

# %% [markdown]
# The heads hold few parameters; most sit in `trunk.late` (its stride-32 block has 8w channels).
# Transfer stage 1 therefore trains a small fraction of the network, which is what makes it fast.
#
# ## Settings

# %%
cfg = params["pretrain"]
print("robots:", cfg["robots"], "| frames per type:", cfg["per_type"] or "all of the train split")
print("trainable:", cfg["trainable"], "| init_from:", cfg["init_from"])
print(f"batch {cfg['batch_size']}, AdamW lr {cfg['lr']} -> {cfg['lr_min']} (cosine, warm-up {cfg['warmup']}), "
      f"max {cfg['max_steps']} steps, plateau {cfg['plateau']}")
print("loss weights:", params["base"]["loss_weights"])
print("augmentation:", cfg["augment"])

# %% [markdown]
# ## What the network sees
#
# Each training frame is jittered in brightness, contrast, saturation and noise, and, with the
# keys `flip`, `rotate_deg`, `roll_deg` and `dolly`, seen from a virtual camera that is turned,
# mirrored and moved along its axis (`armpose.augment`): the image and mask are warped and the
# joints and base moved to match, so the labels stay on the robot (drawn below: mask tint, base
# square, joints along the chain). The dolly scales the robot's image by up to `dolly` and moves
# its depth to match, giving every rendered view new pairs of apparent size and distance, the cue
# the depth is read from. The draws depend only on the seed, the row and the epoch.

# %%
viz.augmentation_figure(root / "data" / "labels", [0, 1], cfg["augment"], seed=params["base"]["seed"], epochs=3)

# %% [markdown]
# ## Train
#
# Checkpoints go to `models/pretrain/` (`last.pt` every `checkpoint_every` steps, resumable;
# `model.pt` at the end; `history.csv` per step; `summary.json`). If `last.pt` holds a run with the
# same settings, training resumes from it, so a finished run (after `dvc repro`) returns at once.

# %%
result = pretrain.run(params, root)
print(viz_train.format_summary(result))

# %% [markdown]
# ## Loss curves
#
# Left: the training loss terms (unweighted) and the weighted total of eq. 8 per step; right: the
# validation metrics, computed every `eval_every` steps on up to `val_per_type` test frames per
# robot type: median joint and base errors in cm, type accuracy and mask pixel accuracy.

# %%
history = viz_train.read_history(root / "models" / "pretrain" / "history.csv")
viz_train.loss_curves_figure(history, "pretrain")

# %%
print(f"{len(history['step'])} steps, {viz_train.seconds_per_step(history):.3f} s per training step "
      f"(median; the first step and those right after a validation left out); {history['wall_s'][-1]:.1f} s in all")

# %% [markdown]
# Next: notebook 04 adds the KUKA iiwa and the Franka Panda, training only the final layers first.

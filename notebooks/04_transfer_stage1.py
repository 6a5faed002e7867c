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
# # 04 · Transfer stage 1: only the final layers learn
#
# **Stage `transfer_stage1`** of the pipeline (`dvc.yaml` runs the same function,
# `armpose.stages.transfer_stage1.run`).
#
# Miseikis et al. (2019, section V) add new robot types to a network trained on one family by
# **transfer learning**: the parameters of some layers are *frozen* and the rest are adjusted, which
# needs far less data and time than training everything again. Because the new robots differ in
# look (UR and KUKA are silver with bright joint covers, the Panda is black and white) and in joint
# count (6 against 7), they do it in **two stages** (the paper's Fig. 4):
#
# 1. **Stage 1 (this notebook)**: everything is frozen except the *final layers* (blue in Fig. 4).
#    The network learns to combine the visual cues it already has to recognise and locate the new
#    robots. Few parameters change, so the steps are cheap; training runs until the loss stops
#    improving.
# 2. Stage 2 (notebook 05) unfreezes more convolutional layers.
#
# **The transfer set.** "The new training dataset has to include both, the robot that the network
# was originally trained on, as well as the new robot(s)": N frames of *every* robot type, the UR
# types included, drawn from the train split (`transfer_stage1.per_type`). The paper's Fig. 6a
# found that more than about 500 samples per type brought no significant gain, so the default
# profile uses 500.
#
# **The freeze list** is `transfer_stage1.trainable`; by default `[heads]`: the joint, base and
# type branches learn; `trunk.early`, `trunk.late` and `mask_decoder` keep their pretrained weights,
# and their BatchNorm layers stay in eval mode, so even the running statistics do not move.
#
# **Learning without forgetting** (`transfer_stage1.distill`, ours, not the paper's): the transfer
# set holds 500 frames of each UR type against 3,000 in pretraining, and refitting the type branch
# on them costs UR type accuracy (in our default run before this option: 90.6 % after pretraining,
# 88.2 % after transfer). With `distill`, the pretrained network is a teacher on the transfer set's
# UR frames: one more loss term, the KL divergence from its UR type probabilities to the student's
# (softened by a temperature, weighted like the type term), logged as `distill`. Here the trunk is
# frozen, so the teacher reads the same cached trunk features (`armpose.distill`).
#
# **Cached trunk features, two views per frame.** With the trunk frozen, its features never change,
# so they are computed once per frame (`armpose.features`) and each step trains the heads alone.
# Because `augment.zoom` is set, the cache holds every frame twice: as stored and from the zoom
# test's second-look view (the camera turned to the robot and moved closer, labels moved with it),
# so the new robots' heads learn the view the zoom test will show them.
#
# **The plateau rule** ("the system is trained until there is no more improvement"): the training
# loss is smoothed with an exponential moving average (0.98); the stage stops once the smoothed loss
# has not dropped by a relative `plateau.delta` below its best for `plateau.patience` steps, or at
# `max_steps`. The learning rate falls from `lr` to `lr_min` on a cosine over `max_steps`.

# %% tags=["parameters"]
profile = "default"
root = ""

# %% [markdown]
# Papermill parameters: `profile` is a file in `profiles/` (`""` = the project's `params.yaml`),
# `root` is the folder holding `data/` and `models/` (`""` = the project root).

# %%
# %matplotlib inline
import logging
from pathlib import Path

from armpose import viz, viz_train
from armpose.config import load_params, profile_params, project_root
from armpose.labels.dataset import load_dataset
from armpose.model import build_model
from armpose.stages import transfer_stage1
from armpose.train import load_checkpoint

logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s", force=True)
params = profile_params(profile) if profile else load_params()
root = Path(root) if root else project_root()
cfg = params["transfer_stage1"]
print(f"profile {profile or 'params.yaml'!r}; data under {root / 'data'}, models under {root / 'models'}")

# %% [markdown]
# ## Settings and the transfer set

# %%
print("robots:", cfg["robots"], "| frames per type:", cfg["per_type"])
print("init_from:", cfg["init_from"], "| trainable:", cfg["trainable"])
print(f"batch {cfg['batch_size']}, AdamW lr {cfg['lr']} -> {cfg['lr_min']}, max {cfg['max_steps']} steps, "
      f"plateau {cfg['plateau']}")
print("distill:", cfg.get("distill"))

# %%
arrays, index = load_dataset(root / "data" / "labels")
print(viz.format_table(viz_train.transfer_set_table(arrays, params, "transfer_stage1")))

# %% [markdown]
# ## What is frozen

# %%
model = build_model(params["base"].get("model", {}))
print(viz.format_table(viz_train.group_table(model, {"stage 1": cfg["trainable"]}), percent=("share",)))
counts = viz_train.trainable_counts(model, cfg["trainable"])
print(f"\ntrainable {counts['trainable']:,} of {counts['total']:,} parameters "
      f"({100 * counts['fraction']:.1f} %); frozen {counts['frozen']:,}")

# %% [markdown]
# ## Train
#
# From `models/pretrain/model.pt`; outputs in `models/transfer_stage1/` (resumable, as in notebook 03).

# %%
result = transfer_stage1.run(params, root)
print(viz_train.format_summary(result))

# %% [markdown]
# ## Loss curves

# %%
history = viz_train.read_history(root / "models" / "transfer_stage1" / "history.csv")
viz_train.loss_curves_figure(history, "transfer stage 1")

# %% [markdown]
# ## Did the frozen layers stay frozen?
#
# Every state-dict entry (weights, biases, BatchNorm running statistics) of the pretrained and the
# stage-1 checkpoint, compared group by group: a frozen group must be bit-identical, a trainable one
# must have moved.

# %%
before = load_checkpoint(root / "models" / "pretrain" / "model.pt")
after = load_checkpoint(root / "models" / "transfer_stage1" / "model.pt")
check = viz_train.frozen_check(before, after, viz_train.LEAF_GROUPS, trainable=cfg["trainable"])
print(viz.format_table(check))
assert all(row["ok"] for row in check), "a frozen group changed, or a trainable one did not"

# %% [markdown]
# ## Time per step
#
# Median wall time of a training step (the first step, and steps right after a validation, left
# out), against pretraining, which trains every layer: stage 1 skips the backward pass through the
# whole trunk and the decoder. On a busy machine, or over the few steps of the quick profile, the
# numbers are noisy.

# %%
pre = viz_train.read_history(root / "models" / "pretrain" / "history.csv")
t_pre, t_s1 = viz_train.seconds_per_step(pre), viz_train.seconds_per_step(history)
print(f"pretrain {t_pre:.3f} s/step; transfer stage 1 {t_s1:.3f} s/step ({t_s1 / t_pre:.2f} x pretrain)")
print(f"stage 1: {result['steps']} steps, {result['wall_s']:.1f} s, "
      f"{'stopped on the plateau' if result['stopped_on_plateau'] else 'reached max_steps'}")

# %% [markdown]
# Next: notebook 05 unfreezes more convolutional layers (stage 2).

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
# # 05 · Transfer stage 2: unfreeze more convolutional layers
#
# **Stage `transfer_stage2`** of the pipeline (`dvc.yaml` runs the same function,
# `armpose.stages.transfer_stage2.run`).
#
# Section V of Miseikis et al. (2019): "after some point the learning process saturates and no more
# improvements are observed ... At this stage, the second part of the CNN is unlocked, allowing to
# modify parameters for the additional convolutional layers" (red in the paper's Fig. 4), together
# with the stage-1 layers. The visual cues themselves can now adapt to the new robots, e.g. the
# Panda's black and white body; "the training speed is slower compared to the first stage of
# learning, but the loss is reduced even further" (their Fig. 6b).
#
# Here stage 2 starts from the stage-1 weights (`transfer_stage2.init_from`), on the same transfer
# set (N frames per type, UR included), with the freeze list `transfer_stage2.trainable`; by
# default `trunk.late` and `mask_decoder` join the heads, and only `trunk.early` (generic low-level
# features) stays frozen. The learning rate restarts at 1e-3 and falls towards 1e-6 over at most
# `max_steps` (6,000 by default), the paper's schedule (results/experiments/README.md, "Stage 2");
# the same plateau rule can end the stage earlier (in the last default run at step 5,765). With `transfer_stage2.distill` (on by default, see
# notebook 04) the pretrained network keeps teaching the UR types' probabilities; the trunk now
# trains, so the teacher runs on every training image, about 30 % more time per step.

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
from armpose.model import build_model
from armpose.stages import transfer_stage2
from armpose.train import load_checkpoint

logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s", force=True)
params = profile_params(profile) if profile else load_params()
root = Path(root) if root else project_root()
cfg = params["transfer_stage2"]
print(f"profile {profile or 'params.yaml'!r}; data under {root / 'data'}, models under {root / 'models'}")

# %% [markdown]
# ## What learns in each stage

# %%
print("init_from:", cfg["init_from"], "| trainable:", cfg["trainable"])
print(f"batch {cfg['batch_size']}, AdamW lr {cfg['lr']} -> {cfg['lr_min']}, max {cfg['max_steps']} steps, "
      f"plateau {cfg['plateau']}")
model = build_model(params["base"].get("model", {}))
stages = {"stage 1": params["transfer_stage1"]["trainable"], "stage 2": cfg["trainable"]}
print(viz.format_table(viz_train.group_table(model, stages), percent=("share",)))
for name, trainable in stages.items():
    c = viz_train.trainable_counts(model, trainable)
    print(f"{name}: {c['trainable']:,} trainable parameters ({100 * c['fraction']:.1f} %)")

# %%
viz_train.architecture_figure(params, model)

# %% [markdown]
# ## Train

# %%
result = transfer_stage2.run(params, root)
print(viz_train.format_summary(result))

# %%
h1 = viz_train.read_history(root / "models" / "transfer_stage1" / "history.csv")
h2 = viz_train.read_history(root / "models" / "transfer_stage2" / "history.csv")
viz_train.loss_curves_figure(h2, "transfer stage 2")

# %% [markdown]
# ## Both stages: the paper's Fig. 6b
#
# The total training loss of stage 1 (blue span) then stage 2 (red span), against the iteration
# counted across both stages; squares are the validation loss. In the paper, the loss saturates in
# stage 1 and drops again once stage 2 unlocks more layers.

# %%
viz_train.stages_figure(h1, h2)

# %% [markdown]
# `trunk.early` is frozen in both stages, so it must still be the pretrained one:

# %%
check = viz_train.frozen_check(load_checkpoint(root / "models" / "transfer_stage1" / "model.pt"),
                               load_checkpoint(root / "models" / "transfer_stage2" / "model.pt"),
                               viz_train.LEAF_GROUPS, trainable=cfg["trainable"])
print(viz.format_table(check))
assert all(row["ok"] for row in check), "a frozen group changed, or a trainable one did not"

# %% [markdown]
# ## Time per step, stage 1 against stage 2
#
# Stage 2 back-propagates through `trunk.late` and the mask decoder as well, so each step costs
# more (median wall time of a training step; the first step and steps right after a validation
# left out):

# %%
t1, t2 = viz_train.seconds_per_step(h1), viz_train.seconds_per_step(h2)
print(f"stage 1: {t1:.3f} s/step; stage 2: {t2:.3f} s/step; ratio stage 2 / stage 1 = {t2 / t1:.2f}")

# %%
summary = viz_train.summaries_table(root, ["pretrain", "transfer_stage1", "transfer_stage2"])
print(viz.format_table(summary, percent=("val_type_acc", "val_mask_acc")))

# %% [markdown]
# The last table puts the three stages side by side: steps run, whether the plateau rule ended the
# stage, training frames, seconds per step (here: all wall time over all steps, validation
# included) and the final validation metrics on the test split.

# %% [markdown]
# ## How much one run tells
#
# A second draw of the 500 frames per robot type gives a different network. To see how far the
# test scores move between such draws, `python benchmarks/transfer_seeds.py` trains stages 1
# and 2 again from the same pretrained network with other seed offsets and scores each
# (README, "Seeds of the transfer stages"). Over the three seeds of the run before the look-alike
# surfaces, each with its own measured fit weights, the joint medians moved by 0.27 cm
# (UR), 1.10 cm (KUKA) and 1.01 cm (Panda) and UR's type accuracy by 0.58 points: read a difference
# between two settings against that before believing it.

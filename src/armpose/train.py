"""The training loop shared by every training stage (pretrain, transfer stages, full training).

Read top to bottom: set up (device, DDP, seeds), data, model, ``init_from``, freeze list,
optimiser and schedule, then the loop: forward, loss terms, backward, step, log, validate,
checkpoint, stop on plateau. Fine-tuning is the same loop with another ``init_from``, another
learning rate and another list of trainable groups.

Runs unchanged under ``torchrun --nproc_per_node=K`` (DistributedDataParallel; gloo on CPU,
nccl on GPU). Checkpoints are plain dicts (model, optimizer, scheduler, step, stage, config,
plateau state) written atomically; a run started again with ``init_from`` unchanged resumes
from ``<out>/last.pt`` and reaches the same weights as an uninterrupted run.
"""
from __future__ import annotations

import csv
import io
import logging
import math
import os
import time
from pathlib import Path

import torch
import torch.distributed as dist
from tqdm import tqdm

from armpose import distill
from armpose.features import batch_features, cache_trunk_features, trunk_is_frozen
from armpose.data import (InfiniteBatches, LabelledFrames, foreground_fraction, make_loader, transfer_set,
                          validation_subset)
from armpose.io import atomic_write_bytes
from armpose.labels.dataset import load_dataset
from armpose.losses import multi_objective_loss
from armpose.model import build_model, predicted_mask, set_trainable
from armpose.resolution import check_stage_low_res, downscale_batch, input_scale

log = logging.getLogger(__name__)
HISTORY_FIELDS = ["step", "stage", "wall_s", "lr", "total", "mask", "joints", "base", "type", "reproj", "heatmap",
                  "offsets", "direct", "distill", "val_total", "val_joint_cm", "val_base_cm", "val_type_acc", "val_mask_acc"]


# ----------------------------------------------------------------------------- set-up
def setup_distributed() -> tuple[int, int, torch.device]:
    """(rank, world size, device). Under torchrun, joins the process group."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    if torch.cuda.is_available():
        device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
        torch.cuda.set_device(device)
    else:
        device = torch.device("cpu")
    if world > 1 and not dist.is_initialized():
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo")
    return rank, world, device


def save_checkpoint(path: Path, model, optimizer, scheduler, step: int, stage: str, config: dict,
                    extra: dict | None = None) -> None:
    """Atomically write a plain-dict checkpoint (loadable with ``torch.load(weights_only=True)``)."""
    state = {"model": unwrap(model).state_dict(), "optimizer": optimizer.state_dict() if optimizer else None,
             "scheduler": scheduler.state_dict() if scheduler else None, "step": step, "stage": stage,
             "config": config, "extra": extra or {}, "format": 1}
    buf = io.BytesIO()
    torch.save(state, buf)
    atomic_write_bytes(path, buf.getvalue())


def load_checkpoint(path: Path) -> dict:
    """A checkpoint dict; raises ValueError naming the file if it is not an armpose checkpoint."""
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - any unpickling failure means a bad file
        raise ValueError(f"{path}: not a readable checkpoint ({err})") from err
    if not isinstance(ckpt, dict) or ckpt.get("format") != 1 or "model" not in ckpt:
        raise ValueError(f"{path}: not an armpose checkpoint of format 1")
    return ckpt


def load_model(checkpoint: Path, device: torch.device | str = "cpu"):
    """(model in eval mode, checkpoint config) from an armpose checkpoint."""
    ckpt = load_checkpoint(Path(checkpoint))
    model = build_model(ckpt["config"]["base"].get("model", {}))
    model.load_state_dict(ckpt["model"])
    model = model.to(device).to(memory_format=torch.channels_last).eval()
    return model, ckpt["config"]


def unwrap(model):
    return model.module if hasattr(model, "module") else model


def ranks_weight_difference(model) -> float:
    """Largest absolute difference between this rank's weights and rank 0's (0 when in sync)."""
    diff = torch.zeros(1)
    for p in model.state_dict().values():
        if not p.is_floating_point():
            continue
        ref = p.detach().clone()
        dist.broadcast(ref, src=0)
        diff = torch.maximum(diff, (p.detach() - ref).abs().max().cpu().reshape(1))
    dist.all_reduce(diff, op=dist.ReduceOp.MAX)
    return float(diff)


def cosine_lr(step: int, max_steps: int, lr: float, lr_min: float, warmup: int) -> float:
    """Learning rate at ``step``: linear warm-up, then cosine decay from ``lr`` towards ``lr_min``."""
    if step < warmup:
        return lr * (step + 1) / warmup
    progress = min(1.0, (step - warmup) / max(1, max_steps - warmup))
    return lr_min + 0.5 * (lr - lr_min) * (1 + math.cos(math.pi * progress))


class Plateau:
    """Stops when the smoothed training loss has not improved by a relative ``delta`` for
    ``patience`` steps. State is a plain dict, saved in checkpoints.

    The smoothing is an exponential moving average with Adam's bias correction, so an early
    value is the weighted mean of every loss so far, not the first loss; and the best value is
    tracked only once the average spans ``1 / (1 - ema)`` steps (50 at 0.98). Without both, one
    low first batch set a best that the average never beat again, and a stage stopped at
    ``patience + 1`` steps whatever its loss did next."""

    def __init__(self, delta: float, patience: int, ema: float = 0.98, state: dict | None = None):
        self.delta, self.patience, self.ema = delta, patience, ema
        self.window = math.ceil(1.0 / (1.0 - ema))
        self.state = state or {"average": 0.0, "count": 0, "best": None, "best_step": 0}

    def update(self, step: int, loss: float) -> bool:
        s = self.state
        s["count"] += 1
        s["average"] = self.ema * s["average"] + (1 - self.ema) * float(loss)
        smooth = s["average"] / (1 - self.ema ** s["count"])
        if s["count"] < self.window:
            return False
        if s["best"] is None or smooth < s["best"] * (1 - self.delta):
            s["best"], s["best_step"] = smooth, step
        return step - s["best_step"] >= self.patience

    def restore(self, state: dict | None) -> None:
        """Continue from a checkpoint's saved ``state``. One written before the bias-corrected
        average (no ``count``) is dropped with a warning, and the average restarts."""
        if state and "count" in state:
            self.state = state
        elif state:
            log.warning("checkpoint holds an old plateau state; the plateau average restarts")


RUNTIME_KEYS = {"threads", "num_workers", "checkpoint_every", "resume"}
AFTER_TRAINING_KEYS = {"fit_sigmas", "fit_sigmas_on_mirror"}   # what the stage measures once trained


def _identity(config: dict) -> dict:
    """The settings that decide a run's trained weights (not threads, workers or checkpoint
    cadence, nor what is measured after training: the fit sigmas of :mod:`armpose.fit_sigmas`)."""
    ignored = RUNTIME_KEYS | AFTER_TRAINING_KEYS
    return {part: {k: v for k, v in config[part].items() if k not in ignored} if isinstance(config[part], dict)
            else config[part] for part in config}


PRECISIONS = ("fp32", "bf16")


def training_precision(cfg: dict) -> str:
    """The stage's ``precision``: ``fp32`` (default) or ``bf16``, bfloat16 autocast of the trunk
    and mask decoder in training steps (1.4x faster steps on a CPU with AVX512-BF16; the heads,
    the losses, validation and inference stay float32)."""
    precision = str(cfg.get("precision", "fp32"))
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
    return precision


def to_channels_last(images: torch.Tensor) -> torch.Tensor:
    """NHWC memory layout: 1.2-3x faster convolutions on CPU in our runs."""
    return images.contiguous(memory_format=torch.channels_last)


# ----------------------------------------------------------------------------- evaluation
@torch.no_grad()
def validate(model, loader, weights: dict, device) -> dict:
    """Mean loss terms and quick metrics over ``loader``: median joint and base error (cm),
    type accuracy and pixel mask accuracy."""
    model.eval()
    sums: dict[str, float] = {}
    n, joint_err, base_err, type_ok, mask_acc = 0, [], [], [], []
    for batch in loader:
        batch = {k: v.to(device) for k, v in batch.items()}
        out = model(to_channels_last(batch["image"]))
        losses = multi_objective_loss(out, batch, weights)
        b = batch["image"].shape[0]
        for k, v in losses.items():
            sums[k] = sums.get(k, 0.0) + float(v) * b
        n += b
        err = torch.linalg.norm(out["joints"] - batch["joints"], dim=-1)
        joint_err.append(err[batch["joint_valid"]].cpu())
        base_err.append(torch.linalg.norm(out["base"] - batch["base"], dim=-1).cpu())
        type_ok.append((out["type_logits"].argmax(1) == batch["robot"]).cpu())
        pred = predicted_mask(unwrap(model), out["mask_logits"][:, 0])
        mask_acc.append((pred == (batch["mask"] > 0.5)).float().mean(dim=(1, 2)).cpu())
    if n == 0:
        return {}
    return {"val_total": sums["total"] / n,
            "val_joint_cm": 100 * float(torch.cat(joint_err).median()),
            "val_base_cm": 100 * float(torch.cat(base_err).median()),
            "val_type_acc": float(torch.cat(type_ok).float().mean()),
            "val_mask_acc": float(torch.cat(mask_acc).mean())}


def write_history(path: Path, rows: list[dict]) -> None:
    """The per-step history as CSV (the data behind the paper's Fig. 6b), atomically."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=HISTORY_FIELDS, extrasaction="ignore")
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_bytes(path, buf.getvalue().encode())


# ----------------------------------------------------------------------------- distillation
def _teacher(cfg: dict, base: dict, cached: bool, device) -> dict | None:
    """The stage's ``distill`` teacher (:mod:`armpose.distill`) and its settings, or None."""
    if not cfg.get("distill"):
        return None
    dcfg = distill.check_config(cfg["distill"], list(base["robot_types"]))
    if cached:
        distill.check_cached_teacher(dcfg, cfg["init_from"])
    return {"model": distill.load_teacher(Path(dcfg["teacher"]), device, list(base["robot_types"])),
            "weight": float(dcfg["weight"]),
            "temperature": float(dcfg["temperature"]),
            "classes": [base["robot_types"].index(r) for r in dcfg["robots"]]}


def _with_distillation(losses: dict, out: dict, batch: dict, teacher: dict, cached: bool, bf16: bool) -> dict:
    """``losses`` plus the ``distill`` term, added to ``total`` with its weight."""
    model = teacher["model"]
    with torch.no_grad(), torch.autocast(batch["robot"].device.type, dtype=torch.bfloat16, enabled=bf16):
        t_out = model(features=batch_features(batch)) if cached else model(to_channels_last(batch["image"]))
    term = distill.distill_loss(out["type_logits"].float(), t_out["type_logits"].float(), batch["robot"],
                                teacher["classes"], teacher["temperature"])
    total = losses["total"] + teacher["weight"] * term
    assert torch.isfinite(total), {"distill": float(term)}
    return {**losses, "distill": term, "total": total}


def training_rows(arrays, cfg: dict, base: dict):
    """The training-split rows a stage trains on: ``per_type`` of each of its ``robots`` (all
    when None), drawn with ``base.seed`` plus the stage's ``seed_offset``."""
    types = [base["robot_types"].index(r) for r in cfg["robots"]]
    return transfer_set(arrays, "train", types, cfg.get("per_type"), int(base["seed"]) + int(cfg.get("seed_offset", 0)))


# ----------------------------------------------------------------------------- the loop
def train(stage: str, cfg: dict, base: dict, data_dir: Path, out_dir: Path) -> dict:
    """Train one stage. ``cfg`` is the stage's params section, ``base`` the shared one.

    Writes ``out_dir/last.pt`` (resumable), ``out_dir/model.pt`` (final), ``history.csv``.
    Returns the final validation metrics plus timing.
    """
    rank, world, device = setup_distributed()
    master = rank == 0
    bf16 = training_precision(cfg) == "bf16"
    torch.manual_seed(int(base["seed"]))
    if device.type == "cpu":
        torch.set_num_threads(max(1, int(cfg.get("threads", os.cpu_count() or 1)) // world))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)

    # data: the stage's robot types, N per type from the train split (None = all)
    arrays, index = load_dataset(data_dir)
    types = [base["robot_types"].index(r) for r in cfg["robots"]]
    seed = int(base["seed"]) + int(cfg.get("seed_offset", 0))
    rows = training_rows(arrays, cfg, base)
    val_rows = validation_subset(arrays, "test", int(cfg.get("val_per_type", 50)), seed, robots=types)
    train_ds = LabelledFrames(data_dir, rows, augment=cfg.get("augment"), seed=seed)
    val_ds = LabelledFrames(data_dir, val_rows)
    bs = int(cfg["batch_size"]) // world
    val_loader = make_loader(val_ds, bs, shuffle=False, seed=seed, num_workers=0, drop_last=False)

    # model: init_from (scratch | resume | checkpoint path), then the freeze list
    model = build_model(base.get("model", {})).to(device).to(memory_format=torch.channels_last)
    last = out_dir / "last.pt"
    ckpt = None
    config = {"stage": stage, "cfg": cfg, "base": base}
    if last.exists() and cfg.get("resume", True):
        ckpt = load_checkpoint(last)
        if ckpt["stage"] != stage or _identity(ckpt["config"]) != _identity(config):
            log.warning("%s: %s was written with other settings; starting afresh", stage, last)
            ckpt = None
    if ckpt is not None:
        model.load_state_dict(ckpt["model"])
        log.info("%s: resuming from %s at step %d", stage, last, ckpt["step"])
    elif cfg["init_from"] == "resume":
        raise FileNotFoundError(f"{last}: init_from is 'resume' but there is no checkpoint")
    elif cfg["init_from"] != "scratch":
        model.load_state_dict(load_checkpoint(Path(cfg["init_from"]))["model"])
        log.info("%s: initialised from %s", stage, cfg["init_from"])
    set_trainable(model, cfg["trainable"])
    if any(g == "mask_decoder" or g.startswith("mask_decoder.") for g in cfg["trainable"]):
        model.set_mask_prior(foreground_fraction(arrays, rows))   # the decision rule of this training set
    cached = bool(cfg.get("feature_cache", True)) and trunk_is_frozen(cfg["trainable"])
    low_res = check_stage_low_res(stage, cfg, cached)
    done = ckpt is not None and bool(ckpt["extra"].get("finished")) and (out_dir / "model.pt").exists()
    cache_s = float(ckpt["extra"].get("feature_cache_s", 0.0)) if ckpt else 0.0   # earlier sessions of this run
    if cached and not done:  # the trunk never changes in this run: compute its features once
        started = time.perf_counter()
        train_ds = cache_trunk_features(model, train_ds, device, disable_bar=not master)
        cache_s += time.perf_counter() - started
    loader = make_loader(train_ds, bs, shuffle=True, seed=seed, num_workers=0 if cached else int(cfg.get("num_workers", 1)),
                         drop_last=True, distributed=world > 1)
    teacher = _teacher(cfg, base, cached, device)
    params = [p for p in model.parameters() if p.requires_grad]
    optimizer = torch.optim.AdamW(params, lr=float(cfg["lr"]), weight_decay=float(cfg.get("weight_decay", 1e-4)))
    if world > 1:
        model = torch.nn.parallel.DistributedDataParallel(model, device_ids=[device.index] if device.type == "cuda" else None)
    step, history, elapsed, finished = 0, [], 0.0, False
    plateau_cfg = cfg.get("plateau")
    plateau = Plateau(float(plateau_cfg["delta"]), int(plateau_cfg["patience"])) if plateau_cfg else None
    if ckpt is not None:
        optimizer.load_state_dict(ckpt["optimizer"])
        step, history, elapsed = ckpt["step"], ckpt["extra"]["history"], ckpt["extra"]["elapsed"]
        finished = bool(ckpt["extra"].get("finished"))
        if plateau:
            plateau.restore(ckpt["extra"].get("plateau"))
    max_steps, weights = int(cfg["max_steps"]), base["loss_weights"]

    def checkpoint(path: Path) -> None:
        if master:
            extra = {"history": history, "elapsed": elapsed + time.perf_counter() - t0,
                     "plateau": plateau.state if plateau else None, "finished": finished,
                     "feature_cache_s": cache_s}
            save_checkpoint(path, model, optimizer, None, step, stage, config, extra)
            write_history(out_dir / "history.csv", history)

    batches = InfiniteBatches(loader, start_step=step)
    t0 = time.perf_counter()
    bar = tqdm(total=max_steps, initial=step, desc=stage, unit="step", disable=not master, dynamic_ncols=True)
    start_step = step
    while step < max_steps and not finished:
        model.train()
        set_trainable(unwrap(model), cfg["trainable"])  # frozen BatchNorm stays in eval mode
        lr = cosine_lr(step, max_steps, float(cfg["lr"]), float(cfg["lr_min"]), int(cfg.get("warmup", 0)))
        for group in optimizer.param_groups:
            group["lr"] = lr
        batch = {k: v.to(device, non_blocking=True) for k, v in next(batches).items()}
        if low_res and step == low_res["steps"] and step > start_step:
            log.info("%s: step %d, training at the full input resolution from here", stage, step)
        batch = downscale_batch(batch, input_scale(low_res, step))
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=bf16):
            out = model(features=batch_features(batch)) if cached else model(to_channels_last(batch["image"]))
        losses = multi_objective_loss({k: v.float() for k, v in out.items()}, batch, weights)
        if teacher is not None:
            losses = _with_distillation(losses, out, batch, teacher, cached, bf16)
        optimizer.zero_grad(set_to_none=True)
        losses["total"].backward()
        optimizer.step()
        step += 1
        terms = {k: float(v.detach()) for k, v in losses.items()}
        row = {"step": step, "stage": stage, "wall_s": round(elapsed + time.perf_counter() - t0, 3), "lr": lr, **terms}
        if step % int(cfg.get("eval_every", 100)) == 0 or step == max_steps:
            row.update(validate(model, val_loader, weights, device))
        history.append(row)
        bar.set_postfix(loss=f"{terms['total']:.3f}", joints=f"{terms['joints']:.3f}")
        bar.update(1)
        if plateau is not None and plateau.update(step, terms["total"]):
            log.info("%s: loss plateaued at step %d", stage, step)
            break
        if step % int(cfg.get("checkpoint_every", 100)) == 0:
            checkpoint(last)
    bar.close()
    if step > start_step or not (out_dir / "model.pt").exists():  # a finished run is left as it was
        if not any(k.startswith("val_") for k in history[-1]):
            history[-1].update(validate(model, val_loader, weights, device))
        finished = True
        checkpoint(last)
        if master:
            save_checkpoint(out_dir / "model.pt", model, None, None, step, stage, config,
                            {"history": [], "elapsed": elapsed + time.perf_counter() - t0})
    ddp_diff = ranks_weight_difference(unwrap(model)) if world > 1 else 0.0
    final = {k: v for k, v in history[-1].items() if k.startswith("val_")}
    steps_here = len(history)
    wall = history[-1]["wall_s"]
    return {"stage": stage, "steps": step, "stopped_on_plateau": step < max_steps, "wall_s": wall,
            "s_per_step": wall / max(1, steps_here), "num_train_frames": int(len(rows)), "world_size": world,
            "ddp_max_weight_difference": ddp_diff, "feature_cache": cached, "feature_cache_s": round(cache_s, 3),
            **final}

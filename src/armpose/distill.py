"""Learning without forgetting (Li and Hoiem 2016) for the transfer stages: the pretrained
network as a teacher of the robot types it already knows.

The transfer set holds only ``per_type`` frames of each UR robot (500 by default, against
3,000 in pretraining), so refitting the type head on it costs UR type accuracy: on our default
run the pretrained network told UR3, UR5 and UR10 apart in 90.6 % of the UR test frames, the
transfer model in 88.2 %. A stage's ``distill`` section adds one loss term on the frames of the
``robots`` it names: the KL divergence from the teacher's type probabilities to the student's,
both restricted to those robots' classes and softened by ``temperature`` T (times T^2, so its
gradient scale does not depend on T), weighted by ``weight``. It uses no data beyond the
transfer set: the teacher only labels the same frames with what it learned from its own.

``distill: {teacher: models/pretrain/model.pt, robots: [ur3, ur5, ur10], weight: 0.6, temperature: 2.0}``

The teacher reads the same input as the student: the image, or, in a stage whose trunk is
frozen and cached, the cached trunk features (then the teacher must be the checkpoint the
student starts from, whose trunk made the cache; :func:`check_cached_teacher`).
"""
from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F

KEYS = {"teacher", "robots", "weight", "temperature"}


def _positive_number(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
        raise ValueError(f"distill: {name} must be a number > 0, got {value!r}")
    return float(value)


def check_config(cfg, robot_types: list[str]) -> dict:
    """``cfg`` (a stage's ``distill`` section) with defaults, checked: a clear error, naming the
    value, for a section that is not a mapping with a ``teacher``, unknown keys, robots that are
    not a non-empty list of known types, or a weight or temperature that is not > 0."""
    if not isinstance(cfg, dict) or "teacher" not in cfg:
        raise ValueError(f"distill must be a mapping with 'teacher' (a checkpoint path), got {cfg!r}")
    unknown = set(cfg) - KEYS
    if unknown:
        raise ValueError(f"distill: unknown keys {sorted(unknown)}; known: {sorted(KEYS)}")
    out = {"robots": list(robot_types), "weight": 1.0, "temperature": 1.0, **cfg}
    if not isinstance(out["robots"], list) or not out["robots"]:
        raise ValueError(f"distill: robots must be a non-empty list of robot types, got {out['robots']!r}")
    missing = [r for r in out["robots"] if r not in robot_types]
    if missing:
        raise ValueError(f"distill: robots {missing} are not in base.robot_types {robot_types}")
    out["weight"] = _positive_number("weight", out["weight"])
    out["temperature"] = _positive_number("temperature", out["temperature"])
    return out


def resolve_teacher(stage_cfg: dict, root: Path) -> dict:
    """``stage_cfg`` with its ``distill.teacher`` path made relative to the project ``root``."""
    dcfg = stage_cfg.get("distill")
    if not dcfg:
        return stage_cfg
    if not isinstance(dcfg, dict) or "teacher" not in dcfg:
        raise ValueError(f"distill must be a mapping with 'teacher' (a checkpoint path), got {dcfg!r}")
    return {**stage_cfg, "distill": {**dcfg, "teacher": str(Path(root) / dcfg["teacher"])}}


def check_cached_teacher(cfg: dict, init_from: str) -> None:
    """A stage on cached trunk features can only distil from the checkpoint it starts from
    (``init_from: resume`` continues a run that passed this check when it started)."""
    if init_from != "resume" and Path(cfg["teacher"]).resolve() != Path(init_from).resolve():
        raise ValueError(f"distill: with a frozen, cached trunk the teacher must be init_from ({init_from}), "
                         f"got {cfg['teacher']}")


def check_teacher_types(teacher_types: list[str], robot_types: list[str], path: Path) -> None:
    """The teacher's classes must be the student's, in the same order."""
    if list(teacher_types) != list(robot_types):
        raise ValueError(f"distill: teacher {path} was trained on robot types {list(teacher_types)}, "
                         f"this stage on {list(robot_types)}; the type classes must match")


def load_teacher(path: Path, device, robot_types: list[str]) -> torch.nn.Module:
    """The teacher network in eval mode, every parameter frozen; its robot types must be
    ``robot_types``."""
    from armpose.train import load_model   # train imports this module
    model, config = load_model(Path(path), device)
    check_teacher_types(config["base"]["robot_types"], robot_types, Path(path))
    for p in model.parameters():
        p.requires_grad_(False)
    return model


def distill_loss(student_logits: torch.Tensor, teacher_logits: torch.Tensor, robot: torch.Tensor,
                 classes: list[int], temperature: float) -> torch.Tensor:
    """Mean over the frames whose true ``robot`` is in ``classes`` of
    ``T^2 KL(softmax(teacher / T) || softmax(student / T))``, both logits (B, num_types) restricted
    to ``classes``; 0 (with a gradient path) when the batch holds no such frame."""
    idx = torch.as_tensor(classes, device=student_logits.device)
    rows = torch.isin(robot.long(), idx)
    if not bool(rows.any()):
        return student_logits.sum() * 0.0
    t = float(temperature)
    log_student = F.log_softmax(student_logits[rows][:, idx].float() / t, -1)
    log_teacher = F.log_softmax(teacher_logits[rows][:, idx].float() / t, -1)
    return F.kl_div(log_student, log_teacher, log_target=True, reduction="batchmean") * t * t

"""Learning without forgetting (armpose.distill): the loss term, its settings, and a stage with it."""
from pathlib import Path

import pytest
import torch

from armpose.config import profile_params
from armpose.distill import check_cached_teacher, check_config, check_teacher_types, distill_loss, resolve_teacher
from armpose.stages import pretrain, transfer_stage1, transfer_stage2
from armpose.train import load_checkpoint

TYPES = ["ur3", "ur5", "ur10", "iiwa", "panda"]
UR = [0, 1, 2]


def test_loss_is_zero_when_the_student_agrees_and_grows_when_it_does_not():
    teacher = torch.tensor([[2.0, 0.5, -1.0, 0.0, 0.0], [0.1, 1.5, 1.0, 0.0, 0.0]])
    robot = torch.tensor([0, 1])
    assert float(distill_loss(teacher.clone(), teacher, robot, UR, 2.0)) == pytest.approx(0.0, abs=1e-7)
    # only the UR classes count: changing the KUKA and Panda logits changes nothing
    other = teacher.clone()
    other[:, 3:] = torch.tensor([5.0, -5.0])
    assert float(distill_loss(other, teacher, robot, UR, 2.0)) == pytest.approx(0.0, abs=1e-6)
    wrong = teacher[:, [2, 1, 0, 3, 4]]
    assert float(distill_loss(wrong, teacher, robot, UR, 2.0)) > 0.05


def test_loss_ignores_frames_of_other_robots_and_keeps_a_gradient_path():
    student = torch.zeros(2, 5, requires_grad=True)
    teacher = torch.tensor([[3.0, 0.0, 0.0, 0.0, 0.0]] * 2)
    none = distill_loss(student, teacher, torch.tensor([3, 4]), UR, 1.0)   # iiwa and Panda only
    assert float(none.detach()) == 0.0
    none.backward()
    assert student.grad is not None and float(student.grad.abs().sum()) == 0.0
    one = distill_loss(student, teacher, torch.tensor([3, 0]), UR, 1.0)
    both = distill_loss(student, teacher, torch.tensor([0, 0]), UR, 1.0)
    assert float(one.detach()) == pytest.approx(float(both.detach()))                          # a mean over the UR frames


def test_settings_are_checked_with_clear_errors(tmp_path):
    assert check_config({"teacher": "t.pt"}, TYPES)["robots"] == TYPES
    with pytest.raises(ValueError, match="unknown keys"):
        check_config({"teacher": "t.pt", "temp": 2}, TYPES)
    with pytest.raises(ValueError, match="'teacher'"):
        check_config({"weight": 1.0}, TYPES)
    with pytest.raises(ValueError, match="ur7"):
        check_config({"teacher": "t.pt", "robots": ["ur7"]}, TYPES)
    with pytest.raises(ValueError, match="temperature"):
        check_config({"teacher": "t.pt", "temperature": 0}, TYPES)
    with pytest.raises(ValueError, match="weight.*-1"):
        check_config({"teacher": "t.pt", "weight": -1}, TYPES)
    with pytest.raises(ValueError, match="non-empty list.*'ur3'"):
        check_config({"teacher": "t.pt", "robots": "ur3"}, TYPES)
    with pytest.raises(ValueError, match="non-empty list"):
        check_config({"teacher": "t.pt", "robots": []}, TYPES)
    for bad in ("models/pretrain/model.pt", True):
        with pytest.raises(ValueError, match="mapping with 'teacher'.*" + str(bad)[:6]):
            check_config(bad, TYPES)
        with pytest.raises(ValueError, match="mapping with 'teacher'"):
            resolve_teacher({"distill": bad}, tmp_path)
    check_cached_teacher({"teacher": "a.pt"}, "resume")                 # a resumed run passed the check before
    with pytest.raises(ValueError, match="init_from"):
        check_cached_teacher({"teacher": "a.pt"}, "b.pt")
    cfg = resolve_teacher({"distill": {"teacher": "models/pretrain/model.pt"}}, tmp_path)
    assert cfg["distill"]["teacher"] == str(tmp_path / "models/pretrain/model.pt")
    assert resolve_teacher({"distill": None}, tmp_path) == {"distill": None}


def test_a_teacher_with_other_robot_types_is_refused():
    check_teacher_types(TYPES, TYPES, Path("t.pt"))
    with pytest.raises(ValueError, match="t.pt.*robot types"):
        check_teacher_types(["ur3", "ur5", "ur10"], TYPES, Path("t.pt"))


def test_transfer_stages_train_with_distillation_and_log_the_term(tiny_project, tmp_path):
    root, tparams = tiny_project
    (tmp_path / "data").symlink_to(root / "data")
    params = profile_params("quick")
    params["base"] = tparams["base"]
    urs = [t for t in ("ur3", "ur5", "ur10") if t in params["base"]["robot_types"]]
    dist = {"teacher": "models/pretrain/model.pt", "robots": urs, "weight": 0.6, "temperature": 2.0}
    params["transfer_stage1"]["distill"] = dist
    params["transfer_stage2"]["distill"] = dist
    pretrain.run(params, tmp_path)
    for stage in (transfer_stage1, transfer_stage2):
        stage.run(params, tmp_path)
    for name in ("transfer_stage1", "transfer_stage2"):
        history = load_checkpoint(tmp_path / "models" / name / "last.pt")["extra"]["history"]
        assert all("distill" in row and row["distill"] >= 0 for row in history)
        assert any(row["distill"] > 0 for row in history), name
        assert "distill" in Path(tmp_path / "models" / name / "history.csv").read_text().splitlines()[0]

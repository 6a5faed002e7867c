"""End to end: ``dvc repro`` on tiny params in a temporary copy of the project, the record stage included."""
import json
import shutil
import subprocess
from pathlib import Path


from armpose.config import project_root, write_params
from armpose.labels.dataset import load_dataset

REPO = Path(__file__).resolve().parents[1]


def _sh(cmd: str, cwd: Path) -> str:
    res = subprocess.run(cmd, shell=True, cwd=cwd, capture_output=True, text=True)
    assert res.returncode == 0, f"{cmd}\n{res.stdout}\n{res.stderr}"
    return res.stdout + res.stderr


def test_dvc_repro_runs_every_stage_and_then_does_nothing(tmp_path, tiny_params):
    work = tmp_path / "proj"
    work.mkdir()
    for item in ("dvc.yaml", "src", "profiles"):
        src = REPO / item
        (shutil.copytree if src.is_dir() else shutil.copy)(src, work / item)
    params = tiny_params(frames=4, workers=2)
    params["record"].update(frames_per_session=4, sessions_per_robot={"panda": 1},
                            tripod_sessions_per_robot={"panda": 1})
    write_params(params, work / "params.yaml")
    _sh("git init -q && git config user.email t@t && git config user.name t && dvc init -q "
        "&& dvc config core.analytics false && dvc config core.check_update false", work)
    _sh("dvc repro", work)
    arrays, index = load_dataset(work / "data" / "labels")
    assert index["num_frames"] == 28 and arrays["images"].shape[0] == 28        # 20 rendered, 8 recorded
    recorded = {r["name"]: r for r in index["recordings"] if r["source"] == "recorded"}
    assert set(recorded) == {"data/record/panda/panda_s00", "data/record/panda/panda_t00"}
    assert recorded["data/record/panda/panda_t00"]["static_camera"]
    assert (arrays["split"][arrays["source"] == 1] == 1).all()                 # one handheld: ceil(0.2) = 1 is test
    test = json.loads((work / "results" / "metrics.json").read_text())["transfer"]["test"]
    assert test["by_source"]["recorded"]["all"]["frames"] == 8
    assert test["camera_pose"]["tripod"]["all"]["images_10"]["estimates"] == 1   # 4 frames: one pooled estimate
    assert test["camera_pose"]["tripod"]["all"]["images_1"]["frames"] == 4
    assert test["sequence"]["all"]["recordings"] == 2 and "jitter_reduction" in test["sequence"]["all"]["kalman"]
    assert test["mirror_test"]["all"]["frames"] == test["all"]["frames"]             # evaluate.mirror_test
    latency = json.loads((work / "results" / "latency.json").read_text())["cpu"]
    assert latency["mirror_batch1_median_ms"] > 0                                   # latency.mirror_test
    assert test["zoom_test"]["all"]["frames"] == test["all"]["frames"]               # evaluate.zoom_test
    assert latency["zoom_batch1_median_ms"] > 0                                     # latency.zoom_test
    table = (work / "results" / "results_table.md").read_text()
    assert "| recorded | Panda | 8 |" in table and "Jitter reduction" in table
    assert test["camera_pose"]["fit"] == "rays" and test["camera_pose"]["rigid"]["fit"] == "rigid"  # evaluate.pose_fit
    assert "| tripod | rigid + rays | 10 |" in table and "| tripod | rigid | 10 |" in table
    assert "## Mirror test" in table
    assert test["kinematic_fit"]["all"]["frames"] == test["all"]["frames"]           # evaluate.kinematic_fit
    assert latency["fit_batch1_median_ms"] > 0                                      # latency.kinematic_fit
    assert "## Kinematic fit" in table and "with the mirror and zoom tests and the fit" in table  # evaluate.headline
    assert test["kinematic_fit"]["on_mirror_test"] and "--mirror --zoom --fit" in table            # evaluate.zoom_on_mirror
    assert json.loads((work / "results" / "latency.json").read_text())["zoom_on_mirror"]          # latency.zoom_on_mirror
    from armpose.train import load_checkpoint                                       # transfer_stage2.fit_sigmas:
    extra = load_checkpoint(work / "models" / "transfer_stage2" / "model.pt")["extra"]   # measured (the tiny set has
    assert extra["fit_sigmas"] == {}                                                # no held-out frames left)
    assert extra["fit_sigmas_on_mirror"] and test["kinematic_fit"]["sigmas_on_mirror_test"]  # .fit_sigmas_on_mirror
    assert "measured after stage 2 on held-out training frames, on mirror-averaged passes" in table
    before = {p.name: p.read_bytes() for p in (work / "data" / "labels").glob("*.npy")}
    out = _sh("dvc repro labels", work)
    assert "didn't change" in out or "up to date" in out, out
    assert {p.name: p.read_bytes() for p in (work / "data" / "labels").glob("*.npy")} == before
    status = _sh("dvc status", work)
    assert "up to date" in status, status


def test_project_root_is_the_dvc_working_directory(tmp_path, monkeypatch):
    (tmp_path / "dvc.yaml").write_text("stages: {}\n")
    (tmp_path / "params.yaml").write_text("base: {}\n")
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("ARMPOSE_ROOT", raising=False)
    assert project_root() == tmp_path.resolve()
    monkeypatch.chdir(REPO / "src")
    assert project_root() == REPO

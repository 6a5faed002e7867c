"""The training loop: frozen layers stay frozen, a killed run resumes to the same weights,
DDP ranks agree, and the stages chain (pretrain -> stage 1 -> stage 2)."""
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from armpose.config import profile_params
from armpose.stages import pretrain, transfer_stage1, transfer_stage2
from armpose.train import load_checkpoint


def quick(root_params: dict, **stage_overrides) -> dict:
    params = profile_params("quick")
    params["base"] = root_params["base"]
    for stage, over in stage_overrides.items():
        params[stage].update(over)
    return params


def _weights(path: Path) -> dict:
    return load_checkpoint(path)["model"]


def test_stage1_keeps_frozen_layers_bit_identical(tiny_project, tmp_path, caplog):
    root, tparams = tiny_project
    (tmp_path / "data").symlink_to(root / "data")
    params = quick(tparams)
    pretrain.run(params, tmp_path)
    before = _weights(tmp_path / "models" / "pretrain" / "model.pt")
    first = transfer_stage1.run(params, tmp_path)
    after = _weights(tmp_path / "models" / "transfer_stage1" / "model.pt")
    trainable = set(params["transfer_stage1"]["trainable"])
    changed = {k for k in before if not torch.equal(before[k], after[k])}
    assert changed, "stage 1 trained nothing"
    assert all(k.startswith(tuple(trainable)) for k in changed), sorted(changed)[:5]
    frozen = [k for k in before if not k.startswith(tuple(trainable))]
    assert frozen and all(torch.equal(before[k], after[k]) for k in frozen)
    transfer_stage2.run(params, tmp_path)
    assert (tmp_path / "models" / "transfer_stage2" / "history.csv").exists()
    # a finished stage run again is left exactly as it was
    stage1 = tmp_path / "models" / "transfer_stage1"
    files = {p.name: p.read_bytes() for p in stage1.glob("*.pt")}
    caplog.clear()
    with caplog.at_level("INFO"):
        again = transfer_stage1.run(params, tmp_path)
    assert {p.name: p.read_bytes() for p in stage1.glob("*.pt")} == files
    assert again == first and first["feature_cache"] and first["feature_cache_s"] > 0   # its summary too
    assert "cached trunk features" not in caplog.text                              # without caching again
    # what stage 2 measures after training changes: the weights stay, the sigmas are measured again
    stage2 = tmp_path / "models" / "transfer_stage2" / "model.pt"
    trained = load_checkpoint(stage2)
    measured_on_mirror = trained["extra"]["fit_sigmas_on_mirror"]
    assert params["transfer_stage2"]["fit_sigmas"] and measured_on_mirror == params["transfer_stage2"]["fit_sigmas_on_mirror"]
    params["transfer_stage2"]["fit_sigmas_on_mirror"] = not measured_on_mirror
    caplog.clear()
    with caplog.at_level("INFO", logger="armpose.train"):
        transfer_stage2.run(params, tmp_path)
    assert "resuming" in caplog.text and "starting afresh" not in caplog.text
    again = load_checkpoint(stage2)
    assert again["step"] == trained["step"] and again["extra"]["fit_sigmas_on_mirror"] != measured_on_mirror
    assert all(torch.equal(again["model"][k], v) for k, v in trained["model"].items())


def test_stride4_heads_train_on_cached_trunk_features(tiny_project, tmp_path):
    root, tparams = tiny_project
    (tmp_path / "data").symlink_to(root / "data")
    params = quick(tparams)
    params["base"] = {**params["base"], "model": {**params["base"].get("model", {}), "keypoint_stride": 4}}
    assert params["transfer_stage1"]["feature_cache"]
    pretrain.run(params, tmp_path)
    transfer_stage1.run(params, tmp_path)
    ckpt = load_checkpoint(tmp_path / "models" / "transfer_stage1" / "model.pt")
    assert ckpt["config"]["base"]["model"]["keypoint_stride"] == 4
    assert any(".neck.fine." in k for k in ckpt["model"])


SCRIPT = """
import sys, yaml
from armpose.stages import pretrain
params = yaml.safe_load(open(sys.argv[1]))
pretrain.run(params, sys.argv[2])
"""


def _run_pretrain(params: dict, root: Path, env=None, **popen):
    import yaml
    pfile = root / "params.yaml"
    pfile.write_text(yaml.safe_dump(params))
    return subprocess.Popen([sys.executable, "-c", SCRIPT, str(pfile), str(root)], env=env, **popen)


def test_killed_run_resumes_to_the_same_weights(tiny_project, tmp_path):
    root, tparams = tiny_project
    params = quick(tparams, pretrain={"max_steps": 12, "checkpoint_every": 2, "eval_every": 4})
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "data").symlink_to(root / "data")
    assert _run_pretrain(params, tmp_path / "a").wait() == 0
    last = tmp_path / "b" / "models" / "pretrain" / "last.pt"
    proc = _run_pretrain(params, tmp_path / "b", stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    while time.time() < deadline and not (last.exists() and 2 <= load_checkpoint(last)["step"] < 12):
        time.sleep(0.05)
    proc.kill()
    proc.wait()
    killed_at = load_checkpoint(last)["step"]
    assert killed_at < 12, "the run finished before it could be killed"
    assert _run_pretrain(params, tmp_path / "b").wait() == 0
    wa = _weights(tmp_path / "a" / "models" / "pretrain" / "model.pt")
    wb = _weights(tmp_path / "b" / "models" / "pretrain" / "model.pt")
    assert all(torch.equal(wa[k], wb[k]) for k in wa), f"resumed from step {killed_at} but weights differ"
    ha = (tmp_path / "a" / "models" / "pretrain" / "history.csv").read_text().splitlines()
    hb = (tmp_path / "b" / "models" / "pretrain" / "history.csv").read_text().splitlines()
    assert len(ha) == len(hb) == 13


def test_ddp_two_cpu_ranks_agree(tiny_project, tmp_path):
    root, tparams = tiny_project
    params = quick(tparams, pretrain={"max_steps": 4, "batch_size": 4, "checkpoint_every": 2, "threads": 2})
    (tmp_path / "data").symlink_to(root / "data")
    import yaml
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params))
    script = tmp_path / "ddp_run.py"
    script.write_text("import sys, yaml, json\nfrom armpose.stages import pretrain\n"
                      "res = pretrain.run(yaml.safe_load(open(sys.argv[1])), sys.argv[2])\n"
                      "print('RESULT', json.dumps({k: v for k, v in res.items() if k != 'out'}))\n")
    out = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--nproc_per_node=2", "--master_port=29517",
                          str(script), str(tmp_path / "params.yaml"), str(tmp_path)],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    import json
    results = [json.loads(line.split("RESULT ", 1)[1]) for line in out.stdout.splitlines() if "RESULT " in line]
    assert len(results) == 2
    assert all(r["world_size"] == 2 and r["ddp_max_weight_difference"] == 0.0 for r in results), results
    assert (tmp_path / "models" / "pretrain" / "model.pt").exists()


def test_precision_is_fp32_by_default_and_checked():
    from armpose.train import training_precision
    assert training_precision({}) == "fp32" and training_precision({"precision": "bf16"}) == "bf16"
    with pytest.raises(ValueError, match="precision"):
        training_precision({"precision": "fp16"})

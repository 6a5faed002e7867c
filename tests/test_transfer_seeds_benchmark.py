"""benchmarks/transfer_seeds.py: each seed is trained and measured as the pipeline's stages are."""
import importlib.util
from pathlib import Path

from armpose.config import profile_params
from armpose.stages import pretrain
from armpose.train import load_checkpoint

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "transfer_seeds.py"


def _benchmark():
    spec = importlib.util.spec_from_file_location("transfer_seeds", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_seed_gets_its_fit_sigmas_like_the_pipelines_stage_2(tiny_project, tmp_path):
    bench = _benchmark()
    root, tparams = tiny_project
    (tmp_path / "data").symlink_to(root / "data")
    params = profile_params("quick")
    params["base"] = tparams["base"]
    pretrain.run(params, tmp_path)
    work = tmp_path / "models" / "transfer_seeds" / "default" / "seed_1"
    bench.link_project(tmp_path, work)
    seeded = bench.seed_params(params, 1, [])
    assert seeded["transfer_stage2"]["fit_sigmas"] and seeded["transfer_stage1"]["seed_offset"] == 1
    bench.train_seed(seeded, work)
    extra = load_checkpoint(work / "models" / "transfer_stage2" / "model.pt")["extra"]
    assert "fit_sigmas" in extra and extra["fit_sigmas_on_mirror"] == seeded["transfer_stage2"]["fit_sigmas_on_mirror"]

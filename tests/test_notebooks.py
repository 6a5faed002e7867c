"""The narrated notebooks: paired with their percent scripts, and executable end to end.

The notebooks run with papermill, in pipeline order (record, render, labels, pretrain, transfer
stage 1, transfer stage 2, evaluation, then the beyond-the-paper notebook 07), on the ``quick``
profile into one temporary root, with a working directory that is neither the project nor the root.
"""
from __future__ import annotations

import json
from pathlib import Path

import jupytext
import nbformat
import papermill
import pytest
from jupyter_client.kernelspec import KernelSpecManager

from armpose.config import profile_params

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = ["00_record", "01_render", "02_labels", "03_pretrain", "04_transfer_stage1", "05_transfer_stage2",
             "06_evaluate", "07_beyond"]   # pipeline order; 07 reads what the stages wrote
KERNEL = "python3"


def _cells(nb) -> list[tuple[str, str, list]]:
    return [(c.cell_type, c.source.strip(), list(c.metadata.get("tags", []))) for c in nb.cells]


@pytest.mark.parametrize("name", NOTEBOOKS)
def test_notebook_is_paired_and_clean(name):
    """The committed .ipynb holds the cells of the .py (run `jupytext --sync notebooks/*.py`) and
    no outputs; its first code cell is papermill's parameters cell, holding literals only."""
    script = jupytext.read(ROOT / "notebooks" / f"{name}.py")
    ipynb = nbformat.read(ROOT / "notebooks" / f"{name}.ipynb", as_version=4)
    assert _cells(ipynb) == _cells(script), f"{name}.ipynb is out of sync with {name}.py"
    code = [c for c in ipynb.cells if c.cell_type == "code"]
    assert all(not c.outputs and c.execution_count is None for c in code), f"{name}.ipynb has outputs"
    first = code[0]
    assert first.metadata.get("tags") == ["parameters"]
    assert first.source.strip().splitlines() == ['profile = "default"', 'root = ""']


@pytest.mark.slow
def test_notebooks_execute(tmp_path):
    """render, labels, then the three training stages, quick profile, into tmp_root: every notebook
    runs, figures come out, the dataset and the three stages' weights and histories exist."""
    assert KERNEL in KernelSpecManager().find_kernel_specs(), (
        f"no Jupyter kernel {KERNEL!r}; install one with `python -m ipykernel install --user`")
    tmp_root = tmp_path / "root"
    tmp_root.mkdir()
    work = tmp_path / "cwd"
    work.mkdir()
    executed = {}
    for name in NOTEBOOKS:
        out = tmp_path / f"{name}.out.ipynb"
        papermill.execute_notebook(str(ROOT / "notebooks" / f"{name}.ipynb"), str(out),
                                   parameters={"profile": "quick", "root": str(tmp_root)},
                                   kernel_name=KERNEL, cwd=str(work), progress_bar=False)
        nb = nbformat.read(out, as_version=4)
        assert not nb.metadata.papermill.get("exception")
        assert any("injected-parameters" in c.metadata.get("tags", []) for c in nb.cells)
        executed[name] = nb

    def pngs(nb):
        return sum("image/png" in o.get("data", {}) for c in nb.cells if c.cell_type == "code" for o in c.outputs)

    assert pngs(executed["01_render"]) >= 2      # sample grid, camera poses
    assert pngs(executed["02_labels"]) >= 3      # overlays, mask area, distances
    assert pngs(executed["03_pretrain"]) >= 2    # architecture, loss curves
    assert pngs(executed["04_transfer_stage1"]) >= 1   # loss curves
    assert pngs(executed["05_transfer_stage2"]) >= 3   # architecture, loss curves, both stages
    assert pngs(executed["06_evaluate"]) >= 6    # figures (a)-(f)
    assert pngs(executed["07_beyond"]) >= 2      # poses after the bump, tracked joint over time
    for name in ("metrics.json", "results_table.md", "latency.json", "env.json"):
        assert (tmp_root / "results" / name).exists(), name
    for stage in ("pretrain", "transfer_stage1", "transfer_stage2"):
        out = tmp_root / "models" / stage
        assert (out / "model.pt").exists() and (out / "history.csv").exists() and (out / "summary.json").exists()
    index_path = tmp_root / "data" / "labels" / "index.json"
    assert index_path.exists()
    index = json.loads(index_path.read_text())
    quick = profile_params("quick")
    by_source = {}
    for rec in index["recordings"]:
        by_source[rec["source"]] = by_source.get(rec["source"], 0) + rec["frames"]
    assert by_source["synthetic"] == sum(quick["render"]["frames_per_robot"].values())
    assert by_source["recorded"] > 0, "the record stage's sessions are labelled too"
    assert index["num_frames"] == sum(by_source.values())
    assert index["num_train"] + index["num_test"] == index["num_frames"]
    assert not list(work.iterdir()), "the notebooks wrote into their working directory"

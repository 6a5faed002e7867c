"""The results table: paper numbers beside ours, bold where ours is at least as good, shortfalls listed."""
from armpose.report import PAPER_TABLE_II, beats_paper, results_table


def _fam(mask, typ, joint, base):
    return {"mask_accuracy": mask, "type_accuracy": typ, "joint_median_cm": joint, "base_median_cm": base,
            "mask_iou": 0.5, "joint_mean_cm": joint, "add_auc_10cm": 0.1, "pck_5px": 0.2, "pck_10px": 0.3,
            "frames": 10}


def _metrics():
    fams = {"UR": _fam(0.99, 0.98, 12.0, 11.0), "KUKA": _fam(0.96, 1.0, 3.0, 2.0), "Panda": _fam(0.95, 0.9, 5.0, 4.0)}
    return {"transfer": {"test": {"by_family": fams, "by_source": {}}},
            "train_full": {"test": {"by_family": fams}},
            "latency": {"cpu": {"batch1_median_ms": 9.5, "batch1_p95_ms": 11.0, "threads": 2}},
            "timing": {"pretrain": {"wall_s": 600.0, "s_per_step": 0.4},
                       "transfer_stage1": {"wall_s": 30.0, "s_per_step": 0.04},
                       "stage1_step_speedup": {"pretrain": 10.0}}}


def test_comparison_direction():
    assert beats_paper({"mask_accuracy": 0.971}, "UR", "mask_accuracy")
    assert not beats_paper({"joint_median_cm": 3.2}, "UR", "joint_median_cm")
    assert beats_paper({"joint_median_cm": PAPER_TABLE_II["KUKA"]["joint_median_cm"]}, "KUKA", "joint_median_cm")


def test_table_has_both_columns_bold_wins_and_lists_shortfalls():
    text = results_table(_metrics(), "held-out synthetic renders")
    assert "| Mask accuracy, % | 97.0 | **99.0** | 97.7 | 96.0 | 94.3 | **95.0** |" in text
    assert "| Joint position error (median), cm | 3.12 | 12.00 | 3.30 | **3.00** | 3.64 | 5.00 |" in text
    short = text.split("## Still short of the paper")[1]
    assert "UR joint position error" in short and "KUKA mask accuracy" in short
    assert "KUKA joint" not in short and "UR mask" not in short
    assert "9.5 ms" in text and "held-out synthetic renders" in text and "10.0x faster" in text


def test_git_hash_marks_uncommitted_code_or_params_but_not_pipeline_outputs(tmp_path):
    import subprocess
    from armpose.report import git_hash
    assert git_hash(tmp_path) == "unknown"
    run = (lambda *a: subprocess.run(["git", *a], cwd=tmp_path, check=True, capture_output=True))
    run("init", "-q")
    run("config", "user.email", "t@t")
    run("config", "user.name", "t")
    (tmp_path / "results").mkdir()
    for name in ("params.yaml", "dvc.lock", "results/metrics.json"):
        (tmp_path / name).write_text("a\n")
    run("add", "-A")
    run("commit", "-qm", "x")
    head = run("rev-parse", "HEAD").stdout.decode().strip()
    (tmp_path / "dvc.lock").write_text("b\n")
    (tmp_path / "results" / "metrics.json").write_text("b\n")
    (tmp_path / "untracked.txt").write_text("b\n")
    assert git_hash(tmp_path) == head
    (tmp_path / "params.yaml").write_text("b\n")
    assert git_hash(tmp_path) == head + "-dirty"


def test_headline_reports_the_chosen_variant_and_the_sections_compare_it_with_the_single_pass():
    import pytest
    m = _metrics()
    fitted = {"UR": _fam(0.99, 0.98, 8.0, 7.0), "KUKA": _fam(0.98, 1.0, 3.0, 2.0), "Panda": _fam(0.95, 0.97, 3.5, 4.0)}
    m["transfer"]["test"]["kinematic_fit"] = {"by_family": fitted}
    m["latency"]["cpu"]["fit_batch1_median_ms"] = 60.0
    text = results_table(m, "held-out synthetic renders", headline="kinematic_fit")
    assert "| Joint position error (median), cm | 3.12 | 8.00 | 3.30 | **3.00** | 3.64 | **3.50** |" in text
    assert "with the zoom test and the fit" in text and "60.0 ms per frame" in text
    assert "| UR | 12.00 / 8.00 |" in text                                # the section: single / fit
    assert "Panda joint" not in text.split("## Still short of the paper")[1]
    with pytest.raises(ValueError, match="headline"):
        results_table(m, "x", headline="zoom_test")                      # not run
    with pytest.raises(ValueError, match="headline"):
        results_table(m, "x", headline="best")


def test_cpu_description_reads_the_model_and_the_widest_vector_unit(tmp_path):
    from armpose.report import cpu_description
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\ncpu family\t: 6\nmodel\t\t: 85\nmodel name\t: Example CPU @ 2.0GHz\nflags\t\t: fpu sse4_2 avx avx2 fma\n\n"
                    "processor\t: 1\nmodel name\t: Example CPU @ 2.0GHz\nflags\t\t: fpu sse4_2 avx avx2 fma\n")
    assert cpu_description(info) == {"model": "Example CPU @ 2.0GHz", "family_model": "6/85",
                                      "vector_isa": "avx2"}
    info.write_text("model name\t: Other\nflags\t\t: sse4_2 avx2 avx512f avx512_bf16\n")
    assert cpu_description(info)["vector_isa"] == "avx512_bf16"
    assert cpu_description(tmp_path / "missing") == {"model": None, "family_model": None, "vector_isa": None}

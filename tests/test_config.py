"""params.yaml is the default profile; switching profile is one command."""
import subprocess
import sys

import pytest

from armpose.config import deep_merge, load_params, profile_params, select_profile


def test_committed_params_yaml_is_the_default_profile():
    assert load_params() == profile_params("default")


def test_profiles_only_override(tmp_path):
    quick = profile_params("quick")
    default = profile_params("default")
    assert quick["base"] == default["base"]
    assert sum(quick["render"]["frames_per_robot"].values()) < sum(default["render"]["frames_per_robot"].values())
    assert deep_merge({"a": {"b": 1, "c": 2}}, {"a": {"c": 3}}) == {"a": {"b": 1, "c": 3}}


def test_select_profile_writes_params(tmp_path):
    import shutil
    from pathlib import Path
    repo = Path(__file__).resolve().parents[1]
    shutil.copytree(repo / "profiles", tmp_path / "profiles")
    select_profile("paper", tmp_path)
    assert load_params(tmp_path / "params.yaml") == profile_params("paper")


def test_cli_lists_robots():
    out = subprocess.run([sys.executable, "-m", "armpose.cli", "robots"], capture_output=True, text=True, check=True)
    for name in ("ur3", "ur5", "ur10", "iiwa", "panda"):
        assert name in out.stdout


def test_override_from_text_nests_and_parses_yaml():
    from armpose.config import deep_merge, override_from_text

    params = {"transfer_stage2": {"lr": 5e-4, "plateau": {"delta": 0.01, "patience": 600}}}
    merged = deep_merge(params, override_from_text("transfer_stage2.plateau.patience=900", params))
    assert merged["transfer_stage2"] == {"lr": 5e-4, "plateau": {"delta": 0.01, "patience": 900}}
    assert override_from_text("a.b=[1, 2]") == {"a": {"b": [1, 2]}}
    assert override_from_text("a.b=2e-4")["a"]["b"] == 2e-4
    assert override_from_text("a.b=fp32") == {"a": {"b": "fp32"}}
    for bad in ("lr=1", "transfer_stage2.lr", "a..b=1"):
        with pytest.raises(ValueError, match="SECTION.KEY=VALUE"):
            override_from_text(bad)
    with pytest.raises(KeyError, match="no section 'pretrian'"):
        override_from_text("pretrian.lr=1", params)

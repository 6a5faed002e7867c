"""Shared fixtures: tiny parameter sets and one tiny rendered and labelled project per session."""
from __future__ import annotations

import pytest
import torch

from armpose.config import profile_params


def tiny_params(frames: int = 6, workers: int = 1) -> dict:
    """The quick profile shrunk to ``frames`` frames per robot type."""
    params = profile_params("quick")
    params["render"]["frames_per_robot"] = {r: frames for r in params["base"]["robot_types"]}
    params["render"]["frames_per_recording"] = frames
    params["render"]["frames_per_scene"] = 3
    params["base"]["num_workers"] = workers
    return params


@pytest.fixture(name="tiny_params")
def tiny_params_fixture():
    """:func:`tiny_params` as a fixture, for test modules."""
    return tiny_params


@pytest.fixture(scope="session")
def tiny_project(tmp_path_factory):
    """A temporary project root with ``data/render`` and ``data/labels`` from :func:`tiny_params`."""
    from armpose.stages import labels, render
    root = tmp_path_factory.mktemp("tiny_project")
    params = tiny_params(frames=12, workers=2)
    render.run(params, root)
    labels.run(params, root)
    return root, params


@pytest.fixture(scope="module")
def one_torch_thread():
    """Tiny tensors: one thread is as fast, and far faster when other jobs share the CPU."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)

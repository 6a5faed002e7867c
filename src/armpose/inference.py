"""The trained network prepared for inference: BatchNorm folded into the convolution before it.

In eval mode a BatchNorm is a fixed per-channel affine map, so ``conv -> BN`` equals one
convolution with scaled weights and a bias (:func:`torch.nn.utils.fusion.fuse_conv_bn_eval`).
Folding every such pair removes a pass over each feature map: on the 2-core reference machine
``dvc repro latency`` measured a batch-1 median of 16.5 ms before folding (commit 5082ea2) and
14.8 ms after (``results/latency.json``, same checkpoint); the outputs agree with the unfolded
network to float rounding (``tests/test_inference.py``).

:func:`load_inference_model` is what ``armpose predict``, the ``evaluate`` and ``latency``
stages and the benchmarks load; training and the measurements made inside training stages
(:mod:`armpose.fit_sigmas`) keep :func:`armpose.train.load_model`, whose network can still be
trained. A folded network must not be trained: its BatchNorms are gone.
"""
from __future__ import annotations

import copy
import logging
from pathlib import Path

import torch
from torch import nn
from torch.nn.utils.fusion import fuse_conv_bn_eval

from armpose.train import load_model

log = logging.getLogger(__name__)


def fold_batchnorm(model: nn.Module) -> nn.Module:
    """A copy of ``model`` (in eval mode) with every ``Conv2d`` directly followed by a
    ``BatchNorm2d`` in an ``nn.Sequential`` replaced by one folded ``Conv2d`` (the BatchNorm by
    ``nn.Identity``). Other modules, buffers and attributes are kept. Returns the copy in eval mode."""
    folded = copy.deepcopy(model).eval()
    count = 0
    for module in folded.modules():
        if not isinstance(module, nn.Sequential):
            continue
        names = list(module._modules)
        for first, second in zip(names, names[1:]):
            conv, bn = module._modules[first], module._modules[second]
            if isinstance(conv, nn.Conv2d) and isinstance(bn, nn.BatchNorm2d):
                module._modules[first] = fuse_conv_bn_eval(conv, bn)
                module._modules[second] = nn.Identity()
                count += 1
    left = sum(isinstance(m, nn.BatchNorm2d) for m in folded.modules())
    log.debug("folded %d BatchNorm layers into their convolutions (%d left)", count, left)
    return folded


def load_inference_model(checkpoint: Path, device: torch.device | str = "cpu") -> tuple[nn.Module, dict]:
    """``(model, config)``: the checkpoint's network in eval mode, BatchNorm folded
    (:func:`fold_batchnorm`), channels-last, on ``device``; ``config`` is the checkpoint's."""
    model, config = load_model(Path(checkpoint), "cpu")
    model = fold_batchnorm(model).to(device).to(memory_format=torch.channels_last).eval()
    return model, config

"""The inference network: BatchNorm folded into the convolutions, same outputs as the trained one."""
import pytest
import torch
from torch import nn

from armpose.inference import fold_batchnorm, load_inference_model
from armpose.model import ArmPoseNet
from armpose.train import save_checkpoint

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def trained_looking_model(seed: int = 0) -> ArmPoseNet:
    """A small network whose BatchNorms hold non-trivial statistics and affine weights, as after
    training (a fresh BatchNorm is the identity, which would make folding trivially right)."""
    torch.manual_seed(seed)
    model = ArmPoseNet(width=8)
    g = torch.Generator().manual_seed(seed)
    for m in model.modules():
        if isinstance(m, nn.BatchNorm2d):
            n = m.num_features
            m.running_mean.copy_(torch.randn(n, generator=g) * 0.3)
            m.running_var.copy_(torch.rand(n, generator=g) * 2 + 0.2)
            m.weight.data.copy_(torch.rand(n, generator=g) + 0.5)
            m.bias.data.copy_(torch.randn(n, generator=g) * 0.2)
    return model.eval()


def batchnorms(model: nn.Module) -> int:
    return sum(isinstance(m, nn.BatchNorm2d) for m in model.modules())


def test_folding_removes_every_batchnorm_and_keeps_the_outputs():
    model = trained_looking_model()
    folded = fold_batchnorm(model)
    assert batchnorms(model) > 0 and batchnorms(folded) == 0
    x = torch.rand(2, 3, 48, 64, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        a, b = model(x), folded(x)
    assert set(a) == set(b)
    for key in a:
        if torch.is_tensor(a[key]) and a[key].is_floating_point():
            scale = a[key].abs().max().clamp(min=1.0)
            assert torch.allclose(a[key], b[key], atol=1e-4 * float(scale), rtol=1e-4), key


def test_folding_leaves_the_trained_model_untouched():
    model = trained_looking_model()
    before = {k: v.clone() for k, v in model.state_dict().items()}
    fold_batchnorm(model)
    after = model.state_dict()
    assert before.keys() == after.keys()
    assert all(torch.equal(before[k], after[k]) for k in before)


def test_a_folded_checkpoint_predicts_what_the_trained_one_does(tmp_path):
    model = trained_looking_model(seed=3)
    config = {"base": {"model": {"width": 8}}, "cfg": {}}
    save_checkpoint(tmp_path / "model.pt", model, None, None, 1, "pretrain", config)
    loaded, loaded_config = load_inference_model(tmp_path / "model.pt")
    assert loaded_config == config and batchnorms(loaded) == 0 and not loaded.training
    x = torch.rand(1, 3, 48, 64, generator=torch.Generator().manual_seed(2))
    with torch.no_grad():
        want, got = model(x)["joints"], loaded(x.contiguous(memory_format=torch.channels_last))["joints"]
    assert torch.allclose(want, got, atol=1e-4)

"""The lifting solve: base position from image rays and a metric base-relative shape."""
import pytest
import torch

from armpose.lifting import solve_base


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def robot_case(b: int = 4, n: int = 7, seed: int = 0):
    """Random bases 1.5-3.5 m ahead and joint offsets of an arm-sized robot (metres, camera frame)."""
    g = torch.Generator().manual_seed(seed)
    base = torch.stack([torch.rand(b, generator=g) - 0.5, torch.rand(b, generator=g) * 0.4,
                        1.5 + 2 * torch.rand(b, generator=g)], -1).double()
    offsets = (torch.rand(b, n, 3, generator=g).double() - 0.5) * 1.2
    offsets = torch.cat([offsets, torch.zeros(b, 1, 3, dtype=torch.float64)], 1)       # the base: offset 0
    points = base[:, None] + offsets
    rays = points[..., :2] / points[..., 2:]
    return base, offsets, rays


def test_exact_rays_and_shape_give_the_true_base_whatever_the_prior():
    base, offsets, rays = robot_case()
    wrong_prior = base + torch.tensor([0.3, -0.2, 1.0], dtype=torch.float64)
    solved = solve_base(rays, offsets, torch.ones(rays.shape[:2], dtype=torch.float64), wrong_prior, 1e-9)
    torch.testing.assert_close(solved, base, rtol=0, atol=1e-6)


def test_depth_follows_the_apparent_size():
    """The same shape seen half as large is twice as far (rays through the optical centre)."""
    base, offsets, rays = robot_case()
    weights = torch.ones(rays.shape[:2], dtype=torch.float64)
    near = solve_base(rays, offsets, weights, base, 1e-9)
    far = solve_base(rays, 2 * offsets, weights, base, 1e-9)
    torch.testing.assert_close(far, 2 * near, rtol=1e-6, atol=1e-9)


def test_zero_weight_points_are_ignored():
    base, offsets, rays = robot_case()
    rays = rays.clone()
    rays[:, 3] += 0.2                                      # a wrong ray...
    weights = torch.ones(rays.shape[:2], dtype=torch.float64)
    weights[:, 3] = 0                                      # ...with no weight
    torch.testing.assert_close(solve_base(rays, offsets, weights, base * 2, 1e-9), base, rtol=0, atol=1e-6)


def test_coincident_rays_fall_back_to_the_prior_depth():
    """Every point on one ray says nothing about depth: the prior decides it, with no NaN."""
    b = 3
    rays = torch.zeros(b, 8, 2)
    offsets = torch.zeros(b, 8, 3)
    prior = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 3.0], [0.0, 0.0, 1.5]])
    solved = solve_base(rays, offsets, torch.ones(b, 8), prior)
    torch.testing.assert_close(solved, prior, rtol=1e-5, atol=1e-5)


def test_gradients_reach_rays_offsets_weights_and_prior():
    base, offsets, rays = robot_case(b=2)
    rays = (rays + 0.01).requires_grad_()
    offsets = offsets.clone().requires_grad_()
    weights = torch.full(rays.shape[:2], 0.5, dtype=torch.float64, requires_grad=True)
    prior = (base + 0.1).requires_grad_()
    solve_base(rays, offsets, weights, prior).sum().backward()
    for t in (rays, offsets, weights, prior):
        assert t.grad is not None and torch.isfinite(t.grad).all() and t.grad.abs().sum() > 0
    assert torch.autograd.gradcheck(lambda r, o, w, p: solve_base(r, o, w, p, 0.05),
                                    (rays.detach().requires_grad_(), offsets.detach().requires_grad_(),
                                     weights.detach().requires_grad_(), prior.detach().requires_grad_()))


def test_prior_weight_must_be_positive():
    base, offsets, rays = robot_case(b=1)
    with pytest.raises(ValueError, match="prior_weight"):
        solve_base(rays, offsets, torch.ones(1, 8, dtype=torch.float64), base, 0.0)

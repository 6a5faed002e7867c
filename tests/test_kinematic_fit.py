"""armpose.kinematic_fit: the robot model fitted to the network's points recovers an exact robot,
repairs depth noise along the rays, keeps joint limits, and names bad input."""
import numpy as np
import pytest
import torch

from armpose.kinematic_fit import FitSettings, fit_predictions, fit_robot, kabsch, vector_from_rotation
from armpose.robots import get_robot
from armpose.robots.kinematics import Kinematics, SerialChain, axis_angle_matrix

TYPES = ["ur3", "ur5", "ur10", "iiwa", "panda"]


def posed_robots(name: str, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``(points (n, J + 1, 3), q (n, J))``: random configurations in front of a camera, 1.5-2.5 m away."""
    rng = np.random.default_rng(seed)
    kin = Kinematics(get_robot(name))
    lim = np.array(kin.spec.joint_limits)
    q = rng.uniform(lim[:, 0], lim[:, 1], (n, len(lim)))
    base = SerialChain(kin).positions(torch.tensor(q)).numpy()
    R = axis_angle_matrix(torch.tensor(rng.normal(0, 1.0, (n, 3)))).numpy()
    t = np.column_stack([rng.uniform(-0.3, 0.3, (n, 2)), rng.uniform(1.5, 2.5, n)])
    return base @ R.transpose(0, 2, 1) + t[:, None], q


@pytest.mark.parametrize("name", ["ur5", "panda"])
def test_exact_points_give_back_the_robot(name):
    points, _ = posed_robots(name, 6)
    fit = fit_robot(points, name)
    assert np.abs(fit["points"] - points).max() < 0.01   # depth is weighted weakly: LM stops within millimetres
    T = fit["T_cam_base"]
    np.testing.assert_allclose(T[:, :3, 3], points[:, 0], atol=0.01)      # the base is the frame's origin
    lim = np.array(get_robot(name).joint_limits)
    assert (fit["q"] >= lim[:, 0] - 1e-3).all() and (fit["q"] <= lim[:, 1] + 1e-3).all()


def test_depth_noise_along_the_rays_is_repaired():
    """Points on their true rays, but each at a depth off by a shared 6 % and 4 % of its own: the
    fitted robot's joints are closer to the truth than the points it was fitted to."""
    points, _ = posed_robots("ur10", 40, seed=1)
    rng = np.random.default_rng(2)
    scale = (1 + rng.normal(0, 0.06, (40, 1, 1))) * (1 + rng.normal(0, 0.04, (40, points.shape[1], 1)))
    noisy = points * scale
    fit = fit_robot(noisy, "ur10")
    before = np.median(np.linalg.norm(noisy - points, axis=-1))
    after = np.median(np.linalg.norm(fit["points"] - points, axis=-1))
    assert after < 0.75 * before, (before, after)


def test_a_type_s_depth_ratio_from_its_sigmas_undoes_a_shared_depth_bias():
    """Points on their true rays but 12 % too close (and 4 % noise each): the fit with the type's
    ``depth_ratio`` of 0.88 lands nearer the truth than the fit without it."""
    points, _ = posed_robots("ur10", 30, seed=5)
    rng = np.random.default_rng(6)
    near = points * 0.88 * (1 + rng.normal(0, 0.04, (30, points.shape[1], 1)))
    types = np.full(30, 2)
    sig = {"ray_sigma": 0.012, "log_depth_sigma": 0.1}
    plain = fit_predictions(near[:, 1:], near[:, 0], types, TYPES, FitSettings(starts=64), {"ur10": sig})
    fixed = fit_predictions(near[:, 1:], near[:, 0], types, TYPES, FitSettings(starts=64),
                            {"ur10": {**sig, "depth_ratio": 0.88}})
    err = {k: np.median(np.linalg.norm(v["joints"][:, :6] - points[:, 1:], axis=-1)) for k, v in
           (("plain", plain), ("fixed", fixed))}
    print(err)
    assert err["fixed"] < 0.6 * err["plain"], err


def test_fit_predictions_fits_each_frame_s_predicted_type_and_keeps_unused_slots():
    ur, _ = posed_robots("ur3", 3, seed=3)
    panda, _ = posed_robots("panda", 2, seed=4)
    joints = np.zeros((5, 7, 3))
    joints[:3, :6], joints[3:] = ur[:, 1:], panda[:, 1:]
    joints[:3, 6] = [9.0, 9.0, 9.0]                                       # the unused seventh slot of a UR
    base = np.concatenate([ur[:, 0], panda[:, 0]])
    types = np.array([0, 0, 0, 4, 4])
    out = fit_predictions(joints, base, types, TYPES, FitSettings(starts=64))
    np.testing.assert_allclose(out["joints"][:3, :6], ur[:, 1:], atol=0.01)
    np.testing.assert_allclose(out["joints"][3:], panda[:, 1:], atol=0.01)
    assert (out["joints"][:3, 6] == 9.0).all() and np.isnan(out["q"][:3, 6]).all() and np.isfinite(out["q"][3:]).all()
    assert out["T_cam_base"].shape == (5, 4, 4) and out["cost"].shape == (5,)


def test_bad_points_are_refused_with_the_robot_named():
    with pytest.raises(ValueError, match="ur5.*\\(B, 7, 3\\)"):
        fit_robot(np.zeros((2, 8, 3)), "ur5")
    bad = posed_robots("ur5", 1)[0]
    bad[0, 2, 1] = np.nan
    with pytest.raises(ValueError, match="ur5.*non-finite"):
        fit_robot(bad, "ur5")


def test_kabsch_and_rotation_vectors_round_trip():
    rng = np.random.default_rng(5)
    v = torch.tensor(rng.normal(0, 0.8, (4, 3)))
    R = axis_angle_matrix(v)
    np.testing.assert_allclose(vector_from_rotation(R).numpy(), v.numpy(), atol=1e-9)
    A = torch.tensor(rng.normal(size=(4, 6, 3)))
    t = torch.tensor(rng.normal(size=(4, 3)))
    R2, t2 = kabsch(A, A @ R.transpose(1, 2) + t[:, None])
    np.testing.assert_allclose(R2.numpy(), R.numpy(), atol=1e-9)
    np.testing.assert_allclose(t2.numpy(), t.numpy(), atol=1e-9)

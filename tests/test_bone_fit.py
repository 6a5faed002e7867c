"""Bone-length fit (armpose.bone_fit): depths along fixed rays, the robot's bones restored."""
import numpy as np
import pytest

from armpose.bone_fit import bone_fit, bone_lengths, fit_depths
from armpose.robots import get_robot
from armpose.robots.kinematics import Kinematics

TYPES = ["ur3", "ur5", "ur10", "iiwa", "panda"]


def skeletons(robot: str, n: int, seed: int = 0) -> np.ndarray:
    """(n, 1 + J, 3) base and joint origins of ``robot`` at random angles, seen by random
    cameras 1.5-2.5 m away (metres, camera optical frame)."""
    rng = np.random.default_rng(seed)
    spec = get_robot(robot)
    q = rng.uniform(-1.5, 1.5, (n, spec.num_joints))
    pts = np.concatenate([np.zeros((n, 1, 3)), Kinematics(spec).joint_positions(q)], axis=1)
    a = rng.normal(size=(n, 3, 3))
    rot = np.linalg.qr(a)[0] * np.sign(np.linalg.det(np.linalg.qr(a)[0]))[:, None, None]
    shift = np.stack([rng.normal(0, 0.2, n), rng.normal(0, 0.2, n), rng.uniform(1.5, 2.5, n)], axis=1)
    return np.einsum("nij,nkj->nki", rot, pts) + shift[:, None]


def project(p: np.ndarray) -> np.ndarray:
    return p[..., :2] / p[..., 2:3]


@pytest.mark.parametrize("robot", TYPES)
def test_bone_lengths_do_not_depend_on_the_angles(robot):
    pts = skeletons(robot, 20)
    bones = np.linalg.norm(np.diff(pts, axis=1), axis=-1)
    np.testing.assert_allclose(bones, np.broadcast_to(bone_lengths(robot), bones.shape), atol=1e-9)


@pytest.mark.parametrize("robot", ["ur5", "panda"])
def test_the_true_skeleton_is_kept(robot):
    pts = skeletons(robot, 30)
    L = np.tile(bone_lengths(robot), (len(pts), 1))
    fitted = fit_depths(pts, L, np.ones_like(L, bool), sigma_depth=0.1)
    np.testing.assert_allclose(fitted, pts, atol=2e-4)


@pytest.mark.parametrize("robot", ["ur5", "iiwa", "panda"])
def test_per_point_depth_errors_shrink_and_rays_stay(robot):
    pts = skeletons(robot, 200, seed=1)
    rng = np.random.default_rng(2)
    noisy = pts * (1 + rng.normal(0, 0.06, (len(pts), pts.shape[1], 1)))    # each point slid along its ray
    L = np.tile(bone_lengths(robot), (len(pts), 1))
    fitted = fit_depths(noisy, L, np.ones_like(L, bool), sigma_depth=0.1)
    before = np.median(np.linalg.norm(noisy - pts, axis=-1))
    after = np.median(np.linalg.norm(fitted - pts, axis=-1))
    assert after < 0.6 * before, (before, after)
    np.testing.assert_allclose(project(fitted), project(noisy), atol=1e-12)


def objective(points, net, L, sigma_depth, sigma_bone=0.01):
    d = np.linalg.norm(np.diff(points, axis=-2), axis=-1)
    return (((d - L) / sigma_bone) ** 2).sum(-1) + ((np.log(points[..., 2] / net[..., 2]) / sigma_depth) ** 2).sum(-1)


def test_the_grid_minimum_is_found_where_a_bone_must_flip():
    """Three points (two bones) with large depth errors, so that bones may have to flip between
    pointing towards and away from the camera: the fit reaches the minimum of a brute-force
    search over all three depths (on the grid the search uses), which a descent from the
    network's depths often does not."""
    pts = skeletons("ur10", 40, seed=3)[:, 2:5]                 # joints 2-4: bones of 0.64 and 0.57 m
    rng = np.random.default_rng(4)
    net = pts * (1 + rng.normal(0, 0.15, (len(pts), 3, 1)))
    L = np.linalg.norm(np.diff(pts, axis=1), axis=-1)
    fitted = fit_depths(net, L, np.ones_like(L, bool), sigma_depth=0.1)
    descent = fit_depths(net, L, np.ones_like(L, bool), sigma_depth=0.1, search=False)
    best = np.zeros(len(pts))
    grid = np.exp(np.linspace(-0.5, 0.5, 101))
    rays = net / net[..., 2:3]
    for i in range(len(pts)):
        z = net[i, :, 2]
        cand = (rays[i, 0] * z[0] * grid[:, None, None, None],
                rays[i, 1] * z[1] * grid[None, :, None, None],
                rays[i, 2] * z[2] * grid[None, None, :, None])
        cand = np.stack(np.broadcast_arrays(*cand), axis=-2)    # (G, G, G, 3 points, 3)
        best[i] = objective(cand, net[i], L[i], 0.1).min()
    found = objective(fitted, net, L, 0.1)
    assert (found <= 1.02 * best + 1e-6).all(), np.flatnonzero(found > 1.02 * best + 1e-6)
    assert (objective(descent, net, L, 0.1) > 1.02 * best + 1e-6).sum() >= 2


def test_bone_fit_leaves_unused_slots_and_fits_each_type():
    ur = skeletons("ur5", 4)
    iiwa = skeletons("iiwa", 4)
    joints = np.zeros((8, 7, 3))
    joints[:4, :6], joints[4:] = ur[:, 1:] * 1.05, iiwa[:, 1:] * 1.05
    joints[:4, 6] = [0.3, 0.2, 2.0]                      # a UR's unused seventh slot
    base = np.concatenate([ur[:, 0], iiwa[:, 0]])
    types = np.array([1] * 4 + [3] * 4)
    out_joints, out_base = bone_fit(joints, base, types, TYPES, sigma_depth=0.1)
    np.testing.assert_array_equal(out_joints[:4, 6], joints[:4, 6])
    for rows, robot in ((slice(0, 4), "ur5"), (slice(4, 8), "iiwa")):
        n = len(bone_lengths(robot))
        pts = np.concatenate([out_base[rows, None], out_joints[rows, :n]], axis=1)
        np.testing.assert_allclose(np.linalg.norm(np.diff(pts, axis=1), axis=-1),
                                   np.tile(bone_lengths(robot), (4, 1)), atol=0.01)


@pytest.mark.parametrize("value", [0.0, -1.0, float("nan"), "0.1"])
def test_bad_sigma_is_named(value):
    pts = skeletons("ur5", 2)
    L = np.tile(bone_lengths("ur5"), (2, 1))
    with pytest.raises(ValueError, match="sigma_depth"):
        fit_depths(pts, L, np.ones_like(L, bool), sigma_depth=value)


def test_a_non_finite_point_is_returned_as_given_and_the_rest_still_fit():
    pts = skeletons("ur5", 6, seed=7)
    net = pts * 1.04
    net[2, 3] = np.nan                                    # one joint of frame 2 missing
    L = np.tile(bone_lengths("ur5"), (len(pts), 1))
    fitted = fit_depths(net, L, np.ones_like(L, bool), sigma_depth=0.1)
    assert np.isnan(fitted[2, 3]).all() and np.isfinite(np.delete(fitted, 3, axis=1)).all()
    np.testing.assert_allclose(fitted[0], fit_depths(net[:1], L[:1], np.ones_like(L[:1], bool), sigma_depth=0.1)[0])


def test_mismatched_shapes_are_refused():
    with pytest.raises(ValueError, match="do not match"):
        fit_depths(np.ones((2, 7, 3)), np.ones((2, 7)), np.ones((2, 7), bool), sigma_depth=0.1)
    with pytest.raises(ValueError, match="bone_valid"):
        fit_depths(np.ones((2, 7, 3)), np.ones((2, 6)), np.ones((2, 5), bool), sigma_depth=0.1)


def test_bones_below_min_bone_are_not_held():
    """Panda's coincident joint origins (bones of 0 m): with ``min_bone`` they do not pull two
    points that the network puts on different rays towards the camera; with every bone below
    ``min_bone`` nothing moves."""
    pts = skeletons("panda", 10, seed=5)
    rng = np.random.default_rng(6)
    net = pts.copy()
    net[..., :2] += rng.normal(0, 0.02, net[..., :2].shape)      # 2 cm of ray error on every point
    types = np.full(len(pts), TYPES.index("panda"))
    held_all = bone_fit(net[:, 1:], net[:, 0], types, TYPES, sigma_depth=0.1, min_bone=0.0)[0]
    held_long = bone_fit(net[:, 1:], net[:, 0], types, TYPES, sigma_depth=0.1, min_bone=0.05)[0]
    depth_change = lambda fitted: np.median(fitted[:, [0, 1, 4, 5], 2] / net[:, 1:][:, [0, 1, 4, 5], 2])
    assert depth_change(held_all) < depth_change(held_long) - 0.01
    untouched = bone_fit(net[:, 1:], net[:, 0], types, TYPES, sigma_depth=0.1, min_bone=1.0)
    np.testing.assert_allclose(untouched[0], net[:, 1:], atol=1e-9)
    np.testing.assert_allclose(untouched[1], net[:, 0], atol=1e-9)

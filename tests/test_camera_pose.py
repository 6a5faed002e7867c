"""camera_pose with an oracle network: true UR5 joints (real forward kinematics) moved into the
camera frame by a random T_cam_base, plus Gaussian noise of known sigma."""
from __future__ import annotations

import json

import numpy as np
import pytest

from armpose import camera_pose as cp
from armpose.geometry import Camera, matrix_to_quat, quat_to_matrix, transform_points

N_CONFIGS = 60
SIGMAS = [0.0, 0.005, 0.01, 0.02, 0.04]
K = Camera(480, 360, 525.0, 525.0, 239.5, 179.5).K


def random_pose(rng: np.random.Generator) -> np.ndarray:
    """A T_cam_base with a uniform random rotation and the base 1.5-3 m in front of the camera."""
    q = rng.normal(size=4)
    T = np.eye(4)
    T[:3, :3] = quat_to_matrix(q / np.linalg.norm(q))
    T[:3, 3] = [rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(1.5, 3.0)]
    return T


@pytest.fixture(scope="module")
def arm():
    """Base origin plus the 6 joint positions of UR5 (base frame, metres) for random joint angles,
    ``(N_CONFIGS, 7, 3)``, and one random T_cam_base per configuration."""
    from armpose.robots import get_robot
    from armpose.robots.kinematics import Kinematics
    rng = np.random.default_rng(7)
    spec = get_robot("ur5")
    q = rng.uniform(-np.pi, np.pi, size=(N_CONFIGS, spec.num_joints))
    joints = Kinematics(spec).joint_positions(q).astype(np.float64)
    points = np.concatenate([np.zeros((N_CONFIGS, 1, 3)), joints], axis=1)
    poses = np.stack([random_pose(rng) for _ in range(N_CONFIGS)])
    return points, poses


def observe(T, points_base, sigma, seed):
    """Oracle network output: the true camera-frame points plus N(0, sigma^2) noise per axis."""
    rng = np.random.default_rng(seed)
    return transform_points(T, points_base) + rng.normal(0.0, sigma, points_base.shape)


def errors(T_est, T_true):
    return cp.rotation_error_deg(T_est, T_true), cp.translation_error_m(T_est, T_true)


@pytest.mark.parametrize("method", ["lstsq", "huber", "ransac"])
def test_exact_points_give_exact_pose(arm, method):
    points, poses = arm
    for i in range(20):
        est = cp.robust_rigid(points[i], observe(poses[i], points[i], 0.0, i), method=method)
        rot, trans = errors(est.T, poses[i])
        assert rot < 0.1 and trans < 1e-3, (i, rot, trans)
        assert rot < 1e-6 and trans < 1e-9, (i, rot, trans)  # far below the brief's bound
        assert est.inliers.all() and est.rmse_m < 1e-9
        np.testing.assert_allclose(est.quaternion, matrix_to_quat(poses[i][:3, :3]), atol=1e-8)


def test_umeyama_returns_a_proper_rotation_for_mirrored_points(arm):
    points, _ = arm
    src = points[0]
    R, _ = cp.umeyama(src, src * np.array([-1.0, 1.0, 1.0]))  # a reflection is the LS optimum without det fix
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)


def test_umeyama_zero_weight_ignores_a_point(arm):
    points, poses = arm
    dst = observe(poses[1], points[1], 0.0, 1)
    dst[4] += [0.3, -0.2, 0.4]
    w = np.ones(7)
    w[4] = 0.0
    R, t = cp.umeyama(points[1], dst, w)
    assert cp.rotation_error_deg(R, poses[1]) < 1e-6
    assert cp.translation_error_m(t, poses[1]) < 1e-9
    R, t = cp.umeyama(points[1], dst)
    assert cp.translation_error_m(t, poses[1]) > 0.01


def median_errors(arm, sigma, method, n=50):
    points, poses = arm
    errs = np.array([errors(cp.robust_rigid(points[i], observe(poses[i], points[i], sigma, 1000 + i),
                                            method=method).T, poses[i]) for i in range(n)])
    return np.median(errs, axis=0)


@pytest.mark.parametrize("method", ["lstsq", "huber"])
def test_error_grows_smoothly_with_noise(arm, method):
    med = np.array([median_errors(arm, s, method) for s in SIGMAS])  # (sigma, [rot_deg, trans_m])
    assert (med[0] < [1e-6, 1e-9]).all(), med[0]
    assert (np.diff(med, axis=0) > 0).all(), med
    ratios = med[2:] / med[1:-1]  # sigma doubles at each of these steps: errors about double too
    assert ((ratios > 1.6) & (ratios < 2.5)).all(), (med, ratios)


def test_pooling_ten_images_beats_one(arm):
    points, _ = arm
    rng = np.random.default_rng(3)
    single, pooled = [], []
    for trial in range(20):
        T = random_pose(rng)
        idx = rng.choice(N_CONFIGS, size=10, replace=False)
        samples = [(points[i], observe(T, points[i], 0.02, 100 * trial + k), None) for k, i in enumerate(idx)]
        single.append(errors(cp.robust_rigid(samples[0][0], samples[0][1]).T, T))
        est = cp.pool_poses(samples)
        pooled.append(errors(est.T, T))
        assert est.residuals_m.shape == (70,) and est.inliers.shape == (70,)
    single, pooled = np.median(single, axis=0), np.median(pooled, axis=0)
    assert (pooled < 0.5 * single).all(), (single, pooled)


def test_pool_of_one_equals_robust_rigid(arm):
    points, poses = arm
    dst = observe(poses[2], points[2], 0.01, 2)
    valid = np.ones(7, dtype=bool)
    valid[3] = False
    np.testing.assert_allclose(cp.pool_poses([(points[2], dst, valid)]).T,
                               cp.robust_rigid(points[2], dst, valid).T, atol=1e-12)


def with_gross_outlier(T, points_base, sigma, seed, distance=0.5):
    """Oracle output with one random joint moved ``distance`` metres in a random direction."""
    rng = np.random.default_rng(seed)
    dst = observe(T, points_base, sigma, seed + 1)
    j = int(rng.integers(len(points_base)))
    d = rng.normal(size=3)
    dst[j] += distance * d / np.linalg.norm(d)
    return dst, j


def test_one_joint_half_a_metre_off(arm):
    points, poses = arm
    trans = {m: [] for m in cp.METHODS}
    add = {m: [] for m in cp.METHODS}
    for i in range(20):
        dst, j = with_gross_outlier(poses[i], points[i], 0.0, 500 + i)
        for m in cp.METHODS:
            est = cp.robust_rigid(points[i], dst, method=m)
            trans[m].append(cp.translation_error_m(est.T, poses[i]))
            add[m].append(cp.add_m(est.T, poses[i], points[i]))
            if m == "ransac":
                assert not est.inliers[j] and est.inliers.sum() == 6, (i, j, est.inliers)
    assert max(trans["ransac"]) < 0.01 and max(add["ransac"]) < 0.01
    # Huber bounds the outlier's pull; on a folded arm (points within ~threshold) it can still lose.
    assert np.mean(np.array(trans["huber"]) < 0.01) >= 0.9 and np.mean(np.array(add["huber"]) < 0.01) >= 0.9
    assert np.median(trans["lstsq"]) > 0.01 and np.median(add["lstsq"]) > 0.01


def test_gross_outlier_with_small_noise(arm):
    points, poses = arm
    for m, bound in (("huber", 0.01), ("ransac", 0.01), ("lstsq", None)):
        errs = []
        for i in range(20):
            dst, _ = with_gross_outlier(poses[i], points[i], 0.003, 900 + i)
            errs.append(cp.translation_error_m(cp.robust_rigid(points[i], dst, method=m).T, poses[i]))
        if bound is None:
            assert np.median(errs) > 0.02, m
        else:
            assert np.median(errs) < bound, (m, np.median(errs))


def test_missing_and_invalid_points_are_ignored(arm):
    points, poses = arm
    dst = observe(poses[5], points[5], 0.0, 5)
    dst[2] = np.nan
    dst[6] += 1.0
    valid = np.ones(7, dtype=bool)
    valid[6] = False
    est = cp.robust_rigid(points[5], dst, valid, method="lstsq")
    assert cp.translation_error_m(est.T, poses[5]) < 1e-9
    assert np.isnan(est.residuals_m[2]) and np.isnan(est.residuals_m[6])
    assert not est.inliers[2] and not est.inliers[6] and est.inliers.sum() == 5
    text = json.dumps(cp.to_json(est))  # NaN residuals become null: valid JSON
    d = json.loads(text)
    assert d["residuals_m"][2] is None and d["inliers"][6] is False
    np.testing.assert_allclose(d["T_cam_base"], est.T)
    np.testing.assert_allclose(d["translation_m"], est.T[:3, 3])
    np.testing.assert_allclose(d["quaternion_xyzw"], matrix_to_quat(est.T[:3, :3]))
    assert d["rmse_m"] == pytest.approx(est.rmse_m)
    with pytest.raises(ValueError, match="at least 3 valid"):
        cp.robust_rigid(points[5], dst, np.array([True, True, False, False, False, False, False]))


def test_refine_reprojection_recovers_pose_from_exact_pixels(arm):
    points, poses = arm
    for i in range(10):
        start = cp.robust_rigid(points[i], observe(poses[i], points[i], 0.02, 40 + i)).T
        uv = Camera(480, 360, 525.0, 525.0, 239.5, 179.5).project(transform_points(poses[i], points[i]))
        refined = cp.refine_reprojection(start, points[i], uv, K)
        rot, trans = errors(refined, poses[i])
        assert rot < 1e-3 and trans < 1e-5, (i, errors(start, poses[i]), (rot, trans))
        assert cp.reprojection_errors_px(refined, points[i], uv, K).max() < 1e-3


def test_refine_reprojection_with_pixel_noise_improves_a_noisy_3d_pose(arm):
    """Half-pixel detections against 2 cm 3D noise: rotation gets much better, ADD about halves
    (pixels alone constrain depth weakly: at 1 px ADD no longer improves, rotation still does)."""
    points, poses = arm
    add_before, add_after, rot_before, rot_after = [], [], [], []
    for i in range(40):
        start = cp.robust_rigid(points[i], observe(poses[i], points[i], 0.02, 60 + i)).T
        uv = Camera(480, 360, 525.0, 525.0, 239.5, 179.5).project(transform_points(poses[i], points[i]))
        uv += np.random.default_rng(i).normal(0.0, 0.5, uv.shape)
        refined = cp.refine_reprojection(start, points[i], uv, K)
        add_before.append(cp.add_m(start, poses[i], points[i]))
        add_after.append(cp.add_m(refined, poses[i], points[i]))
        rot_before.append(cp.rotation_error_deg(start, poses[i]))
        rot_after.append(cp.rotation_error_deg(refined, poses[i]))
    assert np.median(add_after) < 0.65 * np.median(add_before), (np.median(add_before), np.median(add_after))
    assert np.median(rot_after) < 0.3 * np.median(rot_before), (np.median(rot_before), np.median(rot_after))


def test_refine_reprojection_leaves_pose_with_too_few_points(arm):
    points, poses = arm
    uv = np.zeros((7, 2))
    valid = np.zeros(7, dtype=bool)
    valid[:2] = True
    np.testing.assert_array_equal(cp.refine_reprojection(poses[0], points[0], uv, K, valid), poses[0])


def test_pose_metrics_on_known_transforms():
    a = np.radians(30.0)
    Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])
    assert cp.rotation_error_deg(Rz, np.eye(3)) == pytest.approx(30.0, abs=1e-9)
    assert cp.rotation_error_deg(-np.diag([1.0, 1.0, -1.0]), np.eye(3)) == pytest.approx(180.0, abs=1e-9)
    tiny = quat_to_matrix(np.array([np.sin(5e-9), 0, 0, np.cos(5e-9)]))  # 1e-8 rad about x
    assert cp.rotation_error_deg(tiny, np.eye(3)) == pytest.approx(np.degrees(1e-8), rel=1e-5)
    T1, T2 = np.eye(4), np.eye(4)
    T2[:3, 3] = [0.03, 0.0, 0.04]
    assert cp.translation_error_m(T1, T2) == pytest.approx(0.05)
    pts = np.random.default_rng(0).normal(size=(9, 3))
    assert cp.add_m(T1, T2, pts) == pytest.approx(0.05)
    T2[:3, :3] = Rz
    expected = np.linalg.norm(pts - (pts @ Rz.T + T2[:3, 3]), axis=1).mean()
    assert cp.add_m(T1, T2, pts) == pytest.approx(expected)


def dream_add_auc(add, threshold=0.1, delta=1e-5):
    """NVlabs/DREAM analysis.pnp_metrics' AUC: trapezoid on a delta grid of fraction-with-ADD<=t."""
    add = np.asarray(add)
    t = np.arange(0.0, threshold, delta)
    counts = [(add[np.isfinite(add)] <= v).sum() / len(add) for v in t]
    return np.trapezoid(counts, dx=delta) / threshold


def test_add_auc():
    assert cp.add_auc(np.zeros(10)) == 1.0
    assert cp.add_auc(np.full(10, 0.1)) == 0.0
    assert cp.add_auc([0.1, 0.5, np.inf]) == 0.0
    mid = (np.arange(1000) + 0.5) / 1000  # evenly spread samples of a uniform distribution on [0, 1]
    assert cp.add_auc(0.1 * mid) == pytest.approx(0.5, abs=1e-12)  # uniform on [0, T]: curve t / T
    assert cp.add_auc(0.2 * mid) == pytest.approx(0.25, abs=1e-12)  # uniform on [0, 2T]: curve t / 2T
    assert cp.add_auc([0.0, np.nan]) == 0.5  # a failed estimate counts against
    assert cp.add_auc([0.02], threshold=0.05) == pytest.approx(0.6)
    values = np.random.default_rng(1).exponential(0.04, size=200)
    assert cp.add_auc(values) == pytest.approx(dream_add_auc(values), abs=2e-4)
    with pytest.raises(ValueError, match="non-negative"):
        cp.add_auc([-0.1])


def test_bad_shapes_name_the_argument():
    with pytest.raises(ValueError, match=r"src must have shape \(N, 3\), got \(5, 2\)"):
        cp.umeyama(np.zeros((5, 2)), np.zeros((5, 3)))
    with pytest.raises(ValueError, match=r"got src \(5, 3\) and dst \(4, 3\)"):
        cp.robust_rigid(np.zeros((5, 3)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match=r"valid must have shape \(5,\), got \(4,\)"):
        cp.robust_rigid(np.zeros((5, 3)), np.zeros((5, 3)), valid=np.ones(4))
    with pytest.raises(ValueError, match=r"uv must have shape \(5, 2\)"):
        cp.refine_reprojection(np.eye(4), np.zeros((5, 3)), np.zeros((5, 3)), K)
    with pytest.raises(ValueError, match="method must be one of"):
        cp.robust_rigid(np.eye(3), np.eye(3), method="lmeds")
    with pytest.raises(ValueError, match=r"R_est must have shape"):
        cp.rotation_error_deg(np.eye(2), np.eye(3))


def network_like(T, points_base, seed, ray_sigma=0.02, depth_sigma=0.06, frame_sigma=0.05):
    """Oracle output with the network's kind of error: each point's ray off by ``ray_sigma`` (rad),
    its depth by ``depth_sigma`` (relative), and the whole frame's depth by ``frame_sigma``."""
    rng = np.random.default_rng(seed)
    p = transform_points(T, points_base)
    ray = p[:, :2] / p[:, 2:] + rng.normal(0.0, ray_sigma, (len(p), 2))
    z = p[:, 2] * np.exp(rng.normal(0.0, depth_sigma, len(p)) + rng.normal(0.0, frame_sigma))
    return np.column_stack([ray * z[:, None], z])


def test_refine_rays_recovers_the_pose_from_exact_points(arm):
    points, poses = arm
    for i in range(10):
        start = cp.robust_rigid(points[i], observe(poses[i], points[i], 0.03, 80 + i)).T
        refined = cp.refine_rays(start, points[i], transform_points(poses[i], points[i]))
        rot, trans = errors(refined, poses[i])
        assert rot < 1e-3 and trans < 1e-5, (i, errors(start, poses[i]), (rot, trans))


def test_refine_rays_beats_the_rigid_fit_on_network_like_errors(arm):
    """Rays good to 0.02 rad, depths to 6 % (and 5 % for the whole frame): weighting each by its
    error beats the rigid fit, which takes the 3D points as equally good in every direction."""
    points, poses = arm
    add, rot = {"rigid": [], "rays": []}, {"rigid": [], "rays": []}
    for i in range(N_CONFIGS):
        seen = network_like(poses[i], points[i], 100 + i)
        rigid = cp.robust_rigid(points[i], seen, method="huber").T
        for name, T in (("rigid", rigid), ("rays", cp.refine_rays(rigid, points[i], seen))):
            add[name].append(cp.add_m(T, poses[i], points[i]))
            rot[name].append(cp.rotation_error_deg(T, poses[i]))
    assert np.median(add["rays"]) < 0.8 * np.median(add["rigid"]), {k: np.median(v) for k, v in add.items()}
    assert np.median(rot["rays"]) < 0.7 * np.median(rot["rigid"]), {k: np.median(v) for k, v in rot.items()}


def test_refine_rays_ignores_a_gross_outlier_marked_invalid(arm):
    points, poses = arm
    seen = transform_points(poses[1], points[1])
    seen[3] += [0.5, -0.4, 1.0]
    start = cp.robust_rigid(points[1], observe(poses[1], points[1], 0.03, 5)).T
    valid = np.ones(7, dtype=bool)
    valid[3] = False
    rot, trans = errors(cp.refine_rays(start, points[1], seen, valid), poses[1])
    assert rot < 1e-3 and trans < 1e-5
    rot_all, trans_all = errors(cp.refine_rays(start, points[1], seen), poses[1])
    assert rot_all > 0.1 or trans_all > 1e-3                 # the outlier, when used, does move it


def test_refine_rays_leaves_the_pose_with_too_few_points_and_names_bad_sigmas(arm):
    points, poses = arm
    valid = np.zeros(7, dtype=bool)
    valid[:2] = True
    seen = transform_points(poses[0], points[0])
    np.testing.assert_array_equal(cp.refine_rays(np.eye(4), points[0], seen, valid), np.eye(4))
    with pytest.raises(ValueError, match="sigma_ray must be a positive number, got 0.0"):
        cp.refine_rays(poses[0], points[0], seen, sigma_ray=0.0)
    with pytest.raises(ValueError, match="sigma_log_depth must be a positive number, got '0.1'"):
        cp.refine_rays(poses[0], points[0], seen, sigma_log_depth="0.1")

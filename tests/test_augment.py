"""armpose.augment: a virtual camera turn warps pixels exactly where the rotated 3D labels project."""
import numpy as np
import pytest

from armpose.augment import centred, dolly_points, draw_dolly, draw_rotation, rotate_points, warp

W, H = 256, 212
K = (309.2, 309.2, (W - 1) / 2, (H - 1) / 2)
CFG = {"flip": 0.5, "rotate_deg": 6.0, "roll_deg": 10.0}


def project(points, k=K):
    fx, fy, cx, cy = k
    return np.stack([fx * points[:, 0] / points[:, 2] + cx, fy * points[:, 1] / points[:, 2] + cy], 1)


def blob_image(uv):
    """An image with one bright 5x5 square per point (integer pixel centres) and its mask."""
    img = np.zeros((H, W, 3), np.uint8)
    for u, v in np.round(uv).astype(int):
        img[v - 2:v + 3, u - 2:u + 3] = 255
    return img, (img[..., 0] > 0).astype(np.uint8)


def centroid_near(img, uv, r=6):
    """Intensity centroid of ``img`` around ``uv`` (pixels)."""
    u0, v0 = np.round(uv).astype(int)
    patch = img[v0 - r:v0 + r + 1, u0 - r:u0 + r + 1, 0].astype(float)
    vv, uu = np.mgrid[v0 - r:v0 + r + 1, u0 - r:u0 + r + 1]
    return np.array([(patch * uu).sum(), (patch * vv).sum()]) / patch.sum()


@pytest.mark.parametrize("seed", range(6))
def test_warped_blobs_sit_where_the_rotated_points_project(seed):
    rng = np.random.default_rng(seed)
    grid = np.array([[u, v] for u in (70, 128, 186) for v in (70, 140)], float)   # blobs far apart
    uv = (grid + rng.uniform(-10, 10, grid.shape)).round()
    z = rng.uniform(1.0, 3.5, 6)
    points = np.column_stack([(uv[:, 0] - K[2]) / K[0] * z, (uv[:, 1] - K[3]) / K[1] * z, z])
    img, mask = blob_image(project(points))
    M = draw_rotation(rng, {"flip": 1.0 if seed % 2 else 0.0, "rotate_deg": 6.0, "roll_deg": 10.0}, K, W)
    assert np.allclose(M @ M.T, np.eye(3)) and np.isclose(abs(np.linalg.det(M)), 1.0)
    assert np.linalg.det(M) < 0 if seed % 2 else np.linalg.det(M) > 0, "the mirror is drawn with probability flip"
    out, out_mask = warp(img, mask, M, K)
    moved = project(rotate_points(points, M))
    for p in moved:
        assert np.linalg.norm(centroid_near(out, p) - p) < 0.5
        assert out_mask[int(round(p[1])), int(round(p[0]))] == 1


def test_no_geometric_keys_means_no_warp_and_off_centre_principal_point_never_mirrors():
    rng = np.random.default_rng(0)
    assert draw_rotation(rng, {"brightness": 0.2}, K, W) is None
    off = (K[0], K[1], K[2] + 7.0, K[3])
    assert not centred(off, W) and centred(K, W)
    dets = [np.linalg.det(draw_rotation(rng, {"flip": 1.0, "rotate_deg": 3.0}, off, W)) for _ in range(10)]
    assert all(d > 0 for d in dets)


def test_draws_are_reproducible_from_the_generator_seed():
    a = draw_rotation(np.random.default_rng([1, 2, 3]), CFG, K, W)
    b = draw_rotation(np.random.default_rng([1, 2, 3]), CFG, K, W)
    c = draw_rotation(np.random.default_rng([1, 2, 4]), CFG, K, W)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


@pytest.mark.parametrize("seed", range(4))
def test_dollied_blobs_sit_where_the_moved_points_project_at_their_new_depth(seed):
    rng = np.random.default_rng(100 + seed)
    grid = np.array([[u, v] for u in (80, 128, 176) for v in (80, 130)], float)
    uv = (grid + rng.uniform(-8, 8, grid.shape)).round()
    z = rng.uniform(1.5, 3.0, 6)
    points = np.column_stack([(uv[:, 0] - K[2]) / K[0] * z, (uv[:, 1] - K[3]) / K[1] * z, z])
    img, mask = blob_image(project(points))
    M = draw_rotation(rng, {"rotate_deg": 4.0, "roll_deg": 6.0}, K, W)
    scale = draw_dolly(rng, {"dolly": 0.15})
    assert 1 / 1.15 <= scale <= 1.15
    out, out_mask = warp(img, mask, M, K, scale)
    turned = rotate_points(points, M)
    z_ref = turned[:, 2].mean()
    moved = dolly_points(turned, scale, z_ref)
    assert np.allclose(moved[:, 2], turned[:, 2] + z_ref * (1 / scale - 1)), "every depth moves by the dolly"
    for p in project(moved):
        assert np.linalg.norm(centroid_near(out, p) - p) < 0.5
        assert out_mask[int(round(p[1])), int(round(p[0]))] == 1
    # the robot keeps its metric size to within the stretch the module documents
    spread = lambda q: np.linalg.norm(q - q.mean(0), axis=1).mean()
    assert abs(spread(moved) / spread(turned) - 1) < 0.03


def test_dolly_leaves_unused_slots_and_is_off_without_the_key():
    assert draw_dolly(np.random.default_rng(0), CFG) is None
    pts = np.array([[0.1, -0.2, 2.0], [0.0, 0.0, 0.0]])
    moved = dolly_points(pts, 1.1, 2.0)
    assert np.array_equal(moved[1], pts[1])
    assert np.isclose(moved[0, 2], 2.0 / 1.1) and np.allclose(moved[0, :2], pts[0, :2])


def test_zoom_config_fills_defaults_and_names_bad_values():
    from armpose.augment import ZOOM_DEFAULTS, zoom_config
    assert zoom_config({}) is None and zoom_config({"zoom": {"p": 0.0}}) is None
    assert zoom_config({"zoom": {"p": 0.3}}) == {**ZOOM_DEFAULTS, "p": 0.3}
    for bad in ({"p": 0.5, "fill": [0.8, 0.4]}, {"p": 1.5}, {"p": 0.5, "max_zoom": 0.5}, {"p": 0.5, "size": 3}, 0.5):
        with pytest.raises(ValueError, match="zoom"):
            zoom_config({"zoom": bad})


def test_draw_zoom_centres_the_jittered_box_and_scales_within_its_limits():
    from armpose.augment import depth_limit, draw_zoom, draw_zoom_scale, points_box
    pts = np.array([[0.3, 0.2, 2.0], [0.5, -0.1, 2.3], [0.35, 0.0, 1.9], [0.45, 0.1, 2.1]])
    cfg = {"zoom": {"p": 1.0, "fill": [0.5, 0.7], "max_zoom": 2.5, "centre_jitter": 0.0, "scale_jitter": 0.0}}
    M, zcfg = draw_zoom(np.random.default_rng(0), cfg, pts, K, (W, H))
    centre, _ = points_box(pts, K)
    ray = np.array([(centre[0] - K[2]) / K[0], (centre[1] - K[3]) / K[1], 1.0])
    np.testing.assert_allclose(project((M @ ray)[None])[0], K[2:], atol=1e-9)
    turned = rotate_points(pts, M)
    for seed in range(5):
        s = draw_zoom_scale(np.random.default_rng(seed), zcfg, turned, K, (W, H), dolly=0.15)
        _, extent = points_box(dolly_points(turned, s, turned[:, 2].mean()), K)
        assert 0.5 - 1e-6 <= max(extent[0] / W, extent[1] / H) <= 0.7 + 1e-6
    assert draw_zoom(np.random.default_rng(0), {"zoom": {"p": 1e-9}}, pts, K, (W, H)) is None
    # a robot pointing at the camera: the dolly stops with its nearest point at a quarter of the new depth
    deep = np.array([[0.0, 0.0, 0.8], [0.01, 0.0, 2.0], [0.0, 0.01, 3.2]])
    limit = depth_limit(deep)
    s = draw_zoom_scale(np.random.default_rng(0), {**zcfg, "max_zoom": 10.0}, deep, K, (W, H), dolly=0.15)
    assert s == pytest.approx(limit)
    moved = dolly_points(deep, s, deep[:, 2].mean())
    assert moved[:, 2].min() == pytest.approx(0.25 * moved[:, 2].mean())

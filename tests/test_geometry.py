import numpy as np
import pytest

from armpose.geometry import Camera, invert, look_at, matrix_to_quat, pose_to_matrix, quat_to_matrix


def test_quaternion_round_trip():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(50, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= np.where(q[:, 3:] < 0, -1, 1)
    R = quat_to_matrix(q)
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(matrix_to_quat(R), q, atol=1e-12)


def test_invert_is_inverse():
    T = pose_to_matrix(np.array([0.3, -1.0, 2.0]), np.array([0.1, 0.2, 0.3, 0.927]) / np.linalg.norm([0.1, 0.2, 0.3, 0.927]))
    np.testing.assert_allclose(T @ invert(T), np.eye(4), atol=1e-12)


def test_look_at_points_optical_axis_at_target():
    T = look_at([2.0, 1.0, 1.5], [0.0, 0.0, 0.5], roll=0.4)
    p = (invert(T) @ np.array([0, 0, 0.5, 1.0]))[:3]
    assert p[0] == pytest.approx(0, abs=1e-12) and p[1] == pytest.approx(0, abs=1e-12) and p[2] > 0


def test_scale_crop_maps_pixels_consistently():
    cam = Camera(480, 360, 525, 525, 239.5, 179.5)
    crop, (rw, rh), (x0, y0) = cam.scale_crop(256, 212)
    assert (crop.width, crop.height) == (256, 212)
    assert rh == 212 and rw >= 256
    p = np.array([[0.2, -0.1, 2.0], [-0.3, 0.25, 3.0]])
    uv = cam.project(p)
    expected = np.stack([(uv[:, 0] + 0.5) * rw / 480 - 0.5 - x0, (uv[:, 1] + 0.5) * rh / 360 - 0.5 - y0], 1)
    np.testing.assert_allclose(crop.project(p), expected, atol=1e-9)

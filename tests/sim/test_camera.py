"""The PyBullet camera matrices agree with the pinhole model, also after scale-and-crop."""
import numpy as np
import pybullet as pb
import pytest

from armpose.geometry import Camera, invert, look_at, transform_points
from armpose.labels.compute import scale_crop_image
from armpose.sim.camera import projection_matrix, view_matrix


@pytest.fixture()
def sphere_client():
    client = pb.connect(pb.DIRECT)
    vis = pb.createVisualShape(pb.GEOM_SPHERE, radius=0.06, rgbaColor=[1, 0, 0, 1], physicsClientId=client)
    body = pb.createMultiBody(baseVisualShapeIndex=vis, physicsClientId=client)
    yield client, body
    pb.disconnect(client)


def _centroid(mask):
    ys, xs = np.nonzero(mask)
    return np.array([xs.mean(), ys.mean()])


CASES = [([0.3, -0.2, 0.5], [2, 1, 1.2], 0.3), ([0, 0, 0], [-1.5, 0.5, 0.4], -0.2), ([0.5, 0.5, 1.0], [1, -2, 2], 0.0)]


@pytest.mark.parametrize("point,eye,roll", CASES)
def test_rendered_sphere_lands_where_projected(sphere_client, point, eye, roll):
    client, body = sphere_client
    cam = Camera(480, 360, 420, 415, 250.3, 170.7)  # off-centre principal point on purpose
    pb.resetBasePositionAndOrientation(body, point, [0, 0, 0, 1], physicsClientId=client)
    T = look_at(eye, [0, 0, 0.4], roll=roll)
    *_, seg = pb.getCameraImage(cam.width, cam.height, view_matrix(T), projection_matrix(cam),
                                renderer=pb.ER_TINY_RENDERER, physicsClientId=client)
    seg = np.asarray(seg).reshape(cam.height, cam.width)
    uv = cam.project(transform_points(invert(T), np.array([point], float))[0])
    assert np.abs(_centroid(seg == body) - uv).max() < 0.25


def test_scale_crop_image_matches_crop_camera(sphere_client):
    client, body = sphere_client
    cam = Camera(480, 360, 525, 525, 239.5, 179.5)
    pb.resetBasePositionAndOrientation(body, [0.2, 0.1, 0.6], [0, 0, 0, 1], physicsClientId=client)
    T = look_at([1.8, 0.6, 1.0], [0, 0, 0.5])
    _, _, rgba, _, _ = pb.getCameraImage(cam.width, cam.height, view_matrix(T), projection_matrix(cam),
                                         renderer=pb.ER_TINY_RENDERER, physicsClientId=client)
    red = np.asarray(rgba, np.uint8).reshape(cam.height, cam.width, 4)[..., :3]
    small = scale_crop_image(red, cam, 256, 212)
    crop = cam.scale_crop(256, 212)[0]
    mask = (small[..., 0] > 150) & (small[..., 1] < 80) & (small[..., 2] < 80)
    uv = crop.project(transform_points(invert(T), np.array([[0.2, 0.1, 0.6]]))[0])
    assert np.abs(_centroid(mask) - uv).max() < 0.35

"""PyBullet view and projection matrices for an OpenCV-convention pinhole camera.

PyBullet (OpenGL) cameras look down -z with y up; armpose cameras look down +z
with y down. Matrices are returned flattened column-major, as PyBullet expects.
"""
from __future__ import annotations

import numpy as np

from armpose.geometry import Camera, invert

_CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])
NEAR, FAR = 0.05, 20.0  # clipping planes, metres


def view_matrix(T_world_cam: np.ndarray) -> list[float]:
    """OpenGL view matrix for a camera whose optical frame has pose ``T_world_cam`` (4x4)."""
    T_gl_world = invert(T_world_cam @ _CV_TO_GL)
    return T_gl_world.T.reshape(-1).tolist()


def projection_matrix(cam: Camera, near: float = NEAR, far: float = FAR) -> list[float]:
    """OpenGL projection for pinhole ``cam``: pixel (i, j)'s centre is at (u, v) = (i, j).

    The principal-point terms match PyBullet's TinyRenderer rasterisation, which puts
    image rows one pixel lower than the textbook OpenGL mapping; a test checks that
    rendered spheres land within 0.25 px of :meth:`Camera.project`.
    """
    W, H = cam.width, cam.height
    P = np.zeros((4, 4))
    P[0, 0] = 2.0 * cam.fx / W
    P[0, 2] = 1.0 - 2.0 * cam.cx / W
    P[1, 1] = 2.0 * cam.fy / H
    P[1, 2] = (2.0 * cam.cy + 2.0) / H - 1.0
    P[2, 2] = -(far + near) / (far - near)
    P[2, 3] = -2.0 * far * near / (far - near)
    P[3, 2] = -1.0
    return P.T.reshape(-1).tolist()

"""Procedural textures for domain randomisation (noise, checkers, stripes, blobs), as uint8 RGB."""
from __future__ import annotations

import cv2
import numpy as np


def _palette(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.uniform(0, 255, size=(n, 3))


def procedural_texture(rng: np.random.Generator, size: int = 128) -> np.ndarray:
    """One random texture ``(size, size, 3)`` uint8: a random kind with random colours and scale."""
    kind = rng.integers(4)
    a, b = _palette(rng, 2)
    yy, xx = np.mgrid[0:size, 0:size] / size
    if kind == 0:  # smooth value noise
        cells = int(rng.integers(3, 16))
        noise = cv2.resize(rng.uniform(0, 1, (cells, cells)).astype(np.float32), (size, size),
                           interpolation=cv2.INTER_CUBIC)
        t = np.clip(noise, 0, 1)[..., None]
    elif kind == 1:  # checkerboard
        n = int(rng.integers(2, 12))
        t = ((np.floor(xx * n) + np.floor(yy * n)) % 2)[..., None]
    elif kind == 2:  # stripes at a random angle
        ang, n = rng.uniform(0, np.pi), rng.uniform(2, 20)
        t = (0.5 + 0.5 * np.sin(2 * np.pi * n * (np.cos(ang) * xx + np.sin(ang) * yy)))[..., None]
    else:  # blobs
        t = np.zeros((size, size, 1))
        for _ in range(int(rng.integers(3, 12))):
            cx, cy, r = rng.uniform(0, 1), rng.uniform(0, 1), rng.uniform(0.03, 0.2)
            t[..., 0] = np.maximum(t[..., 0], ((xx - cx) ** 2 + (yy - cy) ** 2 < r * r).astype(float))
    img = a * (1 - t) + b * t + rng.normal(0, rng.uniform(0, 12), (size, size, 3))
    return np.clip(img, 0, 255).astype(np.uint8)

"""tracking: causal filters on simulated joint paths at 30 Hz with centimetre noise."""
from __future__ import annotations

import numpy as np
import pytest

from armpose import tracking as tk

RATE = 30.0
FILTERS = {"kalman": tk.KalmanFilter3D, "one_euro": tk.OneEuroFilter}


def joint_path(seed: int, frames: int = 180, joints: int = 7) -> np.ndarray:
    """``(frames, joints, 3)`` smooth paths: per axis a sinusoid of 0.2-0.5 m amplitude at
    0.15-0.5 Hz around a point ~2 m in front of the camera (6 s at 30 Hz)."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames)[:, None, None] / RATE
    amp = rng.uniform(0.2, 0.5, (joints, 3))
    freq = rng.uniform(0.15, 0.5, (joints, 3))
    phase = rng.uniform(0.0, 2 * np.pi, (joints, 3))
    centre = rng.uniform(-1.0, 1.0, (joints, 3)) + [0.0, 0.0, 2.0]
    return centre + amp * np.sin(2 * np.pi * freq * t + phase)


def noisy(truth: np.ndarray, sigma: float, seed: int) -> np.ndarray:
    return truth + np.random.default_rng(seed).normal(0.0, sigma, truth.shape)


@pytest.mark.parametrize("name", FILTERS)
def test_filters_are_causal(name):
    x = noisy(joint_path(0, frames=60), 0.02, 1)
    x[10:13, 2] = np.nan
    base = tk.filter_sequence(x, FILTERS[name]())
    for k in (5, 20, 59):
        changed = x.copy()
        changed[k] += 0.3
        out = tk.filter_sequence(changed, FILTERS[name]())
        np.testing.assert_array_equal(out[:k], base[:k])
        assert np.abs(out[k] - base[k]).min() > 1e-3  # the new frame does move the output


@pytest.mark.parametrize("name", FILTERS)
def test_live_updates_match_filter_sequence(name):
    x = noisy(joint_path(1, frames=40), 0.02, 2)
    filt = FILTERS[name]()
    live = np.stack([filt.update(frame) for frame in x])
    np.testing.assert_array_equal(live, tk.filter_sequence(x, FILTERS[name]()))
    times = np.arange(40) / RATE
    np.testing.assert_allclose(tk.filter_sequence(x, FILTERS[name](), times), live, atol=1e-12)


@pytest.mark.parametrize("name", ["default", "one_euro"])
@pytest.mark.parametrize("sigma", [0.02, 0.03])
def test_default_filters_halve_jitter_without_raising_error(name, sigma):
    jitter_ratio, error_ratio = [], []
    for seed in range(10):
        truth = joint_path(seed)
        x = noisy(truth, sigma, 100 + seed)
        y = tk.filter_sequence(x) if name == "default" else tk.filter_sequence(x, tk.OneEuroFilter())
        jitter_ratio.append(tk.jitter(x).mean() / tk.jitter(y).mean())
        error_ratio.append(tk.median_error(y, truth) / tk.median_error(x, truth))
    # measured: default (Kalman) jitter / 3.7, error x 0.65-0.8; 1-euro jitter / 2.2-2.5, error x 0.74-0.95
    assert min(jitter_ratio) >= 2.0, jitter_ratio
    assert max(error_ratio) <= 1.05, error_ratio


def test_jitter_reduction_is_not_free_for_a_too_smooth_filter():
    """The error criterion has teeth: a very smooth 1-euro filter lags and loses on error."""
    truth = joint_path(3)
    x = noisy(truth, 0.02, 7)
    y = tk.filter_sequence(x, tk.OneEuroFilter(min_cutoff=0.2, beta=0.0))
    assert tk.jitter(x).mean() / tk.jitter(y).mean() > 10
    assert tk.median_error(y, truth) > 1.05 * tk.median_error(x, truth)


def test_kalman_predicts_through_missing_frames():
    t = np.arange(90) / RATE
    truth = np.stack([0.1 + 0.4 * t, -0.2 + 0.1 * t, 2.0 - 0.3 * t], axis=-1)  # constant velocity
    x = truth.copy()
    x[60:70] = np.nan
    y = tk.filter_sequence(x, tk.KalmanFilter3D())
    assert np.isfinite(y).all()
    assert np.linalg.norm(y[60:70] - truth[60:70], axis=-1).max() < 1e-3
    held = tk.filter_sequence(x, tk.OneEuroFilter())
    np.testing.assert_array_equal(held[60:70], np.broadcast_to(held[59], (10, 3)))  # 1-euro holds


@pytest.mark.parametrize("name", FILTERS)
def test_nan_entries_are_per_element(name):
    x = noisy(joint_path(4, frames=30), 0.02, 3)
    x[:5, 1] = np.nan  # joint 1 not seen for the first 5 frames
    x[12, 3, 2] = np.nan  # one coordinate missing in one frame
    y = tk.filter_sequence(x, FILTERS[name]())
    assert np.isnan(y[:5, 1]).all()
    assert np.isfinite(y[5:]).all() and np.isfinite(y[:, [0, 2, 3, 4, 5, 6]]).all()
    np.testing.assert_array_equal(y[5, 1], x[5, 1])  # a new element starts at its first measurement


@pytest.mark.parametrize("name", FILTERS)
def test_bad_input_raises(name):
    filt = FILTERS[name]()
    filt.update(np.zeros((7, 3)), t=0.0)
    with pytest.raises(ValueError, match=r"x must keep the shape of the first frame \(7, 3\), got \(6, 3\)"):
        filt.update(np.zeros((6, 3)), t=0.1)
    with pytest.raises(ValueError, match="t must increase"):
        filt.update(np.zeros((7, 3)), t=0.0)
    filt.reset()
    assert filt.update(np.ones(3)).shape == (3,)  # reset forgets the shape
    with pytest.raises(ValueError, match=r"times must have shape \(4,\)"):
        tk.filter_sequence(np.zeros((4, 3)), filt, times=np.arange(3))


def test_jitter_and_median_error_values():
    k = np.arange(10.0)[:, None]
    line = k * [0.1, 0.2, -0.3]
    assert tk.jitter(line) == pytest.approx(0.0, abs=1e-12)
    parabola = 0.5 * k ** 2 * [0.03, 0.0, 0.04]  # second difference (0.03, 0, 0.04): 0.05 m/frame^2
    assert tk.jitter(parabola) == pytest.approx(0.05)
    both = np.stack([line, parabola], axis=1)
    np.testing.assert_allclose(tk.jitter(both), [0.0, 0.05], atol=1e-12)
    with_gap = parabola.copy()
    with_gap[4] = np.nan
    assert tk.jitter(with_gap) == pytest.approx(0.05)
    pred = np.zeros((4, 3))
    truth = np.array([[0.01, 0, 0], [0.02, 0, 0], [0.03, 0, 0], [np.nan, 0, 0]])
    assert tk.median_error(pred, truth) == pytest.approx(0.02)
    assert tk.median_error(pred, truth, valid=[True, False, False, True]) == pytest.approx(0.01)
    with pytest.raises(ValueError, match=r"values must have shape \(T, \.\.\., 3\) with T >= 3, got \(2, 3\)"):
        tk.jitter(np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"got pred \(4, 3\) and truth \(4, 2\)"):
        tk.median_error(pred, np.zeros((4, 2)))

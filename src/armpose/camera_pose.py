"""Camera-to-robot pose from one image: align predicted joints with forward kinematics.

The network predicts the base and joint positions in the camera optical frame (OpenCV: x right,
y down, z forward; metres). Forward kinematics of the measured joint angles gives the same points
in the robot base frame. The rigid transform that maps the second set onto the first is
``T_cam_base`` (4x4, metres; see :mod:`armpose.geometry` for the conventions): the camera
extrinsics without an Eye-to-Hand calibration.

- :func:`umeyama`: weighted rigid least squares (no scale), ``dst ~ R @ src + t``;
- :func:`robust_rigid`: the same, robust to grossly wrong joints (Huber IRLS or RANSAC);
- :func:`refine_reprojection`: polish a pose by minimising the 2D reprojection error (pixels);
- :func:`refine_rays`: polish a pose on each predicted point's ray, and weakly its depth: the
  network's 2D positions are far better than its depths, which the rigid fit weights alike;
- :func:`pool_poses`: one static camera, several images, one pose;
- metrics: :func:`rotation_error_deg`, :func:`translation_error_m`, :func:`add_m`, :func:`add_auc`.

All arrays are numpy float64; angles in degrees only where the name says so.
"""
from __future__ import annotations

import dataclasses
import itertools
import logging

import cv2
import numpy as np

from armpose.geometry import matrix_to_quat, transform_points

log = logging.getLogger(__name__)

METHODS = ("lstsq", "huber", "ransac")
NOISE_FACTOR = 2.5  # a point is an outlier when its residual exceeds threshold_m and 2.5 x the median residual


@dataclasses.dataclass(frozen=True)
class PoseEstimate:
    """A rigid pose ``T`` (4x4, metres) mapping ``src`` points onto ``dst`` points.

    ``residuals_m[i]`` is ``|T src_i - dst_i|`` in metres (NaN where point i was not usable),
    ``inliers[i]`` is True where point i was used in the final fit, ``rmse_m`` is the root mean
    square residual over the inliers, and ``quaternion`` is the rotation in xyzw order, ``qw >= 0``.
    """

    T: np.ndarray
    quaternion: np.ndarray
    residuals_m: np.ndarray
    inliers: np.ndarray
    rmse_m: float

    @property
    def R(self) -> np.ndarray:
        """The 3x3 rotation block of :attr:`T`."""
        return self.T[:3, :3]

    @property
    def translation_m(self) -> np.ndarray:
        """The translation of :attr:`T` in metres; for ``T_cam_base``, the base origin in the camera frame."""
        return self.T[:3, 3]


def _points(p, name: str) -> np.ndarray:
    """``p`` as a float64 ``(N, 3)`` array, or a ValueError naming ``name`` and its shape."""
    p = np.asarray(p, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {p.shape}")
    return p


def _pair(src, dst) -> tuple[np.ndarray, np.ndarray]:
    """Validated ``(N, 3)`` correspondences with the same N."""
    src, dst = _points(src, "src"), _points(dst, "dst")
    if src.shape != dst.shape:
        raise ValueError(f"src and dst must have the same shape, got src {src.shape} and dst {dst.shape}")
    return src, dst


def _mask(mask, n: int, name: str) -> np.ndarray:
    """A boolean ``(n,)`` mask (all True when ``mask`` is None)."""
    if mask is None:
        return np.ones(n, dtype=bool)
    m = np.asarray(mask)
    if m.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {m.shape}")
    return m.astype(bool)


def to_matrix(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The 4x4 homogeneous transform of rotation ``R (3, 3)`` and translation ``t (3,)``."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def umeyama(src, dst, weights=None) -> tuple[np.ndarray, np.ndarray]:
    """Rigid least squares ``(R, t)`` minimising ``sum_i w_i |R src_i + t - dst_i|^2``.

    ``src`` and ``dst`` are ``(N, 3)`` with N >= 3, finite; ``weights`` ``(N,)`` non-negative
    (default all 1). ``R`` is a proper rotation (det +1): Umeyama (1991) without the scale.
    Collinear points leave the rotation about their line undetermined; this is logged.
    """
    src, dst = _pair(src, dst)
    n = len(src)
    if n < 3:
        raise ValueError(f"umeyama needs at least 3 points, got src of shape {src.shape}")
    if not (np.isfinite(src).all() and np.isfinite(dst).all()):
        raise ValueError("src and dst must be finite; drop or mask the missing points (see robust_rigid)")
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (n,):
        raise ValueError(f"weights must have shape ({n},), got {w.shape}")
    if not np.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
        raise ValueError("weights must be finite, non-negative and not all zero")
    w = w / w.sum()
    mu_s, mu_d = w @ src, w @ dst
    H = (dst - mu_d).T @ ((src - mu_s) * w[:, None])
    U, S, Vt = np.linalg.svd(H)
    if S[1] <= 1e-12 * max(S[0], 1e-300):
        log.warning("umeyama: points are (nearly) collinear; the rotation about their line is undetermined")
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U) * np.linalg.det(Vt)) or 1.0])
    R = U @ D @ Vt
    return R, mu_d - R @ mu_s


def _residuals(R: np.ndarray, t: np.ndarray, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """``|R src_i + t - dst_i|`` per point, metres."""
    return np.linalg.norm(src @ R.T + t - dst, axis=1)


def _cutoff(r: np.ndarray, k: float) -> float:
    """Inlier cutoff (metres): the larger of ``k`` and :data:`NOISE_FACTOR` times the median residual,
    so that noise larger than ``k`` does not turn good points into outliers."""
    return max(k, NOISE_FACTOR * float(np.median(r)))


def _refit_inliers(R, t, src, dst, k: float, rounds: int = 10) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least squares on the points within :func:`_cutoff` of ``(R, t)``, repeated until that set is
    stable (at most ``rounds`` times); returns ``(R, t, mask of the points of the last fit)``.
    With fewer than 3 points within the cutoff of the start, the start is kept with that mask."""
    keep = None
    for _ in range(rounds):
        r = _residuals(R, t, src, dst)
        new = r <= _cutoff(r, k)
        if keep is not None and (new == keep).all():
            break
        if new.sum() < 3:
            if keep is None:
                log.warning("inlier refit: %d points within %.3f m of the start; start kept", int(new.sum()), k)
                keep = new
            break
        keep = new
        R, t = umeyama(src[keep], dst[keep])
    return R, t, keep


def _huber(src, dst, k: float, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """Huber M-estimate by iteratively reweighted Umeyama from the least-squares fit, weights
    ``min(1, k / r)``."""
    R, t = umeyama(src, dst)
    for _ in range(iterations):
        r = _residuals(R, t, src, dst)
        R_new, t_new = umeyama(src, dst, np.minimum(1.0, k / np.maximum(r, 1e-12)))
        done = np.abs(R_new - R).max() < 1e-12 and np.abs(t_new - t).max() < 1e-12
        R, t = R_new, t_new
        if done:
            break
    return R, t


def _triplets(n: int, iterations: int, rng: np.random.Generator):
    """All 3-point index sets when there are at most ``iterations`` of them, else random ones."""
    if n * (n - 1) * (n - 2) // 6 <= iterations:
        yield from itertools.combinations(range(n), 3)
        return
    for _ in range(iterations):
        yield tuple(rng.choice(n, size=3, replace=False))


def _ransac(src, dst, k: float, iterations: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The best pose of RANSAC over minimal 3-point sets, scored by squared residuals truncated at
    ``k`` (MSAC); collinear sets are skipped."""
    rng = np.random.default_rng(seed)
    best, best_cost = None, np.inf
    for idx in _triplets(len(src), iterations, rng):
        s = src[list(idx)]
        if np.linalg.norm(np.cross(s[1] - s[0], s[2] - s[0])) < 1e-6:  # (nearly) collinear: skip
            continue
        R, t = umeyama(s, dst[list(idx)])
        cost = (np.minimum(_residuals(R, t, src, dst), k) ** 2).sum()
        if cost < best_cost:
            best, best_cost = (R, t), cost
    if best is None:
        log.warning("ransac: every 3-point sample was collinear; falling back to least squares")
        return umeyama(src, dst)
    return best


def robust_rigid(src, dst, valid=None, method: str = "huber", threshold_m: float = 0.05,
                 iterations: int | None = None, seed: int = 0) -> PoseEstimate:
    """Robust rigid fit ``dst ~ T src``; for ``src = FK points (base frame)`` and
    ``dst = predicted points (camera frame)``, ``T`` is ``T_cam_base``.

    ``valid`` ``(N,)`` marks usable points; points with a NaN coordinate are never used.
    ``method``:

    - ``"lstsq"``: plain :func:`umeyama` on all usable points (every one is an inlier);
    - ``"huber"``: IRLS with Huber weights ``min(1, threshold_m / r)`` from the least-squares fit
      (``iterations`` default 50), then the inlier refit below;
    - ``"ransac"``: minimal 3-point sets (all of them when there are at most ``iterations``,
      default 200, else random ones drawn with ``seed``) scored by truncated squared residuals
      (MSAC, truncation ``threshold_m``), then the inlier refit below.

    Inlier refit: least squares on the points whose residual is at most the larger of
    ``threshold_m`` and ``NOISE_FACTOR`` (2.5) times the median residual, repeated until that set
    is stable. ``inliers`` in the result are exactly the points of the final fit.
    Choose ``threshold_m`` about three times the typical per-point error (5 cm suits errors up to
    ~1.5 cm). Huber weights bound a bad point's pull but do not remove it: when the arm is folded
    (its points spread over little more than ``threshold_m``), one gross outlier can still win
    (1 of 50 random UR5 configurations in our trials; none of the 20 in the tests). ``"ransac"``
    does not fail that way but is more sensitive to a threshold below the noise: on UR5 with 2 cm
    noise, its median rotation error is 1.4x that of least squares at ``threshold_m=0.05`` and equal at 0.1.
    """
    src, dst = _pair(src, dst)
    use = _mask(valid, len(src), "valid") & np.isfinite(src).all(1) & np.isfinite(dst).all(1)
    if use.sum() < 3:
        raise ValueError(f"robust_rigid needs at least 3 valid finite correspondences, got {int(use.sum())} "
                         f"of {len(src)}")
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if not threshold_m > 0:
        raise ValueError(f"threshold_m must be positive, got {threshold_m}")
    s, d = src[use], dst[use]
    if method == "lstsq":
        R, t = umeyama(s, d)
        keep = np.ones(len(s), dtype=bool)
    else:
        if method == "huber":
            R, t = _huber(s, d, threshold_m, 50 if iterations is None else iterations)
        else:
            R, t = _ransac(s, d, threshold_m, 200 if iterations is None else iterations, seed)
        R, t, keep = _refit_inliers(R, t, s, d, threshold_m)
    inliers = np.zeros(len(src), dtype=bool)
    inliers[use] = keep
    return _estimate(to_matrix(R, t), src, dst, use, inliers)


def _estimate(T: np.ndarray, src, dst, use: np.ndarray, inliers: np.ndarray) -> PoseEstimate:
    """:class:`PoseEstimate` of pose ``T`` on the correspondences marked ``use``."""
    residuals = np.full(len(src), np.nan)
    residuals[use] = _residuals(T[:3, :3], T[:3, 3], src[use], dst[use])
    r = residuals[inliers] if inliers.any() else residuals[use]
    n_out = int(use.sum() - inliers.sum())
    if n_out:
        log.debug("pose fit: %d of %d usable points rejected as outliers", n_out, int(use.sum()))
    return PoseEstimate(T=T, quaternion=matrix_to_quat(T[:3, :3]), residuals_m=residuals,
                        inliers=inliers, rmse_m=float(np.sqrt(np.mean(r ** 2))))


def pool_poses(samples, method: str = "huber", threshold_m: float = 0.05, iterations: int | None = None,
               seed: int = 0) -> PoseEstimate:
    """One ``T_cam_base`` from several images of a static camera and base.

    ``samples`` is a sequence of ``(points_base (J, 3), points_cam (J, 3), valid (J,) or None)``;
    J may differ between samples. All correspondences are stacked and solved once with
    :func:`robust_rigid`; residuals and inliers are in stacking order.
    """
    samples = list(samples)
    if not samples:
        raise ValueError("pool_poses needs at least one (points_base, points_cam, valid) sample, got none")
    src, dst, val = [], [], []
    for i, sample in enumerate(samples):
        if len(sample) != 3:
            raise ValueError(f"samples[{i}] must be (points_base, points_cam, valid), got {len(sample)} items")
        pb, pc = _pair(sample[0], sample[1])
        src.append(pb)
        dst.append(pc)
        val.append(_mask(sample[2], len(pb), f"samples[{i}] valid"))
    return robust_rigid(np.concatenate(src), np.concatenate(dst), np.concatenate(val), method=method,
                        threshold_m=threshold_m, iterations=iterations, seed=seed)


def refine_reprojection(T, points_base, uv, K, valid=None, dist_coeffs=None) -> np.ndarray:
    """``T_cam_base`` refined by Levenberg-Marquardt on the 2D reprojection error.

    ``T`` is the initial 4x4 pose, ``points_base`` ``(N, 3)`` the FK points (metres, base frame),
    ``uv`` ``(N, 2)`` their detected pixels (OpenCV convention), ``K`` the 3x3 intrinsics,
    ``dist_coeffs`` optional distortion (None: rectified). Needs at least 3 valid points in
    front of the camera; with fewer, ``T`` is returned unchanged and a warning logged.
    Uses ``cv2.solvePnPRefineLM``. Pixels alone constrain depth weakly (an arm ~0.5 m across at
    2 m: 1 px of noise is ~1.5 cm of depth), so this pays when the 2D detections are sub-pixel
    or when rotation matters more than depth.
    """
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"T must have shape (4, 4), got {T.shape}")
    pb = _points(points_base, "points_base")
    uv = np.asarray(uv, dtype=np.float64)
    if uv.shape != (len(pb), 2):
        raise ValueError(f"uv must have shape ({len(pb)}, 2) to match points_base, got {uv.shape}")
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3):
        raise ValueError(f"K must have shape (3, 3), got {K.shape}")
    z = transform_points(T, pb)[:, 2]
    use = (_mask(valid, len(pb), "valid") & np.isfinite(pb).all(1) & np.isfinite(uv).all(1)
           & (np.nan_to_num(z, nan=-1.0) > 0))
    if use.sum() < 3:
        log.warning("refine_reprojection: %d usable points (< 3); pose left unchanged", int(use.sum()))
        return T.copy()
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    tvec = T[:3, 3].reshape(3, 1).copy()
    dist = np.zeros(5) if dist_coeffs is None else np.asarray(dist_coeffs, dtype=np.float64)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-12)
    rvec, tvec = cv2.solvePnPRefineLM(np.ascontiguousarray(pb[use]), np.ascontiguousarray(uv[use]), K, dist,
                                      rvec, tvec, criteria)
    return to_matrix(cv2.Rodrigues(rvec)[0], tvec.ravel())


RAY_SIGMA = 0.02          # normalised image coordinates (~rad): the network's median ray error on
LOG_DEPTH_SIGMA = 0.06    # held-out training frames, and its median |log depth error| on the same
                          # frames (python benchmarks/pose_fit_sigmas.py, results/pose_fit_sigmas.json)


def refine_rays(T, points_base, points_cam, valid=None, sigma_ray: float = RAY_SIGMA,
                sigma_log_depth: float = LOG_DEPTH_SIGMA) -> np.ndarray:
    """``T_cam_base`` refined so that each FK point ``points_base[i]`` (base frame) lies on the
    ray of its predicted point ``points_cam[i]`` (camera frame), to ``sigma_ray`` (normalised
    image coordinates, about radians), and near its predicted depth, to ``sigma_log_depth``
    (relative): Levenberg-Marquardt on those residuals over the 6 pose parameters, from ``T``.

    The rigid fit (:func:`robust_rigid`) weights every 3D direction alike, but the network's
    rays are far better than its depths (a joint slid along its predicted ray to the true depth
    is 3.5-5.3 cm off, against 11-20 cm as predicted); this weights each by its typical error.
    The same pose for all rows, so rows of several images of one static camera pool. Needs 3
    valid points in front of the camera (predicted and at ``T``); with fewer, ``T`` is returned."""
    from scipy.optimize import least_squares
    for name, value in (("sigma_ray", sigma_ray), ("sigma_log_depth", sigma_log_depth)):
        if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
            raise ValueError(f"refine_rays: {name} must be a positive number, got {value!r}")
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"T must have shape (4, 4), got {T.shape}")
    src, dst = _pair(points_base, points_cam)
    use = _mask(valid, len(src), "valid") & np.isfinite(src).all(1) & np.isfinite(dst).all(1)
    use &= (np.nan_to_num(dst[:, 2], nan=-1.0) > 1e-3) & (transform_points(T, np.nan_to_num(src))[:, 2] > 1e-3)
    if use.sum() < 3:
        log.warning("refine_rays: %d usable points (< 3); pose left unchanged", int(use.sum()))
        return T.copy()
    src, dst = src[use], dst[use]
    ray, log_z = dst[:, :2] / dst[:, 2:], np.log(dst[:, 2])

    def residuals(x):
        p = src @ cv2.Rodrigues(x[:3])[0].T + x[3:]
        z = np.maximum(p[:, 2], 1e-3)
        return np.concatenate([((p[:, :2] / z[:, None] - ray) / sigma_ray).ravel(), (np.log(z) - log_z) / sigma_log_depth])

    x0 = np.concatenate([cv2.Rodrigues(T[:3, :3])[0].ravel(), T[:3, 3]])
    x = least_squares(residuals, x0, method="lm").x
    return to_matrix(cv2.Rodrigues(x[:3])[0], x[3:])


def reprojection_errors_px(T, points_base, uv, K) -> np.ndarray:
    """Pixel distance ``(N,)`` between the projections of ``T @ points_base`` and ``uv`` (no distortion)."""
    p = transform_points(np.asarray(T, dtype=np.float64), _points(points_base, "points_base"))
    proj = p @ np.asarray(K, dtype=np.float64).T
    return np.linalg.norm(proj[:, :2] / proj[:, 2:3] - np.asarray(uv, dtype=np.float64), axis=1)


def _rotation_block(R, name: str) -> np.ndarray:
    """The rotations ``(..., 3, 3)`` of rotations or 4x4 transforms."""
    R = np.asarray(R, dtype=np.float64)
    if R.ndim < 2 or R.shape[-2:] not in ((3, 3), (4, 4)):
        raise ValueError(f"{name} must have shape (..., 3, 3) or (..., 4, 4), got {R.shape}")
    return R[..., :3, :3]


def rotation_error_deg(R_est, R_true) -> np.ndarray | float:
    """Geodesic angle (degrees) between rotations, ``(..., 3, 3)`` or 4x4 transforms.

    Computed as ``2 asin(|R_est - R_true|_F / sqrt(8))``, accurate for small angles.
    """
    a, b = _rotation_block(R_est, "R_est"), _rotation_block(R_true, "R_true")
    s = np.linalg.norm(a - b, axis=(-2, -1)) / np.sqrt(8.0)
    out = np.degrees(2.0 * np.arcsin(np.clip(s, 0.0, 1.0)))
    return float(out) if out.ndim == 0 else out


def _translation(t, name: str) -> np.ndarray:
    """Translations ``(..., 3)`` of translations or 4x4 transforms."""
    t = np.asarray(t, dtype=np.float64)
    if t.shape[-2:] == (4, 4):
        return t[..., :3, 3]
    if t.ndim < 1 or t.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (..., 3) or (..., 4, 4), got {t.shape}")
    return t


def translation_error_m(t_est, t_true) -> np.ndarray | float:
    """Euclidean distance (metres) between translations ``(..., 3)`` or those of 4x4 transforms."""
    out = np.linalg.norm(_translation(t_est, "t_est") - _translation(t_true, "t_true"), axis=-1)
    return float(out) if out.ndim == 0 else out


def add_m(T_est, T_true, points_base) -> np.ndarray | float:
    """ADD: mean distance (metres) between ``points_base (N, 3)`` moved by ``T_est`` and by ``T_true``
    (each ``(..., 4, 4)``)."""
    T_est, T_true = np.asarray(T_est, dtype=np.float64), np.asarray(T_true, dtype=np.float64)
    for name, T in (("T_est", T_est), ("T_true", T_true)):
        if T.shape[-2:] != (4, 4):
            raise ValueError(f"{name} must have shape (..., 4, 4), got {T.shape}")
    p = _points(points_base, "points_base")
    out = np.linalg.norm(transform_points(T_est, p) - transform_points(T_true, p), axis=-1).mean(-1)
    return float(out) if out.ndim == 0 else out


def add_auc(add_values, threshold: float = 0.1) -> float:
    """Area under the ADD accuracy curve, normalised to [0, 1], as NVlabs/DREAM reports it.

    The curve is the fraction of samples with ADD <= t for t in [0, ``threshold``] (metres);
    non-finite values (failed estimates) count in the denominator and are never below t.
    DREAM integrates this curve with the trapezoid rule on a 1e-5 m grid; this is the exact
    integral, ``mean(clip(1 - add / threshold, 0, 1))``, which that sum approximates (to < 1e-4).
    """
    a = np.asarray(add_values, dtype=np.float64).ravel()
    if a.size == 0:
        raise ValueError("add_values must not be empty")
    if not threshold > 0:
        raise ValueError(f"threshold must be positive, got {threshold}")
    if (a[np.isfinite(a)] < 0).any():
        raise ValueError("add_values must be non-negative distances")
    a = np.where(np.isfinite(a), a, np.inf)
    return float(np.mean(np.clip(1.0 - a / threshold, 0.0, 1.0)))


def to_json(estimate: PoseEstimate) -> dict:
    """A JSON-ready dict of a :class:`PoseEstimate`; NaN residuals (unused points) become None."""
    return {
        "T_cam_base": estimate.T.tolist(),
        "quaternion_xyzw": estimate.quaternion.tolist(),
        "translation_m": estimate.translation_m.tolist(),
        "rmse_m": float(estimate.rmse_m),
        "residuals_m": [None if not np.isfinite(r) else float(r) for r in estimate.residuals_m],
        "inliers": [bool(b) for b in estimate.inliers],
    }

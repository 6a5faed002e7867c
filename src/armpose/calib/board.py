"""The ChArUco calibration board: its geometry, its image, detection and single-view pose (PnP).

Board frame (OpenCV's ChArUco convention, checked by a test): origin at the top-left outer
corner of the chessboard as printed by :meth:`BoardSpec.image` (margin excluded); x along the
top edge to the right (``squares_x`` squares), y down along the left edge (``squares_y``
squares), z = x cross y, pointing *into* the board, away from its printed face. A camera that
sees the board is at z < 0. Lengths in metres. The mocap rigid body of the board must be
defined in this frame (or its fixed offset applied before calibration).

Camera: a rectified pinhole :class:`armpose.geometry.Camera`, OpenCV optical frame
(x right, y down, z forward); the centre of pixel (i, j) is at (u, v) = (i, j).
Optional OpenCV distortion coefficients undistort the detected corners onto that pinhole camera.
"""
from __future__ import annotations

import dataclasses
import functools
import logging

import cv2
import numpy as np

from armpose.geometry import Camera

log = logging.getLogger(__name__)

MIN_CORNERS = 6  # fewer detected ChArUco corners than this: no pose for the view


@dataclasses.dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board: squares along x and y, square and marker side in metres, ArUco dictionary name.

    ``legacy_pattern`` selects the pre-OpenCV-4.6 layout for boards with an even number of rows.
    """

    squares_x: int
    squares_y: int
    square_length: float
    marker_length: float
    dictionary: str = "DICT_4X4_50"
    legacy_pattern: bool = False

    def __post_init__(self) -> None:
        if int(self.squares_x) < 2 or int(self.squares_y) < 2:
            raise ValueError(f"board needs at least 2x2 squares, got {self.squares_x}x{self.squares_y}")
        if not 0 < self.marker_length < self.square_length:
            raise ValueError(f"need 0 < marker_length < square_length (metres), got "
                             f"{self.marker_length} and {self.square_length}")
        if not self.dictionary.startswith("DICT_") or not hasattr(cv2.aruco, self.dictionary):
            raise ValueError(f"unknown ArUco dictionary {self.dictionary!r} (e.g. DICT_4X4_50, DICT_5X5_100)")
        size = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary)).bytesList.shape[0]
        if size < self.num_markers:
            raise ValueError(f"dictionary {self.dictionary} has {size} markers, the board needs {self.num_markers}")

    @property
    def num_markers(self) -> int:
        return self.squares_x * self.squares_y // 2

    @property
    def num_corners(self) -> int:
        return (self.squares_x - 1) * (self.squares_y - 1)

    @property
    def size(self) -> tuple[float, float]:
        """Chessboard width and height in metres."""
        return self.squares_x * self.square_length, self.squares_y * self.square_length

    @property
    def center(self) -> np.ndarray:
        """Centre of the chessboard in the board frame (metres)."""
        w, h = self.size
        return np.array([w / 2, h / 2, 0.0])

    @classmethod
    def from_dict(cls, d: dict) -> BoardSpec:
        """Strict: the four geometry keys are required, unknown keys are an error."""
        required = ("squares_x", "squares_y", "square_length", "marker_length")
        allowed = {f.name for f in dataclasses.fields(cls)}
        if not isinstance(d, dict):
            raise ValueError(f"board description must be a JSON object, got {type(d).__name__}")
        missing = [k for k in required if k not in d]
        if missing:
            raise ValueError(f"board description lacks {missing}; needs {list(required)}")
        unknown = sorted(set(d) - allowed)
        if unknown:
            raise ValueError(f"unknown board keys {unknown}; allowed {sorted(allowed)}")
        for k in ("squares_x", "squares_y"):
            if not isinstance(d[k], int) or isinstance(d[k], bool):
                raise ValueError(f"board {k} must be an integer, got {d[k]!r}")
        for k in ("square_length", "marker_length"):
            if not isinstance(d[k], (int, float)) or isinstance(d[k], bool) or not np.isfinite(d[k]):
                raise ValueError(f"board {k} must be a finite number of metres, got {d[k]!r}")
        return cls(d["squares_x"], d["squares_y"], float(d["square_length"]), float(d["marker_length"]),
                   str(d.get("dictionary", "DICT_4X4_50")), bool(d.get("legacy_pattern", False)))

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def image(self, px_per_square: int = 100, margin_px: int = 0) -> tuple[np.ndarray, int]:
        """The printable board as a grey uint8 image with a white margin, and its pixels per square.

        That is ``px_per_square`` or the next size up that OpenCV 5.0's ``generateImage`` can draw:
        it fails an ROI assertion at some sizes (e.g. 50, 85, 120 px for 0.07 m squares, 0.054 m markers).
        """
        for px in range(px_per_square, px_per_square + 8):
            w, h = self.squares_x * px + 2 * margin_px, self.squares_y * px + 2 * margin_px
            try:
                return cv_board(self).generateImage((w, h), marginSize=margin_px, borderBits=1), px
            except cv2.error:
                continue
        raise ValueError(f"OpenCV cannot draw {self} at {px_per_square}-{px} px per square")


@functools.lru_cache(maxsize=8)
def cv_board(spec: BoardSpec) -> cv2.aruco.CharucoBoard:
    """The OpenCV board object for ``spec`` (cached)."""
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, spec.dictionary))
    board = cv2.aruco.CharucoBoard((spec.squares_x, spec.squares_y), spec.square_length, spec.marker_length,
                                   dictionary)
    board.setLegacyPattern(spec.legacy_pattern)
    return board


@dataclasses.dataclass
class BoardObservation:
    """Detected ChArUco corners of one image: ids ``(K,)``, pixels ``(K, 2)`` (undistorted onto the
    pinhole camera) and the matching board-frame points ``(K, 3)`` in metres."""

    ids: np.ndarray
    image_points: np.ndarray
    object_points: np.ndarray

    def __len__(self) -> int:
        return len(self.ids)


def _gray(image: np.ndarray) -> np.ndarray:
    if image.ndim == 3:
        return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY if image.shape[2] == 3 else cv2.COLOR_RGBA2GRAY)
    return image


def detect_board(image: np.ndarray, spec: BoardSpec, camera: Camera | None = None,
                 distortion: np.ndarray | None = None) -> BoardObservation | None:
    """ChArUco corners in an RGB or grey uint8 image; ``None`` when fewer than :data:`MIN_CORNERS`
    were found or they are collinear. With ``distortion`` (OpenCV coefficients; needs ``camera``),
    the corners are undistorted onto the pinhole ``camera``."""
    board = cv_board(spec)
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(_gray(image))
    if ids is None or len(ids) < MIN_CORNERS:
        return None
    ids = np.asarray(ids, dtype=np.int64).reshape(-1)  # 5.0: (K,); 4.x: (K, 1)
    corners = np.asarray(corners, dtype=np.float64).reshape(-1, 2)  # 5.0: (K, 2); 4.x: (K, 1, 2)
    if board.checkCharucoCornersCollinear(ids):
        return None
    if distortion is not None and np.any(np.asarray(distortion) != 0):
        if camera is None:
            raise ValueError("undistorting corners needs the camera intrinsics")
        corners = cv2.undistortPoints(corners[:, None], camera.K, np.asarray(distortion, np.float64),
                                      P=camera.K).reshape(-1, 2)
    obj = np.asarray(board.getChessboardCorners(), dtype=np.float64)[ids]
    return BoardObservation(ids, corners, obj)


def _rvec_tvec_to_matrix(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3))[0]
    T[:3, 3] = np.asarray(tvec, np.float64).reshape(3)
    return T


def reprojection_errors(T_cam_board: np.ndarray, obs: BoardObservation, camera: Camera) -> np.ndarray:
    """Pixel distance ``(K,)`` between the detected corners and the board corners projected with ``T_cam_board``."""
    p = obs.object_points @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
    return np.linalg.norm(camera.project(p) - obs.image_points, axis=-1)


def board_pose(obs: BoardObservation, camera: Camera) -> tuple[np.ndarray, float]:
    """``T_cam_board`` (4x4, metres) from one view by planar PnP (IPPE, then Levenberg-Marquardt),
    and the RMS reprojection error in pixels."""
    obj = obs.object_points.astype(np.float64)
    img = obs.image_points.astype(np.float64)
    ok, rvec, tvec = cv2.solvePnP(obj, img, camera.K, None, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise ValueError("PnP failed on the detected board corners")
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, camera.K, None, rvec, tvec)
    T = _rvec_tvec_to_matrix(rvec, tvec)
    rms = float(np.sqrt(np.mean(reprojection_errors(T, obs, camera) ** 2)))
    return T, rms

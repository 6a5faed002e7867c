"""Rig-to-camera calibration on a simulated session: accuracy against the truth, outlier rejection,
too few views, per-view residuals, the board frame convention, and the CLI with its input checks."""
from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from armpose.calib.board import BoardSpec, detect_board
from armpose.calib.cli import main
from armpose.calib.rig import MIN_VIEWS, NotEnoughViewsError, calibrate_rig, pose_error
from armpose.calib.simulate import simulate_session
from armpose.calib.views import write_session
from armpose.geometry import quat_to_matrix

MAX_MM, MAX_DEG = 2.0, 0.2  # required accuracy of T_rig_cam


@pytest.fixture(scope="module")
def session():
    """16 rendered views of the board, mocap noise 0.5 mm / 0.1 deg RMS on rig and board."""
    return simulate_session(seed=11, num_views=16)


@pytest.fixture(scope="module")
def views(session):
    return session.rig_views()


@pytest.fixture(scope="module")
def result(session, views):
    return calibrate_rig(views, session.camera, session.board.center)


def test_simulated_session_is_a_real_problem(session, views):
    deg, mm = pose_error(np.eye(4), session.T_rig_cam)
    assert 30 <= mm <= 80 and 5 <= deg <= 20  # the offset the solver must find
    assert len(session.images) == 16 and session.images[0].shape == (360, 480, 3)
    assert sum(v.observation is not None for v in views) >= 14
    rig_deg, rig_mm = pose_error(session.T_world_rig[0], session.T_world_cam[0] @ np.linalg.inv(session.T_rig_cam))
    assert 0 < rig_mm < 3 and 0 < rig_deg < 0.6  # the mocap poses are noisy, as given to the solver


def test_recovers_rig_to_camera_transform(session, result):
    deg, mm = pose_error(result.T_rig_cam, session.T_rig_cam)
    print(f"T_rig_cam error: {mm:.3f} mm, {deg:.4f} deg")
    assert mm < MAX_MM and deg < MAX_DEG
    assert result.rejected == []


def test_pose_error_fails_a_wrong_transform(session):
    wrong = session.T_rig_cam.copy()
    wrong[:3, 3] += [0.0, 0.003, 0.0]
    assert pose_error(wrong, session.T_rig_cam)[1] > MAX_MM
    c, s = np.cos(np.radians(0.3)), np.sin(np.radians(0.3))
    wrong = session.T_rig_cam @ np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    assert pose_error(wrong, session.T_rig_cam)[0] > MAX_DEG


def test_per_view_residuals_are_reported(result, views):
    assert [v.name for v in result.views] == [v.name for v in views]
    for v, view in zip(result.views, views):
        assert v.corners == len(view.observation)
        assert v.status == "used"
        assert 0 <= v.rotation_deg < 2.0 and 0 <= v.translation_mm < 6.0 and 0 < v.reprojection_px < 2.0
    assert 0 < result.rms_reprojection_px < 1.5
    d = json.loads(json.dumps(result.to_dict()))
    assert len(d["views"]) == len(views) and d["rejected"] == []
    assert {"rotation_deg", "translation_mm", "reprojection_px", "status", "corners"} <= set(d["views"][0])


def test_outlier_view_is_rejected(session, views):
    bad = [copy.copy(v) for v in views]
    bad[5].T_world_rig = bad[5].T_world_rig.copy()
    bad[5].T_world_rig[:3, 3] += np.array([0.03, -0.04, 0.0])  # 5 cm mocap glitch
    res = calibrate_rig(bad, session.camera, session.board.center)
    assert res.rejected == [views[5].name]
    rejected = res.views[5]
    assert rejected.status == "rejected" and rejected.translation_mm > 20 and rejected.reprojection_px > 5
    deg, mm = pose_error(res.T_rig_cam, session.T_rig_cam)
    print(f"with an outlier view: {mm:.3f} mm, {deg:.4f} deg")
    assert mm < MAX_MM and deg < MAX_DEG


def test_too_few_views_raise_a_clear_error(session, views):
    with pytest.raises(NotEnoughViewsError) as err:
        calibrate_rig(views[:MIN_VIEWS - 1], session.camera, session.board.center)
    assert isinstance(err.value, ValueError)
    assert f"at least {MIN_VIEWS} usable board views; 2 given, 2 usable" in str(err.value)
    undetected = [copy.copy(v) for v in views[:4]]
    undetected[0].observation = undetected[3].observation = None
    with pytest.raises(ValueError, match=f"4 given, 2 usable.*{views[0].name}: board not detected"):
        calibrate_rig(undetected, session.camera, session.board.center)


def test_board_frame_is_opencv_charuco():
    spec = BoardSpec(5, 4, 0.05, 0.035, "DICT_4X4_50")
    image, px = spec.image(80)
    obs = detect_board(image, spec)
    assert obs is not None and len(obs) == spec.num_corners
    first = int(np.argmin(obs.ids))
    np.testing.assert_allclose(obs.object_points[first], [0.05, 0.05, 0.0])  # x right, y down, metres
    np.testing.assert_allclose(obs.image_points[first], [px - 0.5, px - 0.5], atol=0.1)  # pixel-centre convention
    np.testing.assert_allclose(obs.image_points / px * 0.05 + 0.5 / px * 0.05, obs.object_points[:, :2], atol=2e-3)


def test_cli_end_to_end(session, tmp_path, capsys):
    paths = write_session(session, tmp_path)
    out = tmp_path / "rig.json"
    argv = ["--views", str(paths["views"]), "--intrinsics", str(paths["intrinsics"]),
            "--board", str(paths["board"]), "--out", str(out)]
    assert main(argv) == 0
    assert "T_rig_cam from 16 of 16 views" in capsys.readouterr().out
    rig = json.loads(out.read_text())
    T = np.array(rig["T_rig_cam"])
    np.testing.assert_allclose(quat_to_matrix(np.array(rig["quaternion_xyzw"])), T[:3, :3], atol=1e-9)
    np.testing.assert_allclose(rig["translation"], T[:3, 3])
    deg, mm = pose_error(T, session.T_rig_cam)
    assert mm < MAX_MM and deg < MAX_DEG
    assert len(rig["views"]) == 16 and rig["rejected"] == []

    board_csv = paths["views"] / "board_poses.csv"  # a board measured once: one "*" row
    lines = board_csv.read_text().splitlines()
    board_csv.write_text(lines[0] + "\n*," + lines[1].split(",", 1)[1] + "\n")
    assert main(argv) == 0
    deg, mm = pose_error(np.array(json.loads(out.read_text())["T_rig_cam"]), session.T_rig_cam)
    assert mm < MAX_MM and deg < MAX_DEG


@pytest.fixture(scope="module")
def small_session():
    return simulate_session(seed=2, num_views=4)


def _cli_error(small_session, tmp_path, capsys, edit) -> str:
    paths = write_session(small_session, tmp_path, truth=False)
    edit(paths)
    rc = main(["--views", str(paths["views"]), "--intrinsics", str(paths["intrinsics"]),
               "--board", str(paths["board"]), "--out", str(tmp_path / "rig.json")])
    assert rc == 1 and not (tmp_path / "rig.json").exists()
    return capsys.readouterr().err


def _replace_field(path, line: int, col: int, value: str) -> None:
    rows = [r.split(",") for r in path.read_text().splitlines()]
    rows[line - 1][col] = value
    path.write_text("\n".join(",".join(r) for r in rows) + "\n")


def test_cli_names_file_row_and_value(small_session, tmp_path, capsys):
    err = _cli_error(small_session, tmp_path / "a", capsys,
                     lambda p: _replace_field(p["views"] / "rig_poses.csv", 3, 7, "0.9"))
    assert "rig_poses.csv:3: quaternion is not unit" in err and "0.9" in err
    err = _cli_error(small_session, tmp_path / "b", capsys,
                     lambda p: _replace_field(p["views"] / "board_poses.csv", 4, 2, "abc"))
    assert "board_poses.csv:4: y is not a number (value: 'abc')" in err
    err = _cli_error(small_session, tmp_path / "c", capsys, lambda p: (p["views"] / "view_001.png").unlink())
    assert "rig_poses.csv:3: image file" in err and "view_001.png is missing" in err
    err = _cli_error(small_session, tmp_path / "d", capsys, lambda p: p["board"].write_text('{"squares_x": 7}'))
    assert "board.json" in err and "lacks" in err and "square_length" in err
    err = _cli_error(small_session, tmp_path / "e", capsys, lambda p: p["intrinsics"].write_text('{"width": 480}'))
    assert "cam.json" in err and "intrinsics need width, height, fx, fy, cx, cy" in err


def test_cli_help_documents_the_layout(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--help"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert "rig_poses.csv       image,x,y,z,qx,qy,qz,qw" in out and "board.json" in out
    with pytest.raises(SystemExit) as exit_:
        main(["--views", "v"])
    assert exit_.value.code == 2 and "missing --intrinsics, --board, --out" in capsys.readouterr().err

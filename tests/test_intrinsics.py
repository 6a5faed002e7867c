"""The one intrinsics reader: good files, a recording.json, and every bad input named."""
from __future__ import annotations

import json

import numpy as np
import pytest

from armpose.intrinsics import IntrinsicsError, load_intrinsics, read_intrinsics

CAM = {"width": 640, "height": 480, "fx": 600.0, "fy": 601.0, "cx": 319.5, "cy": 239.5}


def _write(tmp_path, obj, name="cam.json"):
    path = tmp_path / name
    path.write_text(obj if isinstance(obj, str) else json.dumps(obj))
    return path


def test_reads_a_camera_and_its_distortion(tmp_path):
    camera, dist = read_intrinsics(_write(tmp_path, {**CAM, "distortion": [0.1, -0.2, 0.0, 0.0, 0.01]}))
    assert (camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy) == (640, 480, 600.0, 601.0,
                                                                                        319.5, 239.5)
    np.testing.assert_array_equal(dist, [0.1, -0.2, 0.0, 0.0, 0.01])
    assert read_intrinsics(_write(tmp_path, CAM))[1] is None


def test_reads_the_camera_of_a_recording_json(tmp_path):
    path = _write(tmp_path, {"robot": "ur5", "source": "recorded", "camera": CAM}, "recording.json")
    assert load_intrinsics(path).fx == 600.0


@pytest.mark.parametrize("content, problem, value", [
    ({k: v for k, v in CAM.items() if k != "cy"}, "intrinsics need width", None),
    ({**CAM, "fx": -5.0}, "fx must be a positive number", "-5.0"),
    ({**CAM, "width": True}, "width must be a positive number", "True"),
    ({**CAM, "distortion": [0.1, 0.2, 0.3]}, "distortion must be a list", "[0.1, 0.2, 0.3]"),
    ('{"width": 640,\n "height": }', "not valid JSON", None),
])
def test_bad_files_name_the_file_and_the_value(tmp_path, content, problem, value):
    path = _write(tmp_path, content)
    with pytest.raises(IntrinsicsError) as err:
        read_intrinsics(path)
    assert str(path) in str(err.value) and problem in str(err.value)
    if value is not None:
        assert value in str(err.value)


def test_bad_json_names_the_line(tmp_path):
    with pytest.raises(IntrinsicsError, match=r"cam\.json:2: not valid JSON"):
        read_intrinsics(_write(tmp_path, '{"width": 640,\n "height": }'))


def test_missing_file(tmp_path):
    with pytest.raises(IntrinsicsError, match="missing file"):
        read_intrinsics(tmp_path / "nope.json")


def test_load_intrinsics_wants_rectified_images(tmp_path):
    assert load_intrinsics(_write(tmp_path, {**CAM, "distortion": [0.0] * 5})).cx == 319.5
    with pytest.raises(IntrinsicsError, match="rectified"):
        load_intrinsics(_write(tmp_path, {**CAM, "distortion": [0.1, 0, 0, 0, 0]}))

"""armpose.io: atomic writes and JSON input files read with errors that name the file."""
from __future__ import annotations

import json

import pytest

from armpose.calib.views import CalibInputError
from armpose.intrinsics import IntrinsicsError
from armpose.io import InputFileError, atomic_write_json, read_json_input
from armpose.recording import RecordingError


def test_atomic_write_json_round_trips_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "sub" / "out.json"
    atomic_write_json(path, {"a": [1, 2]})
    assert json.loads(path.read_text()) == {"a": [1, 2]}
    assert [p.name for p in path.parent.iterdir()] == ["out.json"]


def test_read_json_input_parses(tmp_path):
    path = tmp_path / "x.json"
    path.write_text('{"k": 3}')
    assert read_json_input(path) == {"k": 3}


def test_read_json_input_names_file_and_line_of_a_syntax_error(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text('{\n  "k": ,\n}')
    with pytest.raises(InputFileError, match=r"bad\.json:2: not valid JSON") as info:
        read_json_input(path)
    assert info.value.file == str(path) and info.value.row == 2


def test_read_json_input_missing_and_unreadable(tmp_path):
    with pytest.raises(InputFileError, match=r"nope\.json: missing file"):
        read_json_input(tmp_path / "nope.json")
    (tmp_path / "folder.json").mkdir()
    with pytest.raises(InputFileError, match="not readable"):
        read_json_input(tmp_path / "folder.json")
    binary = tmp_path / "bin.json"
    binary.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(InputFileError, match="not readable"):
        read_json_input(binary)


@pytest.mark.parametrize("error", [RecordingError, CalibInputError, IntrinsicsError])
def test_input_errors_share_one_base_and_are_raised_as_themselves(tmp_path, error):
    assert issubclass(error, InputFileError) and issubclass(error, ValueError)
    with pytest.raises(error, match="missing file"):
        read_json_input(tmp_path / "absent.json", error)

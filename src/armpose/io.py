"""Atomic file writes, and reading users' input files with errors that say where.

Writes go to a temporary file in the same folder, then ``os.replace``: a reader never sees
a half-written file, and an interrupted writer leaves at most a ``*.tmp*`` file that no
reader looks at.

:class:`InputFileError` is the base of every bad-input error (recordings, calibration
input, intrinsics): it names the file, the row or line (None for the whole file) and the
offending value. :func:`read_json_input` parses a JSON input file and raises such an error.
"""
from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any, Callable

import numpy as np


class InputFileError(ValueError):
    """A bad input file: ``file``, ``row`` (None for the whole file) and ``value`` say where and what."""

    def __init__(self, file: Path | str, row: int | None, value, problem: str):
        self.file, self.row, self.value, self.problem = str(file), row, value, problem
        where = f"{file}:{row}" if row is not None else f"{file}"
        super().__init__(f"{where}: {problem} (value: {value!r})")


def read_json_input(path: Path | str, error: type[InputFileError] = InputFileError) -> Any:
    """The parsed JSON of ``path``; ``error`` naming the file (and the line of a syntax error)
    if it is missing, unreadable or not JSON."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise error(path, None, None, "missing file") from None
    except json.JSONDecodeError as err:
        raise error(path, err.lineno, err.msg, "not valid JSON") from err
    except (OSError, UnicodeDecodeError) as err:
        raise error(path, None, str(err), "not readable") from err


def _atomic(path: Path, write: Callable[[str], None], suffix: str = "") -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + suffix, dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically."""
    def write(tmp: str) -> None:
        with open(tmp, "w") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
    _atomic(path, write)


def atomic_write_json(path: Path, obj: Any) -> None:
    """Write ``obj`` as indented JSON atomically."""
    atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=False) + "\n")


def atomic_save_npy(path: Path, array: np.ndarray) -> None:
    """Save one array as ``.npy`` atomically (readable with ``np.load(mmap_mode='r')``)."""
    def write(tmp: str) -> None:
        with open(tmp, "wb") as fh:
            np.save(fh, array)
    _atomic(path, write)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write raw bytes atomically."""
    def write(tmp: str) -> None:
        with open(tmp, "wb") as fh:
            fh.write(data)
    _atomic(path, write)

"""Import a user's raw recording (a folder of images and CSVs, or a ROS 1/ROS 2 bag) into the
recording format of :mod:`armpose.recording`.

Each image is matched to the joint sample and the camera pose sample nearest in time (within a
tolerance); the result is written atomically and :func:`import_folder` / :func:`import_bag` return a
summary dict of what was kept, dropped and why. Bad input raises :class:`SourceError` (a
:class:`~armpose.recording.RecordingError`) naming the file and the CSV row or bag topic, message
index and stamp, and the value.
"""
from armpose.importers.assemble import ImportOptions
from armpose.importers.bag import import_bag
from armpose.importers.common import NothingKeptError, SourceError, load_transform
from armpose.importers.folder import import_folder
from armpose.intrinsics import load_intrinsics

__all__ = ["ImportOptions", "NothingKeptError", "SourceError", "import_bag", "import_folder",
           "load_intrinsics", "load_transform"]

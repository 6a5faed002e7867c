"""Import a ROS 1 bag (``*.bag`` file) or a ROS 2 bag (folder with ``metadata.yaml``) with the
pure-Python ``rosbags`` library; no ROS installation is needed.

Topics:

- images: ``sensor_msgs/Image`` (rgb8, bgr8, rgba8, bgra8, mono8) or ``sensor_msgs/CompressedImage``
  (any format OpenCV decodes); must be rectified (e.g. ``image_rect_color``): nothing is undistorted;
- joints: ``sensor_msgs/JointState``, mapped by name to the robot's joint order (radians);
- camera pose: ``geometry_msgs/PoseStamped`` from mocap (the rig's or camera's pose, metres,
  xyzw), composed as in :class:`~armpose.importers.assemble.ImportOptions`; or a fixed pose;
- intrinsics (optional): ``sensor_msgs/CameraInfo``, first message; the projection matrix P
  (the rectified camera), or K where P is all zeros.

Messages are timed by their ``header.stamp`` (capture time), or by the bag's record time with
``stamp="bag"``. Message indices in errors count from 0 per topic, in bag order.
"""
from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from armpose.geometry import Camera
from armpose.importers.assemble import ImageRef, ImportOptions, RawRecording, assemble, check_output
from armpose.importers.common import StreamBuilder, Where, check_joint_names, finite_or_raise, pose_problem
from armpose.robots.registry import RobotSpec, get_robot

log = logging.getLogger(__name__)

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
JOINT_TYPES = ("sensor_msgs/msg/JointState",)
POSE_TYPES = ("geometry_msgs/msg/PoseStamped",)
INFO_TYPES = ("sensor_msgs/msg/CameraInfo",)
ENCODINGS = {"rgb8": (3, None), "bgr8": (3, cv2.COLOR_BGR2RGB), "rgba8": (4, cv2.COLOR_RGBA2RGB),
             "bgra8": (4, cv2.COLOR_BGRA2RGB), "mono8": (1, cv2.COLOR_GRAY2RGB)}


def open_bag(path: str | Path) -> AnyReader:
    """An unopened reader: ROS 1 if the path ends in ``.bag``, else a ROS 2 bag folder (a path to its
    ``metadata.yaml`` or storage file is taken as the folder)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such bag")
    if path.is_file() and path.suffix != ".bag":
        path = path.parent
    return AnyReader([path], default_typestore=get_typestore(Stores.LATEST))


def _topics(reader: AnyReader) -> str:
    return ", ".join(f"{c.topic} ({c.msgtype})" for c in reader.connections) or "none"


def find_topic(reader: AnyReader, bag: str, topic: str | None, types: tuple[str, ...], what: str,
               required: bool = True) -> str | None:
    """``topic`` checked against ``types``, or the single topic of those types when ``topic`` is None."""
    if topic is None:
        found = sorted({c.topic for c in reader.connections if c.msgtype in types})
        if len(found) == 1:
            return found[0]
        if not found and not required:
            return None
        raise ValueError(f"{bag}: {'no' if not found else 'several'} {what} topics ({', '.join(found)}); "
                         f"name one. Topics: {_topics(reader)}")
    conns = [c for c in reader.connections if c.topic == topic]
    if not conns:
        raise ValueError(f"{bag}: no topic {topic} for {what}. Topics: {_topics(reader)}")
    for c in conns:
        if c.msgtype not in types:
            raise Where(bag, topic=topic).error(c.msgtype, f"{what} topic must be of type {' or '.join(types)}")
    return topic


def message_stamp(msg, bag_ns: int, mode: str, where: Where) -> int:
    """Nanoseconds: ``header.stamp`` (``mode="header"``) or the bag's record time (``"bag"``)."""
    if mode == "bag":
        return int(bag_ns)
    stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
    if stamp == 0:
        raise where.error(0, "header.stamp is zero; match on the bag's record time instead (--stamp bag)")
    return int(stamp)


def joint_sample(msg, spec: RobotSpec, where: Where, ignore: tuple[str, ...]) -> tuple[np.ndarray | None, list]:
    """Robot-ordered joint angles (radians) and extra names, or (None, names) for a message with
    none of the robot's joints (another device's)."""
    names, positions = list(msg.name), np.asarray(msg.position, dtype=np.float64)
    if len(positions) != len(names):
        raise where.error(len(positions), f"JointState has {len(names)} names but {len(positions)} positions")
    if not set(names) & set(spec.joints):
        return None, names
    extra = check_joint_names(names, spec, where, ignore)
    values = positions[[names.index(j) for j in spec.joints]]
    finite_or_raise(values, spec.joints, where)
    return values, extra


def pose_sample(msg) -> np.ndarray:
    """``(x, y, z, qx, qy, qz, qw)`` of a PoseStamped (metres, xyzw)."""
    p, q = msg.pose.position, msg.pose.orientation
    return np.array([p.x, p.y, p.z, q.x, q.y, q.z, q.w], dtype=np.float64)


def _field(msg, name: str) -> np.ndarray:
    """CameraInfo matrices are ``k``/``p`` in ROS 2 and ``K``/``P`` in ROS 1."""
    return np.asarray(getattr(msg, name) if hasattr(msg, name) else getattr(msg, name.upper()), dtype=np.float64)


def camera_from_info(msg, where: Where) -> Camera:
    """Intrinsics (pixels) of a CameraInfo: from P (rectified) or, if P is zero, K."""
    P, K, D = _field(msg, "p"), _field(msg, "k"), _field(msg, "d")
    fx, fy, cx, cy = (P[0], P[5], P[2], P[6]) if P.any() else (K[0], K[4], K[2], K[5])
    if msg.width <= 0 or msg.height <= 0 or fx <= 0 or fy <= 0:
        raise where.error([msg.width, msg.height, fx, fy], "CameraInfo has no usable size or focal length")
    if D.any() and not P.any():
        log.warning("%s: distortion without P; the frames must already be rectified", where)
    return Camera(int(msg.width), int(msg.height), float(fx), float(fy), float(cx), float(cy))


def image_to_rgb(msg, msgtype: str, where: Where) -> np.ndarray:
    """RGB uint8 ``(H, W, 3)`` of an Image or CompressedImage message."""
    if msgtype.endswith("CompressedImage"):
        bgr = cv2.imdecode(np.frombuffer(msg.data, dtype=np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            raise where.error(msg.format, "compressed image cannot be decoded")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    enc = msg.encoding.lower()
    if enc not in ENCODINGS:
        raise where.error(msg.encoding, f"unsupported image encoding; use one of {', '.join(ENCODINGS)}")
    ch, code = ENCODINGS[enc]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < w * ch or data.size < h * step:
        raise where.error(data.size, f"image data too short for {w}x{h} {enc} with step {step}")
    img = np.ascontiguousarray(data[:h * step].reshape(h, step)[:, :w * ch].reshape(h, w, ch))
    return img if code is None else cv2.cvtColor(img[..., 0] if ch == 1 else img, code)


class _Scan:
    """State of the first pass over a bag."""

    def __init__(self, spec: RobotSpec, want_pose: bool):
        self.images: list[ImageRef] = []
        self.image_order = StreamBuilder("image", 0)
        self.joints = StreamBuilder("joint_states", spec.num_joints)
        self.poses = StreamBuilder("camera pose", 7) if want_pose else None
        self.camera: Camera | None = None
        self.counts: Counter = Counter()
        self.extra: set[str] = set()
        self.other_devices: set[str] = set()


def _scan(reader: AnyReader, bag: str, roles: dict[str, str], spec: RobotSpec, opts: ImportOptions,
          stamp_mode: str) -> _Scan:
    """First pass: every message of the chosen topics except image pixels."""
    scan = _Scan(spec, "pose" in roles.values())
    conns = [c for c in reader.connections if c.topic in roles]
    per_conn: Counter = Counter()
    for conn, bag_ns, rawdata in reader.messages(connections=conns):
        role, index = roles[conn.topic], scan.counts[conn.topic]
        scan.counts[conn.topic] += 1
        per_conn[conn.id] += 1
        if role == "info" and scan.camera is not None:
            continue
        msg = reader.deserialize(rawdata, conn.msgtype)
        where = Where(bag, topic=conn.topic, index=index)
        where = Where(bag, topic=conn.topic, index=index, stamp_ns=message_stamp(msg, bag_ns, stamp_mode, where))
        _take(scan, role, msg, where, (conn.id, per_conn[conn.id] - 1), spec, opts)
    return scan


def _take(scan: _Scan, role: str, msg, where: Where, key, spec: RobotSpec, opts: ImportOptions) -> None:
    """Add one deserialized message to the scan."""
    if role == "image":
        scan.image_order.add(where.stamp_ns, (), where)
        scan.images.append(ImageRef(where.stamp_ns, where, key))
    elif role == "joints":
        values, names = joint_sample(msg, spec, where, opts.ignore_joints)
        if values is None:
            scan.counts["joint messages without robot joints"] += 1
            scan.other_devices.update(names)
        else:
            scan.extra.update(names)
            scan.joints.add(where.stamp_ns, values, where)
    elif role == "pose":
        pose = pose_sample(msg)
        problem = pose_problem(pose)
        scan.poses.check_order(where.stamp_ns, where)
        if problem:
            log.warning("%s: %s; pose sample dropped", where, problem)
            scan.counts["invalid pose samples"] += 1
        else:
            scan.poses.add(where.stamp_ns, pose, where)
    elif role == "info":
        scan.camera = camera_from_info(msg, where)


def _decoder(reader: AnyReader, topic: str):
    """Second pass: ``decode(refs)`` yields ``(ref, rgb)`` for the wanted image messages."""
    def decode(refs: list[ImageRef]) -> Iterator[tuple[ImageRef, np.ndarray]]:
        wanted = {ref.key: ref for ref in refs}
        conns = [c for c in reader.connections if c.topic == topic]
        per_conn: Counter = Counter()
        for conn, _, rawdata in reader.messages(connections=conns):
            key = (conn.id, per_conn[conn.id])
            per_conn[conn.id] += 1
            ref = wanted.pop(key, None)
            if ref is not None:
                yield ref, image_to_rgb(reader.deserialize(rawdata, conn.msgtype), conn.msgtype, ref.where)
            if not wanted:
                return
    return decode


def read_bag(reader: AnyReader, bag: str, opts: ImportOptions, image_topic: str | None, joint_topic: str,
             pose_topic: str | None, camera_info_topic: str | None, stamp: str) -> RawRecording:
    """Validate the topics and scan an open bag (see the module docstring)."""
    if stamp not in ("header", "bag"):
        raise ValueError(f"stamp must be 'header' or 'bag', got {stamp!r}")
    if (pose_topic is None) == (opts.camera_pose is None):
        raise ValueError("give exactly one of a pose topic (--pose-topic) and a fixed camera pose (--camera-pose)")
    spec = get_robot(opts.robot)
    roles = {find_topic(reader, bag, image_topic, IMAGE_TYPES, "image"): "image",
             find_topic(reader, bag, joint_topic, JOINT_TYPES, "joint state"): "joints"}
    if pose_topic is not None:
        roles[find_topic(reader, bag, pose_topic, POSE_TYPES, "camera pose")] = "pose"
    info = None if opts.camera is not None else find_topic(reader, bag, camera_info_topic, INFO_TYPES,
                                                           "camera info", required=False)
    if info is not None:
        roles[info] = "info"
    scan = _scan(reader, bag, roles, spec, opts, stamp)
    if scan.other_devices:
        log.info("ignored JointState messages without %s joints (names %s)", spec.name, sorted(scan.other_devices))
    ignored = {"extra_joints": sorted(scan.extra),
               "joint_messages_without_robot_joints": scan.counts["joint messages without robot joints"]}
    if pose_topic is not None:
        ignored["invalid_pose_samples"] = scan.counts["invalid pose samples"]
    image = next(t for t, r in roles.items() if r == "image")
    return RawRecording(bag, "bag", scan.images, scan.joints, scan.poses, _decoder(reader, image), scan.camera,
                        f"CameraInfo topic {info}" if info else "", f"topic {pose_topic}" if pose_topic
                        else "fixed camera pose", ignored)


def import_bag(bag: str | Path, out: str | Path, robot: str, *, image_topic: str | None = None,
               joint_topic: str = "/joint_states", pose_topic: str | None = None,
               camera_info_topic: str | None = None, stamp: str = "header", **options) -> dict:
    """Import a ROS 1 or ROS 2 bag into the recording ``out``; returns the summary dict.

    ``image_topic`` / ``camera_info_topic`` default to the bag's only topic of that type (no
    CameraInfo is needed when ``camera`` is given). Exactly one of ``pose_topic`` and
    ``camera_pose`` is required. ``options`` are :class:`~armpose.importers.assemble.ImportOptions`
    fields. Raises :class:`~armpose.importers.common.SourceError` naming the bag, topic, message
    index and stamp for bad input.
    """
    opts = ImportOptions(robot=robot, **options)
    check_output(Path(out), opts.overwrite)
    with open_bag(bag) as reader:
        raw = read_bag(reader, str(bag), opts, image_topic, joint_topic, pose_topic, camera_info_topic, stamp)
        return assemble(raw, Path(out), opts)

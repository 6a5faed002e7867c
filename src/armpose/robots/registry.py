"""The robot registry: each robot type is a YAML description, not code.

A description names the URDF source, the ordered joints whose positions are
estimated, the base link, the joint limits (radians), joints held fixed (such
as the Panda fingers) and the real robot's appearance. Adding a robot type is a
new file in ``robots/configs/`` or a call to :func:`register`.
"""
from __future__ import annotations

import dataclasses
import hashlib
import os
import re
import site
import tempfile
from functools import lru_cache
from pathlib import Path
from typing import Any

import yaml

CONFIG_DIR = Path(__file__).parent / "configs"


class UnknownRobotError(KeyError):
    """Raised for a robot type that no description defines."""


@dataclasses.dataclass(frozen=True)
class Appearance:
    """Link colours as RGBA in [0, 1]; ``default_color`` None keeps the meshes' own."""

    default_color: tuple[float, ...] | None = None
    link_colors: dict[str, tuple[float, ...]] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class RobotSpec:
    """One robot type. Joint angles in radians, lengths in metres."""

    name: str
    family: str
    urdf: dict[str, str]
    base_link: str
    joints: tuple[str, ...]
    joint_limits: tuple[tuple[float, float], ...]
    fixed_joints: dict[str, float]
    reach: float
    appearance: Appearance
    render_max_faces: int = 4000  # triangles per visual mesh for rendering; 0 = full meshes

    @property
    def num_joints(self) -> int:
        return len(self.joints)

    def urdf_path(self) -> Path:
        """A URDF file that PyBullet and pytorch-kinematics can load as is.

        ``package://`` mesh URIs are rewritten to absolute paths in a cached
        copy; URDFs without them are used in place.
        """
        return resolved_urdf(resolve_source(self.urdf["source"], self.urdf["path"]))

    def urdf_bytes(self) -> bytes:
        return self.urdf_path().read_bytes()

    def render_urdf_path(self) -> Path:
        """The URDF PyBullet renders: visual meshes simplified to ``render_max_faces`` (cached)."""
        from armpose.robots.meshes import render_urdf
        return render_urdf(self.urdf_path(), self.render_max_faces)


def source_root(source: str) -> Path:
    """The folder a URDF ``source`` name refers to."""
    if source == "pybullet_data":
        import pybullet_data
        return Path(pybullet_data.getDataPath())
    if source == "example-robot-data":
        for sp in site.getsitepackages() + [site.getusersitepackages()]:
            cand = Path(sp) / "cmeel.prefix" / "share" / "example-robot-data"
            if cand.is_dir():
                return cand
        raise FileNotFoundError("example-robot-data is not installed (pip install -r environment.txt)")
    if source == "file":
        return Path("/")
    raise ValueError(f"unknown URDF source {source!r}; use pybullet_data, example-robot-data or file")


def resolve_source(source: str, path: str) -> Path:
    """Absolute path of ``path`` inside ``source`` (``file`` takes an absolute or cwd-relative path)."""
    full = Path(path) if source == "file" else source_root(source) / path
    if not full.exists():
        raise FileNotFoundError(f"URDF {full} (source {source!r}) does not exist")
    return full.resolve()


def resolved_urdf(path: Path) -> Path:
    """``path`` itself, or a cached copy whose mesh paths are all absolute.

    ``package://NAME/`` URIs (NAME a known source, else a folder next to the URDF) and paths relative to the URDF's folder
    are rewritten, so the copy loads from any folder in PyBullet and pytorch-kinematics.
    """
    text = path.read_text()
    if "package://" not in text:
        return path

    def absolute(match: re.Match) -> str:
        name = match.group(1)
        if name.startswith("package://"):
            pkg, _, rest = name[len("package://"):].partition("/")
            try:
                return f'filename="{source_root(pkg) / rest}"'
            except ValueError:  # not a known package: PyBullet's reading, relative to the URDF
                return f'filename="{path.parent / pkg / rest}"'
        if os.path.isabs(name):
            return match.group(0)
        return f'filename="{path.parent / name}"'

    text = re.sub(r'filename="([^"]+)"', absolute, text)
    digest = hashlib.sha1(text.encode()).hexdigest()[:12]
    out = Path(tempfile.gettempdir()) / "armpose-urdf" / f"{path.stem}-{digest}.urdf"
    if not out.exists():
        from armpose.io import atomic_write_text
        atomic_write_text(out, text)
    return out


def spec_from_dict(cfg: dict[str, Any]) -> RobotSpec:
    """Build a :class:`RobotSpec` from a parsed description, with clear errors."""
    required = ["name", "family", "urdf", "base_link", "joints", "joint_limits"]
    missing = [k for k in required if k not in cfg]
    if missing:
        raise ValueError(f"robot description {cfg.get('name', '?')!r} lacks {missing}")
    if len(cfg["joint_limits"]) != len(cfg["joints"]):
        raise ValueError(f"robot {cfg['name']!r}: {len(cfg['joints'])} joints but "
                         f"{len(cfg['joint_limits'])} joint_limits")
    app = cfg.get("appearance") or {}
    return RobotSpec(
        name=cfg["name"], family=cfg["family"], urdf=dict(cfg["urdf"]), base_link=cfg["base_link"],
        joints=tuple(cfg["joints"]),
        joint_limits=tuple((float(lo), float(hi)) for lo, hi in cfg["joint_limits"]),
        fixed_joints={k: float(v) for k, v in (cfg.get("fixed_joints") or {}).items()},
        reach=float(cfg.get("reach", 1.0)),
        render_max_faces=int(cfg.get("render_max_faces", 4000)),
        appearance=Appearance(
            default_color=tuple(app["default_color"]) if app.get("default_color") else None,
            link_colors={k: tuple(v) for k, v in (app.get("link_colors") or {}).items()},
        ),
    )


_EXTRA: dict[str, RobotSpec] = {}


@lru_cache(maxsize=None)
def _builtin() -> dict[str, RobotSpec]:
    specs = {}
    for path in sorted(CONFIG_DIR.glob("*.yaml")):
        spec = spec_from_dict(yaml.safe_load(path.read_text()))
        specs[spec.name] = spec
    return specs


def register(cfg: dict[str, Any] | RobotSpec) -> RobotSpec:
    """Add a robot type at run time (e.g. from a test or a user's own YAML)."""
    spec = cfg if isinstance(cfg, RobotSpec) else spec_from_dict(cfg)
    _EXTRA[spec.name] = spec
    return spec


def register_file(path: str | os.PathLike) -> RobotSpec:
    """Register the robot described in a YAML file."""
    return register(yaml.safe_load(Path(path).read_text()))


def all_robots() -> dict[str, RobotSpec]:
    """Every known robot type by name."""
    return {**_builtin(), **_EXTRA}


def get_robot(name: str) -> RobotSpec:
    """The description of robot type ``name``; raises :class:`UnknownRobotError`."""
    robots = all_robots()
    if name not in robots:
        raise UnknownRobotError(f"unknown robot type {name!r}; known: {', '.join(sorted(robots))}")
    return robots[name]

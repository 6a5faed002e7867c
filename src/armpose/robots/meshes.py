"""Simplified visual meshes for fast CPU rendering.

PyBullet's TinyRenderer spends most of a robot render on triangle setup: a UR5's visual
meshes hold about 95,000 triangles. :func:`render_urdf` writes a cached copy of a URDF whose
visual meshes are decimated (fast-simplification, quadric error) to at most ``max_faces``
triangles per mesh, one OBJ and one URDF ``<visual>`` per material group, so that mesh
colours survive. Both the renderer and
the mask labels use this copy, so labels match the rendered pixels exactly; a test bounds the
difference to the full-resolution meshes. Kinematics always read the original URDF.
"""
from __future__ import annotations

import copy
import hashlib
import os
import re
import shutil
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

MESH_VERSION = 5
MIN_GROUP_FACES = 400


def _groups(path: Path):
    """(vertices, faces, rgb) per material group of a mesh file, in the file's own frame and units."""
    import trimesh
    scene = trimesh.load(str(path), force="scene", process=False)
    out = []
    for node in scene.graph.nodes_geometry:
        T, name = scene.graph[node]
        mesh = scene.geometry[name]
        if len(mesh.faces) == 0:
            continue
        verts = trimesh.transform_points(np.asarray(mesh.vertices, float), T)
        mat = getattr(mesh.visual, "material", None)
        color = getattr(mat, "diffuse", None)
        if color is None:
            color = getattr(mat, "baseColorFactor", None)
        rgb = (np.asarray(color[:3], float) / 255.0) if color is not None else np.full(3, 0.8)
        out.append((verts, np.asarray(mesh.faces, np.int64), rgb))
    return out


def _weld(verts: np.ndarray, faces: np.ndarray, tol: float = 1e-6):
    """Merge vertices closer than ``tol`` metres (mesh files often store triangle soups,
    which quadric decimation would tear apart); drops degenerate faces."""
    key = np.round(verts / tol).astype(np.int64)
    uniq, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    faces = inverse.reshape(-1)[faces]
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    return verts[first], faces[keep]


def _decimate(verts: np.ndarray, faces: np.ndarray, max_faces: int):
    if len(faces) <= max_faces:
        return verts, faces
    verts, faces = _weld(verts, faces)
    import fast_simplification
    v, f = fast_simplification.simplify(verts.astype(np.float32), faces.astype(np.int32),
                                        target_count=max_faces)
    return np.asarray(v, float), np.asarray(f, np.int64)


def write_obj(verts: np.ndarray, faces: np.ndarray, out: Path) -> None:
    """Write one triangle mesh as a plain OBJ (PyBullet renders one material per file reliably)."""
    lines = ["v {:.6f} {:.6f} {:.6f}".format(*v) for v in verts]
    lines += ["f {} {} {}".format(*(f + 1)) for f in faces]
    out.write_text("\n".join(lines) + "\n")


def simplify_mesh(src: Path, stem: Path, max_faces: int) -> list[tuple[Path, np.ndarray]]:
    """Decimate ``src`` to at most ``max_faces`` triangles in all, one OBJ per material group
    (``stem_gK.obj``). Returns ``[(path, rgb)]``, rgb in [0, 1]."""
    groups = _groups(src)
    total = sum(len(f) for _, f, _ in groups) or 1
    out = []
    for k, (verts, faces, rgb) in enumerate(groups):
        # a group's share of the budget, but never below MIN_GROUP_FACES: small parts keep their shape
        v, f = _decimate(verts, faces, max(MIN_GROUP_FACES, int(max_faces * len(faces) / total)))
        if len(f):
            path = stem.with_name(f"{stem.name}_g{k}.obj")
            write_obj(v, f, path)
            out.append((path, rgb))
    return out


def render_urdf(urdf: Path, max_faces: int) -> Path:
    """A cached copy of ``urdf`` (absolute mesh paths) with simplified visual meshes.

    ``max_faces`` <= 0 returns ``urdf`` unchanged. The cache lives in the system temp folder,
    keyed by the URDF's content and the budget, and is written atomically (folder rename), so
    concurrent workers are safe.
    """
    if max_faces <= 0:
        return urdf
    text = urdf.read_text()
    key = hashlib.sha1(f"{MESH_VERSION}:{max_faces}:{text}".encode()).hexdigest()[:12]
    final = Path(tempfile.gettempdir()) / "armpose-meshes" / f"{urdf.stem}-{key}"
    target = final / urdf.name
    if target.exists():
        return target
    final.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f".{final.name}.", dir=final.parent))
    try:
        root = ET.fromstring(text)
        done: dict[str, list] = {}
        for link in root.findall("link"):
            for visual in link.findall("visual"):
                mesh = visual.find("geometry/mesh")
                if mesh is None:
                    continue
                src = mesh.get("filename")
                if src not in done:
                    stem = work / f"mesh{len(done):03d}_{re.sub(r'[^A-Za-z0-9]', '_', Path(src).stem)}"
                    done[src] = simplify_mesh(urdf.parent / src, stem, max_faces)  # absolute src stays so
                index = list(link).index(visual)
                link.remove(visual)
                for k, (path, rgb) in enumerate(done[src]):
                    part = copy.deepcopy(visual)
                    part.find("geometry/mesh").set("filename", str(final / path.name))
                    if len(done[src]) > 1 or part.find("material") is None:
                        for m in part.findall("material"):
                            part.remove(m)
                        mat = ET.SubElement(part, "material", name=f"{path.stem}")
                        ET.SubElement(mat, "color", rgba="{:.4f} {:.4f} {:.4f} 1".format(*rgb))
                    link.insert(index + k, part)
        for collision in root.iter("collision"):
            for mesh in collision.iter("mesh"):
                mesh.set("filename", str(urdf.parent / mesh.get("filename")))
        (work / urdf.name).write_text(ET.tostring(root, encoding="unicode"))
        try:
            os.rename(work, final)
        except OSError:  # another process won the race; its copy is identical
            pass
    finally:
        if work.exists():
            shutil.rmtree(work)
    return target

"""dvc.yaml declares the code each stage runs: every armpose module a stage imports, at any depth
and inside functions too, is one of its ``deps`` (a file, or below a folder). Otherwise editing
that module would not make ``dvc repro`` run the stage again."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
STAGES = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]


def _module_file(name: str) -> Path | None:
    """The file of armpose module ``name`` (a package's ``__init__.py``), or None if not a module."""
    base = SRC.joinpath(*name.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.exists():
            return path
    return None


def _imports(path: Path) -> set[str]:
    """Every ``armpose...`` module named by an import anywhere in ``path`` (``from a import b``
    counts ``a.b`` too when ``b`` is a module)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names if a.name.startswith("armpose")}
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("armpose") and not node.level:
            names.add(node.module)
            names |= {f"{node.module}.{a.name}" for a in node.names if _module_file(f"{node.module}.{a.name}")}
    return names


def imported_files(module: str) -> set[Path]:
    """The files of ``module`` and of every armpose module it imports, transitively, with the
    ``__init__.py`` of the packages on the way."""
    seen, todo = set(), [module]
    while todo:
        name = todo.pop()
        parts = name.split(".")
        for k in range(1, len(parts) + 1):
            path = _module_file(".".join(parts[:k]))
            if path is not None and path not in seen:
                seen.add(path)
                todo.extend(_imports(path))
    return seen


def _covered(path: Path, deps: list[str]) -> bool:
    rel = path.relative_to(ROOT).as_posix()
    return any(rel == d or rel.startswith(d.rstrip("/") + "/") for d in deps)


@pytest.mark.parametrize("stage", sorted(STAGES))
def test_stage_deps_cover_the_code_it_imports(stage):
    cmd = STAGES[stage]["cmd"]
    assert cmd.startswith("python -m armpose."), cmd
    deps = [d if isinstance(d, str) else next(iter(d)) for d in STAGES[stage].get("deps", [])]
    missing = sorted(p.relative_to(ROOT).as_posix() for p in imported_files(cmd.split()[2])
                     if p.name != "__init__.py" and not _covered(p, deps))
    assert not missing, f"dvc.yaml stage {stage!r} runs code it does not list in deps: {missing}"


def test_the_import_walk_finds_lazy_imports():
    files = {p.relative_to(ROOT).as_posix() for p in imported_files("armpose.stages.evaluate")}
    assert "src/armpose/sequence_eval.py" in files, "imported inside a function"
    assert "src/armpose/intrinsics.py" in files, "reached through sequence_eval -> sequence"

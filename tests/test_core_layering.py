"""Layering of the numerical core: no module of core/, methods/, sim/ or geometry imports
another module's private (``_x``) names, and the simulator does not depend on core/."""

from __future__ import annotations

import ast
from pathlib import Path

import evmotion

PKG = Path(evmotion.__file__).resolve().parent
CHECKED = ["core", "methods", "sim", "geometry.py"]


def _files():
    for part in CHECKED:
        p = PKG / part
        yield from ([p] if p.is_file() else sorted(p.rglob("*.py")))


def _imports(path):
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            yield node.module, [a.name for a in node.names]
        elif isinstance(node, ast.Import):
            yield from ((a.name, []) for a in node.names)


def _is_submodule(module: str, name: str) -> bool:
    """Whether ``from module import name`` imports a module of that package (a package's
    private modules are for its siblings), not a private name of a module."""
    base = PKG.parent.joinpath(*module.split("."))
    return (base / f"{name}.py").is_file() or (base / name / "__init__.py").is_file()


def test_no_private_names_imported_across_modules():
    bad = [f"{f.relative_to(PKG)}: from {mod} import {n}"
           for f in _files() for mod, names in _imports(f) if mod.startswith("evmotion")
           for n in names if n.startswith("_") and not _is_submodule(mod, n)]
    assert bad == []


def test_sim_and_geometry_do_not_import_core():
    bad = [f"{f.relative_to(PKG)}: {mod}" for f in _files()
           if f.relative_to(PKG).parts[0] in ("sim", "geometry.py")
           for mod, _ in _imports(f) if mod.startswith(("evmotion.core", "evmotion.methods"))]
    assert bad == []

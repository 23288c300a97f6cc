"""Layering of the package: no module of evmotion (core/, methods/, sim/, io/, cli/, ...
every one) imports another module's private (``_x``) names, imports a private module, or
reaches into an imported module's private attributes (``mod._x``); and the simulator does
not depend on core/."""

from __future__ import annotations

import ast
from pathlib import Path

import evmotion

PKG = Path(evmotion.__file__).resolve().parent
CHECKED = ["core", "methods", "sim", "geometry.py"]


def _files(parts=None):
    if parts is None:
        yield from sorted(PKG.rglob("*.py"))
        return
    for part in parts:
        p = PKG / part
        yield from ([p] if p.is_file() else sorted(p.rglob("*.py")))


def _imports(path):
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            yield node.module, [a.name for a in node.names]
        elif isinstance(node, ast.Import):
            yield from ((a.name, []) for a in node.names)


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _module_aliases(tree) -> dict[str, str]:
    """Local names bound to evmotion modules by the imports of ``tree``: name -> module."""
    out = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("evmotion"):
                    out[a.asname or a.name.split(".")[0]] = a.name if a.asname else "evmotion"
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("evmotion"):
            for a in node.names:
                if _is_module(f"{node.module}.{a.name}"):
                    out[a.asname or a.name] = f"{node.module}.{a.name}"
    return out


def _is_module(dotted: str) -> bool:
    base = PKG.parent.joinpath(*dotted.split("."))
    return base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()


def private_uses(source: str, rel: str) -> list[str]:
    """Every use in ``source`` (the module at ``rel``) of another evmotion module's private
    name or of a private module: ``from m import _x``, ``import m._x`` /
    ``from m._x import y``, ``m._x``."""
    tree = ast.parse(source)
    bad = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("evmotion"):
            if any(_private(p) for p in node.module.split(".")):
                bad.append(f"{rel}:{node.lineno}: from {node.module} import ...")
            bad += [f"{rel}:{node.lineno}: from {node.module} import {a.name}"
                    for a in node.names if _private(a.name)]
        elif isinstance(node, ast.Import):
            bad += [f"{rel}:{node.lineno}: import {a.name}" for a in node.names
                    if a.name.startswith("evmotion") and any(map(_private, a.name.split(".")))]
    aliases = _module_aliases(tree)
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and _private(node.attr):
            root = node.value
            while isinstance(root, ast.Attribute):
                root = root.value
            if isinstance(root, ast.Name) and root.id in aliases:
                bad.append(f"{rel}:{node.lineno}: {ast.unparse(node)}")
    return bad


def test_no_private_names_used_across_modules():
    bad = [line for f in _files() for line in private_uses(f.read_text(), f.relative_to(PKG))]
    assert bad == []


def test_the_check_finds_private_uses():
    # the scan itself: each form of reaching into another module is reported
    src = ("from evmotion.core import warps\nfrom evmotion.core.iwe import _x\n"
           "from evmotion.methods._k import f\nimport evmotion.core._y\n"
           "z = warps._helper\n")
    found = private_uses(src, "methods/probe.py")
    assert [s.split(": ", 1)[1] for s in found] == [
        "from evmotion.core.iwe import _x", "from evmotion.methods._k import ...",
        "import evmotion.core._y", "warps._helper"]


def test_sim_and_geometry_do_not_import_core():
    bad = [f"{f.relative_to(PKG)}: {mod}" for f in _files(CHECKED)
           if f.relative_to(PKG).parts[0] in ("sim", "geometry.py")
           for mod, _ in _imports(f) if mod.startswith(("evmotion.core", "evmotion.methods"))]
    assert bad == []

"""List the functions of ``src/evmotion`` with many parameters (an AST scan, nothing runs).

    python benchmarks/scan_params.py [--min 15] [--numba] [ROOT]

One line per function, ``path:line name P params, L lines (C of code)``: ``P`` counts the
positional and keyword parameters less ``self``/``cls`` (``*args``/``**kw`` count one
each), ``L`` the lines of the definition, ``C`` those from the first statement after the
docstring. Numba kernels (decorated ``njit``/``jit``) are left out, or with ``--numba``
listed alone (their parameters are what a compiled call passes one by one).
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "src" / "evmotion"


def _is_numba(fn: ast.FunctionDef) -> bool:
    for dec in fn.decorator_list:
        node = dec.func if isinstance(dec, ast.Call) else dec
        name = node.attr if isinstance(node, ast.Attribute) else getattr(node, "id", "")
        if name in ("njit", "jit", "vectorize", "guvectorize"):
            return True
    return False


def _n_params(fn: ast.FunctionDef) -> int:
    a = fn.args
    names = [p.arg for p in a.posonlyargs + a.args + a.kwonlyargs]
    if names and names[0] in ("self", "cls"):
        names = names[1:]
    return len(names) + (a.vararg is not None) + (a.kwarg is not None)


def _code_start(fn: ast.FunctionDef) -> int:
    body = fn.body
    first = body[0]
    if (isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant)
            and isinstance(first.value.value, str) and len(body) > 1):
        return body[1].lineno
    return first.lineno


def scan(root: Path, minimum: int, numba: bool) -> list[str]:
    """The lines of the listing, sorted by path and line."""
    out = []
    for path in sorted(root.rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            if _is_numba(node) != numba or _n_params(node) < minimum:
                continue
            lines = node.end_lineno - node.lineno + 1
            code = node.end_lineno - _code_start(node) + 1
            out.append((str(path.relative_to(root)), node.lineno,
                        f"{node.name} {_n_params(node)} params, {lines} lines ({code} of code)"))
    return [f"{p}:{line} {rest}" for p, line, rest in sorted(out)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("root", nargs="?", type=Path, default=ROOT)
    ap.add_argument("--min", type=int, default=15, help="least number of parameters listed")
    ap.add_argument("--numba", action="store_true", help="list the numba kernels instead")
    args = ap.parse_args(argv)
    for line in scan(args.root, args.min, args.numba):
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""AST scan of ``src/evmotion``: functions with many parameters or long bodies.

Counts positional and keyword parameters (``*args`` and ``**kwargs`` count one each;
``self``/``cls`` do not) and the lines of code without the docstring. Numba kernels
(functions decorated with ``njit``/``jit``/``vectorize``) are left out of the parameter
list: they take flat arrays by design. Run: ``python benchmarks/scan_params.py
[--min-params 15] [--min-code 80] [paths...]``; prints ``file:line name N params, L lines
(C of code)``, one function a line.
"""

from __future__ import annotations

import argparse
import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "evmotion"
KERNEL_DECORATORS = {"njit", "jit", "vectorize", "guvectorize", "stencil"}


def _is_kernel(fn: ast.AST) -> bool:
    for d in fn.decorator_list:
        node = d.func if isinstance(d, ast.Call) else d
        name = node.attr if isinstance(node, ast.Attribute) else getattr(node, "id", "")
        if name in KERNEL_DECORATORS:
            return True
    return False


def n_params(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    a = fn.args
    names = [p.arg for p in (*a.posonlyargs, *a.args, *a.kwonlyargs)]
    n = len(names) - (1 if names and names[0] in ("self", "cls") else 0)
    return n + (a.vararg is not None) + (a.kwarg is not None)


def code_lines(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> tuple[int, int]:
    """Total lines of ``fn`` and its lines of code: the body less the docstring (the
    signature and decorators are not code)."""
    total = fn.end_lineno - fn.lineno + 1
    body = fn.body
    if len(body) > 1 and isinstance(body[0], ast.Expr) \
            and isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str):
        body = body[1:]
    return total, fn.end_lineno - body[0].lineno + 1


def scan(paths, min_params: int, min_code: int) -> list[tuple[str, int, str, int, int, int]]:
    rows = []
    for path in paths:
        files = [path] if path.is_file() else sorted(path.rglob("*.py"))
        for f in files:
            tree = ast.parse(f.read_text())
            for node in ast.walk(tree):
                if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    continue
                n = n_params(node)
                total, code = code_lines(node)
                if (n >= min_params and not _is_kernel(node)) or code >= min_code:
                    rel = f.relative_to(SRC) if f.is_relative_to(SRC) else f
                    rows.append((str(rel), node.lineno, node.name, n, total, code))
    return sorted(rows)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("paths", nargs="*", type=Path, default=[SRC])
    ap.add_argument("--min-params", type=int, default=15)
    ap.add_argument("--min-code", type=int, default=10 ** 9,
                    help="also list functions with at least this many lines of code")
    args = ap.parse_args(argv)
    for rel, line, name, n, total, code in scan(args.paths, args.min_params, args.min_code):
        print(f"{rel}:{line} {name} {n} params, {total} lines ({code} of code)")


if __name__ == "__main__":
    main()

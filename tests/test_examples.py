"""Every gallery script in examples/ runs and writes the pictures it promises (``PNGS``).

``make docs`` runs the same scripts and the docs pages show their pictures; this keeps them
working between documentation builds. A script that needs an optional extra names it in
``NEEDS`` and is skipped when it is absent.
"""

from __future__ import annotations

import ast
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
SCRIPTS = sorted(EXAMPLES.glob("*.py"))


def _constant(script: Path, name: str):
    """Module-level constant ``name`` of ``script``, read without running it."""
    for node in ast.parse(script.read_text()).body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == name
                                                for t in node.targets):
            return ast.literal_eval(node.value)
    return None


def test_gallery_is_there():
    assert len(SCRIPTS) >= 5, SCRIPTS
    for script in SCRIPTS:
        pngs = _constant(script, "PNGS")
        assert pngs and all(p.endswith(".png") for p in pngs), f"{script.name}: PNGS {pngs}"
        assert ast.get_docstring(ast.parse(script.read_text())), f"{script.name}: no docstring"


@pytest.mark.slow
@pytest.mark.parametrize("script", SCRIPTS, ids=[s.stem for s in SCRIPTS])
def test_example_writes_its_pictures(script, tmp_path):
    needs = _constant(script, "NEEDS")
    if needs and importlib.util.find_spec(needs) is None:
        pytest.skip(f"{script.name} needs the optional package {needs!r}")
    out = tmp_path / "out"
    env = {**os.environ, "MPLBACKEND": "Agg"}
    src = str(Path(__file__).resolve().parents[1] / "src")
    env["PYTHONPATH"] = os.pathsep.join([src, *filter(None, [env.get("PYTHONPATH")])])
    run = subprocess.run([sys.executable, str(script), str(out)], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    for name in _constant(script, "PNGS"):
        png = out / name
        assert png.is_file() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
        assert png.stat().st_size > 2000, f"{name}: {png.stat().st_size} bytes, nearly empty"
    assert not list(tmp_path.glob("*.png")), "pictures written outside the folder given"

"""Sphinx configuration of the evmotion documentation (built by ``make docs``, offline)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS.parent / "src"))

project = "evmotion"
author = "evmotion developers"
copyright = "evmotion developers, MIT licence"
release = version = "0.1.0"

extensions = ["sphinx.ext.autodoc", "sphinx.ext.napoleon"]
# no network at build time (no intersphinx), and the pages load nothing from outside
exclude_patterns = ["_build", "_gallery", "Thumbs.db", ".DS_Store"]
html_theme = "alabaster"
html_title = "evmotion"
html_static_path: list[str] = []

napoleon_numpy_docstring = True
napoleon_google_docstring = False
napoleon_use_rtype = False
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_default_options: dict[str, object] = {}
# optional extras: document their modules from the docstrings even where they are absent
autodoc_mock_imports = [m for m in ("torch", "cv2", "imageio_ffmpeg", "rosbags", "distributed")
                        if importlib.util.find_spec(m) is None]
nitpicky = False

# Guides written alongside the code; listed in the index's "Guides" toctree when present.
OPTIONAL_GUIDES = ("adding_a_warp", "cluster")
_MARK = ".. optional guides (filled in by conf.py)"


def _add_optional_guides(app, docname: str, source: list[str]) -> None:
    if docname != "index":
        return
    present = [g for g in OPTIONAL_GUIDES if (DOCS / f"{g}.rst").is_file()]
    lines = "".join(f"   {g}\n" for g in present)
    source[0] = source[0].replace(f"   {_MARK}\n", lines)


def setup(app) -> None:
    app.connect("source-read", _add_optional_guides)

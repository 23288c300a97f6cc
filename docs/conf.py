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


_CLI_MARK = ".. command reference (filled in by conf.py)"
# the width argparse wraps the help at here (it reads COLUMNS): the page must not depend
# on the terminal the documentation was built in
_CLI_COLUMNS = "92"


def _help(parser, argv: list[str]) -> str:
    """What ``evmotion ARGV`` prints (``--help`` exits the parser)."""
    import contextlib
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
        parser.parse_args(argv)
    return out.getvalue()


def _cli_reference() -> str:
    """One section per command: its ``--help``, from the parser ``evmotion`` itself runs."""
    import os

    os.environ["COLUMNS"] = _CLI_COLUMNS
    from evmotion.cli import COMMANDS, build_parser

    parser = build_parser()
    parts = []
    for title, argv in [("evmotion", ["--help"])] + [(f"evmotion {c}", [c, "--help"])
                                                      for c in COMMANDS]:
        text = _help(parser, argv)
        body = "".join(f"   {line}".rstrip() + "\n" for line in text.splitlines())
        parts.append(f"{title}\n{'-' * len(title)}\n\n.. code-block:: text\n\n{body}\n")
    return "\n".join(parts)


def _add_cli_reference(app, docname: str, source: list[str]) -> None:
    if docname == "cli":
        source[0] = source[0].replace(_CLI_MARK, _cli_reference())


def setup(app) -> None:
    app.connect("source-read", _add_optional_guides)
    app.connect("source-read", _add_cli_reference)

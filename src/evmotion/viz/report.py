"""A small static HTML report: headings, text, figures (referenced relatively) and tables."""

from __future__ import annotations

import base64
import html
import math
import mimetypes
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

from evmotion.errors import FormatError, ParameterError
from evmotion.utils import atomic_write_text

__all__ = ["HtmlReport"]

_CSS = """
body { font-family: sans-serif; max-width: 70em; margin: 1em auto; padding: 0 1em; }
figure { display: inline-block; margin: 0.5em; vertical-align: top; }
figure img { max-width: 100%; border: 1px solid #ccc; }
figcaption, caption { font-size: 0.9em; color: #333; }
table { border-collapse: collapse; margin: 1em 0; }
td, th { border: 1px solid #bbb; padding: 0.2em 0.6em; text-align: right; }
th { background: #eee; }
"""


def _cell(v) -> str:
    if isinstance(v, float):
        return "&ndash;" if math.isnan(v) else f"{v:.4g}"
    if hasattr(v, "item") and getattr(v, "ndim", 1) == 0:
        return _cell(v.item())
    return html.escape(str(v))


class HtmlReport:
    """Collect figures, tables and text, then write one self-contained HTML page.

    By default the figures are embedded in the page (base64 ``data:`` URIs), so the HTML
    file alone shows everything wherever it is copied. With ``embed=False`` they are linked
    by paths relative to the page's own folder: keep the pictures beside it when moving it.
    Either way a figure file missing when the page is written is an error, not a broken
    image.

    Parameters
    ----------
    title : str
        Page title and top heading.
    embed : bool
        Embed the figures (default) or link them relatively.

    Examples
    --------
    >>> rep = HtmlReport("Flow on sim.h5")
    >>> rep.add_text("Window 0, multicm.")
    >>> rep.add_table([{"method": "multicm", "AEE": 0.81}], caption="Accuracy")
    >>> import numpy as np
    >>> from evmotion.viz import save_flow_png
    >>> pic = save_flow_png("flow_000.png", np.zeros((8, 8, 2)), max_speed=100.0)
    >>> rep.add_figure("flow_000.png", caption="Flow (px/s)")
    >>> rep.write("out/report.html").name
    'report.html'
    """

    def __init__(self, title: str, *, embed: bool = True):
        self.title = str(title)
        self.embed = bool(embed)
        self._items: list[tuple[str, object]] = []

    def add_heading(self, text: str, level: int = 2) -> None:
        """A section heading (``level`` 2-4)."""
        self._items.append(("heading", (str(text), min(max(int(level), 2), 4))))

    def add_text(self, text: str) -> None:
        """A paragraph of plain text (escaped; blank lines separate paragraphs)."""
        self._items.append(("text", str(text)))

    def add_figure(self, path: str | os.PathLike, caption: str = "") -> None:
        """An image file (PNG...); a relative ``path`` is taken from the current directory
        now, as any file argument, not from the page's folder."""
        self._items.append(("figure", (Path(path).resolve(), str(caption))))

    @property
    def figure_paths(self) -> list[Path]:
        """The figures added so far, in order."""
        return [item[0] for kind, item in self._items if kind == "figure"]

    def add_table(self, rows: Sequence[Mapping[str, object]], caption: str = "") -> None:
        """A table from a list of dicts (columns: union of keys in first-seen order)."""
        rows = [dict(r) for r in rows]
        if not rows:
            raise ParameterError("add_table needs at least one row")
        self._items.append(("table", (rows, str(caption))))

    def _figure_src(self, path: Path, base: Path) -> str:
        if not path.is_file():
            raise FormatError(path, "report figure not found (write it before the report)")
        if self.embed:
            mime = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
            return f"data:{mime};base64," + base64.b64encode(path.read_bytes()).decode("ascii")
        return Path(os.path.relpath(path, base)).as_posix()

    def render(self, base_dir: str | os.PathLike = ".") -> str:
        """The HTML text; linked figures (``embed=False``) get paths relative to
        ``base_dir``, the folder of the page."""
        base = Path(base_dir).resolve()
        t = html.escape(self.title)
        out = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
               f"<title>{t}</title>", f"<style>{_CSS}</style>", "</head>", "<body>",
               f"<h1>{t}</h1>"]
        for kind, item in self._items:
            if kind == "heading":
                text, level = item
                out.append(f"<h{level}>{html.escape(text)}</h{level}>")
            elif kind == "text":
                for para in item.split("\n\n"):
                    out.append(f"<p>{html.escape(para)}</p>")
            elif kind == "figure":
                path, caption = item
                src = html.escape(self._figure_src(path, base), quote=True)
                cap = html.escape(caption)
                img = f'<img src="{src}" alt="{cap}">'
                # a data URI is not a useful link target (and doubles the page's size)
                if not self.embed:
                    img = f'<a href="{src}">{img}</a>'
                out.append(f"<figure>{img}<figcaption>{cap}</figcaption></figure>")
            else:
                rows, caption = item
                cols: list[str] = []
                for r in rows:
                    cols += [k for k in r if k not in cols]
                out.append("<table>")
                if caption:
                    out.append(f"<caption>{html.escape(caption)}</caption>")
                out.append("<tr>" + "".join(f"<th>{html.escape(str(c))}</th>" for c in cols)
                           + "</tr>")
                for r in rows:
                    out.append("<tr>" + "".join(f"<td>{_cell(r.get(c, ''))}</td>" for c in cols)
                               + "</tr>")
                out.append("</table>")
        out += ["</body>", "</html>", ""]
        return "\n".join(out)

    def write(self, path: str | os.PathLike) -> Path:
        """Write the page atomically; returns its path."""
        path = Path(path)
        atomic_write_text(path, self.render(path.parent))
        return path

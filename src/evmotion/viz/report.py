"""A small static HTML report: headings, text, figures (referenced relatively) and tables."""

from __future__ import annotations

import html
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

from evmotion.errors import ParameterError
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

    Figures are referenced by paths relative to the page, so keep the PNGs beside (or
    below) the HTML file when moving it.

    Parameters
    ----------
    title : str
        Page title and top heading.

    Examples
    --------
    >>> rep = HtmlReport("Flow on sim.h5")
    >>> rep.add_text("Window 0, multicm.")
    >>> rep.add_table([{"method": "multicm", "AEE": 0.81}], caption="Accuracy")
    >>> rep.add_figure("out/flow_000.png", caption="Flow (px/s)")  # doctest: +SKIP
    >>> rep.write("out/report.html")  # doctest: +SKIP
    """

    def __init__(self, title: str):
        self.title = str(title)
        self._items: list[tuple[str, object]] = []

    def add_heading(self, text: str, level: int = 2) -> None:
        """A section heading (``level`` 2-4)."""
        self._items.append(("heading", (str(text), min(max(int(level), 2), 4))))

    def add_text(self, text: str) -> None:
        """A paragraph of plain text (escaped; blank lines separate paragraphs)."""
        self._items.append(("text", str(text)))

    def add_figure(self, path: str | os.PathLike, caption: str = "") -> None:
        """An image file (PNG...), linked relatively from the page when written."""
        self._items.append(("figure", (Path(path).resolve(), str(caption))))

    def add_table(self, rows: Sequence[Mapping[str, object]], caption: str = "") -> None:
        """A table from a list of dicts (columns: union of keys in first-seen order)."""
        rows = [dict(r) for r in rows]
        if not rows:
            raise ParameterError("add_table needs at least one row")
        self._items.append(("table", (rows, str(caption))))

    def render(self, base_dir: str | os.PathLike = ".") -> str:
        """The HTML text, with figure paths relative to ``base_dir``."""
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
                rel = Path(os.path.relpath(path, base)).as_posix()
                src = html.escape(rel, quote=True)
                cap = html.escape(caption)
                out.append(f'<figure><a href="{src}"><img src="{src}" alt="{cap}"></a>'
                           f"<figcaption>{cap}</figcaption></figure>")
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

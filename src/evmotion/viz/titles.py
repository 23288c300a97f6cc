"""Titles of pictures wrapped to their width: a title longer than a small sensor's
picture was cut at both ends (probe BK)."""

from __future__ import annotations

import textwrap

__all__ = ["wrap_title"]


def wrap_title(title: str | None, width_px: float, char_px: float) -> list[str]:
    """The lines of ``title`` on a picture ``width_px`` wide whose font's characters are
    about ``char_px`` wide (at least 20 characters a line); none for no title.

    Examples
    --------
    >>> wrap_title("a recording: 30,000 events, [0.002539, 0.062113) s", 150, 7.5)
    ['a recording: 30,000', 'events, [0.002539,', '0.062113) s']
    >>> wrap_title(None, 150, 7.5)
    []
    """
    if not title:
        return []
    # capitals are about 1.4 times as wide: "NOT A MEASUREMENT" was cut at both ends of a
    # 336-px picture (probe CK)
    letters = [c for c in title if c.isalpha()]
    upper = sum(c.isupper() for c in letters) / len(letters) if letters else 0.0
    return textwrap.wrap(title, max(20, int(width_px / (char_px * (1 + 0.4 * upper))))) \
        or [title]

"""Titles of pictures wrapped to their width: a title longer than a small sensor's
picture was cut at both ends (probe BK)."""

from __future__ import annotations

import textwrap

__all__ = ["duration_text", "parameters_text", "quantity_text", "wrap_title"]


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


def duration_text(t_us: float) -> str:
    """A duration given in µs, in the unit that reads best (s, ms or µs; 3 significant
    digits): ``1.73e+03 ms`` had titled a 1.7 s window (probe DA).

    Examples
    --------
    >>> duration_text(1_730_000), duration_text(49_650), duration_text(850)
    ('1.73 s', '49.6 ms', '850 µs')
    >>> duration_text(999_600), duration_text(999.7)
    ('1 s', '1 ms')
    """
    # rounded to 3 digits first: 999,600 µs is 1 s, not "1e+03 ms" (review DR)
    t = abs(float(f"{float(t_us):.3g}"))
    if t >= 1e6:
        return f"{t_us / 1e6:.3g} s"
    if t >= 1e3:
        return f"{t_us / 1e3:.3g} ms"
    return f"{t_us:.3g} µs"


def quantity_text(name: str, value: float, unit: str, digits: int = 3, sep: str = "=") -> str:
    """``name=value unit``, a reciprocal unit folded into the value (``g11=-0.0103/s``,
    not ``g11=-0.0103 1/s``); ``digits`` significant digits, ``sep`` between the name and
    the value.

    Examples
    --------
    >>> quantity_text("g11", -0.0103, "1/s"), quantity_text("vx", 52.1, "px/s")
    ('g11=-0.0103/s', 'vx=52.1 px/s')
    >>> quantity_text("g31", 2e-05, "1/(px s)"), quantity_text("k", 3.0, "")
    ('g31=2e-05/(px s)', 'k=3')
    >>> quantity_text("hz", 1.0, "1/s", digits=4, sep=" = ")
    'hz = 1/s'
    """
    v = f"{value:.{digits}g}"
    if unit.startswith("1/"):
        return f"{name}{sep}{v}{unit[1:]}"
    return f"{name}{sep}{v} {unit}".rstrip()


def parameters_text(names, values, units) -> str:
    """A warp's parameters for a panel's title: each :func:`quantity_text`, two to a line
    (eight values on one line ran into the next panel, probe DA).

    Examples
    --------
    >>> print(parameters_text(("vx", "vy", "hz"), (219.0, -129.0, 1.5), ("px/s",) * 2 + ("1/s",)))
    vx=219 px/s, vy=-129 px/s
    hz=1.5/s
    """
    parts = [quantity_text(n, float(v), u) for n, v, u in zip(names, values, units, strict=True)]
    return "\n".join(", ".join(parts[k:k + 2]) for k in range(0, len(parts), 2))

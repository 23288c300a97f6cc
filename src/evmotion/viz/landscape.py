"""The picture of a cost landscape (thesis Fig. 3.12): the cost along one warp parameter,
with its minimum marked and, when the landscape is flat, said on the picture."""

from __future__ import annotations

import os

import numpy as np

__all__ = ["landscape_png"]


def landscape_png(path: str | os.PathLike, values: np.ndarray, curves: dict[str, np.ndarray],
                  *, name: str, unit: str, title: str, minimum: float,
                  verdict: str | None = None) -> None:
    """Write the landscape PNG atomically.

    Parameters
    ----------
    path : path-like
        The PNG.
    values : ndarray (S,)
        The parameter's values (``unit``).
    curves : dict of str to ndarray (S,)
        The curves to draw, by label (a label with "penalty" is dashed).
    name, unit : str
        The parameter and its unit, for the x axis.
    title : str
        The picture's title (warp, objective, window, fixed parameters).
    minimum : float
        Where the first curve is lowest, marked with a vertical line.
    verdict : str, optional
        Why the minimum is no measurement (a flat landscape, a minimum at the range's
        edge), written on the picture; None when it is one.

    Examples
    --------
    >>> v = np.linspace(-1, 1, 5)
    >>> landscape_png("land.png", v, {"no regularizer": v**2 - 1}, name="vx", unit="px/s",
    ...               title="translation", minimum=0.0)
    >>> import os; os.path.getsize("land.png") > 0
    True
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from evmotion.utils import atomic_path
    from evmotion.viz.titles import quantity_text

    fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
    for k, (label, c) in enumerate(curves.items()):
        # each later curve thinner: one equal to an earlier (a penalty 0 over the range)
        # had hidden it exactly (probe DA)
        ax.plot(values, c, label=label, ls="--" if "penalty" in label else "-",
                lw=max(3.0 - k, 1.0))
    ax.axvline(minimum, color="0.4", lw=0.8, ls=":",
               label=f"minimum: {quantity_text(name, minimum, unit, digits=4, sep=' = ')}")
    if verdict:
        ax.text(0.5, 0.5, f"NO MEASUREMENT\n{verdict}", transform=ax.transAxes, ha="center",
                va="center", fontsize=9, color="firebrick", wrap=True,
                bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "firebrick"})
    ax.set_xlabel(f"{name} [{unit}]")
    ax.set_ylabel("cost J = -G/G0 + lambda R")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", bbox_inches="tight")
    plt.close(fig)

"""Names of the library's choices, for command-line parsers and documentation.

Importing this module loads nothing beyond the standard library (no numpy, numba or
scipy), so that a parser offering these choices (``evmotion egomotion --help``) does not
load the numerical core. The registries named below are the truth; ``tests/test_catalog.py``
checks each tuple against its registry, so a warp or objective added there and not here
fails the suite.

Examples
--------
>>> "rotation" in WARP_NAMES
True
"""

from __future__ import annotations

__all__ = ["OBJECTIVE_NAMES", "WARP_NAMES", "WEIGHT_DATASETS"]

#: Warps :func:`evmotion.core.warps.make_warp` builds (keys of
#: :data:`evmotion.core.warps.WARPS`).
WARP_NAMES: tuple[str, ...] = ("zoom", "translation", "rotation", "se2", "inplane",
                               "similarity", "affine", "homography")

#: Focus objectives (keys of :data:`evmotion.core.objectives.OBJECTIVES`).
OBJECTIVE_NAMES: tuple[str, ...] = ("variance", "gradient_magnitude", "avg_timestamp",
                                    "avg_timestamp_norm")

#: Data sets with thesis regularizer weights, Sec. 3.6.1 (keys of
#: :data:`evmotion.core.collapse.DEFAULT_WEIGHTS`).
WEIGHT_DATASETS: tuple[str, ...] = ("mvsec", "dsec", "ecd")

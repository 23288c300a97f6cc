"""Collapse regularizers and whitening under their historical module name.

The implementations live in :mod:`evmotion.core.collapse` (divergence, deformation, RCAD)
and :mod:`evmotion.core.whitening`; this module re-exports their public API so that code
written against ``evmotion.core.regularizers`` keeps working.

Examples
--------
>>> from evmotion.core.regularizers import REGULARIZERS
>>> sorted(REGULARIZERS)
['deformation', 'divergence', 'rcad']
"""

from __future__ import annotations

from evmotion.core.collapse import (
    DEFAULT_MARGINS,
    DEFAULT_WEIGHTS,
    RCAD_STRIDE,
    REGULARIZERS,
    PenaltyOptions,
    chains_pair,
    regularizer_maps,
    regularizer_value_grad,
    window_span,
)
from evmotion.core.whitening import whiten

__all__ = [
    "DEFAULT_MARGINS",
    "DEFAULT_WEIGHTS",
    "RCAD_STRIDE",
    "REGULARIZERS",
    "PenaltyOptions",
    "chains_pair",
    "regularizer_maps",
    "regularizer_value_grad",
    "whiten",
    "window_span",
]

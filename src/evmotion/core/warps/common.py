"""Constants and small numba helpers shared by every warp family's kernels."""

from __future__ import annotations

import numpy as np
from numba import njit

#: fastmath without the no-NaN/no-inf assumptions: lets LLVM fuse and reorder arithmetic
#: (rounding-level differences) while non-finite events still propagate as NaN/inf.
FAST_FINITE = {"contract", "arcp", "nsz", "reassoc"}

#: Events per block of the vectorized trigonometric passes.
BLOCK = 512

#: Empty arrays passed to kernels for "no Jacobian" / "no weights" / "every block".
EMPTY2 = np.zeros((0, 0))
EMPTY1 = np.zeros(0)
NO_BLOCKS = np.zeros(0, np.int64)

_ABS_BITS = np.uint64(0x7FFFFFFFFFFFFFFF)

@njit(cache=True, error_model="numpy")
def max_abs(a):
    """``max |a|`` of a contiguous float64 array (0 if empty; NaN if any is NaN)."""
    # the magnitudes of floats order like their bit patterns without the sign, and an
    # integer max vectorizes where a float max (NaN semantics) does not; a NaN's pattern
    # exceeds inf's, so NaN still wins
    bits = a.view(np.uint64)
    m = np.uint64(0)
    for k in range(bits.shape[0]):
        m = max(m, bits[k] & _ABS_BITS)
    out = np.empty(1, np.uint64)
    out[0] = m
    return out.view(np.float64)[0]


@njit(cache=True, error_model="numpy", inline="always")
def rows01(m):
    """The first two rows of the 3x3 matrix ``m`` as six scalars: the kernels hold K and
    K^-1 in registers (their output arrays might alias the matrices, which would force a
    reload per event)."""
    return m[0, 0], m[0, 1], m[0, 2], m[1, 0], m[1, 1], m[1, 2]

"""evmotion: estimate motion with an event camera.

The public API is re-exported here; see the README for a tour.
"""

import os as _os
import sys as _sys

try:  # the C module: `signal` imports enum first, milliseconds more without a handler
    import _signal
except ImportError:
    import signal as _signal


def _interrupted_at_start(signum, frame) -> None:
    _os.write(2, b"evmotion: interrupted\n")
    _os._exit(130)


# The evmotion command (the installed script, or python -m evmotion) answers Ctrl-C with
# one line from here on, before the imports below and those of evmotion.cli, until
# evmotion.cli.main puts its own handler in place; nothing has been written yet. Only the
# interpreter's start-up (site, the script's first line) comes before this.
if _os.path.basename(_sys.argv[0] if _sys.argv else "") in ("evmotion", "evmotion.exe") or \
        getattr(_sys, "orig_argv", [])[1:3] == ["-m", "evmotion"]:
    _signal.signal(_signal.SIGINT, _interrupted_at_start)
    # One BLAS thread unless the user set one (read when numpy loads, which it has not yet):
    # the estimates' matrix products are small (tile-flow upsampling, optimizer steps) and
    # OpenBLAS's threads spin between them. flow --method multicm, 35 windows: 18-19 s CPU,
    # 9.5-10.5 s wall with its default threads; 7.6 s CPU, 7.8-8.7 s wall with one.
    for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        _os.environ.setdefault(_var, "1")

from evmotion.errors import (  # noqa: E402  (after the Ctrl-C handler above)
    CalibrationError,
    CollapseWarning,
    EmptyWindowError,
    EventDataError,
    EvmotionError,
    EvmotionWarning,
    FormatError,
    ParameterError,
    PoorFitWarning,
    TimeUnitGuessWarning,
    UnderfitWarning,
    UnusedCalibrationWarning,
)
from evmotion.jitcache import ensure_cache_dir  # noqa: E402

# before any kernel is defined (the modules above define none): an installation numba
# cannot cache next to gets a cache folder elsewhere (one line on stderr), not an error
ensure_cache_dir()

__version__ = "0.1.0"

# The methods pull in numba kernels, and even the event container numpy: import them on
# first use, so that `import evmotion` is fast and the command line has its Ctrl-C handling
# in place before any heavy import starts.
_LAZY = {
    "EventArray": "evmotion.events",
    "Window": "evmotion.events",
    "concatenate": "evmotion.events",
    "estimate_egomotion": "evmotion.methods.egomotion",
    "estimate_flow": "evmotion.methods.multicm",
    "TripletMatcher": "evmotion.methods.triplet",
    "simulate": "evmotion.sim",
    "read_events": "evmotion.io",
    "write_events": "evmotion.io",
    "read_flow": "evmotion.io",
    "Camera": "evmotion.camera",
}


# subpackages and modules reached as attributes (evmotion.methods.bos.estimate_bos, as
# the README writes them) without importing them all at start-up
_SUBMODULES = ("camera", "catalog", "core", "demo", "errors", "eval", "events", "filters",
               "geometry", "io", "methods", "parallel", "sim", "utils", "viz")


def __getattr__(name: str):
    import importlib

    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    if name in _SUBMODULES:
        return importlib.import_module(f"evmotion.{name}")
    raise AttributeError(f"module 'evmotion' has no attribute '{name}'")


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY, *_SUBMODULES})

__all__ = [
    "Camera",
    "TripletMatcher",
    "estimate_egomotion",
    "estimate_flow",
    "read_events",
    "read_flow",
    "simulate",
    "write_events",
    "CalibrationError",
    "EmptyWindowError",
    "EventArray",
    "EventDataError",
    "EvmotionError",
    "FormatError",
    "ParameterError",
    "EvmotionWarning",
    "CollapseWarning",
    "PoorFitWarning",
    "TimeUnitGuessWarning",
    "UnderfitWarning",
    "UnusedCalibrationWarning",
    "Window",
    "concatenate",
]

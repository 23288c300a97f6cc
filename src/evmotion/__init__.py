"""evmotion: estimate motion with an event camera.

The public API is re-exported here; see the README for a tour.
"""

from evmotion.errors import (
    CalibrationError,
    EmptyWindowError,
    EventDataError,
    EvmotionError,
    FormatError,
    ParameterError,
)
from evmotion.events import EventArray, Window, concatenate
from evmotion.jitcache import ensure_cache_dir

# before any kernel is defined (the modules above define none): an installation numba
# cannot cache next to gets a cache folder elsewhere (one line on stderr), not an error
ensure_cache_dir()

__version__ = "0.1.0"

# The methods pull in numba kernels; import them on first use so `import evmotion` stays fast.
_LAZY = {
    "estimate_egomotion": "evmotion.methods.egomotion",
    "estimate_flow": "evmotion.methods.multicm",
    "TripletMatcher": "evmotion.methods.triplet",
    "simulate": "evmotion.sim",
    "read_events": "evmotion.io",
    "write_events": "evmotion.io",
    "Camera": "evmotion.camera",
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'evmotion' has no attribute '{name}'")

__all__ = [
    "Camera",
    "TripletMatcher",
    "estimate_egomotion",
    "estimate_flow",
    "read_events",
    "simulate",
    "write_events",
    "CalibrationError",
    "EmptyWindowError",
    "EventArray",
    "EventDataError",
    "EvmotionError",
    "FormatError",
    "ParameterError",
    "Window",
    "concatenate",
]

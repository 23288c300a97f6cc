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

__version__ = "0.1.0"

__all__ = [
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

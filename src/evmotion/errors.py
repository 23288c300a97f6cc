"""Exceptions that evmotion raises for bad input.

Every error names what was wrong (file, field, value) and, where possible, what to do
about it. The CLI prints these without a traceback.
"""

from __future__ import annotations

from os import PathLike


class EvmotionError(ValueError):
    """Base class of every error evmotion raises on purpose."""


class FormatError(EvmotionError):
    """A file is corrupt, truncated, of the wrong format, or lacks a field.

    Parameters
    ----------
    path : path-like or None
        The file concerned.
    message : str
        What is wrong, naming the field and value.
    hint : str, optional
        What the user can do about it.
    """

    def __init__(self, path: str | PathLike | None, message: str, hint: str | None = None):
        self.path = None if path is None else str(path)
        self.hint = hint
        text = message if self.path is None else f"{self.path}: {message}"
        if hint:
            text += f" ({hint})"
        super().__init__(text)


class EventDataError(EvmotionError):
    """Event arrays that break the container's invariants (unsorted, out of sensor...)."""


class EmptyWindowError(EvmotionError):
    """A window or slice holds no events where the computation needs some."""


class CalibrationError(EvmotionError):
    """Calibration is missing or invalid."""


class ParameterError(EvmotionError):
    """An argument is out of range or NaN."""


class MissingDependencyError(EvmotionError):
    """An optional dependency needed for this feature is not installed."""

    def __init__(self, package: str, feature: str, extra: str | None = None):
        how = f"pip install 'evmotion[{extra}]'" if extra else f"pip install {package}"
        super().__init__(f"{feature} needs the package '{package}', which is not installed: {how}")


class EvmotionWarning(UserWarning):
    """Base class of the warnings evmotion issues about results that may not be
    measurements. The CLI prints each as one line on stderr."""


class CollapseWarning(EvmotionWarning):
    """An estimate shows event collapse (events squeezed onto few pixels, area amplification
    near zero, or speeds the window cannot hold); the message names the cure."""


class PoorFitWarning(EvmotionWarning):
    """The motion model explains the window poorly (e.g. independently moving objects over a
    static scene): the estimate is not the camera's motion."""

"""Exceptions that evmotion raises for bad input.

Every error names what was wrong (file, field, value) and, where possible, what to do
about it. The CLI prints these without a traceback.
"""

from __future__ import annotations

import re
from os import PathLike

# Longest message part kept from text that comes from a file (a header line, a library's
# error): a corrupt file must not turn an error into a screenful.
MAX_DETAIL = 300
_CONTROL = re.compile(r"[\x00-\x1f\x7f]+")


def one_line(text: str, limit: int = MAX_DETAIL) -> str:
    """``text`` on one line: runs of control characters (newlines included) become one
    space, and what exceeds ``limit`` characters is cut, ending in "...".

    Examples
    --------
    >>> one_line("bad\\nvalue\\x00 here")
    'bad value here'
    """
    text = _CONTROL.sub(" ", str(text)).strip()
    text = re.sub(" {2,}", " ", text)
    return text if len(text) <= limit else text[:limit - 3] + "..."


class EvmotionError(ValueError):
    """Base class of every error evmotion raises on purpose."""


class FormatError(EvmotionError):
    """A file is corrupt, truncated, of the wrong format, or lacks a field.

    The text is always one line naming the path: control characters in ``message`` or
    ``hint`` (e.g. from a corrupt header) become spaces and very long parts are cut.

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
        self.message = one_line(message)
        self.hint = None if hint is None else one_line(hint)
        where = None if self.path is None else one_line(self.path, 1000)
        text = self.message if where is None else f"{where}: {self.message}"
        if self.hint:
            text += f" ({self.hint})"
        super().__init__(text)


class EventDataError(EvmotionError):
    """Event arrays that break the container's invariants (unsorted, out of sensor...)."""


class UnsortedError(EventDataError):
    """Timestamps that step back: ``t[at] > t[at + 1]`` (µs), with what to do about it.

    Examples
    --------
    >>> e = UnsortedError(5, 120, 100, "sort them")
    >>> str(e.shifted(1000))
    'timestamps are not sorted: t[1005]=120 > t[1006]=100 us (sort them)'
    """

    def __init__(self, at: int, t_at: int, t_next: int, hint: str):
        self.at, self.t_at, self.t_next, self.hint = int(at), int(t_at), int(t_next), hint
        super().__init__(f"timestamps are not sorted: t[{self.at}]={self.t_at} > "
                         f"t[{self.at + 1}]={self.t_next} us ({hint})")

    def shifted(self, offset: int) -> UnsortedError:
        """The same error in a chunk that starts ``offset`` events into the recording."""
        return UnsortedError(self.at + offset, self.t_at, self.t_next, self.hint)


class InvertedPolarityError(EventDataError):
    """Events whose polarity sums anti-correlate with what the frames show: their ON and
    OFF read the other way round (the flow would come out reversed)."""


class EmptyWindowError(EvmotionError):
    """A window or slice holds no events where the computation needs some."""


class CalibrationError(EvmotionError):
    """Calibration is missing or invalid."""


class ParameterError(EvmotionError):
    """An argument is out of range or NaN."""


class WorkerDiedError(EvmotionError):
    """A worker process of a parallel run died (killed from outside, or crashed): the pool
    cannot go on, and the windows it was computing have no result."""


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


class UnderfitWarning(EvmotionWarning):
    """A schlieren flow explains the events' increment at a fraction of its size where they
    fired (:attr:`evmotion.methods.bos.BosResult.fit_gain`): its magnitude is too small."""


class UnusedCalibrationWarning(EvmotionWarning):
    """A recording's calibration file cannot be read and is left out; its events are read
    all the same, and what needs intrinsics then says it has none."""


class TimeUnitGuessWarning(EvmotionWarning):
    """Times that state no unit (whole numbers in a text list) were read in the unit a
    guess gives; the message names it and how to state another."""


class PoorFitWarning(EvmotionWarning):
    """The motion model explains the window poorly (e.g. independently moving objects over a
    static scene): the estimate is not the camera's motion."""

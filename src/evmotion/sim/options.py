"""Options objects of the simulators: the tuning of :func:`~evmotion.sim.simulate`,
:func:`~evmotion.sim.simulate_log_function` and :func:`~evmotion.sim.simulate_schlieren`
as one frozen, checked value each, so that a configuration can be built once, stored,
compared and passed around (``simulate("rotation", options=opts)``) while the keywords
keep working (``simulate("rotation", mismatch=0.0)``).

Examples
--------
>>> opts = SimOptions(threshold=0.3, noise_rate=0.1)
>>> opts.refractory_us, opts.backend
(0, 'numba')
>>> SimOptions(threshold=-1)
Traceback (most recent call last):
...
evmotion.errors.ParameterError: threshold must be finite and >= 0.001 (log intensity), got -1
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evmotion.catalog import (
    MAX_MISMATCH,
    MAX_PIXEL_RATE,
    MAX_REFRACTORY_US,
    MIN_EVENT_PHOTONS,
    MIN_THRESHOLD,
)
from evmotion.errors import CalibrationError, ParameterError
from evmotion.sim.photoreceptor import EVENT_BANDWIDTHS
from evmotion.utils import check_number, check_switches, whole_number

__all__ = ["EventOptions", "SchlierenOptions", "SimOptions", "check_number"]


def _set(obj, name: str, value) -> None:
    """Store a checked (normalized) value on a frozen dataclass."""
    object.__setattr__(obj, name, value)




@dataclass(frozen=True)
class EventOptions:
    """The event sensor of the simulators: thresholds, refractory period, noise, and how
    finely a pixel's log intensity is sampled.

    Attributes
    ----------
    threshold : float
        Nominal contrast threshold C (log intensity) for ON and OFF events, at least
        :data:`~evmotion.catalog.MIN_THRESHOLD` (0.001).
    mismatch : float
        Relative standard deviation of the per-pixel thresholds (ON and OFF drawn
        independently, clipped to at least 0.25 C), in [0, 1].
    refractory_us : int
        Refractory period, µs: a pixel emits no event within this time after its last; at
        most 1e7 (10 s).
    noise_rate : float
        Background-activity noise, events per second per pixel (Poisson, random
        polarity).
    hot_pixels : int
        Number of hot pixels, each firing at ``hot_rate``.
    hot_rate : float
        Rate of each hot pixel, events/s.
    max_step_fraction : float
        Bound on the log-intensity change between samples of a pixel, as a fraction of
        ``threshold`` (at least 0.01).

    Raises
    ------
    ParameterError
        One line naming the field, its allowed range with units, and the value.
    """

    threshold: float = 0.2
    mismatch: float = 0.03
    refractory_us: int = 0
    noise_rate: float = 0.0
    hot_pixels: int = 0
    hot_rate: float = 1000.0
    max_step_fraction: float = 0.5

    def __post_init__(self):
        _set(self, "threshold", check_number("threshold", self.threshold, MIN_THRESHOLD,
                                             units="log intensity"))
        _set(self, "mismatch", check_number("mismatch", self.mismatch, 0.0, MAX_MISMATCH,
                                            units="relative std"))
        # (10.5 had run as 10 µs, probe BE; 1e30 overflowed a C long, probe OPT)
        _set(self, "refractory_us", whole_number("refractory_us (µs)", self.refractory_us,
                                                 lo=0, hi=MAX_REFRACTORY_US))
        # a pixel's events are at least a microsecond apart: 1e9 went on to numpy's
        # "Unable to allocate 65.5 TiB", rc 1 (probe CE)
        _set(self, "noise_rate", check_number("noise_rate", self.noise_rate,
                                              hi=MAX_PIXEL_RATE, units="events/s per pixel"))
        _set(self, "hot_pixels", int(check_number("hot_pixels", self.hot_pixels,
                                                  units="pixels")))
        _set(self, "hot_rate", check_number("hot_rate", self.hot_rate, hi=MAX_PIXEL_RATE,
                                            units="events/s"))
        # (a pixel is sampled about 1 / max_step_fraction times a threshold crossing:
        # 1e-30 never ended, like a threshold of 1e-30; probe OPT)
        _set(self, "max_step_fraction", check_number(
            "max_step_fraction", self.max_step_fraction, 0.01,
            units="fraction of threshold"))

    @property
    def target(self) -> float:
        """Largest log-intensity change between samples of a pixel."""
        return self.max_step_fraction * self.threshold

    def check_hot_pixels(self, n_pixels: int) -> None:
        """Refuse more hot pixels than the sensor's ``n_pixels``."""
        if self.hot_pixels > n_pixels:
            raise ParameterError(f"hot_pixels ({self.hot_pixels}) exceeds the number of "
                                 f"pixels ({n_pixels})")


@dataclass(frozen=True)
class SimOptions(EventOptions):
    """Tuning of :func:`~evmotion.sim.simulate`: the event sensor of
    :class:`EventOptions` plus the ground truth's frame rate, the intrinsics and the
    kernel backend (every field is also a keyword of ``simulate``, same default).

    Attributes
    ----------
    threshold, mismatch, refractory_us, noise_rate, hot_pixels, hot_rate, max_step_fraction
        As :class:`EventOptions`.
    frame_rate : float
        Rate of the virtual ground-truth frames, Hz (> 0).
    K : array_like (3, 3), optional
        Intrinsics, pixels (finite, positive focal lengths); default
        :func:`~evmotion.sim.scenes.default_K` of the sensor. Stored as nested tuples.
    backend : {"numba", "numpy"}
        ``numpy``: the plain-numpy reference of the kernel, slow, kept for testing and
        benchmarking; both give identical events.

    Raises
    ------
    ParameterError, CalibrationError
        One line naming the field and the value.

    Examples
    --------
    >>> SimOptions(K=[[100, 0, 40], [0, 100, 30], [0, 0, 1]]).K[0]
    (100.0, 0.0, 40.0)
    """

    frame_rate: float = 100.0
    K: tuple | None = None
    backend: str = "numba"

    def __post_init__(self):
        super().__post_init__()
        _set(self, "frame_rate", check_number("frame_rate", self.frame_rate, lo_open=True,
                                              units="Hz"))
        if self.backend not in ("numba", "numpy"):
            raise ParameterError(f"backend must be 'numba' or 'numpy', got {self.backend!r}")
        if self.K is not None:
            K = np.asarray(self.K, dtype=np.float64) if _numeric(self.K) else np.eye(0)
            if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 \
                    or K[1, 1] <= 0:
                raise CalibrationError(f"K must be a finite 3x3 pinhole matrix with positive "
                                       f"focal lengths (pixels), got "
                                       f"{np.asarray(self.K).tolist()!r}")
            _set(self, "K", tuple(tuple(row) for row in K.tolist()))


def _numeric(value) -> bool:
    try:
        np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        return False
    return True


@dataclass(frozen=True)
class SchlierenOptions:
    """Tuning of :func:`~evmotion.sim.simulate_schlieren` (every field is also a keyword
    of it, same default).

    Attributes
    ----------
    magnitude_px : float
        Largest inter-frame displacement ``|v| Δt`` over the pixels and frame intervals,
        px, in (0, 50] (the thesis' scenes: about 0.05-3 px).
    dot_density : float
        Background dots per px².
    dot_radius_px : float
        Mean dot radius, px.
    dot_contrast : float
        Print contrast of the dots, in [0, 1].
    speed_px_s : float, optional
        The air's speed, px/s (plume rise speed; see
        :func:`~evmotion.sim.schlieren.make_field`).
    photons : float, optional
        Expected photons of a white pixel per frame: Poisson shot noise. None:
        noise-free frames.
    gain : float, optional
        Grey levels (ADC units) per photon, > 0 (default ``(2**bit_depth - 1) / photons``:
        a white pixel at full scale whatever the light, the quantization never bites);
        needs ``photons``. A real camera at a fixed exposure keeps the gain set for the
        bright scene: pass it here to dim the frames at a fixed gain.
    read_noise_e : float
        Temporal dark (read) noise of the frame camera, electrons rms, in [0, 1e6]: a
        seeded Gaussian added to the photoelectrons before the gain; needs ``photons``
        when > 0. Default 0 (shot noise only).
    bit_depth : int
        ADC bit depth of the frames, in [1, 16]: values are rounded and clipped to
        ``[0, 2**bit_depth - 1]``; stored as uint8 up to 8 bits, uint16 above (the
        values are not rescaled to 16 bits). Default 8.
    normalize : bool
        Stretch each quantized frame to the full range ``[0, 2**bit_depth - 1]`` (its
        minimum to 0, its maximum to full scale, rounded back to integers), as the thesis
        did with its dark frames; a flat frame is left as it is. Default False.
    exposure_s : float, optional
        Exposure time centred on each frame time, s (default half the frame period; at
        most the frame period).
    contrast_threshold : float
        Nominal contrast threshold of the events (log intensity).
    mismatch, refractory_us, noise_rate, max_step_fraction
        Event sensor, as :class:`EventOptions`.
    event_photons : float, optional
        Low light for the events: expected photons of a white event pixel per
        ``event_tau_us`` (shot noise on the log intensity), in [0.1, 1e12]. None: bright
        light.
    event_tau_us : int
        Time constant of the event pixels' shot noise, µs, in [1, 1e6].
    max_step_px : float
        Largest displacement change between full samples of the radiance for the events
        and within the exposure, px, in (0, 2].
    event_bandwidth : {"fixed", "intensity"}
        The event pixels' photoreceptor under ``event_photons``
        (:mod:`evmotion.sim.photoreceptor`): ``"fixed"`` noise bandwidth (the worst case,
        default) or ``"intensity"``, the DVS's time constant growing as the light falls;
        ``"intensity"`` needs ``event_photons``.

    Raises
    ------
    ParameterError
        One line naming the field, its allowed range with units, and the value.

    Examples
    --------
    >>> SchlierenOptions(photons=50).gain
    5.1
    """

    magnitude_px: float = 1.0
    dot_density: float = 0.06
    dot_radius_px: float = 1.0
    dot_contrast: float = 0.85
    speed_px_s: float | None = None
    photons: float | None = None
    gain: float | None = None
    read_noise_e: float = 0.0
    bit_depth: int = 8
    normalize: bool = False
    exposure_s: float | None = None
    contrast_threshold: float = 0.2
    mismatch: float = 0.03
    refractory_us: int = 0
    noise_rate: float = 0.0
    event_photons: float | None = None
    event_tau_us: int = 1000
    max_step_px: float = 0.25
    max_step_fraction: float = 0.5
    event_bandwidth: str = "fixed"

    def __post_init__(self):
        _set(self, "contrast_threshold", check_number(
            "contrast_threshold", self.contrast_threshold, MIN_THRESHOLD,
            units="log intensity"))
        self.event_options()  # checks the rest of the event sensor
        _set(self, "magnitude_px", check_number("magnitude_px", self.magnitude_px, 0.0,
                                                50.0, lo_open=True, units="px"))
        if self.exposure_s is not None:
            _set(self, "exposure_s", check_number("exposure_s", self.exposure_s, 0.0, 1.0,
                                                  units="s"))
        depth = check_number("bit_depth", self.bit_depth, 1.0, 16.0, units="bits")
        if isinstance(self.bit_depth, bool) or depth != int(depth):
            raise ParameterError(f"bit_depth must be an integer in [1, 16] (bits), got "
                                 f"{self.bit_depth!r}")
        _set(self, "bit_depth", int(depth))
        check_switches(normalize=self.normalize)
        _set(self, "normalize", bool(self.normalize))
        _set(self, "read_noise_e", check_number("read_noise_e", self.read_noise_e, 0.0, 1e6,
                                                units="electrons rms"))
        if self.photons is not None:
            photons = check_number("photons", self.photons, 0.0, 1e9, lo_open=True,
                                   units="photons per frame")
            _set(self, "photons", photons)
            _set(self, "gain", (2 ** self.bit_depth - 1) / photons if self.gain is None
                 else check_number("gain", self.gain, 0.0, lo_open=True,
                                   units="grey levels per photon"))
        elif self.gain is not None:
            raise ParameterError("gain needs photons (shot-noise mode)")
        elif self.read_noise_e > 0:
            raise ParameterError("read_noise_e needs photons (shot-noise mode: the noise is "
                                 "in electrons)")
        _set(self, "max_step_px", check_number("max_step_px", self.max_step_px, 0.0, 2.0,
                                               lo_open=True, units="px"))
        if self.event_photons is not None:
            _set(self, "event_photons", check_number(
                "event_photons", self.event_photons, MIN_EVENT_PHOTONS, 1e12,
                units="photons per event_tau_us"))
        _set(self, "event_tau_us", int(check_number("event_tau_us", self.event_tau_us, 1.0,
                                                    1e6, units="µs")))
        if self.event_bandwidth not in EVENT_BANDWIDTHS:
            raise ParameterError(f"event_bandwidth must be one of {list(EVENT_BANDWIDTHS)}, "
                                 f"got {self.event_bandwidth!r}")
        if self.event_bandwidth != "fixed" and self.event_photons is None:
            raise ParameterError(f"event_bandwidth={self.event_bandwidth!r} needs "
                                 "event_photons")

    def event_options(self) -> EventOptions:
        """The event sensor as :class:`EventOptions` (checked there)."""
        return EventOptions(threshold=self.contrast_threshold, mismatch=self.mismatch,
                            refractory_us=self.refractory_us, noise_rate=self.noise_rate,
                            max_step_fraction=self.max_step_fraction)

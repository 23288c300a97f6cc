"""Options objects of the simulators (and of the triplet stream and the multicm problem):
``options=`` gives the same result as the keywords, bad values and ambiguous calls are
refused in one line naming the field."""

from __future__ import annotations

import numpy as np
import pytest

from evmotion.errors import CalibrationError, ParameterError
from evmotion.sim import (
    EventOptions,
    SchlierenOptions,
    SimOptions,
    simulate,
    simulate_log_function,
    simulate_schlieren,
)

SMALL = dict(duration_s=0.004, sensor_size=(20, 28), seed=3, show_progress=False)


def _same_events(a, b):
    for f in ("x", "y", "t", "p"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))


def test_simulate_options_equal_keywords():
    kw = dict(threshold=0.15, mismatch=0.0, refractory_us=40, noise_rate=5.0, hot_pixels=2,
              frame_rate=200.0, K=[[40.0, 0, 13.5], [0, 40.0, 9.5], [0, 0, 1]])
    longer = dict(SMALL, duration_s=0.02)
    a = simulate("rotation", **longer, **kw)
    b = simulate("rotation", **longer, options=SimOptions(**kw))
    assert len(a.events) > 50 and a.stats["n_noise"] > 0
    _same_events(a.events, b.events)
    np.testing.assert_array_equal(a.gt.frame_times_us, b.gt.frame_times_us)
    np.testing.assert_array_equal(b.gt.K, np.array(kw["K"]))
    # the positional threshold is still the sixth argument
    c = simulate("rotation", 0.02, (20, 28), 3, "dots", 0.15, show_progress=False,
                 **{k: v for k, v in kw.items() if k != "threshold"})
    _same_events(a.events, c.events)


def test_options_change_the_result():
    base = simulate("translation", **SMALL)
    coarse = simulate("translation", **SMALL, options=SimOptions(threshold=0.4))
    assert 0 < len(coarse.events) < len(base.events)


@pytest.mark.parametrize("kw, match", [
    ({"threshold": 0.0}, r"threshold must be finite and >= 0.001 \(log intensity\), got 0.0"),
    # probe OPT: 1e-30 (or a max_step_fraction of 1e-30) never ended; a refractory period
    # of 1e30 µs overflowed a C long
    ({"threshold": 1e-30}, r"threshold must be finite and >= 0.001"),
    ({"max_step_fraction": 1e-30}, r"max_step_fraction must be finite and >= 0.01"),
    ({"refractory_us": 1e30}, r"refractory_us \(µs\) must be a whole number in 0..10000000"),
    ({"mismatch": 2.0}, r"mismatch must be finite and in \[0.0, 1.0\]"),
    ({"refractory_us": -1}, r"refractory_us \(µs\) must be a whole number in 0..10000000, got -1"),
    ({"noise_rate": float("nan")}, "noise_rate"),
    ({"max_step_fraction": 0}, "max_step_fraction"),
    ({"frame_rate": -5}, r"frame_rate .*\(Hz\)"),
    ({"backend": "cuda"}, "backend must be 'numba' or 'numpy', got 'cuda'"),
    ({"threshold": "high"}, "threshold .* got 'high'"),
])
def test_sim_options_refuse_bad_values(kw, match):
    with pytest.raises(ParameterError, match=match) as info:
        SimOptions(**kw)
    assert "\n" not in str(info.value)


def test_sim_options_check_intrinsics_and_are_values():
    with pytest.raises(CalibrationError, match="K must be"):
        SimOptions(K=[[0, 0, 1], [0, 1, 1], [0, 0, 1]])
    with pytest.raises(CalibrationError, match="K must be"):
        SimOptions(K="eye")
    a = SimOptions(K=np.diag([50.0, 50.0, 1.0]), refractory_us=10.0)
    assert a == SimOptions(K=[[50, 0, 0], [0, 50, 0], [0, 0, 1]], refractory_us=10)
    assert isinstance(a.refractory_us, int) and hash(a) == hash(SimOptions(**vars(a)))
    with pytest.raises(AttributeError):
        a.threshold = 0.3  # frozen


def test_ambiguous_and_unknown_keywords_are_refused():
    with pytest.raises(ParameterError, match="either options= or the keyword"):
        simulate("rotation", **SMALL, mismatch=0.0, options=SimOptions())
    with pytest.raises(ParameterError, match="either options= or the keyword"):
        simulate("rotation", 0.004, (20, 28), 3, "dots", 0.3, options=SimOptions())
    with pytest.raises(ParameterError, match=r"simulate\(\) got unknown keyword\(s\) treshold"):
        simulate("rotation", **SMALL, treshold=0.3)
    with pytest.raises(ParameterError, match="options must be a SimOptions"):
        simulate("rotation", **SMALL, options={"threshold": 0.3})
    with pytest.raises(ParameterError, match="hot_pixels"):
        simulate("rotation", **SMALL, hot_pixels=10_000)


def test_log_function_options_equal_keywords():
    def ramp(t, pix):
        v = np.sin(np.arange(6.0) + t * 2e-3)
        return v.reshape(2, 3) if pix is None else v[pix]

    kw = dict(threshold=0.1, mismatch=0.05, refractory_us=30, noise_rate=20.0)
    a = simulate_log_function(ramp, (2, 3), 4000, seed=2, **kw)
    b = simulate_log_function(ramp, (2, 3), 4000, seed=2, options=EventOptions(**kw))
    assert len(a.events) > 20
    _same_events(a.events, b.events)
    assert a.stats == b.stats
    with pytest.raises(ParameterError, match="unknown keyword.*frame_rate"):
        simulate_log_function(ramp, (2, 3), 4000, frame_rate=10.0)


def test_schlieren_options_equal_keywords():
    kw = dict(magnitude_px=0.8, photons=40.0, event_photons=300.0, mismatch=0.0,
              dot_density=0.08)
    common = dict(sensor_size=(24, 32), duration_s=2 / 120, seed=1)
    a = simulate_schlieren("jet", **common, **kw)
    b = simulate_schlieren("jet", **common, options=SchlierenOptions(**kw))
    _same_events(a.events, b.events)
    np.testing.assert_array_equal(a.frames.images, b.frames.images)
    assert a.gt.meta == b.gt.meta and a.gt.meta["gain"] == pytest.approx(255 / 40)
    # the default gain puts white at the ADC's full scale at any bit depth
    assert SchlierenOptions(photons=40.0, bit_depth=10).gain == pytest.approx(1023 / 40)


@pytest.mark.parametrize("kw, match", [
    ({"magnitude_px": 60}, r"magnitude_px .*\(0.0, 50.0\] \(px\)"),
    ({"gain": 2.0}, "gain needs photons"),
    ({"event_tau_us": 0}, r"event_tau_us .*\(µs\)"),
    ({"contrast_threshold": -0.1}, "contrast_threshold"),
    ({"refractory_us": -3}, "refractory_us"),
    ({"photons": 5.0, "read_noise_e": float("inf")}, r"read_noise_e .*\(electrons rms\)"),
    ({"bit_depth": 32}, r"bit_depth .*\[1.0, 16.0\] \(bits\)"),
    ({"contrast_threshold": 1e-30}, r"contrast_threshold must be finite and >= 0.001"),
    ({"event_photons": 1e-30}, r"event_photons must be finite and in \[0.1, "),
])
def test_schlieren_options_refuse_bad_values(kw, match):
    with pytest.raises(ParameterError, match=match):
        SchlierenOptions(**kw)


def test_triplet_stream_options_equal_keywords():
    from evmotion.methods.triplet_stream import TripletOptions, TripletStream

    ev = simulate("translation", duration_s=0.02, sensor_size=(24, 32), seed=0,
                  show_progress=False).events
    kw = dict(n_bins=2, dx=2.0, tau_us=20_000, depth=4)
    flows = []
    for stream in (TripletStream(ev.sensor_size, window_us=10_000, **kw),
                   TripletStream(ev.sensor_size, window_us=10_000,
                                 options=TripletOptions(**kw))):
        per_event = stream.process(ev)
        stream.finish()
        flows.append((per_event, [w.flow for w in stream.windows()]))
    np.testing.assert_array_equal(flows[0][0].vx, flows[1][0].vx)
    assert len(flows[0][1]) == 2
    for f0, f1 in zip(flows[0][1], flows[1][1], strict=True):
        np.testing.assert_array_equal(f0, f1)
    with pytest.raises(ParameterError, match="n_bins must be an integer >= 1, got 0"):
        TripletOptions(n_bins=0)
    with pytest.raises(ParameterError, match="unknown keyword.*bins"):
        TripletStream(ev.sensor_size, bins=2)


def test_multicm_problem_options_equal_keywords():
    from evmotion.core import tileflow as tf
    from evmotion.methods.multicm import MultiCMOptions, MultiCMProblem

    ev = simulate("translation", duration_s=0.01, sensor_size=(32, 40), seed=0,
                  show_progress=False).events
    x, y = ev.x.astype(float), ev.y.astype(float)
    s = (ev.t - ev.t[0]) / (ev.t[-1] - ev.t[0])
    grid = tf.scale_grid(2, ev.sensor_size)
    kw = dict(lam=0.01, time_aware="upwind", n_bins=3, transport_cell=2)
    a = MultiCMProblem(x, y, s, ev.sensor_size, grid, **kw)
    b = MultiCMProblem(x, y, s, ev.sensor_size, grid, options=MultiCMOptions(**kw))
    th = np.random.default_rng(0).normal(size=grid.ny * grid.nx * 2)
    va, ga = a.value_grad(th)
    vb, gb = b.value_grad(th)
    assert va == vb and np.array_equal(ga, gb) and b.n_bins == 3
    assert MultiCMProblem(x, y, s, ev.sensor_size, grid, time_aware="upwind").n_bins == 5
    with pytest.raises(ParameterError, match="unknown keyword.*n_scales"):
        MultiCMProblem(x, y, s, ev.sensor_size, grid, n_scales=3)


@pytest.mark.parametrize("kw, match", [({"duration_s": 1e9}, r"duration_s must be .* 3600"),
                                       ({"frame_rate": 1e9}, "ground-truth frames")])
def test_absurd_durations_and_frame_rates_are_refused_at_once(kw, match):
    # they ran for minutes without a word (1e9 s) or filled the memory (1e9 Hz)
    from evmotion.sim import simulate

    duration = kw.pop("duration_s", 0.1)
    with pytest.raises(ParameterError, match=match):
        simulate("rotation", duration_s=duration, sensor_size=(60, 80), show_progress=False,
                 **kw)

"""Bad arguments to the public functions: the library's own one-line errors, never a raw
numpy / numba exception from deep inside, and never a silently changed input. Each case
is a repro of a new user's report (2026-11-29)."""

from __future__ import annotations

import numpy as np
import pytest

from evmotion.errors import EventDataError, ParameterError
from evmotion.eval.metrics import flow_metrics, fwl, sample_flow_bilinear
from evmotion.events import EventArray
from evmotion.io import iter_events, read_events, write_events
from evmotion.methods.egomotion import estimate_egomotion
from evmotion.methods.multicm import estimate_flow
from evmotion.methods.segmentation import segment_motion
from evmotion.methods.triplet import TripletMatcher, estimate_flow_triplet
from evmotion.sim import simulate
from evmotion.viz import iwe_to_rgb


@pytest.fixture(scope="module")
def ev():
    """Dots moving right at 400 px/s on an 80x128 sensor."""
    rng = np.random.default_rng(0)
    n = 3000
    t = np.sort(rng.integers(0, 50_000, n))
    d = rng.uniform(10, 60, (200, 2))
    k = rng.integers(0, 200, n)
    return EventArray(np.round(d[k, 0] + 400 * t * 1e-6).astype(int),
                      np.round(d[k, 1]).astype(int), t, np.ones(n, int), (80, 128))


@pytest.mark.parametrize("t, match", [
    ([10.9, 20.5, 30.99], r"fractional values \(t\[0\]=10.9\)"),
    ([0.01, 0.02, 0.03], "from seconds"),           # all three used to become 0
    ([0.0, 1.0, np.nan], "NaN"),
    (np.array([10, 2**63 + 5, 2**63 + 6], np.uint64), "beyond"),   # wrapped negative
])
def test_timestamps_are_not_silently_changed(t, match):
    with pytest.raises(EventDataError, match=match):
        EventArray([1, 2, 3], [0, 0, 0], t, [1, 1, 1], (4, 4))
    # whole float microseconds are fine
    assert EventArray([1], [0], [7.0], [1], (4, 4)).t.tolist() == [7]


def test_container_arguments():
    with pytest.raises(EventDataError, match="sensor_size must be two whole numbers"):
        EventArray([1], [0], [0], [1], 4)
    with pytest.raises(EventDataError, match="sensor_size must be two whole numbers"):
        EventArray([1], [0], [0], [1], (4.7, 4))
    # probe BE: a 2-D t was reported as "field 'x' has shape (3,), expected (1,) like 't'"
    with pytest.raises(EventDataError, match=r"field 't' has shape \(1, 3\), expected \(N,\)"):
        EventArray([1, 2, 3], [0, 1, 2], [[10, 20, 30]], [1, 0, 1], (4, 4))
    empty = EventArray([], [], [], [], (4, 4))
    assert empty.x.dtype == np.uint16 and empty.t.dtype == np.int64
    ev = EventArray([1, 2], [0, 0], [0, 5], [1, 1], (4, 4))
    with pytest.raises(ParameterError, match="index events with an int"):
        ev[1.5]
    with pytest.raises(ParameterError, match="whole number in 1.."):
        ev.windows_by_duration(0.5)  # 41 empty windows before
    with pytest.raises(ParameterError, match="whole number in 1.."):
        ev.windows_by_duration(float("nan"))


def test_estimators_name_their_bad_arguments(ev):
    with pytest.raises(ParameterError, match="estimate_flow: events must be an EventArray"):
        estimate_flow([1, 2, 3])
    with pytest.raises(ParameterError, match="n_bins must be a whole number >= 1, got 2.5"):
        estimate_flow(ev, time_aware="burgers", n_bins=2.5)
    with pytest.raises(ParameterError, match="lam must be a number, got '0.1'"):
        estimate_flow(ev, lam="0.1")
    with pytest.raises(ParameterError, match="estimate_flow_triplet"):
        estimate_flow(ev, method="triplet")
    with pytest.raises(ParameterError, match="init must be 2 numbers"):
        estimate_egomotion(ev, warp="translation", init=["a", 0])
    with pytest.raises(ParameterError, match=r"starts\[0\] must be 2 finite numbers"):
        estimate_egomotion(ev, warp="translation", starts=[[1, 2, 3]])
    with pytest.raises(ParameterError, match="n_iter must be an integer >= 1"):
        estimate_egomotion(ev, warp="translation", optimizer="adam", n_iter=0)
    with pytest.raises(ParameterError, match="seed must be an integer >= 0"):
        estimate_egomotion(ev, warp="translation", optimizer="tpe", n_samples=10, seed="a")
    with pytest.raises(ParameterError, match="regularizer is None"):
        estimate_egomotion(ev, warp="translation", weight=100.0)  # the weight weighed nothing
    with pytest.raises(ParameterError, match="n_iter must be an integer >= 1"):
        segment_motion(ev, 2, n_iter=0)  # returned zero parameters as a result
    with pytest.raises(ParameterError, match="seed must be a whole number >= 0"):
        simulate("rotation", duration_s=0.005, sensor_size=(40, 40), seed=-1,
                 show_progress=False)
    with pytest.raises(ParameterError, match="dt_us"):
        TripletMatcher((10, 10), dt_us=float("nan"))
    with pytest.raises(ParameterError, match="sensor_size"):
        TripletMatcher((60000, 60000))  # asked numpy for 215 GiB
    with pytest.raises(ParameterError, match="gap_us"):
        estimate_flow_triplet(ev, dense="robust", gap_us=float("nan"))
    with pytest.raises(ParameterError, match="n_bins must be a whole number"):
        estimate_flow_triplet(ev, n_bins=2.5)


def test_metrics_refuse_what_they_cannot_measure(ev):
    flow = np.tile(np.array([400.0, 0.0], np.float32), (80, 128, 1))
    assert fwl(ev, flow) > 1.5
    with pytest.raises(ParameterError, match="NaN/inf where 3000 of the 3000 events"):
        fwl(ev, np.full_like(flow, np.nan))  # was 0.0
    g = np.zeros((4, 4, 2))
    with pytest.raises(ParameterError, match="out_px"):
        flow_metrics(g + 4, g, out_px=float("nan"))  # %Out was 0 at AEE 5.7
    other = EventArray([9], [9], [0], [1], sensor_size=(10, 10))
    with pytest.raises(ParameterError, match="sensor"):
        flow_metrics(g + 1, g, events=other)
    with pytest.raises(ParameterError, match="finite positions"):
        sample_flow_bilinear(g, np.array([np.nan]), np.array([0.0]))
    with pytest.raises(ParameterError, match="percentile"):
        iwe_to_rgb(np.ones((8, 8)), percentile=200)


def test_readers_name_a_misspelt_option(ev, tmp_path):
    path = tmp_path / "rec.h5"
    write_events(path, ev)
    with pytest.raises(ParameterError, match="unexpected keyword argument 'sensor_sise'"):
        read_events(path, sensor_sise=(80, 128))  # was reported as a corrupt file
    with pytest.raises(ParameterError, match="window_us"):
        list(iter_events(path, window_us=float("nan")))


def test_the_cli_error_line_is_capped():
    # probe AO: a 5 MB file name was echoed whole in the "one line" of an OSError
    from evmotion.cli import MAX_ERROR_CHARS, _one_line

    line = _one_line(OSError(36, "File name too long", "x" * 5_000_000))
    assert len(line) < MAX_ERROR_CHARS + 60 and "characters] ..." in line
    assert _one_line(ValueError("short\nmessage")) == "short message"


def test_egomotion_names_a_warp_that_is_neither_a_name_nor_a_warp():
    # warp=None raised "AttributeError: 'NoneType' object has no attribute 'n_params'"
    # six frames deep (probe)
    from evmotion import estimate_egomotion
    from evmotion.errors import ParameterError
    from evmotion.sim import simulate

    ev = simulate("translation", duration_s=0.02, sensor_size=(40, 50),
                  show_progress=False).events
    for bad in (None, 3):
        with pytest.raises(ParameterError, match=r"warp must be a name \(affine, .*got"):
            estimate_egomotion(ev, warp=bad)


@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_a_non_finite_coordinate_of_an_unchecked_array_is_refused(ev, value):
    # probe BE: one NaN x of an EventArray(..., validate=False) made estimate_egomotion's
    # estimate zero motion; estimate_flow dropped it, estimate_flow_dnn failed in
    # np.bincount and TripletMatcher quoted x=-2147483648
    from evmotion.methods.dnn import estimate_flow_dnn

    x = ev.x.astype(float)
    x[5] = value
    bad = EventArray(x, ev.y, ev.t, ev.p, ev.sensor_size, validate=False)
    msg = rf"field 'x' of event 5 is {value}: coordinates must be finite, not NaN or inf"
    for name, call in (("estimate_egomotion", lambda: estimate_egomotion(bad, warp="translation")),
                       ("estimate_flow", lambda: estimate_flow(bad)),
                       ("estimate_flow_dnn", lambda: estimate_flow_dnn(bad)),
                       ("fwl", lambda: fwl(bad, np.zeros((80, 128, 2))))):
        with pytest.raises(EventDataError, match=f"{name}: {msg}"):
            call()
    with pytest.raises(EventDataError, match=msg):
        TripletMatcher(ev.sensor_size).process(bad)
    with pytest.raises(EventDataError, match=msg):
        bad.check()


def test_a_reference_time_far_outside_the_window_is_refused(ev):
    # probe BE: fwl(win, flow, t_ref_us=10**12) returned 0.0 and estimate_egomotion(t_ref=
    # 10**12) zero motion: every event was warped off the sensor
    flow = np.tile(np.array([400.0, 0.0], np.float32), (80, 128, 1))
    far = int(ev.t[-1]) + 1_000_001
    said = r"t_ref(_us)?=\d+ us lies outside the window's events \[\d+, \d+\] us"
    with pytest.raises(ParameterError, match=said):
        fwl(ev, flow, t_ref_us=far)
    with pytest.raises(ParameterError, match=said):
        estimate_egomotion(ev, warp="translation", t_ref=10**12)
    # within a second of the events: a window's interval whose events bunch at one end
    assert fwl(ev, flow, t_ref_us=far - 1) >= 0


def test_duration_windows_refuse_a_reversed_or_boundless_range():
    # probe BE: t0 > t1 failed with IndexError, and a span of 10**8 us in 1 us windows made
    # every empty window first (tens of GB)
    ev = EventArray(x=[1, 2], y=[1, 1], t=[0, 10], p=[1, 0], sensor_size=(4, 4))
    with pytest.raises(ParameterError, match="t1 = 1000 µs must be after t0 = 5000 µs"):
        ev.windows_by_duration(1000, t0=5000, t1=1000)
    with pytest.raises(ParameterError, match="makes 100,000,000 windows for 2 events"):
        ev.windows_by_duration(1, t0=0, t1=10**8)
    kept = ev.windows_by_duration(1, t0=0, t1=10**8, drop_empty=True)
    assert [(w.index, w.t0, w.t1, w.start, w.stop) for w in kept] == [(0, 0, 1, 0, 1),
                                                                     (1, 10, 11, 1, 2)]


def test_arguments_that_failed_as_bare_python_errors(ev):
    # probe BE: AttributeError 'sensor_size', TypeError of a slice index, TypeError of range()
    from evmotion.events import make_windows

    g = np.zeros((80, 128, 2))
    with pytest.raises(ParameterError, match="flow_metrics: events must be an EventArray"):
        flow_metrics(g, g, events=ev.to_structured())
    with pytest.raises(ParameterError, match="max_windows must be a whole number >= 1, got 2.5"):
        make_windows(ev, duration_us=1000, max_windows=2.5)
    assert len(make_windows(ev, duration_us=1000, max_windows=2.0)) == 2
    r = estimate_flow(ev[:1500], n_scales=2.0, finest_level=2)
    assert r.meta["n_scales"] == 2


def test_options_that_would_do_nothing_are_refused(ev):
    """Probe BE: a string sensor size unpacked into digits ("44" -> (4, 4)), and options
    that apply only with another one given were ignored: dataset= (even an unknown name)
    without a regularizer, n_bins without time-aware transport."""
    with pytest.raises(EventDataError, match="sensor_size must be two whole numbers.*'44'"):
        EventArray([1], [1], [0], [1], "44")
    with pytest.raises(ParameterError, match="dataset='kitti' picks a regularizer's weight"):
        estimate_egomotion(ev, warp="translation", dataset="kitti")
    with pytest.raises(ParameterError, match="dataset='dsec'.*regularizer is None"):
        segment_motion(ev, n_warps=2, warp="translation", dataset="dsec")
    with pytest.raises(ParameterError, match="n_bins=7 sets the time bins.*time_aware is None"):
        estimate_flow(ev, n_bins=7)
    assert estimate_flow(ev, n_bins=3, time_aware="upwind", n_scales=1,
                         finest_level=2).n_bins == 3
    # transport_cell likewise (it ran the plain model unsaid)
    with pytest.raises(ParameterError, match="transport_cell=9 sets the PDE's cells.*time_aw"):
        estimate_flow(ev, transport_cell=9)
    for cell, expect in ((None, 4), (2, 2)):
        res = estimate_flow(ev, transport_cell=cell, time_aware="upwind", n_scales=1,
                            finest_level=2)
        assert res.meta["transport_cell"] == expect


def _with_off_sensor(ev, x, y):
    """``ev`` unchecked, with one more event at (x, y) (off its sensor) at its first time."""
    dtype = np.float32 if isinstance(x, float) or isinstance(y, float) else np.int64
    return EventArray(np.concatenate([[x], ev.x]).astype(dtype),
                      np.concatenate([[y], ev.y]).astype(dtype),
                      np.concatenate([ev.t[:1], ev.t]), np.concatenate([ev.p[:1], ev.p]),
                      ev.sensor_size, validate=False)


@pytest.mark.parametrize("where", ["float y -1", "int y = H"])
def test_an_event_off_the_sensor_is_left_out_of_the_dense_flows(ev, where):
    # undistorted events kept past the border (drop_outside=False): multicm failed in
    # np.bincount ("must have no negative elements"), the network with an IndexError at
    # y = H, the triplet stream as multicm (probe CB)
    from evmotion.methods.dnn import estimate_flow_dnn
    from evmotion.methods.triplet_stream import iter_flow_triplet

    h = ev.sensor_size[0]
    off = (_with_off_sensor(ev, 5.0, -1.0) if where.startswith("float")
           else _with_off_sensor(ev, 5, h))
    kept = EventArray(off.x[1:], off.y[1:], off.t[1:], off.p[1:], ev.sensor_size)
    for fn in (estimate_flow, lambda e: estimate_flow_dnn(e, backend="numpy")):
        np.testing.assert_array_equal(fn(off).flow, fn(kept).flow)
    chunks = [off[:1500], off[1500:]]
    if where.startswith("float"):  # undistorted past the border: on the edge pixel
        assert sum(w.n_events for w in iter_flow_triplet(chunks, window_events=1000)) == 3001
    else:  # a whole-pixel coordinate off the sensor is corrupt: said
        with pytest.raises(ParameterError, match=r"event 0 has y=80 outside the sensor"):
            list(iter_flow_triplet(chunks, window_events=1000))


def test_a_simulation_ground_truth_scores_windows_directly():
    # evaluate_windows(flows, t0s, t1s, sim.gt) failed with "'function' object has no
    # attribute 'shape'", and flow_metrics(res, d) said "'flow' must have shape (H, W, 2),
    # got ()" (probe CB)
    from evmotion.eval.windows import evaluate_windows
    from evmotion.io.flowfiles import FlowSequence

    sim = simulate("translation", duration_s=0.05, sensor_size=(40, 50), seed=0,
                   show_progress=False)
    t0s, t1s = [0, 20_000], [20_000, 40_000]
    seq = sim.gt.flow_sequence(t0s, t1s)
    exact = np.stack([sim.gt.displacement(a, b) / ((b - a) * 1e-6)
                      for a, b in zip(t0s, t1s, strict=True)])
    np.testing.assert_allclose(seq.flow, exact, rtol=1e-6)
    est = exact.copy()
    est[..., 0] += 50.0  # 1 px off over each 20 ms window, along x
    by_gt = evaluate_windows(est, t0s, t1s, sim.gt)
    by_seq = evaluate_windows(est, t0s, t1s, FlowSequence(seq.flow, seq.t0, seq.t1, seq.valid))
    assert by_gt.total["AEE"] == pytest.approx(1.0, rel=1e-4) == by_seq.total["AEE"]
    with pytest.raises(ParameterError, match="gt must be a FlowSequence"):
        evaluate_windows(est, t0s, t1s, sim.gt.flow)
    for bad in (np.nan, 0.5):  # NaN failed in numpy's int conversion, 0.5 was cut to 0
        with pytest.raises(ParameterError, match=r"t0s must be a whole number"):
            sim.gt.flow_sequence([bad], [20_000])
    res = estimate_flow(sim.events[:4000])
    with pytest.raises(ParameterError, match=r"'flow' is a FlowResult: .*res.displacement\(\)"):
        flow_metrics(res, exact[0])
    # fwl takes px/s: its advice had been res.displacement() too (FWL 0.985 for 2.22,
    # probe DB)
    with pytest.raises(ParameterError, match=r"is a FlowResult: give the flow in px/s, e\.g\. "
                                             r"res\.flow$"):
        fwl(sim.events[:4000], res)


def test_triplet_leaves_out_events_off_the_sensor_as_it_says():
    # it warned that they were left out, then refused the first of them (probe DB)
    from evmotion.errors import EvmotionWarning
    from evmotion.methods.triplet import estimate_flow_triplet

    yy, xx = np.mgrid[0:20, 0:20]
    t = np.rint(xx.ravel() / 200.0 * 1e6).astype(np.int64)
    o = np.argsort(t, kind="stable")
    x, y, t = xx.ravel()[o], yy.ravel()[o], t[o]
    inside = EventArray(x, y, t, np.ones(t.size), (20, 20))
    shifted = EventArray(np.where(x < 14, x, x + 30), y, t, np.ones(t.size), (20, 20),
                         validate=False)
    with pytest.warns(EvmotionWarning, match="lie off the sensor .* and are left out"):
        got = estimate_flow_triplet(shifted)
    keep = x < 14
    want = estimate_flow_triplet(EventArray(x[keep], y[keep], t[keep], np.ones(keep.sum()),
                                            (20, 20)))
    np.testing.assert_array_equal(got.flow, want.flow)
    assert estimate_flow_triplet(inside).valid.sum() > got.valid.sum() > 0


def test_switches_given_as_strings_are_refused(ev):
    # "False" and "no" are true to Python: refine="False" refined, signed="no" signed,
    # legend="no" drew the legend, and a 0.5 mask was drawn as valid (probe CB)
    from evmotion.methods.dnn import estimate_flow_dnn
    from evmotion.methods.kymogram import KymoLine, kymogram_from_events
    from evmotion.methods.multicm import estimate_flow_sequence
    from evmotion.viz.flowpic import flow_picture

    line = KymoLine.row(40, ev.sensor_size)
    calls = {"refine": lambda: estimate_flow_dnn(ev, refine="False"),
             "smooth": lambda: estimate_flow_triplet(ev, smooth="no"),
             "signed": lambda: kymogram_from_events(ev, line, signed="no"),
             "warm_start": lambda: estimate_flow_sequence(ev, [(0, 10_000)], warm_start="no"),
             "legend": lambda: flow_picture(np.zeros((4, 4, 2)), legend="no")}
    for name, call in calls.items():
        with pytest.raises(ParameterError, match=f"{name} must be True or False, got '"):
            call()
    with pytest.raises(ParameterError, match="valid mask must hold True / False"):
        flow_picture(np.zeros((4, 4, 2)), valid=np.full((4, 4), 0.5))
    assert flow_picture(np.zeros((4, 4, 2)), valid=np.ones((4, 4))).texts[4] == \
        "grey: no events"


def test_a_swapped_histogram_shape_is_refused(ev):
    from evmotion.viz.images import event_histogram

    h, w = ev.sensor_size
    with pytest.raises(ParameterError, match=r"swapped: shape is \(height, width\)"):
        event_histogram(ev, shape=(w, h))
    assert event_histogram(ev, shape=(h, w)).sum() == len(ev)


def test_nan_and_string_times_are_refused(ev):
    with pytest.raises(ParameterError, match="t0 must be a finite time"):
        ev.slice_time(np.nan, 10_000)
    with pytest.raises(ParameterError, match="t1 must be a finite time"):
        ev.slice_time(0, "10")
    assert len(ev.slice_time(0, 10_000)) == int(np.sum(ev.t < 10_000))
    gt = simulate("translation", duration_s=0.01, sensor_size=(20, 30), seed=0,
                  show_progress=False).gt
    with pytest.raises(ParameterError, match="t_us must be a finite time in microseconds, "
                                             "got 'a'"):
        gt.params("a")


@pytest.mark.parametrize("kw, match", [
    ({"n_iter": 5}, r"n_iter=5 applies to optimizer='adam' only \(optimizer is 'bfgs'\)"),
    ({"lr": 0.1}, "lr=0.1 applies to optimizer='adam' only"),
    ({"n_samples": 50}, "n_samples=50 applies to optimizer='tpe' only"),
    ({"bounds": (np.array([-1.0, -1.0]), np.array([1.0, 1.0]))},
     "bounds=.* applies to optimizer='tpe' only"),
    ({"sigma": 3.0}, r"sigma=3.0 applies to kernel='gaussian' only \(kernel is 'bilinear'\)"),
])
def test_an_option_of_another_optimizer_is_refused(ev, kw, match):
    # n_iter=5, n_samples=5 and sigma=3.0 changed nothing under the bfgs / bilinear
    # defaults, without a word (probe CB)
    with pytest.raises(ParameterError, match=match):
        estimate_egomotion(ev, warp="translation", **kw)
    assert estimate_egomotion(ev, warp="translation", optimizer="adam", n_iter=5).params.size


def test_the_simulator_submodules_are_attributes():
    # evmotion.sim.schlieren was an AttributeError until imported, where
    # evmotion.methods.bos was not (probe CB); a subprocess: this one has imported them
    import subprocess
    import sys

    code = ("import evmotion.sim as s; print(s.schlieren.simulate_schlieren.__name__, "
            "s.gtio.__name__)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["simulate_schlieren", "evmotion.sim.gtio"]


def test_a_ridge_for_the_thesis_mean_is_refused(ev):
    # ignored unsaid with dense="mean", while gap_us outside robust was refused (probe CB)
    with pytest.raises(ParameterError, match="ridge=0.1 applies to dense='lsq' or 'robust'"):
        estimate_flow_triplet(ev, ridge=0.1)
    assert estimate_flow_triplet(ev, dense="lsq", ridge=0.1).flow.shape[0] == 1


def test_an_impossible_noise_rate_is_refused_before_memory_runs_out():
    # 1e9 events/s per pixel went on to numpy's "Unable to allocate 65.5 TiB", rc 1 (probe CE)
    with pytest.raises(ParameterError, match=r"noise_rate must be finite and in \[0.0, "
                                             r"1000000.0\] \(events/s per pixel\)"):
        simulate("translation", duration_s=0.01, sensor_size=(20, 30), noise_rate=1e9)
    with pytest.raises(ParameterError, match=r"would add ~5.4e\+08 noise events"):
        simulate("translation", duration_s=2.0, sensor_size=(300, 300), noise_rate=3e3,
                 show_progress=False)


def test_a_count_window_across_a_gap_ends_after_its_last_event(tmp_path):
    # window 0 of two recordings joined took the 2.19 s gap's length, and its .flo
    # displacement came out hundreds of times too large (probe CF)
    from evmotion.cli import main
    from evmotion.io import read_flow, write_events

    rng = np.random.default_rng(0)
    n = 4000
    t = np.sort(rng.integers(0, 10_000, n))
    t[n // 2:] += 2_000_000  # a 2 s pause half-way
    x0 = rng.uniform(5, 60, n)
    ev = EventArray(np.round(x0 + 400 * (t % 2_000_000) * 1e-6).astype(int),
                    rng.integers(0, 40, n), t, rng.integers(0, 2, n), (40, 70))
    wins = ev.windows_by_count(n // 2)
    assert (wins[0].t0, wins[0].t1) == (int(t[0]), int(t[n // 2 - 1]) + 1)
    assert (wins[1].t0, wins[1].t1) == (int(t[n // 2]), int(t[-1]) + 1)
    same = EventArray([1, 2, 3, 4], [0] * 4, [0, 5, 5, 9], [1] * 4, (4, 8))
    assert [(w.t0, w.t1) for w in same.windows_by_count(2)] == [(0, 5), (5, 10)]
    write_events(tmp_path / "gap.h5", ev)
    assert main(["flow", str(tmp_path / "gap.h5"), "--window-events", str(n // 2),
                 "--out", str(tmp_path / "f.h5")]) == 0
    flow = read_flow(tmp_path / "f.h5")
    assert int(flow.t1[0]) - int(flow.t0[0]) < 20_000


def test_a_triplet_run_without_any_flow_says_why(tmp_path, capsys):
    # 0 % valid on a 5.5 ms ECD window moving ~1000 px/s, without a word (probe CF)
    from evmotion.cli import main
    from evmotion.io import write_events

    rng = np.random.default_rng(0)
    n = 3000
    t = np.sort(rng.integers(0, 6_000, n))  # 6 ms at 1000 px/s: each step under tau
    x0 = rng.uniform(5, 30, 60)
    k = rng.integers(0, 60, n)
    ev = EventArray(np.round(x0[k] + 1000 * t * 1e-6).astype(int), rng.integers(0, 30, n), t,
                    np.ones(n, int), (30, 50))
    write_events(tmp_path / "fast.h5", ev)
    assert main(["flow", str(tmp_path / "fast.h5"), "--method", "triplet", "--out",
                 str(tmp_path / "t.h5")]) == 0
    err = capsys.readouterr().err
    assert "got a flow: a triplet needs steps of 1.41 px at least tau = 3 ms apart" in err
    assert "faster than 471 px/s finds none (a shorter --tau-ms)" in err


def test_times_in_seconds_and_ground_truth_far_off_are_refused():
    # slice_time(0.001, 0.01) gave no event, gt.params(0.025) the motion at 0 µs and
    # gt.params(1e10) an extrapolated zoom, each without a word (probe DB)
    from evmotion.sim import simulate

    sim = simulate("zoom", duration_s=0.03, sensor_size=(30, 40), seed=0,
                   show_progress=False)
    with pytest.raises(ParameterError, match=r"t0 = 0.001 µs: times are in microseconds "
                                             r"\(seconds\? 0.001 s is 1000 µs\)"):
        sim.events.slice_time(0.001, 0.01)
    assert len(sim.events.slice_time(0, 1000)) == np.count_nonzero(sim.events.t < 1000)
    with pytest.raises(ParameterError, match="t_us = 0.025 µs: times are in microseconds"):
        sim.gt.params(0.025)
    with pytest.raises(ParameterError, match="lies outside the simulated 0..30000 µs"):
        sim.gt.params(1e10)
    with pytest.raises(ParameterError, match="t1_us = 5e"):
        sim.gt.displacement(0, 5e6)
    assert sim.gt.params(25_000)["hz"] > sim.gt.params(0)["hz"]
    sim.gt.displacement(0, 1e6)  # a second past the end: the models' own span


def test_odd_reference_times_counts_and_cameras_get_one_line():
    # estimate_egomotion(t_ref=nan) raised numpy's ValueError (inf: OverflowError, [1000]:
    # TypeError), a Camera as K failed in float(), segment_motion(n_warps=2.0) in range()
    # and a (3, 2) init for 2 clusters in reshape (probe DB)
    from evmotion.camera import Camera
    from evmotion.sim import simulate

    ev = simulate("rotation", duration_s=0.03, sensor_size=(60, 80), seed=0,
                  show_progress=False).events
    for t in (float("nan"), float("inf"), [1000]):
        with pytest.raises(ParameterError, match="t_ref must be a whole number"):
            estimate_egomotion(ev, warp="translation", t_ref=t)
    cam = Camera(60.0, 60.0, 39.5, 29.5)
    np.testing.assert_array_equal(estimate_egomotion(ev, warp="rotation", K=cam).params,
                                  estimate_egomotion(ev, warp="rotation", K=cam.K).params)
    seg = segment_motion(ev, 2.0, warp="translation", n_iter=1)
    assert seg.params.shape == (2, 2)
    with pytest.raises(ParameterError, match=r"n_warps must be a whole number >= 1, got 2.5"):
        segment_motion(ev, 2.5, warp="translation")
    with pytest.raises(ParameterError, match=r"init must hold 2 x 2 finite translation "
                                             r"parameters .* got shape \(3, 2\)"):
        segment_motion(ev, 2, warp="translation", init=np.zeros((3, 2)))
    with pytest.raises(ParameterError, match="tol must be finite"):
        segment_motion(ev, 2, warp="translation", tol=float("nan"))


def test_float32_times_past_their_precision_are_said():
    # float32 holds whole µs up to 2^24 only: an epoch's times became one, and 1e9 µs
    # steps of 64 µs, without a word; float16 times warned of numpy's cast (probe DB)
    import warnings

    from evmotion.errors import EvmotionWarning

    with pytest.warns(EvmotionWarning, match=r"float32, which holds whole microseconds "
                                             r"exactly only up to 16,777,216.*steps of 64 µs"):
        EventArray([1, 2], [1, 1], np.array([1e9, 1e9 + 10], np.float32), [1, 1], (4, 4))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ev = EventArray([1, 2], [1, 1], np.array([1, 2], np.float16), [1, 1], (4, 4))
        EventArray([1, 2], [1, 1], np.array([2**24 - 1, 2**24], np.float32), [1, 1], (4, 4))
    assert ev.t.tolist() == [1, 2]

"""The library used from a script as another lab would (probe P): what was a hang, a
silent non-measurement or a deep exception is now a clear result or error."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from evmotion import EventArray
from evmotion.errors import EventDataError, EvmotionWarning, PoorFitWarning, UnderfitWarning

RNG = np.random.default_rng(5)


def _noise(n=5000, size=(90, 120), seed=0):
    rng = np.random.default_rng(seed)
    return EventArray(x=rng.integers(0, size[1], n), y=rng.integers(0, size[0], n),
                      t=np.sort(rng.integers(0, 100_000, n)), p=rng.integers(0, 2, n),
                      sensor_size=size)


def test_indexing_past_the_end_raises_and_iteration_is_refused():
    ev = EventArray(x=[1, 2, 3], y=[1, 1, 1], t=[0, 1, 2], p=[1, 1, 1], sensor_size=(4, 4))
    assert ev[-1].t[0] == 2 and ev[2].t[0] == 2
    for k in (3, -4, 10**9):
        with pytest.raises(IndexError):
            ev[k]
    with pytest.raises(TypeError, match="not iterated event by event"):
        list(ev)  # it never ended: ev[k] past the end was an empty array


def test_step_slices_subsample_in_time_order():
    ev = _noise(100)
    sub = ev[::3]
    np.testing.assert_array_equal(sub.t, ev.t[::3])
    assert sub.x.flags.c_contiguous
    with pytest.raises(EventDataError, match="out of time order"):
        ev[::-1]


def test_from_structured_takes_other_tools_field_names():
    arr = np.zeros(3, [("ts", "<i8"), ("x", "<u2"), ("y", "<u2"), ("pol", "i1")])
    arr["ts"], arr["x"], arr["pol"] = [0, 5, 9], [1, 2, 3], [1, -1, 1]
    ev = EventArray.from_structured(arr, (4, 4))
    np.testing.assert_array_equal(ev.t, [0, 5, 9])
    np.testing.assert_array_equal(ev.p, [1, 0, 1])


def test_from_structured_takes_the_unit_its_time_field_names():
    # probe AN: a t_ns field was taken as µs, and every estimate came out 1000x small
    for name, scale in (("t_ns", 1000), ("timestamp_us", 1), ("t[ms]", 0.001)):
        arr = np.zeros(3, [(name, "<i8"), ("x", "<u2"), ("y", "<u2"), ("p", "?")])
        arr[name] = np.array([0, 5_000, 9_000]) * scale
        ev = EventArray.from_structured(arr, (4, 4))
        np.testing.assert_array_equal(ev.t, [0, 5_000, 9_000])
    # a unit given wins over the name's
    ev = EventArray.from_structured(arr, (4, 4), time_unit_us=1.0)
    np.testing.assert_array_equal(ev.t, [0, 5, 9])


def test_nanoseconds_since_the_epoch_are_refused_as_microseconds():
    t_ns = 1_700_000_000_000_000_000 + np.arange(3) * 1_000_000
    with pytest.raises(EventDataError, match=r"field 't' reaches 1700000000002000000, as "
                       r"microseconds past the year 5000: nanoseconds.*\(t \+ 500\) // 1000"):
        EventArray(x=[1, 2, 3], y=[0, 0, 0], t=t_ns, p=[1, 1, 1], sensor_size=(4, 4))
    # today's epoch µs (1.7e15) are times
    ev = EventArray(x=[1, 2, 3], y=[0, 0, 0], t=(t_ns + 500) // 1000, p=[1, 1, 1],
                    sensor_size=(4, 4))
    assert ev.duration_us == 2_000


def test_iter_flow_triplet_takes_a_whole_event_array():
    from evmotion.methods.triplet_stream import iter_flow_triplet

    ev = EventArray(x=[2, 3, 4], y=[5, 5, 5], t=[0, 10_000, 20_000], p=[1, 1, 1],
                    sensor_size=(10, 10))
    wins = list(iter_flow_triplet(ev, window_us=30_000))  # it spun forever
    assert len(wins) == 1 and float(wins[0].flow[5, 4, 0]) == 100.0


def test_events_off_the_sensor_are_refused_or_warned():
    from evmotion import estimate_egomotion, estimate_flow

    ev = _noise(3000)
    off = EventArray(x=ev.x.astype(np.int64) + 500, y=ev.y, t=ev.t, p=ev.p,
                     sensor_size=ev.sensor_size, validate=False)
    for call in (lambda: estimate_egomotion(off, warp="translation"),
                 lambda: estimate_flow(off)):
        with pytest.raises(EventDataError, match="all 3000 events lie off the sensor"):
            call()  # egomotion returned params 0, cost 0 and no warning
    swapped = EventArray(x=ev.x, y=ev.y, t=ev.t, p=ev.p, sensor_size=(120, 90),
                         validate=False)  # (W, H) for (H, W)
    with pytest.warns(EvmotionWarning, match=r"events lie off the sensor .*\(height, width\)"):
        estimate_egomotion(swapped, warp="translation")


def test_unsorted_unchecked_events_are_refused_by_the_estimators():
    # validate=False and shuffled: estimate_bos cut its interval by binary search and
    # solved the wrong events (881 px/s off), egomotion reported a window running
    # backwards, multicm said "spanning -2534 us" (probe)
    from evmotion import estimate_egomotion, estimate_flow
    from evmotion.errors import UnsortedError
    from evmotion.methods.bos import estimate_bos

    ev = _noise(3000)
    order = np.random.default_rng(1).permutation(len(ev))
    mixed = EventArray(x=ev.x[order], y=ev.y[order], t=ev.t[order], p=ev.p[order],
                       sensor_size=ev.sensor_size, validate=False)
    frame = np.random.default_rng(2).uniform(0.2, 0.8, ev.sensor_size)
    for call in (lambda: estimate_egomotion(mixed, warp="translation"),
                 lambda: estimate_flow(mixed),
                 lambda: estimate_bos(mixed, frame, t0_us=int(ev.t[0]), t1_us=int(ev.t[-1]))):
        with pytest.raises(UnsortedError, match=r"timestamps are not sorted: t\[\d+\]="):
            call()


@pytest.mark.parametrize("dense", ["mean", "lsq", "robust"])
def test_triplet_dense_flow_of_noise_is_no_measurement(dense):
    from evmotion.methods.triplet import estimate_flow_triplet
    from evmotion.methods.triplet_stream import iter_flow_triplet

    ev = _noise(5000)
    with pytest.warns(PoorFitWarning, match="no focus in 1 of 1 windows"):
        res = estimate_flow_triplet(ev, dense=dense)
    assert not res.valid.any() and res.gains[0] < 1.05  # robust: 100 % valid at 208 px/s
    wins = list(iter_flow_triplet(ev, dense=dense, window_us=200_000))
    assert wins[0].no_focus and not wins[0].valid.any()


def test_triplet_dense_flow_of_a_moving_scene_keeps_its_mask():
    from evmotion.methods.triplet import estimate_flow_triplet
    from evmotion.sim import simulate

    ev = simulate("translation", duration_s=0.05, sensor_size=(90, 120), seed=1,
                  show_progress=False).events
    with warnings.catch_warnings():
        warnings.simplefilter("error", PoorFitWarning)
        # (a 50 ms recording: the slow steps' triplets are missing, said apart)
        warnings.filterwarnings("ignore", "1 window.* slow steps' triplets", PoorFitWarning)
        res = estimate_flow_triplet(ev, dense="robust")
    # valid where the events support a flow (18.6 % of this sensor), not the 9-px
    # filter's spread into the still background around them
    from evmotion.methods.flowresult import event_support

    support = event_support(ev.x, ev.y, ev.sensor_size, 2, 2)
    assert res.gains[0] > 1.5 and 0.8 * support.mean() < res.valid.mean() <= support.mean()


def test_egomotion_result_says_whether_it_is_a_measurement():
    from evmotion import estimate_egomotion

    with pytest.warns(PoorFitWarning):
        res = estimate_egomotion(_noise(5000), warp="translation")
    assert res.poor_fit and not res.valid
    d = res.as_dict()
    assert d["valid"] is False and d["poor_fit"] is True


def test_estimate_bos_says_when_its_flow_is_too_small():
    from evmotion.methods.bos import estimate_bos, estimate_bos_sequence
    from evmotion.sim.schlieren import simulate_schlieren

    bos = simulate_schlieren("plume", sensor_size=(90, 80), duration_s=3 / 120, seed=0)
    f, t = bos.frames.images, bos.frames.t
    with pytest.warns(UnderfitWarning, match=r"1/\d\.\d\d of its size"):
        res = estimate_bos(bos.events, f[0], t0_us=t[0], t1_us=t[1], frame_next=f[1],
                           scales=(16, 8), iterations=30)
    assert res.fit_gain > 1.25  # 2.35: 0.20x the true magnitude, and no word before
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        estimate_bos_sequence(bos.events, f[:3], t[:3], scales=(16, 8), iterations=30)
    under = [w for w in said if issubclass(w.category, UnderfitWarning)]
    assert len(under) == 1 and "median over 2 intervals" in str(under[0].message)


def test_dotted_names_of_the_readme_and_tab_completion():
    import subprocess
    import sys

    code = ("import evmotion; f = evmotion.methods.bos.estimate_bos; "
            "g = evmotion.io.read_events; h = evmotion.eval.metrics.fwl; "
            "d = dir(evmotion); print(all(n in d for n in ('estimate_flow', 'EventArray', "
            "'simulate', 'methods', 'io')), 'triplet' in dir(evmotion.methods))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr  # 'module evmotion has no attribute methods'
    assert res.stdout.split() == ["True", "True"]


def test_arguments_that_failed_deep_inside_are_named():
    from evmotion import estimate_egomotion, estimate_flow, write_events
    from evmotion.errors import ParameterError
    from evmotion.eval.metrics import fwl
    from evmotion.methods.flowresult import FlowResult
    from evmotion.methods.triplet import TripletMatcher, estimate_flow_triplet

    ev = _noise(2000)
    cases = [
        (lambda: estimate_egomotion(ev, warp="translation", optimizer="tpe",
                                    bounds=([0], [1])), "bounds must be"),  # broadcast error
        (lambda: TripletMatcher(ev.sensor_size, dx="a"), "dx must be"),  # ufunc isfinite
        (lambda: TripletMatcher((20_000, 20_000)),
         r"sensor_size height must be a whole number in 1\.\.16384, got 20000"),
        (lambda: TripletMatcher(ev.sensor_size).process(ev.to_structured()),
         "events must be an EventArray"),  # no attribute 'sensor_size'
        (lambda: write_events("s.h5", ev.to_structured()), "from_structured"),
        (lambda: fwl(ev, np.zeros((*ev.sensor_size, 2)), mask=np.ones((3, 3), bool)),
         "mask has shape"),  # IndexError
        (lambda: fwl(ev, np.zeros((*ev.sensor_size, 2)), mask=np.full(ev.sensor_size, 0.5)),
         r"mask must be boolean \(or 0 / 1\); it holds 0.5 at"),  # read as True
        (lambda: fwl(ev, np.zeros((*ev.sensor_size, 2)), t_ref_us="mid"), "t_ref_us must"),
        (lambda: FlowResult(np.zeros((4, 5, 2), np.float32), 0, 10, 5, (), {}, 1.0, [], {},
                            None, 0, 0).displacement(float("nan")),
         "'t0_us' must be finite"),  # ValueError: cannot convert float NaN to integer
        (lambda: estimate_flow(ev, init=np.zeros((120, 90, 2))), "H and W swapped"),
        (lambda: estimate_flow(ev, n_scales=3, time_aware="upwind", time_aware_scales=9),
         "time_aware_scales"),
    ]
    for call, words in cases:
        with pytest.raises(ParameterError, match=words):
            call()

    from evmotion.errors import EmptyWindowError

    with pytest.raises(EmptyWindowError, match="selects no pixel"):  # NaN and numpy noise
        fwl(ev, np.zeros((*ev.sensor_size, 2)), mask=np.zeros(ev.sensor_size, bool))
    with pytest.warns(PoorFitWarning):  # (t0, t1) pairs as iter_events takes them
        res = estimate_flow_triplet(ev, windows=[(0, 50_000), (50_000, 100_000)])
    assert [(w.t0, w.t1) for w in res.windows] == [(0, 50_000), (50_000, 100_000)]


def test_evaluation_and_picture_helpers_name_bad_arguments(tmp_path):
    """Arguments of the helpers around the estimators that failed as raw Python / numpy
    errors, or were truncated (probe AU)."""
    from evmotion.errors import ParameterError
    from evmotion.eval import evaluate_windows, sharpness_windows
    from evmotion.events import EventArray
    from evmotion.io import write_flo
    from evmotion.io.flowfiles import FlowSequence
    from evmotion.methods.bos import estimate_bos_sequence
    from evmotion.methods.dnn import estimate_flow_dnn
    from evmotion.methods.kymogram import KymoLine, kymogram_from_events
    from evmotion.methods.triplet import estimate_flow_triplet
    from evmotion.parallel import map_windows
    from evmotion.viz import flow_to_rgb, iwe_to_rgb

    gt = FlowSequence(np.zeros((2, 4, 5, 2), np.float32), np.array([0, 10]), np.array([10, 20]))
    ev = EventArray([1, 2, 3], [1, 1, 1], [0, 5, 15], [1, 1, 1], (4, 5))
    arr = np.zeros(3, dtype=[("x", "<i2"), ("y", "<i2"), ("t", "<f8"), ("p", "?")])
    cases = [
        (lambda: evaluate_windows(np.zeros((1, 4, 5, 2)), [0, 10], [10, 20], gt),
         "1 flow windows for 2 t0s"),  # IndexError
        (lambda: evaluate_windows(np.zeros((2, 3, 5, 2)), [0, 10], [10, 20], gt),
         "not the same grid"),  # broadcast ValueError
        (lambda: evaluate_windows(np.zeros((2, 4, 5, 2)), [10, 20], [0, 10], gt),
         "t0s and t1s swapped"),
        (lambda: sharpness_windows(np.zeros((1, 4, 5, 2)), [0, 10], [10, 20], ev),
         "one flow per window"),
        (lambda: EventArray.from_structured(arr, (4, 8), time_unit_us=0),
         r"time_unit_us must be finite and in \[1e-06, "),  # every t became 0
        (lambda: EventArray.from_structured(arr, (4, 8), time_unit_us="s"),
         "time_unit_us must be"),  # UFuncTypeError
        (lambda: ev.windows_at([0, 5, 10], dt=1.5), r"dt \(frames\) must be a whole"),
        (lambda: kymogram_from_events([1, 2], KymoLine.row(0, (4, 5))),
         "kymogram_from_events: events must be an EventArray"),
        (lambda: estimate_flow_dnn([1, 2]), "estimate_flow_dnn: events must be an EventArray"),
        (lambda: write_flo(tmp_path / "z.flo", np.zeros((2, 2, 2)), dt_s="0.01"),
         "dt_s must be finite"),  # ufunc isfinite
        (lambda: flow_to_rgb(np.zeros((2, 2, 2)), max_magnitude="10"), "max_magnitude must"),
        (lambda: iwe_to_rgb(np.ones((2, 2)), vmax=-1.0), "vmax must be finite and > 0"),
        # fractions of µs had been floored
        (lambda: estimate_flow_triplet(ev, [(0, 2000.5)]),
         r"windows\[0\] t1 \(us\) must be a whole number"),
        (lambda: map_windows(len, ev, [(0.5, 10)]), r"windows\[0\] t0 \(us\) must be a whole"),
        (lambda: estimate_bos_sequence(ev, [np.ones((4, 5))] * 2, [0.0, 0.0083]),
         r"times_us must be whole microseconds, got \[0.0, 0.0083\] \(seconds\?"),
    ]
    for call, words in cases:
        with pytest.raises(ParameterError, match=words):
            call()
    # evaluate_windows takes lists as arrays
    assert len(evaluate_windows(np.zeros((2, 4, 5, 2)).tolist(), [0, 10], [10, 20],
                                gt).windows) == 2



def test_reading_and_writing_say_what_is_lost_or_empty(tmp_path):
    from evmotion.errors import ParameterError
    from evmotion.io import read_events, write_events
    from evmotion.sim import simulate

    ev = _noise(500, size=(30, 40))
    write_events(tmp_path / "a.h5", ev)
    with pytest.raises(ParameterError, match="t1 = 10 µs must be after t0 = 20 µs"):
        read_events(tmp_path / "a.h5", t0=20, t1=10)  # 0 events, silently
    with pytest.warns(EvmotionWarning, match="keeps no sensor size"):
        write_events(tmp_path / "a.npy", ev)
    with pytest.warns(EvmotionWarning, match="no event in 0.01 s.*constant image"):
        simulate("translation", duration_s=0.01, sensor_size=(30, 40),
                 image=np.ones((10, 10)), show_progress=False)


def test_nanoseconds_read_as_microseconds_are_questioned(tmp_path):
    from evmotion.io import read_events

    t = np.sort(RNG.integers(0, 30_000_000_000, 6600))  # 30 s in ns, not multiples of 1000
    arr = np.zeros(t.size, [("x", "<u2"), ("y", "<u2"), ("t", "<i8"), ("p", "u1")])
    arr["t"] = t
    # (over a sensor: the rate is judged on the pixels that fired)
    arr["x"], arr["y"] = RNG.integers(0, 100, t.size), RNG.integers(0, 100, t.size)
    np.save(tmp_path / "ns.npy", arr)
    with pytest.warns(EvmotionWarning, match=r"6600 events over [\d.e+]+ s on the \d+ pixels "
                                             r"that fired.*--time-unit ns"):
        read_events(tmp_path / "ns.npy", sensor_size=(100, 100))


def test_egomotion_on_too_few_events_to_test_is_no_measurement():
    # windows of ~1000 events of a real-like scene gave speeds of chance (2000 px/s for a
    # true 134) that sharpened the image by 5 %, marked valid: no tile held enough events
    # for the fit test, whose NaN passed
    from evmotion import estimate_egomotion
    from evmotion.sim import simulate

    ev = simulate("translation", duration_s=0.2, seed=2, show_progress=False).events
    with pytest.warns(PoorFitWarning, match="unchecked fit"):
        res = estimate_egomotion(ev[5000:5400], warp="translation")
    assert not np.isfinite(res.diagnostics["fit"]["explained_share"])
    assert res.poor_fit and not res.valid
    with warnings.catch_warnings():
        warnings.simplefilter("error", PoorFitWarning)
        full = estimate_egomotion(ev[5000:35000], warp="translation")
    assert full.valid


def test_the_warning_classes_are_at_the_top_level():
    # probe AN: every error class was in evmotion's namespace, no warning class
    import evmotion

    for name in ("EvmotionWarning", "CollapseWarning", "PoorFitWarning", "UnderfitWarning"):
        assert name in evmotion.__all__ and issubclass(getattr(evmotion, name), UserWarning)
    assert issubclass(evmotion.PoorFitWarning, evmotion.EvmotionWarning)
    assert evmotion.PoorFitWarning is PoorFitWarning


def test_every_output_reads_back_from_the_top_level(tmp_path):
    """Flow is read back as events are: ``evmotion.read_flow`` (probe AY looked for it
    there and met an AttributeError), every name of ``__all__`` resolving."""
    import evmotion
    from evmotion.io import read_flow, write_flo

    assert "read_flow" in evmotion.__all__ and evmotion.read_flow is read_flow
    assert all(getattr(evmotion, name) is not None for name in evmotion.__all__)
    write_flo(tmp_path / "f.flo", np.ones((4, 5, 2), np.float32))
    assert evmotion.read_flow(tmp_path / "f.flo", t0_us=0, t1_us=1000).flow.shape == (1, 4, 5, 2)


def test_metric_thresholds_are_whole_pixels_and_numbers():
    # npe_thresholds=[1.5] was floored to 1 (100 % for errors of 1.2 px), "13" read as 1
    # and 3, out_px="3" met numpy's "ufunc 'isfinite' not supported" (probe)
    from evmotion.errors import ParameterError
    from evmotion.eval import flow_metrics

    gt = np.zeros((4, 4, 2))
    est = gt.copy()
    est[..., 0] = 1.2
    for kw in ({"npe_thresholds": [1.5]}, {"npe_thresholds": "13"}, {"out_px": "3"}):
        with pytest.raises(ParameterError):
            flow_metrics(est, gt, **kw)
    assert flow_metrics(est, gt, npe_thresholds=[1, 2]).npe == {1: 100.0, 2: 0.0}


def test_multicm_refuses_an_infinite_weight_and_another_sensors_start():
    from evmotion import estimate_flow
    from evmotion.errors import ParameterError

    ev = _noise(3000)
    with pytest.raises(ParameterError, match="0 <= lam < inf"):
        estimate_flow(ev, lam=float("inf"))
    # each bound broken is named alone (one message had listed all five; probe)
    for kw, said in ((dict(lam=float("nan")), r"^need 0 <= lam < inf, got lam=nan$"),
                     (dict(max_iter=0), r"^max_iter must be a whole number >= 1, got 0$"),
                     # (-1 said ">= 0", 0 then "need 1 <= n_scales": probe BQ)
                     (dict(n_scales=0), r"^n_scales must be a whole number >= 1, got 0$"),
                     (dict(n_scales=-1), r"^n_scales must be a whole number >= 1, got -1$"),
                     (dict(n_scales=3, finest_level=2),
                      r"^need 1 <= n_scales <= finest_level, got n_scales=3, finest_level=2")):
        with pytest.raises(ParameterError, match=said):
            estimate_flow(ev, **kw)
    from evmotion.errors import EmptyWindowError

    with pytest.raises(EmptyWindowError, match="^window has 1 event spanning 0 us"):
        estimate_flow(ev[:1])  # (it was "1 events", probe BQ)
    other = EventArray(x=ev.x // 2, y=ev.y // 2, t=ev.t, p=ev.p,
                       sensor_size=(ev.sensor_size[0] // 2 + 1, ev.sensor_size[1] // 2 + 1))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = estimate_flow(other, n_scales=2)
    with pytest.raises(ParameterError, match=r"init is the result of a \d+x\d+ px"):
        estimate_flow(ev, n_scales=2, init=r)


def test_switches_take_booleans_and_numbers_are_not_strings():
    # use_polarity="no" and quadruple="no" turned the option on; simulate ran with
    # duration_s="0.01" (probe)
    import evmotion
    from evmotion import TripletMatcher, estimate_egomotion
    from evmotion.errors import ParameterError

    ev = _noise(3000)
    with pytest.raises(ParameterError, match="use_polarity must be True or False, got 'no'"):
        estimate_egomotion(ev, warp="translation", use_polarity="no")
    with pytest.raises(ParameterError, match="quadruple must be True or False, got 'no'"):
        TripletMatcher(ev.sensor_size, quadruple="no")
    with pytest.raises(ParameterError, match="duration_s must be finite .*got '0.01'"):
        evmotion.simulate("zoom", duration_s="0.01", sensor_size=(30, 40), show_progress=False)
    assert TripletMatcher(ev.sensor_size, quadruple=np.bool_(True)).quadruple is True


def test_helpers_name_their_bad_arguments():
    # each met a bare ZeroDivisionError, numpy reshape/convert error, pathlib TypeError or
    # a 70 GiB MemoryError (probe)
    from evmotion.errors import ParameterError
    from evmotion.eval import rms_error
    from evmotion.io import read_events
    from evmotion.methods.triplet import estimate_flow_triplet
    from evmotion.viz.flowpic import flow_picture
    from evmotion.viz.images import event_histogram

    ev = _noise(3000)
    calls = {"flow must have shape": lambda: flow_picture(np.ones((0, 0, 2))),
             r"shape\[0\] \(height\)": lambda: event_histogram(ev, shape=(0, -1)),
             "rms_error takes arrays of numbers": lambda: rms_error("a", "b"),
             "path must be a str or a path-like object, got bytes":
                 lambda: read_events(b"/tmp/x.h5"),
             "path must be a str or a path-like object, got int": lambda: read_events(5),
             r"n_bins=1000000 needs [\d.]+ GiB of voxels": lambda: estimate_flow_triplet(
                 ev, n_bins=10**6)}
    for match, call in calls.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with pytest.raises(ParameterError, match=match):
                call()


def test_network_options_given_to_multicm_are_named_alone():
    # probe BQ: threads=0 was said as "device='cpu', threads=0 are the network's"
    from evmotion import estimate_flow
    from evmotion.errors import ParameterError

    ev = _noise(3000)
    with pytest.raises(ParameterError, match=r"^estimate_flow: threads=0 is the network's "
                                             r"option: it applies with method='dnn'"):
        estimate_flow(ev, threads=0)
    with pytest.raises(ParameterError, match=r"device='cuda' and threads=2 are the network's "
                                             r"options: they apply"):
        estimate_flow(ev, device="cuda", threads=2)
    # a checkpoint for multicm without init='dnn' went unopened, unsaid (probe CK)
    with pytest.raises(ParameterError, match=r"^estimate_flow: checkpoint='nope.pt' is the "
                                             r"network's option: it applies with method='dnn' "
                                             r"or init='dnn'"):
        estimate_flow(ev, checkpoint="nope.pt")


@pytest.mark.parametrize("method", ["multicm", "dnn"])
def test_dense_flow_of_a_few_hundred_events_is_no_measurement(method):
    # probe BQ: the first 100 events of a simulated translation (228 us: 0.05 px of
    # motion) gave a flow of (-4489, -10046) px/s for (220, -130), 592 pixels valid
    from evmotion import estimate_flow
    from evmotion.errors import PoorFitWarning
    from evmotion.sim import simulate

    sim = simulate("translation", duration_s=0.05, sensor_size=(180, 240), seed=0,
                   show_progress=False)
    with pytest.warns(PoorFitWarning, match=r"too few events: 100 \(fewer than 1000\)"):
        res = estimate_flow(sim.events[:100], method=method)
    assert not res.valid.any() and res.meta["no_focus"]
    # on a small sensor as many events a pixel are enough (a fixed 1,000 refused 500 on
    # 32x32 that measured a translation at 0.3 px, probe BR)
    small = simulate("translation", duration_s=0.1, sensor_size=(32, 32), seed=0,
                     params={"vx": 100.0, "vy": 50.0}, show_progress=False).events
    win = small[len(small) // 2:len(small) // 2 + 500]
    res = estimate_flow(win, method=method)
    assert res.valid.any() and not res.meta["no_focus"]

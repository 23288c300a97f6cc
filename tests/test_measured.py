"""The checks of whether an estimate measures anything (methods/measured.py): flicker."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from evmotion.errors import PoorFitWarning
from evmotion.events import EventArray
from evmotion.methods.measured import (
    MAX_ONE_POLARITY,
    MAX_POLARITY_SWING,
    polarity_bursts,
    warn_flicker,
)


def moving(n=20000, shape=(120, 160), seed=0, flicker_share=0.0, hz=120.0, span_us=10_000):
    """Dots of both signs moving right at 2000 px/s, plus ``flicker_share`` of events from
    a light flickering at ``hz`` over the whole sensor (ON while it brightens)."""
    rng = np.random.default_rng(seed)
    h, w = shape
    n_fl = int(n * flicker_share)
    dots = rng.uniform([0, 0], [w, h], (300, 2))
    k = rng.integers(0, 300, n - n_fl)
    t = rng.uniform(0, span_us, n - n_fl)
    x = (dots[k, 0] + 2e-3 * t) % w
    p = k % 2
    tf = rng.uniform(0, span_us, 4 * n_fl)
    phase = np.cos(2 * np.pi * hz * tf * 1e-6)
    tf = tf[rng.uniform(size=tf.size) < np.abs(phase)][:n_fl]  # rate follows |dB/dt|
    pf = (np.cos(2 * np.pi * hz * tf * 1e-6) > 0).astype(int)
    xs = np.r_[x, rng.uniform(0, w, tf.size)]
    ys = np.r_[dots[k, 1], rng.uniform(0, h, tf.size)]
    ts = np.r_[t, tf]
    order = np.argsort(ts, kind="stable")
    return EventArray(x=np.floor(xs[order]).astype(int), y=np.floor(ys[order]).astype(int),
                      t=ts[order].astype(np.int64), p=np.r_[p, pf][order], sensor_size=shape)


def test_flicker_swings_polarity_and_motion_does_not():
    swing, one, _ = polarity_bursts(moving())
    assert swing < 0.2 and one < 0.6
    swing, one, _ = polarity_bursts(moving(flicker_share=0.8))
    assert swing > MAX_POLARITY_SWING
    # 2 ms inside one ON phase of the flicker: one polarity
    _, one, _ = polarity_bursts(moving(flicker_share=0.98, span_us=1500, n=8000))
    assert one > MAX_ONE_POLARITY


def test_one_polarity_at_a_steady_rate_is_not_flicker():
    """Files or sensors without polarity (all ON) at a steady rate are not flagged; a
    burst of them is."""
    ev = moving()
    steady = EventArray(ev.x, ev.y, ev.t, np.ones(len(ev)), ev.sensor_size)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert warn_flicker(steady, "dense flow") is None
    t = np.asarray(steady.t).copy()
    t[: len(t) // 2] = t[: len(t) // 2] // 20  # half the events in the first 5 % of the span
    burst = EventArray(steady.x, steady.y, np.sort(t), steady.p, steady.sensor_size)
    with pytest.warns(PoorFitWarning, match="100% of them have one polarity"):
        assert warn_flicker(burst, "dense flow") is not None


@pytest.mark.parametrize("method", ["multicm", "dnn"])
def test_a_flickering_window_is_no_measurement(method):
    """Probe AK: under 120 Hz flicker with a moving camera the network's flow was 20-800x
    the truth, 80-86 % valid, unflagged (its flow gathers the bursts: FWL 4-23)."""
    if method == "dnn":
        pytest.importorskip("torch")
    from evmotion.methods.multicm import estimate_flow

    with pytest.warns(PoorFitWarning, match="bursts of one polarity"):
        res = estimate_flow(moving(flicker_share=0.8), method=method)
    assert res.meta["no_focus"] and not res.valid.any()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = estimate_flow(moving(), method=method)
    assert not res.meta["no_focus"] and res.valid.any()


def test_flow_alignment_gain_checks_its_flow():
    """A flow of another size raised a raw IndexError; an all-NaN flow returned NaN with
    numpy's RuntimeWarning (probe AI)."""
    from evmotion.errors import ParameterError
    from evmotion.methods.measured import flow_alignment_gain

    ev = moving()
    with pytest.raises(ParameterError, match=r"flow has shape \(10, 10, 2\), expected"):
        flow_alignment_gain(ev, np.zeros((10, 10, 2)), 0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.isnan(flow_alignment_gain(ev, np.full((120, 160, 2), np.nan), 0))
    flow = np.zeros((120, 160, 2))
    flow[..., 0] = 2000.0
    half = flow.copy()
    half[:, :40] = np.nan  # unknown where no estimate: those events are left out
    assert flow_alignment_gain(ev, half, 5000) > 1.5


def panned(n, span_s, speed=(60.0, -30.0), shape=(90, 120), seed=0, dots_per_view=400):
    """``n`` events of a random-dot plane panning at ``speed`` px/s past the sensor for
    ``span_s`` seconds: each dot fires at random times, wherever it is then in view."""
    rng = np.random.default_rng(seed)
    h, w = shape
    vx, vy = speed
    lo = (min(0.0, -vx * span_s), min(0.0, -vy * span_s))
    hi = (w + max(0.0, -vx * span_s), h + max(0.0, -vy * span_s))
    n_dots = int(dots_per_view * (hi[0] - lo[0]) * (hi[1] - lo[1]) / (w * h))
    dots = rng.uniform(lo, hi, (n_dots, 2))
    k = rng.integers(0, n_dots, 40 * n)
    t = rng.uniform(0, span_s, k.size)
    x, y = dots[k, 0] + vx * t, dots[k, 1] + vy * t
    keep = np.flatnonzero((x >= 0) & (x < w) & (y >= 0) & (y < h))[:n]
    order = keep[np.argsort(t[keep])]
    return EventArray(x=np.floor(x[order]).astype(int), y=np.floor(y[order]).astype(int),
                      t=(t[order] * 1e6).astype(np.int64), p=rng.integers(0, 2, order.size),
                      sensor_size=shape)


def test_a_window_the_scene_crossed_is_no_measurement():
    """An 8 s window of a 67 px/s pan on a 240 px sensor (the scene crossed the image twice)
    came out at 2.6 px/s, valid, chance 1.44 (probe AJ). Its flow does not carry the
    window's first half onto its second; a window of the same pan short enough does."""
    from evmotion.methods.measured import MIN_HALVES_CORRELATION, halves_consistency
    from evmotion.methods.multicm import estimate_flow

    long, short = panned(60_000, 8.0), panned(30_000, 0.3)
    with pytest.warns(PoorFitWarning, match="does not carry the window's first half"):
        res = estimate_flow(long)
    assert res.meta["no_focus"] and not res.valid.any()
    assert res.meta["halves_correlation"] < MIN_HALVES_CORRELATION
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = estimate_flow(short)
    assert res.valid.any() and res.meta["halves_correlation"] > 0.5
    assert np.median(res.flow[res.valid], axis=0) == pytest.approx([60, -30], abs=6)
    flow = np.zeros((90, 120, 2))
    flow[..., 0], flow[..., 1] = 60.0, -30.0
    mid = (int(long.t[0]) + int(long.t[-1])) // 2
    assert halves_consistency(long, flow, mid) > MIN_HALVES_CORRELATION  # the true flow passes


def test_one_edge_of_one_sign_at_a_steady_rate_is_not_flicker():
    """A dark bar entering a bright view gives 98 % OFF events, the rest sensor noise, at
    a steady rate: probe AL saw it flagged as flickering light (with good estimates), as
    were scenes whose contrast never reached the OFF threshold (97-98 % ON)."""
    ev = moving()
    p = (np.random.default_rng(1).uniform(size=len(ev)) < 0.02).astype(int)  # 98 % OFF
    edge = EventArray(ev.x, ev.y, ev.t, p, ev.sensor_size)
    assert polarity_bursts(edge)[1] > MAX_ONE_POLARITY
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert warn_flicker(edge, "dense flow") is None


@pytest.mark.parametrize("method", ["egomotion", "multicm", "dnn"])
def test_a_window_across_a_time_gap_is_no_measurement(method):
    """Probe: a window of 30k events holding the last events before a 100 s pause and the
    first after it gave 0.02 px/s for 220, contrast gain 1.19, valid. The same motion with
    its second half 100 s later: no measurement; without the gap, one."""
    from evmotion.methods.egomotion import estimate_egomotion
    from evmotion.methods.multicm import estimate_flow

    if method == "dnn":
        pytest.importorskip("torch")
    ev = moving()
    t = np.asarray(ev.t).copy()
    half = len(t) // 2
    t[half:] += 100_000_000
    gap = EventArray(ev.x, ev.y, t, ev.p, ev.sensor_size)

    def run(events):
        if method == "egomotion":
            res = estimate_egomotion(events, "translation")
            return res.valid
        return bool(estimate_flow(events, method=method).valid.any())

    with pytest.warns(PoorFitWarning, match="time gap: no event for 100"):
        assert not run(gap)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert run(ev)


def test_gap_share():
    from evmotion.methods.measured import gap_share, warn_gap

    assert gap_share(np.arange(100)) == pytest.approx(1 / 99)
    assert gap_share(np.array([5])) == 0.0 and gap_share(np.array([3, 3])) == 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert warn_gap(np.r_[np.arange(10), 18], "flow") is None  # a gap of 9 in 18
    with pytest.warns(PoorFitWarning, match=r"no event for 2e-05 s \(91% of the window\)"):
        assert warn_gap(np.r_[0, 1, 21, 22], "flow") is not None


def test_a_translating_checkerboard_is_motion_not_flicker():
    """Probe BG: a translating checkerboard (the simulator's, pure motion) was flagged as
    flickering light, its flow right (AEE 0.65 px against 3.3 for zero flow) discarded:
    all its edges of one sign enter together, so the sensor's mean polarity swings (0.53)
    as under flicker; but each 8 px block keeps its sign, which flicker does not."""
    from evmotion.methods.measured import MIN_LOCAL_SWING, lit_not_moved, local_swing
    from evmotion.sim import simulate

    sim = simulate("translation", duration_s=0.05, texture="checker", show_progress=False)
    swung = []
    for k in range(0, len(sim.events) - 30_000, 15_000):
        win = sim.events[k:k + 30_000]
        swung.append(polarity_bursts(win)[0])
        assert local_swing(win) < MIN_LOCAL_SWING / 2
        assert lit_not_moved(win) is None
    assert max(swung) > MAX_POLARITY_SWING  # what the sensor-wide test alone flagged
    flicker = moving(flicker_share=0.8)
    assert local_swing(flicker) > 2 * MIN_LOCAL_SWING and lit_not_moved(flicker) is not None


@pytest.mark.parametrize("shape", [(8, 8), (720, 1280)])
def test_the_chance_tests_scatter_is_measured_and_its_gain_unchanged(shape):
    """Probe DB: one shuffle of the times scattered the ratio to 1.31 with nothing moving
    on an 8x8 sensor. ``alignment_chance`` also says how far the alignment lies beyond the
    scatter of 16 shuffles; its gain is the single shuffle's as before (dense image or
    occupied pixels alike)."""
    from evmotion.methods.measured import MIN_CHANCE_Z, alignment_chance, alignment_gain

    rng = np.random.default_rng(1)
    n = 3000
    h, w = shape
    t = np.sort(rng.integers(0, 30_000, n))
    x, y = rng.integers(0, w, n).astype(float), rng.integers(0, h, n).astype(float)
    f = np.tile([120.0, -60.0], (n, 1))
    dt = (t - 15_000) * 1e-6

    def variance(times):  # the chance test's image variance as it was computed before
        xw, yw = np.rint(x - f[:, 0] * times), np.rint(y - f[:, 1] * times)
        keep = (xw >= 0) & (xw < w) & (yw >= 0) & (yw < h)
        counts = np.unique(yw[keep] * w + xw[keep], return_counts=True)[1].astype(float)
        return np.sum(counts**2) / (h * w) - (np.sum(counts) / (h * w)) ** 2

    before = variance(dt) / variance(np.random.default_rng(0).permutation(dt))
    gain, z = alignment_chance(x, y, t, f, 15_000, shape)
    assert gain == pytest.approx(before, rel=1e-12)
    assert alignment_gain(x, y, t, f, 15_000, shape) == gain
    assert abs(z) < MIN_CHANCE_Z  # noise under a motion of its own: within the scatter
    # 20 dots moving with that motion: far beyond it
    dots = rng.uniform(0, [w, h], (20, 2))[rng.integers(0, 20, n)]
    x, y = np.rint(dots[:, 0] + f[:, 0] * dt), np.rint(dots[:, 1] + f[:, 1] * dt)
    keep = (x >= 0) & (x < w) & (y >= 0) & (y < h)
    _, z = alignment_chance(x[keep], y[keep], t[keep], f[keep], 15_000, shape)
    assert z > 4 * MIN_CHANCE_Z
    # the permutations' seed is exposed (it was a hidden 0, probe DK): CHANCE_SEED by
    # default, others draw other permutations and leave the verdict where it was
    from evmotion.methods.measured import CHANCE_SEED

    args = (x[keep], y[keep], t[keep], f[keep], 15_000, shape)
    assert alignment_chance(*args, seed=CHANCE_SEED) == alignment_chance(*args)
    others = [alignment_chance(*args, seed=s)[1] for s in (1, 2)]
    assert len({z, *others}) == 3 and min(others) > 4 * MIN_CHANCE_Z


def test_a_chance_test_that_could_not_run_says_nothing():
    # every event warped off the sensor: gain NaN, z 0 said "+nan % better ... 0.0
    # standard deviations" (review DR)
    import warnings

    from evmotion.methods.measured import warn_by_chance

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert warn_by_chance(float("nan"), "dense flow", z=0.0) is None


def _halves_reference(x, y, t, f, t_ref_us, shape):
    """The halves correlation as first written: both halves' images, each padded and
    summed over its nine shifts (the 3x3 box), correlated over the sensor."""
    h, w = shape
    dt = (int(t_ref_us) - t) * 1e-6
    xw = np.rint(x + f[:, 0] * dt).astype(np.int64)
    yw = np.rint(y + f[:, 1] * dt).astype(np.int64)
    inside = (xw >= 0) & (xw < w) & (yw >= 0) & (yw < h)
    first = t < (int(t[0]) + int(t[-1])) // 2
    images = []
    for half in (first & inside, ~first & inside):
        img = np.bincount(yw[half] * w + xw[half], minlength=h * w).reshape(h, w)
        pad = np.pad(img.astype(np.float64), 1)
        images.append(sum(pad[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3))
                      .ravel())
    a, b = (v - v.mean() for v in images)
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


@pytest.mark.parametrize(("shape", "n", "speed"), [((7, 5), 40, 300.0), ((60, 80), 3000, 80.0),
                                                   ((120, 160), 20_000, 400.0),
                                                   ((1, 9), 30, 50.0)])
def test_halves_correlation_matches_the_padded_images(shape, n, speed):
    """halves_correlation scatters each event's 3x3 box on a framed grid (35 -> 5 ms a
    30k window at 1280x720); it equals the padded images' correlation, edges included."""
    from evmotion.methods.measured import halves_correlation

    rng = np.random.default_rng(n)
    h, w = shape
    x, y = rng.integers(0, w, n), rng.integers(0, h, n)
    t = np.sort(rng.integers(0, 30_000, n))
    f = rng.normal(0, speed, (n, 2))
    for t_ref in (0, 15_000, 30_000):
        assert halves_correlation(x, y, t, f, t_ref, shape) == pytest.approx(
            _halves_reference(x, y, t, f, t_ref, shape), rel=1e-9, abs=1e-12)

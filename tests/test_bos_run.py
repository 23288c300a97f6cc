"""evmotion.methods.bos_run: one contrast threshold per sequence, warm-started intervals."""

import numpy as np
import pytest

from evmotion.errors import ParameterError, UnderfitWarning
from evmotion.io.bosinput import frame_intervals, load_bos_input
from evmotion.methods.bos import estimate_bos, estimate_contrast_threshold
from evmotion.methods.bos_run import sequence_contrast_threshold, solve_bos_input


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    from evmotion.sim.schlieren import simulate_schlieren, write_schlieren

    d = tmp_path_factory.mktemp("run") / "jet"
    write_schlieren(simulate_schlieren("jet", sensor_size=(48, 40), duration_s=4 / 120,
                                       seed=1), d)
    return load_bos_input(d)


def test_frame_intervals_select_overlap_and_limits():
    ft = np.array([0, 10, 20, 30, 40])
    assert frame_intervals(ft, 12, 40).tolist() == [[1, 10, 20], [2, 20, 30], [3, 30, 40]]
    assert frame_intervals(ft, 0, 40, t0=10, t1=30).tolist() == [[1, 10, 20], [2, 20, 30]]
    assert frame_intervals(ft, 0, 40, max_intervals=1).tolist() == [[0, 0, 10]]
    assert frame_intervals(ft, 41, 50).shape == (0, 3)


def test_max_intervals_must_be_a_count(data):
    """-1 used to drop the last interval silently (a slice)."""
    from evmotion.errors import ParameterError

    for bad in (-1, 0, 1.5):
        with pytest.raises(ParameterError, match="max_intervals"):
            load_bos_input(data.source, max_intervals=bad)


def test_iter_bos_input_checks_start_and_workers(data):
    from evmotion.errors import ParameterError
    from evmotion.methods.bos_run import iter_bos_input

    for kw in ({"start": float("nan")}, {"start": 1.5}, {"start": -1}, {"workers": 0},
               {"workers": float("nan")}, {"workers": 1.5}):
        with pytest.raises(ParameterError, match=next(iter(kw))):
            iter_bos_input(data, 0.2, **kw)


def test_sequence_c_is_the_median_of_the_intervals(data):
    c, est = sequence_contrast_threshold(data, samples=3)
    picks = [0, 2, 3]  # round(linspace(0, 3, 3))
    ref = [estimate_contrast_threshold(data.events, data.frames[i], data.frames[i + 1],
                                       t0_us=int(data.frame_times[i]),
                                       t1_us=int(data.frame_times[i + 1]))
           for i in picks]
    np.testing.assert_allclose(est, ref)
    assert c == pytest.approx(np.median(ref))
    with pytest.raises(ParameterError, match="samples"):
        sequence_contrast_threshold(data, samples=0)


def test_one_worker_warm_starts_in_order(data):
    run = solve_bos_input(data, contrast_threshold=0.2, iterations=10, scales=(32, 16, 8))
    assert run.c_source == "given" and len(run.results) == len(data.intervals) == 4
    prev = None
    for (i, t0, t1), res in zip(data.intervals, run.results, strict=True):
        ref = estimate_bos(data.events, data.frames[i], t0_us=int(t0), t1_us=int(t1),
                           frame_next=data.frames[i + 1], init=prev, contrast_threshold=0.2,
                           iterations=10, scales=(32, 16, 8))
        np.testing.assert_array_equal(res.flow, ref.flow)
        prev = ref
    with pytest.raises(ParameterError, match="workers"):
        solve_bos_input(data, workers=0)


def _threshold_warnings(data, events, frames) -> list[str]:
    """The warnings of :func:`sequence_contrast_threshold` on one interval [0, 1000) us of
    ``events`` between the two ``frames``."""
    import dataclasses
    import warnings

    from evmotion.errors import EvmotionWarning

    run = dataclasses.replace(data, events=events, frames=frames,
                              frame_times=np.array([0, 1000]),
                              intervals=np.array([[0, 0, 1000]]), roi=None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sequence_contrast_threshold(run)
    return [str(w.message) for w in caught if issubclass(w.category, EvmotionWarning)]


def test_sequence_c_from_the_events_alone_is_said(data):
    """Frames of weak air imaged at 6 grey levels: their noise exceeds their change, C
    comes from the events' slope (low where the air changes the image by less than C), and
    the run says so instead of scaling the flow silently; bright frames say nothing of
    it."""
    import sys
    from pathlib import Path

    from evmotion.events import EventArray

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from test_bos import _weak_air

    bg, moved, ev = _weak_air()
    t = np.sort(np.random.default_rng(1).integers(0, 1000, len(ev)))
    ev = EventArray(x=ev.x, y=ev.y, t=t, p=ev.p, sensor_size=ev.sensor_size)
    said = {}
    for white in (255, 6):
        frames = np.rint(np.clip(np.stack([bg, moved]), 0, 1) * white).astype(np.uint8)
        said[white] = _threshold_warnings(data, ev, frames)
    # weak air: one event where a pixel fires at all, said as such at any exposure
    assert [m for m in said[255] if "fire more than once" not in m] == []
    alone = [m for m in said[6] if "from the events alone" in m]
    assert len(alone) == 1 and "--contrast-threshold" in alone[0]


def test_a_low_contrast_background_warns_that_the_magnitude_is_uncertain(data):
    """Dots of 15 % contrast behind 1 px of air: most of the change stays below C, the
    pixels that fired correlate with it well enough to give a C (4x low on probe A's
    scene of this kind, flow 0.2x), and around them the events follow it weakly; the run
    says the magnitude is uncertain. Dots of 80 % contrast say nothing."""

    from scipy.ndimage import gaussian_filter, map_coordinates

    from evmotion.events import EventArray

    n, c = 160, 0.15
    rng = np.random.default_rng(0)
    dots = gaussian_filter((rng.random((n, n)) < 0.15).astype(float), 1.0)
    yy, xx = np.mgrid[0:n, 0:n]
    amp = np.exp(-((xx - n / 2) ** 2 + (yy - n / 2) ** 2) / (2 * (n / 5) ** 2))
    said = {}
    for contrast in (0.8, 0.15):
        bg = (1 - contrast) + contrast * dots / dots.max()
        moved = map_coordinates(bg, [yy, xx - amp], order=3, mode="nearest")
        d = np.log(moved) - np.log(bg)
        first = c + rng.uniform(-c, c, d.shape) * np.sign(d)  # level in the 2C band
        k = np.where(np.abs(d) >= first, 1 + np.floor((np.abs(d) - first) / c), 0)
        s = (k * np.sign(d)).astype(int)
        ys, xs = np.nonzero(s)
        m = np.abs(s[ys, xs])
        ev = EventArray(x=np.repeat(xs, m), y=np.repeat(ys, m),
                        t=np.sort(rng.integers(0, 1000, m.sum())), p=np.repeat(s[ys, xs] > 0, m),
                        sensor_size=(n, n))
        frames = np.rint(np.stack([bg, moved]) * 255).astype(np.uint8)
        said[contrast] = _threshold_warnings(data, ev, frames)
    assert said[0.8] == []
    assert any("follow the frames' change weakly" in m and "uncertain" in m
               for m in said[0.15])


def test_air_below_threshold_nearly_everywhere_is_said(data):
    """Slow air (0.3 px between two frames of dots of 80 % contrast): nearly every pixel
    that fires fires once, most of the change stays below C, and the flow came out
    0.68-0.87x its size without a word (probe AY, 240 fps); the run says so, with C
    estimated or given. The same air at 1.5 px says nothing."""
    import dataclasses
    import warnings

    from scipy.ndimage import gaussian_filter, map_coordinates

    from evmotion.errors import EvmotionWarning
    from evmotion.events import EventArray
    from evmotion.methods.bos_run import sequence_threshold

    n, c = 160, 0.2
    rng = np.random.default_rng(0)
    dots = gaussian_filter((rng.random((n, n)) < 0.15).astype(float), 1.0)
    bg = 0.2 + 0.8 * dots / dots.max()
    yy, xx = np.mgrid[0:n, 0:n]
    bump = np.exp(-((xx - n / 2) ** 2 + (yy - n / 2) ** 2) / (2 * (n / 5) ** 2))
    said = {}
    for amp in (1.5, 0.3):
        moved = map_coordinates(bg, [yy, xx - amp * bump], order=3, mode="nearest")
        d = np.log(moved) - np.log(bg)
        first = rng.uniform(0, c, d.shape)  # a settled sensor: levels anywhere in [0, C)
        k = np.where(np.abs(d) >= first, 1 + np.floor((np.abs(d) - first) / c), 0)
        s = (k * np.sign(d)).astype(int)
        ys, xs = np.nonzero(s)
        m = np.abs(s[ys, xs])
        ev = EventArray(x=np.repeat(xs, m), y=np.repeat(ys, m),
                        t=np.sort(rng.integers(0, 1000, m.sum())),
                        p=np.repeat(s[ys, xs] > 0, m), sensor_size=(n, n))
        run = dataclasses.replace(data, events=ev,
                                  frames=np.rint(np.stack([bg, moved]) * 255).astype(np.uint8),
                                  frame_times=np.array([0, 1000]),
                                  intervals=np.array([[0, 0, 1000]]), roi=None)
        for given in (None, c):
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                sequence_threshold(run, given)
            said[amp, given] = [str(w.message) for w in caught
                                if issubclass(w.category, EvmotionWarning)
                                and "fire more than once" in str(w.message)]
    assert said[1.5, None] == said[1.5, c] == []
    assert len(said[0.3, None]) == len(said[0.3, c]) == 1
    assert "too small" in said[0.3, c][0]


def test_a_flow_that_explains_the_events_at_a_fraction_of_their_size_is_said(tmp_path):
    """Air structures finer than the finest 8-px patches: the flow comes out 0.4-0.7x its
    size without a word (probe I's renders); the flow's predicted increment then falls
    short of the measured one where the events fired (fit gain 1.3-1.6, 1.01-1.08 on
    scenes solved well), and the run says so."""
    import warnings

    from evmotion.errors import EvmotionWarning
    from evmotion.methods.bos import warn_underfit

    with pytest.warns(EvmotionWarning, match="1/1.6. of its size.*too small"):
        warn_underfit([1.55, 1.62, float("nan"), 1.7])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_underfit([1.01, 1.08, 1.3])  # the median decides
        warn_underfit([])


def test_the_fit_gain_of_a_well_solved_and_a_too_coarse_flow():
    """fit_gain near 1 on a simulated plume of 240 x 200 px; a flow held to 64-px patches
    (the coarsest scale only) explains far less of the events' increment."""
    from evmotion.sim.schlieren import simulate_schlieren

    sim = simulate_schlieren("plume", sensor_size=(240, 200), duration_s=2 / 120, seed=0)
    f, t = sim.frames.images, sim.frames.t
    kw = dict(t0_us=int(t[1]), t1_us=int(t[2]), frame_next=f[2], contrast_threshold=0.2)
    good = estimate_bos(sim.events, f[1], **kw)
    coarse = estimate_bos(sim.events, f[1], scales=(64,), **kw)
    assert 0.8 < good.fit_gain < 1.25 < coarse.fit_gain, (good.fit_gain, coarse.fit_gain)


def test_the_sensors_start_up_interval_is_said(tmp_path):
    """The simulator starts every pixel at its reference level, as a sensor switched on
    with the recording: its first interval's events follow the frames' change at about
    half the later rate (the flow there came out 0.26-0.56x). Said once, naming the
    interval and the --t0 that leaves it out; a selection that starts later is not."""
    from evmotion.errors import EvmotionWarning
    from evmotion.methods.bos_run import warn_startup
    from evmotion.sim.schlieren import simulate_schlieren, write_schlieren

    d = tmp_path / "ice"
    write_schlieren(simulate_schlieren("ice", sensor_size=(120, 160), duration_s=6 / 120,
                                       seed=0), d)
    with pytest.warns(EvmotionWarning, match=r"begin in the frame interval \[0, 8333\) us .*"
                                             r"no valid pixel; --t0 0.008333"):
        assert warn_startup(load_bos_input(d)) == (0,)
    # the sequence solve writes it with no valid pixel, the next intervals as they are
    with pytest.warns(EvmotionWarning, match="begin in the frame interval"):
        run = solve_bos_input(load_bos_input(d, max_intervals=3), iterations=20)
    assert [bool(r.valid.any()) for r in run.results] == [False, True, True]
    # one interval, or two, after it: nothing to tell it by, said as such (probe AM: two
    # frames gave 0.19x, valid, unsaid)
    # (with the other start-up warnings' range, probe BY: 0.26-0.56x here, 0.81 there)
    with pytest.warns(EvmotionWarning, match=r"\[0, 8333\) us and fewer than two intervals "
                                             r"that follow tell.*\(0\.26-0\.81x on simulated"):
        assert warn_startup(load_bos_input(d, max_intervals=2)) == ()
    later = load_bos_input(d, t0=8333)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", EvmotionWarning)
        assert warn_startup(later) == ()


def test_a_start_up_followed_by_a_cut_interval_is_said(tmp_path):
    """Three intervals, the last cut by the recording's end: one interval that tells a
    rate follows the first, and the start-up check returned without a word (probe CJ: the
    first interval went out valid at 0.19x)."""
    import warnings

    from evmotion.errors import EvmotionWarning
    from evmotion.io import read_events, write_events
    from evmotion.io.bosinput import load_bos_input
    from evmotion.methods.bos_run import warn_startup
    from evmotion.sim.schlieren import simulate_schlieren, write_schlieren

    d = tmp_path / "ice"
    write_schlieren(simulate_schlieren("ice", sensor_size=(120, 160), duration_s=6 / 120,
                                       seed=0), d)
    write_events(d / "events.txt", read_events(d).slice_time(0, 2 * 8333 + 5000))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the cut and the empty intervals, said elsewhere
        data = load_bos_input(d)
    assert len(data.intervals) == 3 and data.cut == (2,)
    with pytest.warns(EvmotionWarning, match=r"begin in the frame interval \[0, 8333\) us "
                                             r"and fewer than two intervals that follow"):
        assert warn_startup(data) == ()


@pytest.fixture(scope="module")
def ice10(tmp_path_factory):
    from evmotion.io import read_events
    from evmotion.sim.schlieren import simulate_schlieren, write_schlieren

    d = tmp_path_factory.mktemp("ice10") / "ice"
    write_schlieren(simulate_schlieren("ice", sensor_size=(120, 160), duration_s=10 / 120,
                                       seed=0), d)
    return d, read_events(d)


def _keeping(ice10, tmp_path, keep):
    import shutil

    from evmotion.io import write_events

    d, ev = ice10
    shutil.copytree(d, tmp_path / "v")
    write_events(tmp_path / "v" / "events.txt", ev[keep(ev.t)])
    return tmp_path / "v"


def test_the_start_up_t0_is_written_to_the_us_on_an_epoch_clock(ice10, tmp_path):
    """Probe BC: on a host clock (1.7e9 s) the hint said --t0 1.7e+09, the first frame's
    time rounded, which keeps the interval it was to leave out."""
    import shutil

    from evmotion.errors import EvmotionWarning
    from evmotion.events import EventArray
    from evmotion.io import write_events
    from evmotion.methods.bos_run import warn_startup

    d, ev = ice10
    v = tmp_path / "epoch"
    shutil.copytree(d, v)
    offset = 1_700_000_000_000_000
    write_events(v / "events.txt", EventArray(ev.x, ev.y, ev.t + offset, ev.p,
                                              sensor_size=ev.sensor_size))
    lines = (d / "images.txt").read_text().split("\n")
    (v / "images.txt").write_text("".join(
        f"{(int(round(float(t) * 1e6)) + offset) // 1_000_000}."
        f"{(int(round(float(t) * 1e6)) + offset) % 1_000_000:06d} {name}\n"
        for t, name in (ln.split() for ln in lines if ln.strip())))
    with pytest.warns(EvmotionWarning, match=r"--t0 1700000000\.008333 leaves it out"):
        assert warn_startup(load_bos_input(v)) == (0,)


def test_start_up_that_lasts_into_the_next_interval_is_said(ice10, tmp_path):
    """Another renderer's pixels took two intervals to settle: the second one's events
    followed the change at 0.80 of the settled rate and its flow came out 0.68-0.81x,
    valid, unsaid (probe). Here 30 % of that interval's events are dropped."""
    from evmotion.errors import EvmotionWarning
    from evmotion.methods.bos_run import unmeasured_intervals

    rng = np.random.default_rng(0)
    thin = _keeping(ice10, tmp_path, lambda t: ~((t >= 8333) & (t < 16667)
                                                  & (rng.random(t.size) < 0.3)))
    with pytest.warns(EvmotionWarning, match=r"and the next, \[8333, 16667\) us, at 0\.7\d "
                                             r"of the settled rate.* leaves them out"):
        assert unmeasured_intervals(load_bos_input(thin)) == (0, 1)
    with pytest.warns(EvmotionWarning, match=r"begin in the frame interval \[0, 8333\) us "
                                             r"and follow"):
        assert unmeasured_intervals(load_bos_input(ice10[0])) == (0,)


def test_start_up_among_rates_that_disagree_is_said_as_unknown(ice10, tmp_path):
    """Probe BF: under 100 Hz flicker of 2-10 % the next intervals' rates spread 2.1-4.3,
    and the start-up check returned without a word (the first interval went out at 0.59x,
    valid). Here half of one later interval's events are dropped."""
    from evmotion.errors import EvmotionWarning
    from evmotion.methods.bos_run import warn_startup

    rng = np.random.default_rng(2)
    uneven = _keeping(ice10, tmp_path, lambda t: ~((t >= 16667) & (t < 25000)
                                                    & (rng.random(t.size) < 0.6)))
    with pytest.warns(EvmotionWarning, match=r"\[0, 8333\) us, and the next intervals' events "
                                             r"follow .* at rates \d\.\dx apart \(schlieren "
                                             r"too faint .*flickering light.*cannot be "
                                             r"told.*--t0 0\.008333"):
        assert warn_startup(load_bos_input(uneven)) == ()


def test_a_first_interval_of_next_to_no_change_is_not_called_start_up(ice10, tmp_path):
    """Probe BF: still air and noise events before a plume came into view followed the
    frames' change at 0.05-0.07 of the later rate and were said to be the sensor's
    start-up; still written with no valid pixel, they are now said as what they may be."""
    from evmotion.errors import EvmotionWarning
    from evmotion.methods.bos_run import warn_startup

    rng = np.random.default_rng(3)
    quiet = _keeping(ice10, tmp_path, lambda t: ~((t < 8333) & (rng.random(t.size) < 0.97)))
    with pytest.warns(EvmotionWarning, match=r"\[0, 8333\) us and follow the frames' change "
                                             r"there at 0\.\d\d .*next to no change the events "
                                             r"follow: still air, or noise"):
        assert warn_startup(load_bos_input(quiet)) == (0,)


def test_a_nearly_empty_interval_does_not_hide_the_start_up(ice10, tmp_path):
    """One interval of next to no events among the next four (still air, a gap) made
    their rates disagree, and the start-up interval went out at 0.37x, valid (probe)."""
    from evmotion.errors import EvmotionWarning
    from evmotion.methods.bos_run import warn_startup

    rng = np.random.default_rng(1)
    gap = _keeping(ice10, tmp_path, lambda t: ~((t >= 25000) & (t < 33333)
                                                 & (rng.random(t.size) < 0.99)))
    with pytest.warns(EvmotionWarning, match=r"begin in the frame interval \[0, 8333\)"):
        assert warn_startup(load_bos_input(gap)) == (0,)


def test_a_cut_recordings_last_interval_is_no_measurement_nor_in_c(ice10, tmp_path):
    """Events stopping 80 % into the last interval gave its flow at 0.81x, valid, and
    raised the sequence's C; a cut start-up interval and a cut end both fed C's median
    (probe: C 0.178 -> 0.194)."""
    from evmotion.errors import EvmotionWarning
    from evmotion.methods.bos_run import sequence_contrast_threshold

    cut = _keeping(ice10, tmp_path, lambda t: t < 75000 + 0.8 * 8333)
    with pytest.warns(EvmotionWarning, match=r"\[75000, 83333\) us 80 % covered\): their "
                                             r"recording was cut there"):
        data = load_bos_input(cut)
    assert data.cut == (9,)
    with pytest.warns(EvmotionWarning, match="begin in the frame interval"):
        run = solve_bos_input(data, iterations=10)
    assert [bool(r.valid.any()) for r in run.results] == [False] + [True] * 8 + [False]
    _, every = sequence_contrast_threshold(data)
    _, kept = sequence_contrast_threshold(data, exclude=(0, 9))
    assert len(every) == 10 and len(kept) == 8
    assert run.c_samples.tolist() == kept.tolist()


def test_a_background_that_varies_pixel_to_pixel_is_said(data):
    """A white-noise background (probe AF): C came out right, the flow worse than the zero
    flow (AE 0.60 rad), and nothing was said. Its neighbouring pixels do not correlate;
    dots of a pixel or two, as BOS uses, do."""
    import dataclasses
    import warnings

    from scipy.ndimage import gaussian_filter

    from evmotion.errors import EvmotionWarning
    from evmotion.methods.bos import MIN_TEXTURE_CORRELATION, texture_correlation
    from evmotion.methods.bos_run import require_texture

    rng = np.random.default_rng(0)
    noise = rng.integers(30, 226, (2, 64, 80)).astype(np.uint8)
    dots = gaussian_filter((rng.random((64, 80)) < 0.1).astype(float), 0.8)
    dots = np.rint(255 * (1 - 0.8 * dots / dots.max())).astype(np.uint8)
    assert texture_correlation(noise[0]) < 0.05
    assert texture_correlation(dots) > 2 * MIN_TEXTURE_CORRELATION
    said = {}
    for name, frames in (("noise", noise), ("dots", np.stack([dots, dots]))):
        run = dataclasses.replace(data, frames=frames, frame_times=np.array([0, 1000]),
                                  intervals=np.array([[0, 0, 1000]]), roi=None)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            require_texture(run)
        said[name] = [str(w.message) for w in caught if issubclass(w.category, EvmotionWarning)]
    assert said["dots"] == []
    assert len(said["noise"]) == 1 and "vary from one pixel to the next" in said["noise"][0]


def test_frames_that_change_where_no_event_fires_are_said(tmp_path):
    """Events covering the top-left part of the frames only (another sensor, a crop; probe
    AF: C 0.7x, nothing said): the frames change as much far from every event as near
    them. The whole scene's frames are still where no event fires."""
    import shutil
    import sys
    import warnings
    from pathlib import Path

    from evmotion.errors import EvmotionWarning
    from evmotion.methods.bos_run import warn_uncovered

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from rendered_schlieren import render_scene

    render_scene(tmp_path / "whole", scene="shift", size=(96, 128), duration_s=0.03,
                 fps=200.0, speed_px_s=40.0, noise_hz=0.0, seed=3)
    shutil.copytree(tmp_path / "whole", tmp_path / "part")
    lines = (tmp_path / "whole" / "events.txt").read_text().splitlines()
    (tmp_path / "part" / "events.txt").write_text("".join(
        ln + "\n" for ln in lines if int(ln.split()[1]) < 60 and int(ln.split()[2]) < 40))
    said = {}
    for name in ("whole", "part"):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            ratio = warn_uncovered(load_bos_input(tmp_path / name))
        said[name] = (ratio, [str(w.message) for w in caught
                              if issubclass(w.category, EvmotionWarning)])
    assert said["whole"] == (None, [])  # the air moves everywhere: no pixel far from events
    ratio, msgs = said["part"]
    assert ratio > 1.1 and len(msgs) == 1 and "--roi 0 0 60 40" in msgs[0]


def test_frames_not_registered_with_the_events_are_said_or_refused(tmp_path):
    """Frames rolled 2 px against their events (a second camera or a beam splitter off;
    probe AM: AEE worse than the zero flow, valid, exit 0) are refused; 1 px, said; the
    registered scene peaks unshifted."""
    import dataclasses
    import warnings

    from evmotion.errors import EventDataError, EvmotionWarning
    from evmotion.methods.bos_run import check_registration, registration_shift
    from evmotion.sim.schlieren import simulate_schlieren, write_schlieren

    write_schlieren(simulate_schlieren("plume", sensor_size=(96, 120), duration_s=4 / 120,
                                       seed=2), tmp_path / "plume")
    data = load_bos_input(tmp_path / "plume")
    shift, best, zero = registration_shift(data)
    assert shift == (0, 0) and best == zero > 0.5
    with warnings.catch_warnings():
        warnings.simplefilter("error", EvmotionWarning)
        assert check_registration(data) == (0, 0)

    def rolled(dx, dy):
        return dataclasses.replace(data, frames=np.roll(data.frames, (dy, dx), axis=(1, 2)))

    assert registration_shift(rolled(2, -1))[0] == (2, -1)
    with pytest.raises(EventDataError, match=r"shifted by \(\+2, -1\) px .* not registered"):
        check_registration(rolled(2, -1))
    with pytest.warns(EvmotionWarning, match=r"shifted by \(\+1, \+0\) px"):
        assert check_registration(rolled(1, 0)) == (1, 0)


def test_a_small_roi_of_weak_air_is_not_refused_as_unregistered(tmp_path):
    """Probe OPT: one interval of a 40x40 px ROI beside the plume peaked at a 2 px shift
    by chance (correlation 0.64 against 0.53) and the registered scene was refused; the
    gain a shift needs grows with the correlation's sampling error (2x, here 0.30)."""
    import warnings

    from evmotion.errors import EvmotionWarning
    from evmotion.methods.bos_run import check_registration, registration_shift
    from evmotion.sim.schlieren import simulate_schlieren, write_schlieren

    write_schlieren(simulate_schlieren("plume", sensor_size=(120, 100), duration_s=0.1,
                                       seed=0, show_progress=False), tmp_path / "plume")
    data = load_bos_input(tmp_path / "plume", roi=(0, 10, 40, 40), max_intervals=1)
    shift, best, zero = registration_shift(data)
    assert max(map(abs, shift)) >= 2 and best > zero + 0.05  # what had been refused
    with warnings.catch_warnings():
        warnings.simplefilter("error", EvmotionWarning)
        assert check_registration(data) == (0, 0)


def test_a_camera_gain_ramp_is_not_taken_for_air(tmp_path):
    """Frames brightening 2.5 % a frame (auto-exposure), which no event sees: the frames
    had been said to change where no event fires, and the events to follow them weakly
    (correlation 0.40), on a flow measured right (probe AY). The whole frame's log change
    is now left out: C within 2 % of the steady frames', and nothing said."""
    import dataclasses
    import warnings

    from evmotion.errors import EvmotionWarning
    from evmotion.methods.bos_run import warn_uncovered
    from evmotion.sim.schlieren import simulate_schlieren, write_schlieren

    write_schlieren(simulate_schlieren("plume", sensor_size=(120, 160), duration_s=6 / 120,
                                       seed=0), tmp_path / "scene")
    steady = load_bos_input(tmp_path / "scene")
    gain = 0.8 * 1.025 ** np.arange(len(steady.frames))[:, None, None]
    ramp = dataclasses.replace(steady, frames=np.rint(
        np.clip(steady.frames * gain, 0, 255)).astype(steady.frames.dtype))
    said, c = {}, {}
    for name, data in (("steady", steady), ("ramp", ramp)):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            c[name] = sequence_contrast_threshold(data)[0]
            warn_uncovered(data)
        said[name] = [str(w.message) for w in caught if issubclass(w.category, EvmotionWarning)]
    assert c["ramp"] == pytest.approx(c["steady"], rel=0.02)
    assert said["ramp"] == said["steady"] == []


def test_intervals_all_touching_a_blank_frame_name_it(tmp_path):
    """Two intervals and a black frame between them: no C can be estimated, and the run
    had stopped on one interval's fit ("covariance -0.0587"), the frame unnamed (probe
    AY); it is named, with its time."""
    import dataclasses

    from evmotion.errors import EventDataError
    from evmotion.methods.bos_run import sequence_threshold
    from evmotion.sim.schlieren import simulate_schlieren, write_schlieren

    write_schlieren(simulate_schlieren("plume", sensor_size=(96, 128), duration_s=2 / 120,
                                       seed=0), tmp_path / "scene")
    data = load_bos_input(tmp_path / "scene")
    assert len(data.intervals) == 2
    frames = data.frames.copy()
    frames[1] = 0
    black = dataclasses.replace(data, frames=frames)
    with pytest.raises(EventDataError, match=rf"frame 1 at {int(data.frame_times[1])} us; "
                                             "dropped, black or uniform"):
        sequence_threshold(black)


def test_the_runs_underfit_warning_names_its_finest_patches(tmp_path):
    """The runs' underfit warning named no patch size after estimate_bos_sequence's
    learned to name the one of its scales (probe BE); the CLI's runs name theirs too."""
    from evmotion.sim.schlieren import simulate_schlieren, write_schlieren

    d = tmp_path / "plume"
    write_schlieren(simulate_schlieren("plume", sensor_size=(180, 160), duration_s=4 / 120,
                                       seed=0), d)
    with pytest.warns(UnderfitWarning) as said:
        solve_bos_input(load_bos_input(d), scales=(32, 16), iterations=20)
    under = [str(w.message) for w in said if "finest patches" in str(w.message)]
    assert under and all("finest patches (16 px)" in m for m in under)


def test_lamps_flickering_on_mains_power_are_said(ice10, tmp_path):
    """Probe BF: 100 Hz flicker of 5-10 % turned the flow's direction by 6-24 degrees
    with its phase, and nothing said so. Here the events are thinned at 200 Hz."""
    import warnings

    from evmotion.errors import EvmotionWarning
    from evmotion.methods.bos_run import warn_mains_flicker

    rng = np.random.default_rng(4)
    lit = _keeping(ice10, tmp_path, lambda t: rng.random(t.size)
                   < 0.6 + 0.4 * np.sin(2 * np.pi * 200e-6 * t))
    with pytest.warns(EvmotionWarning, match=r"carries a 200 Hz line, \d+x .*mains power"):
        assert warn_mains_flicker(load_bos_input(lit))[0] == 200.0
    with warnings.catch_warnings():
        warnings.simplefilter("error", EvmotionWarning)
        assert warn_mains_flicker(load_bos_input(ice10[0])) is None

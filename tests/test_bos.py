"""Event-based BOS solver (thesis ch. 6): kernels vs numpy, analytic gradients vs finite
differences, recovery of a known flow from LEGM-synthesized data, magnitudes, errors."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from _bos_reference import objective_numpy, upsample_numpy
from bos_synth import legm_case, potential, random_dots
from evmotion.errors import (
    EmptyWindowError,
    EventDataError,
    EvmotionWarning,
    ParameterError,
    UnderfitWarning,
)
from evmotion.events import EventArray
from evmotion.methods import bos_kernels
from evmotion.methods.bos import (
    BosLevel,
    BosOptions,
    estimate_bos,
    estimate_bos_sequence,
    estimate_contrast_threshold,
    event_sums,
    iter_bos_sequence,
    potential_from_flow,
)
from evmotion.methods.bos_kernels import (
    LevelBuffers,
    interp_index,
    objective_grad,
    upsample,
)
from evmotion.methods.flowresult import SUPPORT_MIN_EVENTS, SUPPORT_RADIUS, event_support

DT_US = 8333


@pytest.fixture(scope="module")
def case():
    return legm_case((128, 128), seed=0)


def _errors(flow_px_s, d_true, dt_s=DT_US * 1e-6, min_px=0.05):
    est = flow_px_s * dt_s
    m = np.hypot(d_true[..., 0], d_true[..., 1]) > min_px
    ne = np.hypot(est[..., 0], est[..., 1])[m]
    nt = np.hypot(d_true[..., 0], d_true[..., 1])[m]
    cos = (est[..., 0] * d_true[..., 0] + est[..., 1] * d_true[..., 1])[m] / (ne * nt + 1e-12)
    ae = float(np.arccos(np.clip(cos, -1, 1)).mean())
    return ae, float(np.median(ne / nt))


def test_interp_index_matches_centres():
    i0, f = interp_index(8, 1, 2, 4)  # two 4-px patches, centres at 1.5 and 5.5
    pos = i0 + f
    np.testing.assert_allclose(pos, np.clip((np.arange(8) - 1.5) / 4, 0, 1))


@pytest.mark.parametrize("k", [1, 2])
def test_upsample_vs_numpy(k):
    rng = np.random.default_rng(1)
    x = rng.normal(size=(3, 5, 4))
    iy, fy = interp_index(40 // k, k, 5, 8)
    ix, fx = interp_index(30 // k, k, 4, 8)
    out = np.zeros((3, 40 // k, 30 // k))
    upsample(x, iy, fy, ix, fx, out)
    np.testing.assert_allclose(out, upsample_numpy(x, iy, fy, ix, fx), atol=1e-12)


def _level_inputs(rng, h=24, w=20, nh=4, nw=3):
    gimg = rng.normal(size=(5, h, w))
    meas = rng.normal(size=(h, w))
    weight = rng.uniform(0.05, 1.0, (h, w))
    xpatch = np.stack([rng.normal(0, 0.5, (nh, nw)), rng.normal(0, 0.5, (nh, nw)),
                       rng.uniform(-0.6, 0.6, (nh, nw)), rng.uniform(-0.6, 0.6, (nh, nw))])
    return xpatch, gimg, meas, weight


@pytest.mark.parametrize("normalized", [True, False])
@pytest.mark.parametrize("use_p", [True, False])
@pytest.mark.parametrize("k", [1.0, 2.0])
def test_objective_kernel_vs_numpy_and_fd(normalized, use_p, k):
    """The fused kernel (patch values in, their gradient out) against the numpy objective of
    the upsampled fields, and its gradient against central differences of that reference."""
    rng = np.random.default_rng(2)
    xpatch, gimg, meas, weight = _level_inputs(rng)
    h, w = meas.shape
    iy, fy = interp_index(h, 1, 4, 7)
    ix, fx = interp_index(w, 1, 3, 7)
    s_meas = float(np.sqrt(np.mean(meas ** 2)))
    lam = (0.5, 0.1, 0.05, 0.05)

    def ref(xp):
        fields = upsample_numpy(xp, iy, fy, ix, fx)
        return objective_numpy(fields, gimg, meas, weight, s_meas, k, *lam, normalized, use_p)

    buf = LevelBuffers(h, w, 4, np.float64)
    grad = np.zeros_like(xpatch)
    got = objective_grad(xpatch, bos_kernels.LevelGrid(iy, fy, ix, fx, 1.0 / k),
                         bos_kernels.LevelImages(gimg, meas, weight, s_meas),
                         bos_kernels.ObjectiveTerms(*lam, normalized, use_p), buf, grad)
    np.testing.assert_allclose(got, ref(xpatch), rtol=1e-10, atol=1e-12)
    step = 1e-6
    for idx in np.ndindex(*xpatch.shape):
        xp, xm = xpatch.copy(), xpatch.copy()
        xp[idx] += step
        xm[idx] -= step
        fd = (ref(xp)[0] - ref(xm)[0]) / (2 * step)
        assert grad[idx] == pytest.approx(fd, rel=1e-4, abs=1e-9), idx


@pytest.mark.parametrize("param", ["poisson", "flow"])
@pytest.mark.parametrize("data_term", ["normalized", "scale"])
@pytest.mark.parametrize("k", [1, 2])
def test_parameter_gradient_fd(case, param, data_term, k):
    """Gradient with respect to q (or the flow) and p on the patch grid, through the Sobel,
    the upsampling and the warp."""
    ev, f0, f1, d, C = case
    o = BosOptions(param=param, data_term=data_term, eps_data=0.05, eps_reg=0.05)
    rng = np.random.default_rng(3)
    logf = np.log(f0[:64, :48])
    meas = rng.normal(0, 0.1, logf.shape)
    weight = rng.uniform(0.05, 1, logf.shape)
    lev = BosLevel(16, k, logf, meas, weight, o, np.float64)
    theta = rng.normal(0, 0.3, (lev.n_params(), lev.nh, lev.nw))
    normalized = data_term == "normalized"
    _, g = lev.value_grad(theta, normalized)
    h = 1e-6
    for idx in [(0, 1, 1), (0, 3, 2), (lev.n_params() - 1, 2, 0), (lev.n_params() - 2, 0, 2),
                (1, 2, 1)]:
        tp, tm = theta.copy(), theta.copy()
        tp[idx] += h
        tm[idx] -= h
        fd = (lev.value_grad(tp, normalized)[0][0] - lev.value_grad(tm, normalized)[0][0]) / (2 * h)
        assert g[idx] == pytest.approx(fd, rel=1e-4, abs=1e-9), idx


def test_event_sums():
    ev = EventArray(x=[1, 1, 2, 0], y=[0, 0, 1, 1], t=[0, 1, 2, 3], p=[1, 0, 1, 1],
                    sensor_size=(2, 3))
    s, c = event_sums(ev)
    np.testing.assert_array_equal(s, [[0, 0, 0], [1, 0, 1]])
    np.testing.assert_array_equal(c, [[0, 2, 0], [1, 0, 1]])
    s, c = event_sums(ev, t0_us=2, t1_us=3)
    np.testing.assert_array_equal(s, [[0, 0, 0], [0, 0, 1]])


def test_contrast_threshold_recovered():
    for C in (0.08, 0.2):
        ev, f0, f1, d, _ = legm_case((128, 128), seed=1, C=C, amplitude=60.0)
        est = estimate_contrast_threshold(ev, f0, f1, t0_us=0, t1_us=DT_US)
        assert est == pytest.approx(C, rel=0.05)


def _plume_240(photons=None):
    from evmotion.sim.schlieren import simulate_schlieren

    sim = simulate_schlieren("plume", sensor_size=(240, 216), duration_s=2 / 120,
                             magnitude_px=2.0, seed=0, photons=photons)
    fr, t = sim.frames.images, sim.frames.t
    return sim.events, fr[1], fr[2], int(t[1]), int(t[2])


def test_contrast_threshold_auto_is_events_regressed_on_frames():
    """'auto' on noise-free frames: var(D) / cov(D, S) at sigma 2 px over the pixels that
    fired (plain numpy); above the events' own slope where the events under-count."""
    from scipy.ndimage import gaussian_filter

    from evmotion.methods.bos import log_frame

    ev, f0, f1, t0, t1 = _plume_240()
    s, counts = event_sums(ev, t0_us=t0, t1_us=t1)
    d = gaussian_filter(log_frame(f1) - log_frame(f0), 2.0, mode="nearest")
    s = gaussian_filter(s, 2.0, mode="nearest")
    fired = counts > 0
    ref = np.mean(d[fired] ** 2) / np.mean(d[fired] * s[fired])
    auto = estimate_contrast_threshold(ev, f0, f1, t0_us=t0, t1_us=t1)
    assert auto == pytest.approx(ref, rel=1e-3)  # less the (tiny) 8-bit frame noise
    c_ev = estimate_contrast_threshold(ev, f0, f1, t0_us=t0, t1_us=t1, method="events")
    assert auto > 1.1 * c_ev  # measured 0.245 vs 0.210


def test_contrast_threshold_auto_removes_frame_noise():
    """The simulated events do not depend on the illumination: with shot noise in the
    frames (300 and 1000 photons per white pixel) 'auto' stays within 5 % of its
    noise-free value (measured 0.240 and 0.247 vs 0.245)."""
    ev, f0, f1, t0, t1 = _plume_240()
    clean = estimate_contrast_threshold(ev, f0, f1, t0_us=t0, t1_us=t1)
    for photons in (300.0, 1000.0):
        ev_n, g0, g1, _, _ = _plume_240(photons)
        assert len(ev_n) == len(ev)
        noisy = estimate_contrast_threshold(ev_n, g0, g1, t0_us=t0, t1_us=t1)
        assert noisy == pytest.approx(clean, rel=0.05)


def _weak_air(n=160, c=0.15, disp=0.3, seed=0):
    """Random dots seen through weak air (0.3 px at the centre) and the events of a sensor
    at ``c`` with random leftover charge: relative intensities of the two frames, events."""
    from scipy.ndimage import gaussian_filter, map_coordinates

    rng = np.random.default_rng(seed)
    bg = gaussian_filter((rng.random((n, n)) < 0.15).astype(float), 1.0)
    bg = 0.2 + 0.8 * bg / bg.max()
    yy, xx = np.mgrid[0:n, 0:n]
    amp = disp * np.exp(-((xx - n / 2) ** 2 + (yy - n / 2) ** 2) / (2 * (n / 5) ** 2))
    moved = map_coordinates(bg, [yy, xx - amp], order=3, mode="nearest")
    d = np.log(moved) - np.log(bg)
    s = np.sign(d).astype(int) * np.floor((np.abs(d) + rng.uniform(0, c, d.shape)) / c
                                          ).astype(int)
    ys, xs = np.nonzero(s)
    m = np.abs(s[ys, xs])
    ev = EventArray(x=np.repeat(xs, m), y=np.repeat(ys, m), t=np.zeros(m.sum(), int),
                    p=np.repeat(s[ys, xs] > 0, m), sensor_size=(n, n))
    return bg, moved, ev


def test_contrast_threshold_of_dark_frames():
    """The same events, the frames imaged at a white of 255, 60, 20 or 6 grey levels. The
    quantization error, absent in still air (an unchanged pixel rounds alike in both
    frames) and so missed by the still-air noise, made C rise as the frames darkened
    (0.126 / 0.129 / 0.205 / 0.472); it now counts as frame noise, and where it exceeds
    half the frames' change C is the events' own slope (low: the sequence warns)."""
    from evmotion.methods.bos import contrast_threshold_slope

    bg, moved, ev = _weak_air()
    got = {}
    for white in (255, 60, 20, 6):
        def q(f, w=white):
            return np.rint(np.clip(f, 0, 1) * w).astype(np.uint8)

        got[white] = contrast_threshold_slope(ev, q(bg), q(moved), t0_us=0, t1_us=1)[:2]
    bright = got[255][0]
    assert got[60] == (pytest.approx(bright, rel=0.1), "frames")
    assert all(slope == "events" and c < bright for c, slope in (got[20], got[6]))


def test_potential_of_the_exact_flow_is_the_simulators_q():
    """The simulator's q is analytic (its flow is grad q): the potential of its flow
    matches it up to a constant, on a plume that enters through the image's edge."""
    from evmotion.eval.windows import evaluate_potential
    from evmotion.sim.schlieren import simulate_schlieren

    gt = simulate_schlieren("plume", sensor_size=(90, 80), duration_s=3 / 120, seed=1).gt
    q = np.stack([potential_from_flow(f) for f in gt.flow])
    rows = evaluate_potential(q, gt.t_us[:-1], gt.t_us[1:], gt.q, gt.t_us)
    assert len(rows) == len(gt.flow)
    for r in rows:
        assert r["q_corr"] > 0.999 and abs(r["q_std_ratio"] - 1) < 0.01
    with pytest.raises(ParameterError, match="flow must be"):
        potential_from_flow(np.zeros((4, 4)))


def test_contrast_threshold_refused_when_events_do_not_follow_the_frames():
    """Events that do not measure the frames' change (here: the plume's events against
    two frames of still air) give no C: a one-line error naming the correlation, where the
    slope alone came out at some number."""
    ev, f0, f1, t0, t1 = _plume_240()
    assert estimate_contrast_threshold(ev, f0, f1, t0_us=t0, t1_us=t1) > 0.1
    with pytest.raises(EventDataError, match=r"correlate 0\.9\d .*\(< 0\.99\)"):
        estimate_contrast_threshold(ev, f0, f1, t0_us=t0, t1_us=t1, min_correlation=0.99)
    rng = np.random.default_rng(0)
    still = f0 * np.exp(rng.normal(0.0, 0.01, f0.shape))  # shot noise only
    with pytest.raises(EventDataError, match="contrast threshold.*--contrast-threshold"):
        estimate_contrast_threshold(ev, f0, still, t0_us=t0, t1_us=t1)
    for bad in (float("nan"), 1.5):
        with pytest.raises(ParameterError, match="min_correlation"):
            estimate_contrast_threshold(ev, f0, f1, t0_us=t0, t1_us=t1, min_correlation=bad)
    still = np.clip(np.rint(still), 0, np.iinfo(f0.dtype).max).astype(f0.dtype)
    with pytest.raises(EventDataError):
        estimate_bos(ev, f0, t0_us=t0, t1_us=t1, frame_next=still, data_term="scale",
                     iterations=5)
    # the normalized term goes on without C, uncalibrated: said (it was silent; probe)
    from evmotion.errors import EvmotionWarning

    with pytest.warns(EvmotionWarning, match="magnitude is not calibrated"):
        res = estimate_bos(ev, f0, t0_us=t0, t1_us=t1, frame_next=still,
                           data_term="normalized", iterations=5)
    assert not res.calibrated


def test_inverted_polarity_is_refused_under_either_data_term():
    """ON and OFF the other way round: refused by name (the normalized term went on
    uncalibrated with the flow reversed; probe AT)."""
    from evmotion.errors import InvertedPolarityError

    ev, f0, f1, t0, t1 = _plume_240()
    flipped = ev.with_polarity_inverted()
    with pytest.raises(InvertedPolarityError, match=r"anti-correlate .*correlation -0\.\d+"):
        estimate_contrast_threshold(flipped, f0, f1, t0_us=t0, t1_us=t1)
    for term in ("scale", "normalized"):
        with pytest.raises(InvertedPolarityError, match="polarity is inverted"):
            estimate_bos(flipped, f0, t0_us=t0, t1_us=t1, frame_next=f1, data_term=term,
                         iterations=5)


def test_recovery_poisson_scale_term(case):
    """Direction and magnitude of a known curl-free flow from the LEGM."""
    ev, f0, f1, d, C = case
    res = estimate_bos(ev, f0, t0_us=0, t1_us=DT_US, frame_next=f1, data_term="scale",
                       iterations=150)
    ae, ratio = _errors(res.flow, d)
    assert res.calibrated and res.contrast_threshold == pytest.approx(C, rel=0.05)
    assert ae < 0.2
    assert 0.85 < ratio < 1.1
    # q integrates the flow (px^2/s): its gradient follows the flow, in px/s (the patch
    # grid's q, upsampled, correlated 0.37-0.45 with it on a rendered plume)
    gy, gx = np.gradient(res.q.astype(np.float64))
    for g, f in ((gx, res.flow[..., 0]), (gy, res.flow[..., 1])):
        assert np.corrcoef(g.ravel(), f.ravel())[0, 1] > 0.99  # measured 0.9998
    ratio_q = np.median(np.hypot(gx, gy)) / np.median(np.hypot(*res.flow.transpose(2, 0, 1)))
    assert 0.9 < ratio_q < 1.1
    # and it is the true potential's rate, up to a constant
    q_true = potential_from_flow(d / (DT_US * 1e-6))
    assert np.corrcoef(res.q.ravel(), q_true.ravel())[0, 1] > 0.98  # measured 0.9987


def test_recovery_normalized_direction_and_rescale(case):
    ev, f0, f1, d, C = case
    kw = dict(t0_us=0, t1_us=DT_US, iterations=150, tol=0, dtype=np.float64)
    raw = estimate_bos(ev, f0, **kw)
    assert not raw.calibrated and raw.scale == 1.0 and raw.contrast_threshold is None
    ae, _ = _errors(raw.flow, d)
    assert ae < 0.2
    res = estimate_bos(ev, f0, contrast_threshold=C, **kw)
    assert res.calibrated
    _, ratio = _errors(res.flow, d)
    assert 0.8 < ratio < 1.15
    # the same path (C only scales the normalized measurement) rescaled: checked over the
    # first iterations, since the normalized problem is flat along the flow's magnitude and
    # rounding differences drift along it later (numba 0.68 / numpy 2.4: 2.7 % of the flow
    # after 150 iterations, 1e-5 px/s after 20)
    kw["iterations"] = 20
    raw, res = estimate_bos(ev, f0, **kw), estimate_bos(ev, f0, contrast_threshold=C, **kw)
    diff = np.abs(res.flow - raw.flow * res.scale)
    assert diff.max() < 1e-4 * np.median(np.abs(res.flow))


def test_poisson_beats_flow_in_angle(case):
    ev, f0, f1, d, C = case
    ae = {p: _errors(estimate_bos(ev, f0, t0_us=0, t1_us=DT_US, contrast_threshold=C,
                                  data_term="scale", param=p, iterations=150).flow, d)[0]
          for p in ("poisson", "flow")}
    assert ae["poisson"] < ae["flow"]


def test_increment_replaces_the_event_sums(case):
    """A given log increment (here the exact, unquantized LEGM one) is the measurement: no C
    is needed, the flow comes out in px, and closer to the truth than from the quantized
    events; the normalized term is rescaled by it too."""
    ev, f0, f1, d, C = case
    inc = np.log(f1) - np.log(f0)
    kw = dict(t0_us=0, t1_us=DT_US, iterations=150)
    res = estimate_bos(ev, f0, data_term="scale", increment=inc, **kw)
    assert res.calibrated and res.contrast_threshold is None
    ae, ratio = _errors(res.flow, d)
    ae_events, _ = _errors(estimate_bos(ev, f0, data_term="scale", contrast_threshold=C,
                                        **kw).flow, d)
    assert ae < 0.6 * ae_events
    assert 0.9 < ratio < 1.1
    norm = estimate_bos(ev, f0, increment=inc, **kw)
    assert norm.calibrated and norm.scale != 1.0
    assert 0.85 < _errors(norm.flow, d)[1] < 1.15
    with pytest.raises(EventDataError, match="increment has shape"):
        estimate_bos(ev, f0, increment=inc[1:], **kw)


def test_deterministic_with_seed(case):
    ev, f0, f1, d, C = case
    kw = dict(t0_us=0, t1_us=DT_US, scales=(32, 16), iterations=30)
    a = estimate_bos(ev, f0, seed=5, **kw)
    b = estimate_bos(ev, f0, seed=5, **kw)
    c = estimate_bos(ev, f0, seed=6, **kw)
    np.testing.assert_array_equal(a.flow, b.flow)
    assert not np.array_equal(a.flow, c.flow)


def test_roi_and_result_layout(case):
    ev, f0, f1, d, C = case
    res = estimate_bos(ev, f0, t0_us=0, t1_us=DT_US, roi=(16, 8, 96, 64), scales=(32, 16),
                       iterations=20, contrast_threshold=C)
    assert res.flow.shape == (128, 128, 2) and res.flow.dtype == np.float32
    inside = np.zeros((128, 128), bool)
    inside[8:72, 16:112] = True
    # valid: the ROI's pixels the window's events support (as every flow method marks them)
    win = ev.slice_time(0, DT_US)
    support = event_support(win.x, win.y, (128, 128), SUPPORT_RADIUS, SUPPORT_MIN_EVENTS)
    np.testing.assert_array_equal(res.valid, inside & support)
    assert 0.5 < res.valid[inside].mean() < 1
    assert np.all(res.flow[~inside] == 0)
    assert [len(x) for x in res.losses] == res.iterations == [20, 20]
    assert len(res.timings_s) == 2 and np.isfinite(res.objective)


def test_convergence_stop_and_pooling(case):
    ev, f0, f1, d, C = case
    res = estimate_bos(ev, f0, t0_us=0, t1_us=DT_US, contrast_threshold=C, iterations=400,
                       tol=1e-3, patience=20, pool=(4, 2, 1, 1))
    assert min(res.iterations) < 400
    assert _errors(res.flow, d)[0] < 0.25


def test_errors(case):
    ev, f0, f1, d, C = case
    kw = dict(t0_us=0, t1_us=DT_US, iterations=2, scales=(16,))
    with pytest.raises(ParameterError, match="textured background"):
        estimate_bos(ev, np.full_like(f0, 0.5), **kw)
    with pytest.raises(EventDataError, match="size"):
        estimate_bos(ev, f0[:100], **kw)
    with pytest.raises(EventDataError, match="overlap in time"):
        estimate_bos(ev, f0, t0_us=10**7, t1_us=10**7 + 100, iterations=2)
    with pytest.raises(ParameterError, match="inside"):
        estimate_bos(ev, f0, roi=(100, 0, 64, 64), **kw)
    with pytest.raises(ParameterError, match="contrast_threshold"):
        estimate_bos(ev, f0, data_term="scale", **kw)
    with pytest.raises(ParameterError, match="param"):
        estimate_bos(ev, f0, param="sobel", **kw)
    with pytest.raises(ParameterError, match="unknown option"):
        estimate_bos(ev, f0, lamda_tv=1.0, **kw)
    # frames of two dtypes are read on two scales (an int64 frame beside a uint8 one gave
    # a flow 7x too large, unsaid; probe)
    f8 = np.clip(f0 * 255, 0, 255).astype(np.uint8)
    with pytest.raises(ParameterError, match="frame is int64 but frame_next uint8"):
        estimate_bos(ev, f8.astype(np.int64), frame_next=f8, **kw)
    few = EventArray(x=[0], y=[0], t=[5], p=[1], sensor_size=(128, 128))
    with pytest.raises(EmptyWindowError):
        estimate_bos(few, f0, roi=(64, 64, 32, 32), **kw)
    with pytest.raises(EventDataError, match="contrast threshold"):
        estimate_contrast_threshold(ev, f0, f0, t0_us=0, t1_us=DT_US)
    with pytest.raises(EventDataError, match="contrast threshold"):
        estimate_bos(ev, f0, frame_next=f0, data_term="scale", **kw)
    # the normalized term goes on without C, flagged uncalibrated
    res = estimate_bos(ev, f0, frame_next=f0, **kw)
    assert not res.calibrated and res.contrast_threshold is None
    with pytest.raises(ParameterError, match="coarse to fine"):
        estimate_bos(ev, f0, t0_us=0, t1_us=DT_US, scales=(8, 16))
    with pytest.raises(ParameterError, match="iterations must be whole numbers in 1..100000"):
        estimate_bos(ev, f0, t0_us=0, t1_us=DT_US, iterations=0)
    with pytest.raises(ParameterError, match="dtype bool"):
        estimate_bos(ev, f0 > 0.5, **kw)
    # one event: the flow it gives is not a measurement on (almost) any pixel, and says so
    one = EventArray(x=[60], y=[60], t=[5], p=[1], sensor_size=(128, 128))
    with pytest.warns(EvmotionWarning, match="support the flow on 0 % of the ROI"):
        res = estimate_bos(one, f0, contrast_threshold=C, **kw)
    assert not res.valid.any()


@pytest.mark.parametrize("opts, match", [
    ({"log_eps": float("nan")}, "log_eps"), ({"log_eps": -1.0}, "log_eps"),
    ({"patience": float("nan")}, "patience"), ({"patience": 1.5}, "patience"),
    ({"seed": -1}, "seed"), ({"seed": 1.5}, "seed"),
    ({"contrast_threshold": 1e300}, "contrast_threshold"),
    ({"contrast_threshold": "0.2"}, "contrast_threshold"),
    ({"iterations": float("nan")}, "iterations"), ({"iterations": 2.7}, "iterations"),
    ({"scales": (float("nan"), 8)}, "scales"), ({"scales": 8}, "scales"),
    ({"scales": (256, 128)}, "finest patches"), ({"dtype": np.int32}, "dtype"),
    ({"t0_us": float("nan")}, "t0_us"), ({"options": {"param": "flow"}}, "BosOptions"),
])
def test_bad_options_are_parameter_errors(case, opts, match):
    """Each used to end in NaN results, a silent zero flow (patches as large as the ROI:
    q on one patch has no gradient), a truncated value, or a raw numpy / Python error."""
    ev, f0, f1, d, C = case
    kw = {"t0_us": 0, "t1_us": DT_US, "iterations": 2, "scales": (16,), **opts}
    with pytest.raises(ParameterError, match=match):
        estimate_bos(ev, f0, **kw)


def test_bad_arguments_of_the_other_functions(case):
    ev, f0, f1, d, C = case
    with pytest.raises(ParameterError, match="sigma"):
        estimate_contrast_threshold(ev, f0, f1, t0_us=0, t1_us=DT_US, sigma=float("nan"))
    with pytest.raises(ParameterError, match="unknown option"):
        estimate_bos_sequence(ev, [f0, f1], [0, DT_US], foo=1)
    for bad in ({"workers": 1.5}, {"chunks": 0}, {"chunks": float("nan")}):
        with pytest.raises(ParameterError, match=next(iter(bad))):
            estimate_bos_sequence(ev, [f0, f1], [0, DT_US], **bad)
    with pytest.raises(ParameterError, match="times_us"):
        estimate_bos_sequence(ev, [f0, f1], [0, float("nan")])
    flow = np.zeros((8, 9, 2))
    flow[3, 3, 0] = np.nan
    with pytest.raises(ParameterError, match="1 pixels with NaN"):
        potential_from_flow(flow)
    with pytest.raises(ParameterError, match="flow must be"):
        potential_from_flow("abc")
    assert BosOptions.fast(scales=(16, 8)).iterations_per_scale() == (150, 300)


def test_sequence_warm_start_and_chunks():
    ev0, f0, f1, d, C = legm_case((64, 64), seed=2, t0=0, t1=DT_US)
    ev1, g0, g1, _, _ = legm_case((64, 64), seed=2, t0=DT_US, t1=2 * DT_US)
    from evmotion.events import concatenate
    ev = concatenate([ev0, ev1])
    frames = [f0, f1, f1 * (g1 / g0)]
    times = [0, DT_US, 2 * DT_US]
    kw = dict(scales=(32, 16), iterations=25, contrast_threshold=C)
    seq = estimate_bos_sequence(ev, frames, times, **kw)
    assert [(r.t0_us, r.t1_us) for r in seq] == [(0, DT_US), (DT_US, 2 * DT_US)]
    first = estimate_bos(ev, f0, t0_us=0, t1_us=DT_US, frame_next=f1, **kw)
    np.testing.assert_array_equal(seq[0].flow, first.flow)
    warm = estimate_bos(ev, f1, t0_us=DT_US, t1_us=2 * DT_US, init=first, **kw)
    np.testing.assert_array_equal(seq[1].flow, warm.flow)
    cold = estimate_bos_sequence(ev, frames, times, chunks=2, **kw)
    second = estimate_bos(ev, f1, t0_us=DT_US, t1_us=2 * DT_US, **kw)
    np.testing.assert_array_equal(cold[1].flow, second.flow)
    # the chunks in two worker processes (evmotion.parallel.map_windows) give the same
    par = estimate_bos_sequence(ev, frames, times, workers=2, **kw)
    for a, b in zip(par, cold, strict=True):
        np.testing.assert_array_equal(a.flow, b.flow)
    with pytest.raises(ParameterError, match="timestamps"):
        estimate_bos_sequence(ev, frames, [0, 5, 5], **kw)
    # a sequence continued from the stored parameters of its previous interval (--resume)
    # is the warm-started one; iter_bos_sequence yields the same results
    cont = list(iter_bos_sequence(ev, frames[1:], times[1:], init=[np.array(a) for a in
                                                                   first.params], **kw))
    np.testing.assert_array_equal(cont[0].flow, seq[1].flow)
    np.testing.assert_array_equal(cont[0].q, warm.q)
    bad = [np.array(a) for a in first.params]
    bad[0][0, 0, 0] = np.nan
    with pytest.raises(ParameterError, match="NaN parameters"):  # was an all-NaN result
        estimate_bos(ev, f1, t0_us=DT_US, t1_us=2 * DT_US, init=bad, **kw)
    with pytest.raises(ParameterError, match="init has 1 scales"):
        estimate_bos(ev, f1, t0_us=DT_US, t1_us=2 * DT_US, init=first.params[:1], **kw)


@pytest.fixture(scope="module")
def sim_ice():
    from evmotion.sim.schlieren import simulate_schlieren

    return simulate_schlieren("ice", sensor_size=(240, 216), duration_s=2 / 120,
                              magnitude_px=2.0, seed=0)


def _sim_gt(sim, k):
    """The simulator's flow over interval k in px, as the apparent motion of the pattern
    (the LEGM's sign: the frame change follows -grad L . v dt)."""
    from evmotion.methods.bos import log_frame

    fr, t = sim.frames.images, sim.frames.t
    gt = sim.gt.flow[k] * (t[k + 1] - t[k]) * 1e-6
    gy, gx = np.gradient(log_frame(fr[k]))
    sign = np.sign(np.sum(-(gx * gt[..., 0] + gy * gt[..., 1])
                          * (log_frame(fr[k + 1]) - log_frame(fr[k]))))
    return sign * gt


def _sim_ice_solve(sim):
    fr, t = sim.frames.images, sim.frames.t
    t0, t1 = int(t[1]), int(t[2])
    res = estimate_bos(sim.events, fr[1], t0_us=t0, t1_us=t1, frame_next=fr[2],
                       data_term="scale")
    gt = _sim_gt(sim, 1)
    win = sim.events.slice_time(t0, t1)
    m = np.zeros(gt.shape[:2], bool)
    m[win.y, win.x] = True
    m &= np.hypot(gt[..., 0], gt[..., 1]) > 0.05
    return res.flow * (t1 - t0) * 1e-6, gt, m


def test_simulator_contrast_threshold_and_direction(sim_ice):
    """On the schlieren simulator: C within 10 % of the sensor's ('events') and the
    scale-aware term's mean angular error below the thesis' worst (0.42 rad)."""
    sim = sim_ice
    fr, t = sim.frames.images, sim.frames.t
    c_ev = estimate_contrast_threshold(sim.events, fr[1], fr[2], t0_us=int(t[1]),
                                       t1_us=int(t[2]), method="events")
    assert c_ev == pytest.approx(sim.gt.contrast_threshold, rel=0.10)
    est, gt, m = _sim_ice_solve(sim)
    cos = np.sum(est * gt, -1)[m] / (np.hypot(*est[m].T) * np.hypot(*gt[m].T) + 1e-12)
    assert np.arccos(np.clip(cos, -1, 1)).mean() < 0.42


@pytest.mark.xfail(strict=True, reason="known defect (issue #12 magnitude goal): median "
                   "|v|/|v_gt| is 0.76 on this 240x216 ice interval with any schedule "
                   "(600/scale too) and with C from 'auto' (0.208) or 'rma' (0.208) alike, "
                   "while the 640x720 scenes reach 0.93-0.99 with 'auto': not the C here")
def test_simulator_magnitude(sim_ice):
    """The scale-aware term's median |v|/|v_gt| within [0.85, 1.15] on the simulator."""
    est, gt, m = _sim_ice_solve(sim_ice)
    ratio = np.median(np.hypot(est[..., 0], est[..., 1])[m] / np.hypot(gt[..., 0], gt[..., 1])[m])
    assert 0.85 < ratio < 1.15


@pytest.mark.parametrize("param", ["poisson", "flow"])
def test_float32_level_matches_float64(case, param):
    """The production precision (float32 images, float32 loops) against float64."""
    ev, f0, f1, d, C = case
    o = BosOptions(param=param)
    rng = np.random.default_rng(4)
    logf = np.log(f0)
    meas = rng.normal(0, 0.1, logf.shape)
    weight = rng.uniform(0.05, 1, logf.shape)
    lev32 = BosLevel(8, 1, logf, meas, weight, o, np.float32)
    lev64 = BosLevel(8, 1, logf, meas, weight, o, np.float64)
    theta = rng.normal(0, 0.3, (lev32.n_params(), lev32.nh, lev32.nw))
    for normalized in (True, False):
        (t32, *_), g32 = lev32.value_grad(theta, normalized)
        (t64, *_), g64 = lev64.value_grad(theta, normalized)
        assert t32 == pytest.approx(t64, rel=1e-5)
        np.testing.assert_allclose(g32, g64, rtol=1e-3, atol=1e-4 * np.abs(g64).max())


def test_on_empty_skip_carries_the_warm_start(case):
    from evmotion.errors import EvmotionWarning

    ev, f0, f1, d, C = case
    kw = dict(t0_us=0, t1_us=DT_US, scales=(32, 16), iterations=10, contrast_threshold=C)
    prev = estimate_bos(ev, f0, **kw)
    late = dict(kw, t0_us=DT_US, t1_us=2 * DT_US)  # after every event of the case
    none = EventArray(x=[0, 1], y=[0, 1], t=[0, 3 * DT_US], p=[1, 0], sensor_size=ev.sensor_size)
    with pytest.raises(EmptyWindowError):
        estimate_bos(none, f0, **late)
    with pytest.warns(EvmotionWarning, match="no valid pixel"):
        skipped = estimate_bos(none, f0, init=prev, on_empty="skip", **late)
    assert not skipped.valid.any() and np.isnan(skipped.objective)
    for a, b in zip(skipped.params, prev.params, strict=True):
        np.testing.assert_array_equal(a, b)
    with pytest.warns(EvmotionWarning):
        cold = estimate_bos(none, f0, on_empty="skip", **late)
    # no warm start to carry: NaN parameters, which the next interval takes as none
    assert all(np.isnan(a).all() for a in cold.params)
    np.testing.assert_array_equal(estimate_bos(ev, f0, init=cold, **kw).flow, prev.flow)


def test_an_interval_outside_the_events_is_skipped(case):
    # probe BE: a sequence whose first or last interval held no event aborted the whole run
    # ("window [0, 16667) us failed: EventDataError: frames and events do not overlap in
    # time"), and estimate_bos(on_empty="skip") raised it too
    ev, f0, f1, d, C = case
    kw = dict(scales=(32, 16), iterations=10, contrast_threshold=C)
    with pytest.warns(EvmotionWarning, match=r"overlap in time: window \[8333, 16666\).*no valid"):
        skipped = estimate_bos(ev, f1, t0_us=DT_US, t1_us=2 * DT_US, on_empty="skip", **kw)
    assert not skipped.valid.any()
    # its class is public, as the exceptions a user sees are (it was _NoEventsInWindow,
    # probe BQ)
    from evmotion.methods.bos import NoEventsInWindowError

    with pytest.raises(NoEventsInWindowError, match="overlap in time"):
        estimate_bos(ev, f1, t0_us=DT_US, t1_us=2 * DT_US, **kw)
    with pytest.warns(EvmotionWarning, match="no valid pixel"):
        seq = estimate_bos_sequence(ev, [f0, f1, f1], [0, DT_US, 2 * DT_US], **kw)
    assert seq[0].valid.any() and not seq[1].valid.any()
    # no event between the first frame and the last: other clocks, not still air
    with pytest.raises(EventDataError, match=r"overlap in time: frames \[8333, 16666\)"):
        estimate_bos_sequence(ev, [f1, f1], [DT_US, 2 * DT_US], **kw)


def test_messages_name_the_frame_and_the_scales_at_fault():
    # probe BE: NaN in frame_next was reported as "frame has NaN or inf values", and the
    # sequence's underfit warning said "finest patches (8 px)" whatever the scales
    from evmotion.sim.schlieren import simulate_schlieren

    sim = simulate_schlieren("plume", sensor_size=(180, 160), duration_s=2 / 120, seed=0)
    f, t, ev = sim.frames.images, sim.frames.t, sim.events
    nan = f[2].astype(float) / 255
    nan[5, 5] = np.nan
    with pytest.raises(ParameterError, match="^frame_next has NaN or inf values"):
        estimate_bos(ev, f[1].astype(float) / 255, t0_us=int(t[1]), t1_us=int(t[2]),
                     frame_next=nan)
    with pytest.warns(UnderfitWarning) as said:
        estimate_bos_sequence(ev.slice_time(int(t[1]), None), f[1:], t[1:], scales=(32, 16),
                              iterations=20)
    under = [str(w.message) for w in said if "finest patches" in str(w.message)]
    assert under and all("finest patches (16 px)" in m for m in under)


def test_background_noise_events_do_not_make_still_air_valid():
    """Uniform noise events (20 per pixel and second) over a plume seen through clean
    frames: two-thirds of the still background was marked valid; the support rule now
    asks for more events than the noise gives in the squares the frames show unchanged."""
    from evmotion.sim.schlieren import simulate_schlieren

    shares = {}
    for rate in (0.0, 20.0):
        sim = simulate_schlieren("plume", sensor_size=(96, 80), duration_s=2 / 120, seed=0,
                                 noise_rate=rate)
        fr, t = sim.frames.images, sim.frames.t
        res = estimate_bos(sim.events, fr[1], t0_us=int(t[1]), t1_us=int(t[2]),
                           frame_next=fr[2], iterations=5)
        still = np.hypot(*np.moveaxis(sim.gt.flow[1], -1, 0)) * (t[2] - t[1]) * 1e-6 < 1e-3
        shares[rate] = (res.valid[still].mean(), res.valid[~still].mean())
    assert shares[20.0][0] < 0.05 and shares[0.0][0] < 0.05
    assert shares[20.0][1] > 0.3 * shares[0.0][1]  # the air keeps most of its support


def test_background_noise_events_over_noisy_frames_do_not_make_still_air_valid():
    """As above with frames of shot noise, where no square of still air is unchanged:
    the plain rule had kept 28 % of the still background valid at 5 noise events per
    pixel and second and 92 % at 20 (probe BC's renderer); the squares that changed least
    now give the noise's count."""
    from evmotion.sim.schlieren import simulate_schlieren

    shares = {}
    for rate in (0.0, 20.0):
        sim = simulate_schlieren("plume", sensor_size=(96, 80), duration_s=2 / 120, seed=0,
                                 noise_rate=rate, photons=2000)
        fr, t = sim.frames.images, sim.frames.t
        assert (fr[2] != fr[1]).mean() > 0.5  # noisy frames: still air changes too
        res = estimate_bos(sim.events, fr[1], t0_us=int(t[1]), t1_us=int(t[2]),
                           frame_next=fr[2], iterations=5)
        still = np.hypot(*np.moveaxis(sim.gt.flow[1], -1, 0)) * (t[2] - t[1]) * 1e-6 < 1e-3
        shares[rate] = (res.valid[still].mean(), res.valid[~still].mean())
    assert shares[20.0][0] < 0.05 and shares[0.0][0] < 0.05, shares
    assert shares[20.0][1] > 0.3 * shares[0.0][1], shares


def test_large_displacements_are_solved_again_at_the_flow_found():
    """The linearized model (6.9) holds within the frame's smoothing: a smooth field moving
    the background up to 4 px came out at 0.78x its magnitude above 2 px, and now says so.
    Solved again with the frame warped by the flow found (relinearize=2), it comes out at
    0.97x and the angle error halves; an interval moving less is solved once."""
    from scipy.ndimage import map_coordinates

    rng = np.random.default_rng(1)
    shape = (96, 96)
    intensity = random_dots(shape, rng)
    L = np.log(intensity)
    dy, dx = np.gradient(potential(shape, rng, n_blobs=4, amplitude=40.0))
    k = 4.0 / np.hypot(dx, dy).max()
    d = np.stack([dx * k, dy * k], axis=-1)
    yy, xx = np.mgrid[0:96, 0:96].astype(float)
    inc = map_coordinates(L, [yy - d[..., 1], xx - d[..., 0]], order=3, mode="nearest") - L
    S = np.round(inc / 0.2).astype(np.int64)
    ys, xs = np.nonzero(S)
    c = np.abs(S[ys, xs])
    ev = EventArray(x=np.repeat(xs, c), y=np.repeat(ys, c),
                    t=np.sort(rng.integers(0, DT_US, c.sum())),
                    p=np.repeat((S[ys, xs] > 0).astype(np.uint8), c), sensor_size=shape)
    kw = dict(t0_us=0, t1_us=DT_US, data_term="scale", increment=inc, iterations=150)
    with pytest.warns(UnderfitWarning, match="linearized model.*relinearize=2"):
        once = estimate_bos(ev, intensity, **kw)  # the thesis' single solve, said
    assert once.displacement_q95 >= 1.0
    again = estimate_bos(ev, intensity, relinearize=2, **kw)
    assert once.relinearized == 0 and again.relinearized == 2
    ae_once, ratio_once = _errors(once.flow, d, min_px=2.0)
    ae_again, ratio_again = _errors(again.flow, d, min_px=2.0)
    assert ratio_once < 0.85 and 0.93 < ratio_again < 1.05
    assert ae_again < 0.6 * ae_once
    assert len(again.iterations) == len(again.params) == 4
    # a small flow: one solve, as the thesis
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnderfitWarning)
        small = estimate_bos(ev, intensity, relinearize=2, **{**kw, "increment": inc * 0.2})
    assert small.relinearized == 0 and small.displacement_q95 < 1.0
    with pytest.raises(ParameterError, match="relinearize"):
        estimate_bos(ev, intensity, relinearize=-1, **kw)


def test_event_sums_refuse_a_reversed_window():
    """t1 before t0 returned zero images (probe AI)."""
    from evmotion.events import EventArray
    from evmotion.methods.bos import event_sums

    ev = EventArray(x=[1, 2], y=[1, 2], t=[10, 20], p=[1, 0], sensor_size=(4, 4))
    with pytest.raises(ParameterError, match="t1_us=0 must be after t0_us=100"):
        event_sums(ev, t0_us=100, t1_us=0)


def test_one_picture_one_flow_whatever_its_dtype():
    # probe AN: the same 8-bit frames as float / 255 moved the flow by 7 %, as uint16 x 257
    # by 3 % (float frames were taken as continuous: another log offset, no quantization)
    from evmotion.methods.bos import quantized_frame
    from evmotion.sim.schlieren import simulate_schlieren

    sim = simulate_schlieren("plume", sensor_size=(90, 80), duration_s=3 / 120, seed=0)
    f, t = sim.frames.images, sim.frames.t
    assert f.dtype == np.uint8
    kw = dict(t0_us=int(t[1]), t1_us=int(t[2]), iterations=20)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = estimate_bos(sim.events, f[1], frame_next=f[2], **kw)
        for conv in (lambda a: a.astype(np.uint16) * 257, lambda a: a.astype(np.float32) / 255,
                     lambda a: a / 255.0, lambda a: a.astype(np.float64)):
            r = estimate_bos(sim.events, conv(f[1]), frame_next=conv(f[2]), **kw)
            assert r.contrast_threshold == ref.contrast_threshold
            np.testing.assert_array_equal(r.flow, ref.flow)
    # continuous intensities, and 16-bit data, stay as they are
    cont = np.array([[0.0, 0.3, 1.0]])
    assert quantized_frame(cont).dtype == np.float64
    deep = np.array([[0, 1000, 65535]], np.uint16)
    assert quantized_frame(deep).dtype == np.uint16


@pytest.mark.parametrize("noise_rate", [2.0, 10.0])
def test_contrast_threshold_finds_still_air_among_noise_events(noise_rate):
    """Noise events at every pixel (2-10 Hz) left no pixel without an event within 5 px:
    the frames' noise was then measured in time, which counts the air's change too, and C
    came out 0.19 for the noise-free scene's 0.28 (flow 0.59-0.66x the true one, probe
    DI). The still air is the pixels whose events are as few as the view's quietest and
    do not follow the frames' change."""
    from scipy.ndimage import gaussian_filter

    from evmotion.methods.bos import TIMED_NOISE, contrast_threshold_slope, still_air
    from evmotion.sim.schlieren import simulate_schlieren

    est = {}
    for rate in (0.0, noise_rate):
        sim = simulate_schlieren("plume", sensor_size=(240, 216), duration_s=3 / 120,
                                 magnitude_px=2.0, seed=0, noise_rate=rate)
        fr, t = sim.frames.images, sim.frames.t
        est[rate] = contrast_threshold_slope(sim.events, fr[1], fr[2], t0_us=int(t[1]),
                                             t1_us=int(t[2]), frame_after=fr[3])
    assert est[noise_rate][1] != TIMED_NOISE
    assert est[noise_rate][0] == pytest.approx(est[0.0][0], rel=0.1)
    # air everywhere is not still air, whatever its quietest pixels
    rng = np.random.default_rng(1)
    d = gaussian_filter(rng.normal(0, 1, (96, 96)), 2.0)
    counts = 1.0 + rng.poisson(np.abs(d) * 20.0).astype(float)
    assert not still_air(counts, d, d + 0.1 * rng.normal(0, 1, d.shape)).any()


def test_contrast_threshold_in_an_roi_measures_the_noise_on_the_whole_view():
    """An ROI drawn around the plume holds no still air: the frames' noise is the camera's
    and is measured on the still air of the whole view, so C in the ROI stays that of the
    whole frame (within 5 %); measured in time instead (the second difference, which also
    counts the air's own change) it came out lower, and the flow with it (probe: 0.257 ->
    0.206, flow 0.97x -> 0.79x the true one)."""
    from evmotion.sim.schlieren import simulate_schlieren

    sim = simulate_schlieren("plume", sensor_size=(240, 216), duration_s=3 / 120,
                             magnitude_px=2.0, seed=0, photons=300.0)
    fr, t = sim.frames.images, sim.frames.t
    ev = sim.events
    whole = estimate_contrast_threshold(ev, fr[1], fr[2], t0_us=int(t[1]), t1_us=int(t[2]),
                                        frame_after=fr[3])
    win = ev.slice_time(int(t[1]), int(t[2]))
    x0, x1 = int(np.percentile(win.x, 2)), int(np.percentile(win.x, 98))
    y0, y1 = int(np.percentile(win.y, 2)), int(np.percentile(win.y, 98))
    roi = (x0, y0, x1 - x0, y1 - y0)
    inside = estimate_contrast_threshold(ev, fr[1], fr[2], t0_us=int(t[1]), t1_us=int(t[2]),
                                         frame_after=fr[3], roi=roi)
    assert inside == pytest.approx(whole, rel=0.05)

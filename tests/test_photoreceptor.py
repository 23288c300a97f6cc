"""The event pixel's photoreceptor models (evmotion.sim.photoreceptor): noise level and
time constant measured on the simulated log intensity, against the model's formulas."""

import numpy as np
import pytest

from evmotion.errors import ParameterError
from evmotion.sim.photoreceptor import NOISE_PHOTONS, TAU_RATIO_MAX, Photoreceptor
from evmotion.sim.schlieren import simulate_schlieren

SHAPE = (100, 200)  # 20000 pixels: noise std to ~1 %, pixel means to ~0.6 % of a step


def flat(level):
    return lambda t_s, pix: np.full(SHAPE if pix is None else len(pix), level)


def noise_std(bandwidth, event_photons, level=1.0, t_us=50_000):
    pr = Photoreceptor(flat(level), SHAPE, event_photons=event_photons, tau_us=1000,
                       bandwidth=bandwidth, seed=1)
    return float(np.std(pr(t_us, None) - np.log(level)))


def test_noise_grows_as_inverse_sqrt_photons_with_fixed_bandwidth():
    s40, s20 = noise_std("fixed", 40.0), noise_std("fixed", 20.0)
    assert s40 == pytest.approx(1 / np.sqrt(40), rel=0.03)
    assert s20 == pytest.approx(1 / np.sqrt(20), rel=0.03)
    assert s20 / s40 == pytest.approx(np.sqrt(2), rel=0.04)


def test_noise_stays_constant_in_dim_light_with_intensity_bandwidth():
    # 40 and 20 photons per ms: time constants 4.05 and 8.1 ms, both below the cap
    s40, s20 = noise_std("intensity", 40.0), noise_std("intensity", 20.0)
    floor = 1 / np.sqrt(NOISE_PHOTONS)
    assert s40 == pytest.approx(floor, rel=0.03)
    assert s20 == pytest.approx(floor, rel=0.03)
    # a darker pixel of the same scene, same floor
    assert noise_std("intensity", 40.0, level=0.5) == pytest.approx(floor, rel=0.03)
    # bright light: the bright-light time constant, noise 1/sqrt(photons) as "fixed"
    assert noise_std("intensity", 1000.0) == pytest.approx(1 / np.sqrt(1000), rel=0.03)
    # darker than the cap allows: the noise grows again
    assert noise_std("intensity", 5.0) == pytest.approx(
        1 / np.sqrt(5.0 * TAU_RATIO_MAX), rel=0.03)


def step_response(bandwidth, event_photons, step_us=100, t0=20_000, lo=0.5, hi=0.55):
    def rad(t_s, pix):
        return np.full(SHAPE if pix is None else len(pix), hi if t_s * 1e6 >= t0 else lo)
    pr = Photoreceptor(rad, SHAPE, event_photons=event_photons, tau_us=1000,
                       bandwidth=bandwidth, seed=2, step_us=step_us)
    ts = np.arange(0, t0 + 60_000, step_us)
    resp = np.array([pr(t, None).mean() for t in ts])
    return ts, (resp - np.log(lo)) / (np.log(hi) - np.log(lo)), pr


@pytest.mark.parametrize("tau_ms", [4.0, 8.0])
def test_time_constant_measured_from_step_response(tau_ms):
    t0, step = 20_000, 100
    ep = NOISE_PHOTONS / (0.55 * tau_ms)  # after the step: tau = tau_ms
    ts, r, pr = step_response("intensity", ep, step_us=step, t0=t0)
    assert float(pr.time_constant_us(np.array([0.55]))[0]) == pytest.approx(tau_ms * 1e3)
    assert abs(r[ts < t0 - step].mean()) < 0.03  # settled before the step
    # the time to 1 - 1/e of the step, from the middle of the knot interval it ramps over
    k = np.nonzero(r >= 1 - np.exp(-1))[0][0]
    t63 = np.interp(1 - np.exp(-1), r[k - 1:k + 1], ts[k - 1:k + 1]) - (t0 - step / 2)
    assert t63 == pytest.approx(tau_ms * 1e3, rel=0.05)
    assert r[-100:].mean() == pytest.approx(1.0, abs=0.03)


def test_fixed_bandwidth_follows_a_step_at_once():
    t0 = 20_000
    ts, r, _ = step_response("fixed", 1e6, t0=t0)  # no low-pass, negligible noise
    assert r[ts == t0][0] == pytest.approx(1.0, abs=0.01)
    assert r[ts == t0 - 100][0] == pytest.approx(0.0, abs=0.01)


def test_pixel_subset_matches_full_sensor_and_order():
    pr = Photoreceptor(flat(0.7), SHAPE, event_photons=30.0, tau_us=1000,
                       bandwidth="intensity", seed=3, step_us=250)
    pix = np.array([0, 5, 19999])
    sub = pr(3100, pix)
    np.testing.assert_array_equal(sub, pr(3100, None).ravel()[pix])
    again = Photoreceptor(flat(0.7), SHAPE, event_photons=30.0, tau_us=1000,
                          bandwidth="intensity", seed=3, step_us=250)
    np.testing.assert_array_equal(again(3100, pix), sub)  # seeded
    pr(20_000, None)
    with pytest.raises(RuntimeError, match="dropped"):
        pr(1000, None)


def test_parameters_are_checked():
    with pytest.raises(ParameterError, match="event_bandwidth"):
        Photoreceptor(flat(1.0), SHAPE, event_photons=1.0, tau_us=1000, bandwidth="slow")
    with pytest.raises(ParameterError, match="event_photons"):
        Photoreceptor(flat(1.0), SHAPE, event_photons=0.0, tau_us=1000)
    kw = dict(sensor_size=(24, 24), duration_s=1 / 60)
    with pytest.raises(ParameterError, match="event_bandwidth"):
        simulate_schlieren("plume", event_photons=10.0, event_bandwidth="slow", **kw)
    with pytest.raises(ParameterError, match="needs event_photons"):
        simulate_schlieren("plume", event_bandwidth="intensity", **kw)


def test_schlieren_events_in_dim_light_intensity_vs_fixed():
    kw = dict(sensor_size=(48, 40), duration_s=1 / 60, magnitude_px=1.0, seed=3,
              event_photons=30.0)
    fixed = simulate_schlieren("plume", **kw)
    slow = simulate_schlieren("plume", event_bandwidth="intensity", **kw)
    again = simulate_schlieren("plume", event_bandwidth="intensity", **kw)
    assert slow.gt.meta["event_bandwidth"] == "intensity"
    np.testing.assert_array_equal(slow.events.t, again.events.t)
    # the fixed bandwidth's noise (std 0.18-0.47 on white-to-dot pixels, redrawn every ms)
    # fires many times more events than the low-passed photoreceptor (std 0.079)
    assert len(fixed.events) > 5 * len(slow.events)


def test_cli_event_bandwidth_reaches_the_ground_truth(tmp_path):
    from evmotion.cli import main
    from evmotion.sim.schlieren import read_schlieren_gt

    out = tmp_path / "dim"
    assert main(["simulate", "schlieren", "--size", "40x48", "--duration", str(1 / 120),
                 "--event-photons", "30", "--event-bandwidth", "intensity",
                 "--out", str(out)]) == 0
    meta = read_schlieren_gt(out).meta
    assert meta["event_bandwidth"] == "intensity" and meta["event_photons"] == 30

"""Schlieren simulator: ground truth consistency, rendering against a numpy reference,
events against the linearized event generation model, noise statistics, files."""

from __future__ import annotations

import math

import numpy as np
import pytest

from evmotion.errors import FormatError, ParameterError
from evmotion.sim.schlieren import (
    BOS_SCENES,
    make_background,
    make_field,
    read_schlieren_gt,
    simulate_schlieren,
    write_schlieren,
)
from evmotion.sim.simulator import simulate_log_function

SIZE = (64, 56)


@pytest.fixture(scope="module")
def plume():
    return simulate_schlieren("plume", sensor_size=SIZE, duration_s=4 / 120, seed=3,
                              magnitude_px=1.5, exposure_s=0.0)


def test_flow_is_displacement_difference_and_gradient_of_q(plume):
    gt = plume.gt
    dt = np.diff(gt.t_us)[:, None, None, None] * 1e-6
    want = (gt.displacement[1:].astype(np.float64) - gt.displacement[:-1]) / dt
    np.testing.assert_allclose(gt.flow, want, rtol=1e-5, atol=1e-3 * np.abs(want).max())
    assert gt.flow.shape == (4, *SIZE, 2) and gt.flow.dtype == np.float32
    # v = ∇q (the Poisson parameterization): central differences of q, inside
    gy, gx = np.gradient(gt.q.astype(np.float64), axis=(1, 2))
    err = np.hypot(gx - gt.flow[..., 0], gy - gt.flow[..., 1])[:, 2:-2, 2:-2]
    assert err.max() < 0.06 * np.linalg.norm(gt.flow, axis=-1).max()
    # curl-free: the flow's rotational part is small against its size
    curl = np.gradient(gt.flow[..., 1], axis=2) - np.gradient(gt.flow[..., 0], axis=1)
    div = np.gradient(gt.flow[..., 0], axis=2) + np.gradient(gt.flow[..., 1], axis=1)
    assert np.abs(curl).max() < 0.05 * np.abs(div).max()


def test_field_kernels_match_numpy_reference():
    f = make_field("jet", (40, 36), 0.05, speed_px_s=400.0, seed=2)
    f.gain = 3.0
    cx, cy, s, a = f.puffs_at(0.02)
    ys, xs = np.mgrid[0:40, 0:36].astype(np.float64)
    ex, ey = xs[..., None] - cx, ys[..., None] - cy
    g = a * np.exp(-0.5 * (ex ** 2 + ey ** 2) / s ** 2)
    phi_ref = g.sum(-1)
    d_ref = np.stack([(-g * ex / s ** 2).sum(-1), (-g * ey / s ** 2).sum(-1)], -1)
    phi, d = f.evaluate(0.02)
    scale = np.abs(d_ref).max()
    assert scale > 0
    np.testing.assert_allclose(d, d_ref, atol=2e-3 * scale)
    np.testing.assert_allclose(phi, phi_ref, atol=2e-3 * np.abs(phi_ref).max())
    pix = np.array([0, 5, 77, 40 * 36 - 1, 700])
    phi_p, d_p = f.evaluate(0.02, pix)
    np.testing.assert_allclose(phi_p, phi.ravel()[pix], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(d_p, d.reshape(-1, 2)[pix], rtol=1e-12, atol=1e-12)


def test_background_kernel_matches_reference():
    bg = make_background((30, 30), density=0.1, radius_px=1.5, seed=4, margin_px=5)
    rng = np.random.default_rng(0)
    sx, sy = rng.uniform(-4, 33, 2000), rng.uniform(-4, 33, 2000)
    np.testing.assert_allclose(bg.radiance(sx, sy), bg.radiance_reference(sx, sy), atol=2e-3)
    v = bg.radiance(sx, sy)
    assert v.min() >= 1 - bg.contrast - 1e-12 and v.max() <= 1.0
    assert v.min() < 0.5 and v.max() > 0.99  # dots and paper both present


def test_frames_are_background_at_displaced_points(plume):
    h, w = SIZE
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    for i in range(len(plume.frames)):
        d = plume.gt.displacement[i].astype(np.float64)
        rad = plume.background.radiance_reference(xs - d[..., 0], ys - d[..., 1])
        ref = np.clip(np.rint(255 * rad), 0, 255)
        diff = np.abs(plume.frames.images[i].astype(np.int64) - ref)
        assert diff.max() <= 1 and (diff > 0).mean() < 0.01
    # the displacement is not rounded to pixels: a nearest-pixel render is different
    d = plume.gt.displacement[2].astype(np.float64)
    nearest = plume.background.radiance_reference(np.rint(xs - d[..., 0]),
                                                  np.rint(ys - d[..., 1]))
    moved = np.abs(d).max(-1) > 0.2
    assert moved.sum() > 20
    assert np.abs(plume.frames.images[2][moved] - np.rint(255 * nearest[moved])).mean() > 3


def test_tiny_displacement_changes_frames():
    sim = simulate_schlieren("ice", sensor_size=(48, 48), duration_s=2 / 120, seed=0,
                             magnitude_px=0.05, exposure_s=0.0)
    step = np.linalg.norm(np.diff(sim.gt.displacement, axis=0), axis=-1)
    assert step.max() == pytest.approx(0.05, rel=1e-5)
    diff = np.abs(sim.frames.images[1].astype(int) - sim.frames.images[0])
    assert diff.max() >= 2  # sub-pixel motion of 0.05 px is rendered, not lost


def test_events_sum_to_log_change_legm(plume):
    """Σ p C between two frames equals the change of log radiance up to one threshold at
    each end (the sensor's reference level), and correlates with the frames' log change."""
    ev, gt = plume.events, plume.gt
    cp, cn = gt.thresholds
    h, w = SIZE
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)

    def log_rad(i):
        d = gt.displacement[i].astype(np.float64)
        return np.log(plume.background.radiance(xs - d[..., 0], ys - d[..., 1]))

    for i in range(len(gt.t_us) - 1):
        m = (ev.t > gt.t_us[i]) & (ev.t <= gt.t_us[i + 1])
        inc = np.zeros((h, w))
        on = m & (ev.p == 1)
        off = m & (ev.p == 0)
        np.add.at(inc, (ev.y[on], ev.x[on]), cp[ev.y[on], ev.x[on]])
        np.add.at(inc, (ev.y[off], ev.x[off]), -cn[ev.y[off], ev.x[off]])
        dlog = log_rad(i + 1) - log_rad(i)
        assert np.all(np.abs(dlog - inc) < np.maximum(cp, cn) * 2 + 1e-3)
        act = np.abs(dlog) > gt.contrast_threshold
        assert act.sum() > 30 and np.corrcoef(dlog[act], inc[act])[0, 1] > 0.9
        frames = plume.frames.images.astype(np.float64)
        dfr = np.log(frames[i + 1] + 1) - np.log(frames[i] + 1)
        assert np.corrcoef(dfr[act], inc[act])[0, 1] > 0.8
    assert ev.t.min() > 0 and ev.t.max() <= gt.t_us[-1]
    assert ev.sensor_size == SIZE


def _reference_events(samples, times, C):
    """Plain-python reference of the crossing rule for one pixel."""
    out = []
    r = samples[0]
    for a, b, t0, t1 in zip(samples[:-1], samples[1:], times[:-1], times[1:], strict=True):
        for sign in (1.0, -1.0):
            while sign * (b - r) >= C:
                r += sign * C
                ti = math.ceil(t0 + (r - a) / (b - a) * (t1 - t0) - 1e-9)
                out.append((min(max(ti, t0 + 1), t1), 1 if sign > 0 else 0))
    return out


def test_simulate_log_function_matches_reference():
    rng = np.random.default_rng(5)
    knots = np.arange(0, 2001, 100)
    walk = np.cumsum(rng.normal(0, 0.3, (knots.size, 3)), axis=0)

    def log_at(t, pix):
        v = np.array([np.interp(t, knots, walk[:, k]) for k in range(3)])
        return v.reshape(1, 3) if pix is None else v[pix]

    res = simulate_log_function(log_at, (1, 3), 2000, breaks_us=knots, max_step_us=100,
                                threshold=0.25, mismatch=0.0, max_step_fraction=0.5)
    ev = res.events
    for k in range(3):
        want = _reference_events(walk[:, k], knots, 0.25)
        got = [(int(t), int(p)) for t, p in zip(ev.t[ev.x == k], ev.p[ev.x == k], strict=True)]
        assert sorted(got) == sorted(want) and len(want) > 5


def test_deterministic_with_seed():
    kw = dict(sensor_size=(40, 40), duration_s=2 / 120, magnitude_px=1.0, photons=50.0)
    a = simulate_schlieren("breath", seed=7, **kw)
    b = simulate_schlieren("breath", seed=7, **kw)
    c = simulate_schlieren("breath", seed=8, **kw)
    np.testing.assert_array_equal(a.frames.images, b.frames.images)
    np.testing.assert_array_equal(a.events.t, b.events.t)
    np.testing.assert_array_equal(a.events.x, b.events.x)
    np.testing.assert_array_equal(a.gt.flow, b.gt.flow)
    assert not np.array_equal(a.frames.images, c.frames.images)
    assert len(a.events) != len(c.events) or not np.array_equal(a.events.x, c.events.x)


@pytest.mark.parametrize("scene", sorted(BOS_SCENES))
@pytest.mark.parametrize("magnitude", [0.05, 3.0])
def test_each_scene_reaches_the_requested_magnitude(scene, magnitude):
    sim = simulate_schlieren(scene, sensor_size=(48, 40), duration_s=3 / 120, seed=1,
                             magnitude_px=magnitude)
    dt = np.diff(sim.gt.t_us) * 1e-6
    per_frame = np.linalg.norm(sim.gt.flow, axis=-1).max(axis=(1, 2)) * dt
    assert per_frame.max() == pytest.approx(magnitude, rel=1e-4)
    # the air covers a region, not one pixel: a tenth of the peak on many pixels
    assert (np.linalg.norm(sim.gt.flow[-1], axis=-1) * dt[-1] > 0.1 * magnitude).sum() > 20
    if magnitude >= 1:
        assert len(sim.events) > 100
    if scene == "plume":
        assert sim.gt.meta["rise_speed_px_s"] == pytest.approx(2400 * 48 / 720)


def test_plume_structures_rise_at_the_rise_speed():
    """q along the plume's axis moves up by rise speed x dt between intervals."""
    sim = simulate_schlieren("plume", sensor_size=(96, 48), duration_s=8 / 120, seed=2,
                             magnitude_px=1.0, speed_px_s=480.0)
    col = sim.gt.q[:, :, 24].astype(np.float64)
    shift = 480.0 / 120  # px per frame
    best = []
    for i in range(col.shape[0] - 1):
        a, b = col[i], col[i + 1]
        s = np.arange(0, 9)
        err = [np.abs(np.interp(np.arange(20, 76) + k, np.arange(96), a)
                      - b[20:76]).mean() for k in s]
        best.append(s[int(np.argmin(err))])
    assert np.median(best) == pytest.approx(shift, abs=1)


def test_low_light_shot_noise_statistics():
    photons = 12.0
    sim = simulate_schlieren("plume", sensor_size=(64, 64), duration_s=1 / 120, seed=0,
                             photons=photons, gain=1.0, exposure_s=0.0)
    h, w = 64, 64
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    z = []
    for i in range(2):
        d = sim.gt.displacement[i].astype(np.float64)
        lam = photons * sim.background.radiance(xs - d[..., 0], ys - d[..., 1])
        z.append((sim.frames.images[i] - lam) / np.sqrt(lam))
    z = np.concatenate([v.ravel() for v in z])
    assert abs(z.mean()) < 0.05 and z.var() == pytest.approx(1.0, abs=0.08)
    # default gain normalizes: a white pixel's mean maps near 255
    sim2 = simulate_schlieren("plume", sensor_size=(64, 64), duration_s=1 / 120, seed=0,
                              photons=photons, exposure_s=0.0)
    assert sim2.gt.meta["gain"] == pytest.approx(255 / photons)
    assert set(np.unique(sim2.frames.images)) <= {min(255, round(k * 255 / photons))
                                                  for k in range(40)}


def _flat(**kw):
    """Frames of a flat white field (dot contrast 1e-6): every pixel sees the same light."""
    args = dict(sensor_size=(96, 96), duration_s=2 / 120, seed=0, exposure_s=0.0,
                dot_contrast=1e-6) | kw
    return simulate_schlieren("plume", **args)


def test_frame_noise_is_shot_and_read_noise_in_quadrature():
    photons, read, gain = 400.0, 10.0, 0.5
    img = _flat(photons=photons, read_noise_e=read, gain=gain).frames.images.astype(float)
    # grey levels: gain * sqrt(shot^2 + read^2), plus 1/12 grey^2 of rounding
    expect = math.sqrt(gain ** 2 * (photons + read ** 2) + 1 / 12)
    assert img.mean() == pytest.approx(gain * photons, abs=0.3)
    assert img.std() == pytest.approx(expect, rel=0.03)
    # without the read noise: shot noise alone, 10 % lower (the test tells them apart)
    shot = _flat(photons=photons, gain=gain).frames.images.astype(float)
    assert shot.std() == pytest.approx(math.sqrt(gain ** 2 * photons + 1 / 12), rel=0.03)


def test_fixed_gain_quantizes_dim_frames_to_a_few_levels():
    # a gain set for 10000 photons at white, light at 100 photons: white is 2.55 grey
    kw = dict(sensor_size=(64, 64), duration_s=2 / 120, seed=0, exposure_s=0.0,
              photons=100.0)
    fixed = simulate_schlieren("plume", gain=255 / 10000, **kw).frames.images
    assert set(np.unique(fixed)) <= {0, 1, 2, 3, 4}
    # the default gain follows the light: the same photons spread over many levels
    assert len(np.unique(simulate_schlieren("plume", **kw).frames.images)) > 40
    # normalizing stretches the range but cannot add levels
    norm = simulate_schlieren("plume", gain=255 / 10000, normalize=True, **kw).frames.images
    for a, b in zip(fixed, norm, strict=True):
        assert len(np.unique(a)) == len(np.unique(b))
        assert b.min() == 0 and b.max() == 255
        # the stretch keeps the order of the grey levels
        np.testing.assert_array_equal(np.argsort(a.ravel(), kind="stable"),
                                      np.argsort(b.ravel(), kind="stable"))


def test_adc_clips_at_full_scale_and_bit_depth():
    # white at 2x full scale: the bright pixels clip at 2**bits - 1
    for bits, dtype in ((8, np.uint8), (4, np.uint8), (12, np.uint16)):
        full = 2 ** bits - 1
        fr = _flat(photons=1000.0, gain=2 * full / 1000.0, bit_depth=bits).frames
        assert fr.images.dtype == dtype and fr.bit_depth == bits
        assert fr.images.max() == full and (fr.images == full).mean() > 0.99
    # a dark pixel with read noise clips at 0, not below
    dark = _flat(photons=1.0, read_noise_e=20.0, gain=1.0).frames.images
    assert dark.min() == 0 and (dark == 0).mean() > 0.3
    # default gain at 10 bits: white near 1023
    ten = _flat(photons=1e6, bit_depth=10).frames
    assert ten.images.dtype == np.uint16 and abs(float(ten.images.mean()) - 1023) < 2


def test_normalize_range():
    from evmotion.sim.schlieren import normalize_range

    img = np.array([[3.0, 5.0], [4.0, 7.0]])
    out = normalize_range(img, 255)
    assert out.min() == 0 and out.max() == 255
    assert out.tolist() == [[0.0, 128.0], [64.0, 255.0]]
    flat = np.full((2, 3), 9.0)
    np.testing.assert_array_equal(normalize_range(flat, 255), flat)
    # normalized frames in the simulator: every frame spans 0..2**bits - 1
    fr = _flat(photons=50.0, read_noise_e=5.0, gain=0.5, normalize=True, bit_depth=10)
    for im in fr.frames.images:
        assert im.min() == 0 and im.max() == 1023
    assert fr.gt.meta["normalize"] is True and fr.gt.meta["bit_depth"] == 10
    assert fr.gt.meta["read_noise_e"] == 5.0


def test_read_noise_is_seeded_and_leaves_shot_noise_draws():
    kw = dict(photons=200.0, read_noise_e=6.8, gain=255 / 10000 * 40)
    a, b = _flat(**kw).frames.images, _flat(**kw).frames.images
    np.testing.assert_array_equal(a, b)
    c = _flat(seed=1, **kw).frames.images
    assert (a != c).mean() > 0.3
    # the defaults (no read noise, 8 bits, no stretch) give the former frames exactly
    old = _flat(photons=200.0).frames.images
    np.testing.assert_array_equal(
        old, _flat(photons=200.0, read_noise_e=0.0, bit_depth=8, normalize=False).frames.images)


def test_exposure_blurs_toward_the_mean():
    kw = dict(sensor_size=(48, 48), duration_s=2 / 120, seed=0, magnitude_px=3.0)
    sharp = simulate_schlieren("jet", exposure_s=0.0, **kw)
    blur = simulate_schlieren("jet", exposure_s=1 / 120, **kw)
    assert blur.gt.meta["exposure_samples"] > 1
    moving = np.linalg.norm(sharp.gt.flow[0], axis=-1) / 120 > 1.0
    assert moving.sum() > 10
    a, b = sharp.frames.images[1].astype(float), blur.frames.images[1].astype(float)
    assert np.abs(a - b)[moving].mean() > 3 * np.abs(a - b)[~moving].mean()
    np.testing.assert_array_equal(sharp.gt.flow, blur.gt.flow)


def test_write_and_read_back(tmp_path, plume):
    from evmotion.io import ecd, read_events
    from evmotion.io.flowfiles import read_flow_h5
    from evmotion.io.frames import read_frames

    gt_path = write_schlieren(plume, tmp_path / "sim")
    gt = read_schlieren_gt(tmp_path / "sim")
    np.testing.assert_array_equal(gt.flow, plume.gt.flow)
    np.testing.assert_array_equal(gt.q, plume.gt.q)
    np.testing.assert_array_equal(gt.displacement, plume.gt.displacement)
    np.testing.assert_array_equal(gt.t_us, plume.gt.t_us)
    np.testing.assert_allclose(gt.thresholds[0], plume.gt.thresholds[0], rtol=1e-6)
    assert gt.meta == plume.gt.meta and gt.contrast_threshold == 0.2
    seq = read_flow_h5(gt_path)
    np.testing.assert_array_equal(seq.flow, plume.gt.flow)
    assert seq.t0.tolist() == plume.gt.t_us[:-1].tolist()
    assert seq.t1.tolist() == plume.gt.t_us[1:].tolist()
    ev = read_events(tmp_path / "sim")
    np.testing.assert_array_equal(ev.t, plume.events.t)
    np.testing.assert_array_equal(ev.p, plume.events.p)
    assert ev.sensor_size == SIZE
    fr = read_frames(tmp_path / "sim")
    np.testing.assert_array_equal(fr.images, plume.frames.images)
    np.testing.assert_array_equal(fr.t, plume.frames.t)
    assert ecd.read_image_list(tmp_path / "sim")["files"][0] == "images/frame_00000000.png"
    with pytest.raises(FormatError, match="not schlieren ground truth"):
        import h5py

        with h5py.File(tmp_path / "x.h5", "w") as f:
            f["a"] = 1
        read_schlieren_gt(tmp_path / "x.h5")


def test_12_bit_frames_keep_their_intensity_scale(tmp_path):
    """Frames of more than 8 bits are written as 16-bit PNGs with the samples in the top
    bits (a 12-bit white used to read back as 1/16 of the full scale)."""
    from evmotion.io.frames import read_frames

    sim = simulate_schlieren("plume", sensor_size=(32, 40), duration_s=1 / 60, seed=0,
                             bit_depth=12)
    assert sim.frames.images.max() <= 4095
    write_schlieren(sim, tmp_path / "s")
    fr = read_frames(tmp_path / "s")
    np.testing.assert_array_equal(fr.images, sim.frames.images.astype(np.uint16) << 4)
    np.testing.assert_allclose(fr.as_float(), sim.frames.as_float(), atol=1 / 4095)


def test_few_bit_frames_keep_their_intensity_scale_and_stale_frames_go(tmp_path):
    """Frames of fewer than 8 bits fill the 8-bit PNG's top bits (4-bit white was written
    as 15 of 255), and a shorter simulation written over a longer one leaves only its
    own frames."""
    from evmotion.io.frames import read_frames

    long = simulate_schlieren("plume", sensor_size=(32, 40), duration_s=4 / 120, seed=0)
    write_schlieren(long, tmp_path / "s")
    sim = simulate_schlieren("plume", sensor_size=(32, 40), duration_s=1 / 60, seed=0,
                             bit_depth=4)
    assert sim.frames.images.max() <= 15
    (tmp_path / "s" / "images" / "notes.png").write_bytes(b"kept")
    write_schlieren(sim, tmp_path / "s")
    fr = read_frames(tmp_path / "s")
    np.testing.assert_array_equal(fr.images, sim.frames.images << 4)
    assert sorted(p.name for p in (tmp_path / "s" / "images").iterdir()) == [
        *(f"frame_{i:08d}.png" for i in range(len(sim.frames.t))), "notes.png"]


@pytest.mark.parametrize("kw, match", [
    (dict(scene="smoke"), "unknown schlieren scene"),
    (dict(magnitude_px=0.0), "magnitude_px"),
    (dict(magnitude_px=float("nan")), "magnitude_px"),
    (dict(duration_s=0.001), "fewer than two frames"),
    (dict(photons=-1.0), "photons"),
    (dict(gain=2.0), "gain needs photons"),
    (dict(sensor_size=(4, 40)), "sensor_size"),
    (dict(dot_density=0.0), "dot_density"),
    (dict(dot_radius_px=50), "dot_radius_px"),
    (dict(exposure_s=0.5), "exposure_s"),
    (dict(photons=10.0, read_noise_e=float("nan")), "read_noise_e"),
    (dict(photons=10.0, read_noise_e=-1.0), "read_noise_e"),
    (dict(photons=10.0, read_noise_e=2e6), "read_noise_e"),
    (dict(read_noise_e=5.0), "read_noise_e needs photons"),
    (dict(bit_depth=0), "bit_depth"),
    (dict(bit_depth=17), "bit_depth"),
    (dict(bit_depth=8.5), "bit_depth must be an integer"),
    (dict(bit_depth=float("nan")), "bit_depth"),
    (dict(bit_depth=True), "bit_depth must be an integer"),
    (dict(normalize="yes"), "normalize must be True or False"),
])
def test_bad_parameters(kw, match):
    args = dict(scene="plume", sensor_size=(32, 32), duration_s=2 / 120) | kw
    with pytest.raises(ParameterError, match=match):
        simulate_schlieren(**args)


def test_cli_simulate_schlieren(tmp_path, capsys):
    import json

    from evmotion.cli import main
    from evmotion.io.frames import read_frames

    out = tmp_path / "jet"
    rc = main(["simulate", "schlieren", "--scene", "jet", "--size", "40x48", "--duration",
               str(2 / 120), "--magnitude", "2", "--photons", "30", "--seed", "4", "--json",
               "--event-photons", "500", "--out", str(out)])
    summary = json.loads(capsys.readouterr().out)
    assert rc == 0 and summary["scene"] == "jet" and summary["n_frames"] == 3
    gt = read_schlieren_gt(out)
    assert gt.flow.shape == (2, 40, 48, 2) and gt.meta["photons"] == 30
    assert gt.meta["seed"] == 4 and gt.meta["magnitude_px"] == 2
    assert gt.meta["event_photons"] == 500
    assert read_frames(out).images.shape == (3, 40, 48)
    assert gt.meta["read_noise_e"] == 0 and gt.meta["bit_depth"] == 8
    assert gt.meta["normalize"] is False
    # the thesis' camera: a fixed gain, read noise, 8 bits, normalized frames
    rc = main(["simulate", "schlieren", "--size", "40x48", "--duration", str(1 / 120),
               "--photons", "100", "--gain", "0.0255", "--read-noise", "6.8", "--bits", "8",
               "--normalize", "--out", str(tmp_path / "dim")])
    capsys.readouterr()
    meta = read_schlieren_gt(tmp_path / "dim").meta
    assert rc == 0 and meta["gain"] == 0.0255 and meta["read_noise_e"] == 6.8
    assert meta["normalize"] is True and meta["bit_depth"] == 8
    dim = read_frames(tmp_path / "dim").images
    assert dim.max() == 255 and len(np.unique(dim[0])) <= 5
    rc = main(["simulate", "schlieren", "--height", "32", "--width", "36", "--duration",
               str(1 / 120), "--out", str(tmp_path / "p")])
    line = capsys.readouterr().out
    assert rc == 0 and line.startswith("schlieren plume:") and line.count("\n") == 1
    assert read_schlieren_gt(tmp_path / "p").flow.shape == (1, 32, 36, 2)
    rc = main(["simulate", "schlieren", "--scene", "smoke", "--out", str(tmp_path / "s")])
    err = capsys.readouterr().err
    assert rc == 2 and "--scene: invalid choice: 'smoke'" in err and err.count("\n") == 1
    rc = main(["simulate", "rotation", "--scene", "jet", "--out", str(tmp_path / "r.h5")])
    assert rc == 2 and "--scene 'jet' does not apply" in capsys.readouterr().err


def test_event_shot_noise_grows_as_light_falls():
    kw = dict(sensor_size=(48, 128), duration_s=3 / 120, seed=0, magnitude_px=1.0)
    base = simulate_schlieren("plume", **kw)
    still = np.linalg.norm(base.gt.displacement, axis=-1).max(axis=0) == 0
    assert still.mean() > 0.1
    counts = []
    for ep in (1e6, 1e3, 100.0, 20.0):
        ev = simulate_schlieren("plume", event_photons=ep, **kw).events
        counts.append((len(ev), int(still[ev.y, ev.x].sum())))
    assert still[base.events.y, base.events.x].sum() == 0  # no air, no light change
    assert abs(counts[0][0] - len(base.events)) < 0.05 * len(base.events)
    assert counts[0][1] == 0
    n_still = [c[1] for c in counts]
    assert n_still == sorted(n_still) and n_still[-1] > 5 * max(n_still[1], 1)
    # the noise is a function of time: the same seed gives the same events
    a = simulate_schlieren("plume", event_photons=100.0, **kw).events
    b = simulate_schlieren("plume", event_photons=100.0, **kw).events
    np.testing.assert_array_equal(a.t, b.t)
    with pytest.raises(ParameterError, match="event_photons"):
        simulate_schlieren("plume", event_photons=0.0, **kw)


def test_flow_is_the_image_motion_legm(plume):
    """The ground-truth flow moves the frames' content: the log change between two frames
    is -∇L · v Δt (brightness constancy, first order), with a positive slope near 1."""
    gt = plume.gt
    logs = np.log(plume.frames.images.astype(np.float64) + 1.0)
    for i in range(len(gt.t_us) - 1):
        dt = (gt.t_us[i + 1] - gt.t_us[i]) * 1e-6
        gy, gx = np.gradient(0.5 * (logs[i] + logs[i + 1]))
        pred = -(gx * gt.flow[i, ..., 0] + gy * gt.flow[i, ..., 1]) * dt
        meas = logs[i + 1] - logs[i]
        act = np.hypot(gt.flow[i, ..., 0], gt.flow[i, ..., 1]) * dt > 0.05
        assert act.sum() > 50
        slope = np.sum(pred[act] * meas[act]) / np.sum(pred[act] ** 2)
        assert 0.6 < slope < 1.4, slope


def test_air_far_slower_than_its_change_is_refused():
    """The change between frames is held at magnitude_px: at speed 1e-3 px/s the air's
    displacement reached 9e5 px and the background 3 TiB of dots (out of memory, exit 1;
    probe). Refused in one line, naming both."""
    with pytest.raises(ParameterError, match="speed_px_s=1.0 with magnitude_px=1.0: the "
                                             "air's displacement reaches"):
        simulate_schlieren("plume", sensor_size=(48, 48), duration_s=0.02, seed=0,
                           speed_px_s=1.0)
    # slower still, the puffs (born over the time the air takes to cross the view) were
    # numbered in the hundreds of millions
    with pytest.raises(ParameterError, match="air that slow takes over 1000 s to cross"):
        simulate_schlieren("breath", sensor_size=(48, 48), duration_s=0.02, seed=0,
                           speed_px_s=1e-6)


@pytest.mark.parametrize("where", ["write_png", "_write_gt", "replace"])
def test_an_interrupted_write_leaves_no_scene_paired_with_another(tmp_path, monkeypatch, where):
    """Ctrl-C while a scene was written over an earlier one had left the new events and
    frames beside the earlier scene's ground truth, looking complete (probe BA). Built in
    a temporary folder and published with the truth last, an interrupted write leaves the
    earlier scene whole (interrupted while building) or no ground truth (while
    publishing), and no temporary folder."""
    import os
    from pathlib import Path

    import evmotion.sim.schlieren as sch
    from _helpers import interrupt_at_call

    out = tmp_path / "scene"
    sch.write_schlieren(sch.simulate_schlieren("jet", sensor_size=(40, 48), duration_s=0.03,
                                               seed=5), out)
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    if where == "replace":  # the second frame moved into the earlier scene's folder
        real, moved = os.replace, []

        def replace(src, dst):
            if Path(dst).parent == out / "images":
                moved.append(dst)
                if len(moved) == 2:
                    raise KeyboardInterrupt
            return real(src, dst)

        monkeypatch.setattr(os, "replace", replace)
    else:
        interrupt_at_call(monkeypatch, sch, where, 2 if where == "write_png" else 1)
    with pytest.raises(KeyboardInterrupt):
        sch.write_schlieren(sch.simulate_schlieren("plume", sensor_size=(40, 48),
                                                   duration_s=2 / 120, seed=0), out)
    monkeypatch.undo()
    left = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    if where == "replace":
        assert "schlieren_gt.h5" not in left
    else:
        assert left == before
    assert [p.name for p in tmp_path.iterdir()] == ["scene"]


def test_the_span_made_is_said(tmp_path, capsys):
    """--duration 0.02 at 120 fps makes 3 frames and events up to 16.7 ms, and the run
    said "0.02 s" (probe BA): the metadata's span_s and the line say the span made."""
    from evmotion.cli import main

    assert main(["simulate", "schlieren", "--size", "40x48", "--duration", "0.02",
                 "--out", str(tmp_path / "s")]) == 0
    out = capsys.readouterr().out
    assert "3 frames" in out and "0.016667 s of --duration 0.02: whole frame intervals" in out
    sim = simulate_schlieren("plume", sensor_size=(40, 48), duration_s=0.02, seed=0)
    assert sim.gt.meta["span_s"] == pytest.approx(2 / 120, abs=1e-6)
    assert sim.gt.meta["duration_s"] == 0.02 and sim.events.t[-1] <= 16_667


def test_info_says_what_the_ground_truth_holds(tmp_path, capsys):
    """info on schlieren_gt.h5 listed a flow file with 'valid_fraction: None' and neither
    q nor the displacement (probe BA): it says what the file is and holds; no masks is
    every pixel (1.0), as eval reads it."""
    import json

    from evmotion.cli import main

    write_schlieren(simulate_schlieren("plume", sensor_size=(40, 48), duration_s=2 / 120,
                                       seed=0), tmp_path / "s")
    assert main(["info", str(tmp_path / "s" / "schlieren_gt.h5"), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert "ground truth" in d["content"] and {"q", "displacement"} <= set(d["datasets"])
    assert d["valid_fraction"] == 1.0 and d["valid_masks"] is False

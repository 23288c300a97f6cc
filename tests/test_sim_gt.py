"""Simulator ground truth: flow sharpens the IWE, flow/displacement/parameter consistency
with each other and with core.warps, occlusion, HDF5 round trip, the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from evmotion.core.warps import make_warp
from evmotion.sim import SCENES, read_ground_truth, simulate, write_ground_truth

SIZE = (130, 173)  # half a DAVIS346: the default speeds stay realistic
PARAMETRIC = [s for s in SCENES if s != "object"]


@pytest.fixture(scope="module")
def sims():
    """One short simulation per scene (module scope: shared by the tests)."""
    return {s: simulate(s, duration_s=0.04, sensor_size=SIZE, seed=0, show_progress=False)
            for s in SCENES}


def _iwe(x, y, shape):
    """Bilinear voting image of warped events (plain numpy)."""
    h, w = shape
    img = np.zeros((h + 1) * (w + 1))
    x0, y0 = np.floor(x), np.floor(y)
    ok = (x0 >= 0) & (y0 >= 0) & (x0 < w - 1) & (y0 < h - 1)
    x, y, x0, y0 = x[ok], y[ok], x0[ok].astype(int), y0[ok].astype(int)
    ax, ay = x - x0, y - y0
    for dx, dy, wgt in ((0, 0, (1 - ax) * (1 - ay)), (1, 0, ax * (1 - ay)),
                        (0, 1, (1 - ax) * ay), (1, 1, ax * ay)):
        np.add.at(img, (y0 + dy) * (w + 1) + x0 + dx, wgt)
    return img.reshape(h + 1, w + 1)[:h, :w]


@pytest.mark.parametrize("scene", SCENES)
def test_gt_flow_sharpens_iwe(sims, scene):
    """Warping events to t_ref with gt.flow at their time gives a much sharper IWE than
    the identity warp: FWL = var(IWE_gt) / var(IWE_id) > 1.5."""
    res = sims[scene]
    ev, gt = res.events, res.gt
    t_ref = 20000
    sel = ev.t < 40000
    x, y, t = ev.x[sel].astype(float), ev.y[sel].astype(float), ev.t[sel]
    assert x.size > 1000
    xw, yw = x.copy(), y.copy()
    edges = np.arange(0, 40001, 1000)
    for a, b in zip(edges[:-1], edges[1:], strict=True):  # flow at each event's time (1 ms bins)
        m = (t >= a) & (t < b)
        f = gt.flow((a + b) / 2)
        xi, yi = x[m].astype(int), y[m].astype(int)
        dt = (t[m] - t_ref) * 1e-6
        xw[m] -= dt * f[yi, xi, 0]
        yw[m] -= dt * f[yi, xi, 1]
    fwl = _iwe(xw, yw, SIZE).var() / _iwe(x, y, SIZE).var()
    assert fwl > 1.5, f"{scene}: FWL {fwl:.2f}"


def test_identity_warp_of_wrong_flow_is_not_sharp(sims):
    """The FWL test can fail: the opposite flow blurs instead of sharpening."""
    res = sims["translation"]
    ev = res.events
    f = res.gt.flow(15000)
    dt = (ev.t - 15000) * 1e-6
    x, y = ev.x.astype(float), ev.y.astype(float)
    fwl = _iwe(x + dt * f[0, 0, 0], y + dt * f[0, 0, 1], SIZE).var() / _iwe(x, y, SIZE).var()
    assert fwl < 1.0


@pytest.mark.parametrize("scene", SCENES)
def test_flow_is_the_derivative_of_displacement(sims, scene):
    gt = sims[scene].gt
    h_us = 2.0
    for t in (3000, 17000):
        fwd = gt.displacement(t, t + h_us) / (h_us * 1e-6)
        bwd = -gt.displacement(t, t - h_us) / (h_us * 1e-6)
        central = (fwd + bwd) / 2
        f = gt.flow(t)
        inside = gt.visible_layer(t) == gt.visible_layer(t + h_us)
        np.testing.assert_allclose(central[inside], f[inside], rtol=1e-3, atol=0.05)


def test_zoom_displacement_is_integrated_not_flow_times_dt(sims):
    """Forward motion: x(t1) - c = (x(t0) - c)(1 - t0 hz) / (1 - t1 hz), which differs
    from flow(t0) * (t1 - t0)."""
    gt = sims["zoom"].gt
    hz = sims["zoom"].params["hz"]
    cx, cy = sims["zoom"].params["foe"]
    t0, t1 = 0.0, 0.25
    d = gt.displacement(t0 * 1e6, t1 * 1e6)
    ys, xs = np.mgrid[0:SIZE[0], 0:SIZE[1]]
    scale = (1 - t0 * hz) / (1 - t1 * hz)
    np.testing.assert_allclose(d[..., 0], (xs - cx) * (scale - 1), atol=1e-3)
    np.testing.assert_allclose(d[..., 1], (ys - cy) * (scale - 1), atol=1e-3)
    naive = gt.flow(t0 * 1e6)[..., 0] * (t1 - t0)
    assert np.abs(naive - d[..., 0]).max() > 1.0


@pytest.mark.parametrize("scene", PARAMETRIC)
def test_params_reproduce_flow_through_core_warps(sims, scene):
    """params(t) are the warp's parameters referenced at t: core.warps' optical flow with
    them equals gt.flow(t)."""
    gt = sims[scene].gt
    layer = gt.layers[0]
    w = make_warp(layer.motion.warp.name, SIZE, K=gt.K, center=layer.motion.warp.center)
    ys, xs = np.mgrid[0:SIZE[0]:7, 0:SIZE[1]:9]
    for t in (0, 12000, 29000):
        p = gt.params(t)
        theta = np.array([p[n] for n in w.param_names])
        u, v = w.optical_flow(xs.ravel().astype(float), ys.ravel().astype(float), theta)
        f = gt.flow(t)[ys, xs].reshape(-1, 2)
        np.testing.assert_allclose(u, f[:, 0], rtol=1e-4, atol=1e-2)
        np.testing.assert_allclose(v, f[:, 1], rtol=1e-4, atol=1e-2)


def test_parameter_semantics(sims):
    rot = sims["rotation"].gt
    assert rot.params(20000)["omega"] == pytest.approx([0.5, -0.7, 1.2])
    np.testing.assert_allclose(rot.angular_velocity(), [0.5, -0.7, 1.2])
    zoom = sims["zoom"].gt.params(20000)
    assert zoom["hz"] == pytest.approx(1.5 / (1 - 0.02 * 1.5))  # time to contact shrinks
    assert zoom["ttc_s"] == pytest.approx(1 / zoom["hz"])
    tr = sims["translation"].gt
    assert tr.params(10000)["vx"] == pytest.approx(220.0)
    np.testing.assert_allclose(tr.flow(10000)[..., 0], 220.0, atol=1e-3)
    np.testing.assert_array_equal(tr.angular_velocity(), 0.0)
    assert np.isnan(sims["affine"].gt.angular_velocity()).all()
    assert sims["rotation"].gt.frame_times_us.tolist() == [0, 10000, 20000, 30000, 40000]


def test_zoom_focus_of_expansion():
    res = simulate("zoom", duration_s=0.005, sensor_size=SIZE, params={"foe": [20.0, 15.0]},
                   show_progress=False)
    f = res.gt.flow(0)
    assert np.abs(f[15, 20]).max() < 1e-3
    assert f[15, 60, 0] > 0 and f[50, 20, 1] > 0  # expansion away from the FOE


def test_object_occludes_background(sims):
    res = sims["object"]
    gt = res.gt
    p = res.params
    top = gt.visible_layer(0)
    ys, xs = np.mgrid[0:SIZE[0], 0:SIZE[1]]
    inside = np.hypot(xs - p["fg_x"], ys - p["fg_y"]) < p["radius"] - 1
    outside = np.hypot(xs - p["fg_x"], ys - p["fg_y"]) > p["radius"] + 1
    assert top[inside].min() == 1 and top[outside].max() == 0
    f = gt.flow(0)
    np.testing.assert_allclose(f[outside], np.broadcast_to([p["bg_vx"], p["bg_vy"]],
                                                           f[outside].shape), atol=1e-3)
    cy, cx = int(p["fg_y"]), int(p["fg_x"])
    np.testing.assert_allclose(f[cy, cx], [p["fg_vx"], p["fg_vy"]], atol=1.5)
    # the disc moves: later it covers pixels it did not cover at t = 0
    later = gt.visible_layer(30000)
    assert (later[~inside] == 1).sum() > 20
    params = gt.params(0)
    assert params["object"]["warp"] == "se2" and params["background"]["vx"] == p["bg_vx"]


def test_event_mask(sims):
    res = sims["translation"]
    m = res.gt.event_mask(0, 10000)
    ev = res.events
    sel = ev.t < 10000
    assert m.sum() == len(set(zip(ev.x[sel].tolist(), ev.y[sel].tolist(), strict=True)))
    assert not res.gt.event_mask(0, 0).any()


def test_ground_truth_round_trip(tmp_path, sims):
    gt = sims["object"].gt
    path = write_ground_truth(tmp_path / "sim_gt.h5", gt)
    back = read_ground_truth(path)
    assert back.scene == "object" and back.sensor_size == SIZE
    np.testing.assert_array_equal(back.frame_times_us, gt.frame_times_us)
    for t in (0, 7000, 20000):
        np.testing.assert_allclose(back.flow(t), gt.flow(t), atol=1e-4)
        np.testing.assert_allclose(back.displacement(t, t + 5000),
                                   gt.displacement(t, t + 5000), atol=1e-4)
    assert back.params(5000)["object"]["vx"] == pytest.approx(gt.params(5000)["object"]["vx"])
    np.testing.assert_array_equal(back.event_mask(10000, 30000), gt.event_mask(10000, 30000))
    import h5py

    with h5py.File(path) as f:
        assert f["flow"].shape == (5, *SIZE, 2)
        np.testing.assert_allclose(f["flow"][1], gt.flow(10000), atol=1e-4)
        assert f["layers/1/params"].shape == (5, 3)
        np.testing.assert_allclose(f["displacement"][2], gt.displacement(20000, 30000),
                                   atol=1e-4)
    rot = read_ground_truth(write_ground_truth(tmp_path / "rot_gt.h5", sims["rotation"].gt))
    np.testing.assert_allclose(rot.angular_velocity(), [0.5, -0.7, 1.2])
    np.testing.assert_allclose(rot.K, sims["rotation"].gt.K)


def test_read_ground_truth_errors(tmp_path):
    from evmotion.errors import FormatError

    with pytest.raises(FormatError, match="not found"):
        read_ground_truth(tmp_path / "missing.h5")
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not hdf5")
    with pytest.raises(FormatError, match="HDF5"):
        read_ground_truth(bad)


@pytest.fixture
def fake_writer(monkeypatch):
    """A stand-in for evmotion.io.write_events (h5py, test-only) recording its calls."""
    import h5py

    import evmotion.io

    calls = []

    def write_events(path, events, format=None, **meta):
        calls.append((path, len(events), format, meta))
        with h5py.File(path, "w") as f:
            for k in ("x", "y", "t", "p"):
                f[k] = getattr(events, k)
        return path

    monkeypatch.setattr(evmotion.io, "write_events", write_events, raising=False)
    return calls


def test_cli_simulate_real_writer(tmp_path, capsys):
    """With the package's own writer: events readable back, flow readable by io."""
    import evmotion.io as io
    from evmotion.cli import main

    out = tmp_path / "r.h5"
    assert main(["simulate", "rotation", "--out", str(out), "--size", "40x50",
                 "--duration", "0.01"]) == 0
    ev = io.read_events(out)
    api = simulate("rotation", duration_s=0.01, sensor_size=(40, 50), show_progress=False)
    np.testing.assert_array_equal(ev.t, api.events.t)
    np.testing.assert_array_equal(ev.x, api.events.x)
    assert "ground truth" in capsys.readouterr().out


def test_cli_simulate(tmp_path, fake_writer, capsys):
    from evmotion.cli import main

    out = tmp_path / "s.h5"
    rc = main(["simulate", "translation", "--out", str(out), "--size", "30x40",
               "--duration", "0.01", "--params", "vx=100", "--params", "vy=-20", "--json",
               "--noise-rate", "1", "--seed", "5"])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["params"]["vx"] == 100.0 and summary["params"]["vy"] == -20.0
    assert summary["sensor_size"] == [30, 40]
    assert fake_writer[0][1] == summary["n_events"] > 0
    gt = read_ground_truth(tmp_path / "s_gt.h5")
    np.testing.assert_allclose(gt.flow(5000)[3, 4], [100.0, -20.0], atol=1e-3)
    api = simulate("translation", duration_s=0.01, sensor_size=(30, 40), seed=5,
                   params={"vx": 100, "vy": -20}, noise_rate=1.0, show_progress=False)
    assert len(api.events) == summary["n_events"]
    # several after one --params, as the help's scene list shows them ('vy=-20' had been
    # an unrecognized argument, probe FLOWFOREIGN)
    rc = main(["simulate", "translation", "--out", str(out), "--size", "30x40",
               "--duration", "0.01", "--params", "vx=100", "vy=-20", "--json",
               "--noise-rate", "1", "--seed", "5"])
    assert rc == 0 and json.loads(capsys.readouterr().out)["params"]["vy"] == -20.0


def test_cli_json_params_and_errors(tmp_path, fake_writer, capsys):
    from evmotion.cli import main

    rc = main(["simulate", "rotation", "--out", str(tmp_path / "r.h5"), "--size", "30x40",
               "--duration", "0.005", "--params", '{"omega": [0.1, 0.2, 0.3]}', "--json"])
    assert rc == 0
    assert json.loads(capsys.readouterr().out)["params"]["omega"] == [0.1, 0.2, 0.3]
    rc = main(["simulate", "rotation", "--out", str(tmp_path / "r.h5"), "--params", "vx=3"])
    assert rc == 2
    assert "no parameter 'vx'" in capsys.readouterr().err
    rc = main(["simulate", "zoom", "--out", str(tmp_path / "z.h5"), "--size", "big"])
    assert rc == 2
    assert "--size" in capsys.readouterr().err


def test_an_interrupted_simulation_leaves_no_other_scenes_truth(tmp_path, monkeypatch):
    """Probe BH: interrupted between its events and its ground truth (written a second or
    two later), 'simulate rotation --out s.h5' left its events beside the translation
    truth of an earlier run at the same name, which info named as theirs."""
    import evmotion.sim
    from evmotion.cli import main

    out = tmp_path / "s.h5"
    argv = ["--size", "40x50", "--duration", "0.02", "--out", str(out)]
    assert main(["simulate", "translation", *argv]) == 0
    assert (tmp_path / "s_gt.h5").exists()

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    monkeypatch.setattr(evmotion.sim, "write_ground_truth", interrupted)
    assert main(["simulate", "rotation", *argv]) == 130
    # the earlier pair as it was (its truth had been deleted first, probe BP)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    monkeypatch.undo()
    # interrupted as the events are written, or just after: a pair either way, nothing
    # hidden left (a finished events file stood with no truth, probe BP)
    import evmotion.io

    write = evmotion.io.write_events
    seen = []
    for when in ("during", "after"):
        def cut(*args, when=when, **kwargs):
            if when == "after":
                write(*args, **kwargs)
            # what a SIGKILL here would leave: no truth beside the events, the earlier one
            # stepped aside (new events stood beside it, probe BR)
            seen.append((tmp_path / "s_gt.h5").exists())
            raise KeyboardInterrupt

        monkeypatch.setattr(evmotion.io, "write_events", cut)
        assert main(["simulate", "rotation", *argv]) == 130
        assert sorted(p.name for p in tmp_path.iterdir()) == ["s.h5", "s_gt.h5"]
        from evmotion.io.h5attrs import file_attrs

        scene = file_attrs(tmp_path / "s_gt.h5", ("scene",)).get("scene")
        assert scene == ("translation" if when == "during" else "rotation"), when
        monkeypatch.undo()
    assert seen == [False, False]
    # a killed run's hidden truths are removed by the next run (they piled up, probe BR)
    import socket

    stale = [tmp_path / f".s_gt.h5.{socket.gethostname()}-999999999.{kind}.h5"
             for kind in ("part", "old")]
    for f in stale:
        f.write_bytes(b"x")
    assert main(["simulate", "rotation", *argv]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.h5", "s_gt.h5"]

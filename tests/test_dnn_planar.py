"""The plane's-motion alternative to the network's flow (methods/dnn/planar.py): its loss is
multicm's, its image is multicm's, it recovers known motions, and estimate_flow_dnn keeps
it only where the loss prefers it."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from evmotion.core.tileflow import iwe_forward  # noqa: E402
from evmotion.events import EventArray  # noqa: E402
from evmotion.methods.dnn import focus as F  # noqa: E402
from evmotion.methods.dnn import planar as P  # noqa: E402
from evmotion.methods.dnn.infer import estimate_flow_dnn  # noqa: E402
from evmotion.methods.dnn.loss import window_problem  # noqa: E402


def _window(seed: int, shape=(40, 60), n=3000, float_xy=False) -> EventArray:
    rng = np.random.default_rng(seed)
    h, w = shape
    x = rng.integers(0, w, n).astype(float)
    y = rng.integers(0, h, n).astype(float)
    if float_xy:
        x = np.clip(x + rng.uniform(-0.45, 0.45, n), 0, w - 1)
        y = np.clip(y + rng.uniform(-0.45, 0.45, n), 0, h - 1)
    return EventArray(x=x, y=y, t=np.sort(rng.integers(0, 20_000, n)),
                      p=rng.integers(0, 2, n), sensor_size=shape)


@pytest.mark.parametrize("float_xy", [False, True])
@pytest.mark.parametrize("kind", ["zero", "random", "planar"])
def test_window_loss_is_multicms_objective(kind, float_xy):
    ev = _window(1, float_xy=float_xy)
    h, w = ev.sensor_size
    rng = np.random.default_rng(2)
    disp = {"zero": np.zeros((h, w, 2)),
            "random": rng.normal(0, 3, (h, w, 2)),
            "planar": P.planar_flow([3, -2, 1, 0.5, -0.3, 0.2, 0.1, -0.1], (h, w))}[kind]
    ref = window_problem(ev).value_grad(np.asarray(disp, np.float64).ravel())[0]
    assert P.window_loss(ev, disp) == pytest.approx(ref, rel=1e-9)


def test_lam_is_the_training_losss():
    import inspect

    assert inspect.signature(window_problem).parameters["lam"].default == P.LAM


def test_numpy_image_is_multicms_bspline_image():
    # points inside, on the border and off the image (whose taps are dropped)
    rng = np.random.default_rng(4)
    h, w, n = 12, 17, 400
    x = rng.uniform(-4, w + 3, n)
    y = rng.uniform(-4, h + 3, n)
    flow = rng.normal(0, 2, (n, 2))
    dtn = rng.uniform(-1, 1, n)
    ref = iwe_forward(x, y, flow, dtn, (h, w))
    got = F.bspline_images((x + dtn * flow[:, 0])[None], (y + dtn * flow[:, 1])[None],
                           (h, w))[0]
    np.testing.assert_allclose(got, ref, atol=1e-12)


def test_focus_gradient_matches_finite_differences():
    ev = _window(5)
    h, w = ev.sensor_size
    x, y = (np.asarray(a, np.float64) for a in (ev.x, ev.y))
    s = F.window_times(ev)
    basis = P._basis(ev.x, ev.y, (h, w))
    g0 = F.identity_focus(x, y, (h, w))
    p = np.array([1.3, -0.7, 0.4, 0.2, -0.3, 0.5, 0.1, -0.2])
    _, dflow = F.multi_focus(x, y, s, basis @ p, (h, w), g0, grad=True)
    grad = np.einsum("nci,nc->i", basis, dflow)
    eps = 1e-6
    for k in range(8):
        d = np.zeros(8)
        d[k] = eps
        fd = (F.multi_focus(x, y, s, basis @ (p + d), (h, w), g0)
              - F.multi_focus(x, y, s, basis @ (p - d), (h, w), g0)) / (2 * eps)
        assert grad[k] == pytest.approx(fd, rel=1e-5, abs=1e-9)


def test_fit_recovers_the_parameters_of_a_planar_field():
    ev = _window(6)
    true = np.array([0.5, -1.0, 2.0, 0.3, -0.4, 1.5, 0.2, -0.1])
    np.testing.assert_allclose(P.fit_planar(ev, P.planar_flow(true, ev.sensor_size)), true,
                               atol=1e-5)


def _sim(scene: str, seed: int, shape=(120, 160), n_max: int = 20_000):
    from evmotion.sim import simulate

    sim = simulate(scene, duration_s=0.2, sensor_size=shape, seed=seed, show_progress=False)
    ev = sim.events
    n = min(len(ev), n_max)
    win = ev[len(ev) // 2 - n // 2: len(ev) // 2 + n // 2]
    gt = sim.gt.displacement(int(win.t[0]), int(win.t[-1]))
    mask = np.zeros(win.sensor_size, bool)
    mask[win.y.astype(int), win.x.astype(int)] = True
    return win, gt, mask


def _aee(disp, gt, mask) -> float:
    return float(np.linalg.norm(disp - gt, axis=-1)[mask].mean())


@pytest.mark.parametrize("scene", ["rotation", "zoom"])
def test_polish_recovers_a_cameras_motion_from_a_rough_start(scene):
    win, gt, mask = _sim(scene, 31, n_max=8000)
    rough = gt * 0.7 + np.random.default_rng(0).normal(0, 0.5, gt.shape)  # 30 % short, noisy
    start = P.fit_planar(win, rough)
    polished = P.planar_flow(P.polish_planar(win, start), win.sensor_size)
    before = _aee(P.planar_flow(start, win.sensor_size), gt, mask)
    after = _aee(polished, gt, mask)
    # 6-7 px over the window; measured 1.81 -> 0.14 px (rotation), 2.18 -> 0.56 (zoom),
    # the optimum the polish from the truth itself reaches
    best = _aee(P.planar_flow(P.polish_planar(win, P.fit_planar(win, gt)), win.sensor_size),
                gt, mask)
    assert after < 0.35 * before and abs(after - best) < 0.05, (before, after, best)


@pytest.mark.slow
def test_network_flow_is_replaced_where_the_loss_prefers_the_plane():
    win, gt, mask = _sim("rotation", 32, (180, 240))
    net = estimate_flow_dnn(win, planar=False, refine=False, with_iwes=False)
    res = estimate_flow_dnn(win, with_iwes=False)
    assert res.meta["planar"] and len(res.meta["planar_params"]) == 8
    assert not net.meta["planar"] and net.meta["planar_params"] is None
    a_net, a_res = _aee(net.displacement(), gt, mask), _aee(res.displacement(), gt, mask)
    assert a_res < 0.5 * a_net, (a_net, a_res)


@pytest.mark.slow
def test_no_plane_where_an_object_moves_on_its_own():
    # bench_dnn's held-out object window: the plane's loss is the higher (0.159 against
    # 0.143-0.163 on three seeds, benchmarks/results/dnn_planar.md); what is kept is the
    # network's flow or its refinement on multicm's tiles (tests/test_dnn_tiles.py)
    from evmotion.sim import simulate

    sim = simulate("object", duration_s=0.2, sensor_size=(260, 346), seed=900_000_003,
                   show_progress=False)
    ev = sim.events
    win = ev[len(ev) // 2 - 20_000: len(ev) // 2 + 20_000]
    res = estimate_flow_dnn(win, with_iwes=False, refine=False)
    assert not res.meta["planar"]
    np.testing.assert_array_equal(res.flow, estimate_flow_dnn(win, planar=False, refine=False,
                                                              with_iwes=False).flow)


def test_binned_focus_finds_the_same_motion():
    # a large sensor's focus is measured on binned images (planar.binning): the motion
    # found is the one found on the pixels, in the sensor's px
    win, gt, mask = _sim("rotation", 33, (240, 320), n_max=12_000)
    start = P.fit_planar(win, gt * 0.8)
    fields = [P.planar_flow(P.polish_planar(win, start, binning=k), win.sensor_size)
              for k in (1, 2)]
    errors = [_aee(f, gt, mask) for f in fields]
    assert errors[1] < 1.5 * errors[0] + 0.05, errors
    assert np.abs(fields[1] - fields[0])[mask].mean() < 0.2
    # and the binned loss still prefers the motion to no motion
    assert P.window_loss(win, fields[1], binning=2) < P.window_loss(win, 0 * fields[1],
                                                                    binning=2)
    assert P.binning(win.sensor_size) == 1 and P.binning((720, 1280)) == 3


def test_long_windows_are_polished_on_evenly_spaced_events(monkeypatch):
    # a window of more than planar.MAX_EVENTS events: the polish sees that many, spread
    # over the whole window (its first and last event included)
    from evmotion.methods.dnn import infer

    seen = []
    real = P.polish_planar

    def spy(events, params, evaluations=P.POLISH_EVALUATIONS, binning=1):
        seen.append((len(events), int(events.t[0]), int(events.t[-1])))
        return real(events, params, evaluations, binning)

    monkeypatch.setattr(P, "MAX_EVENTS", 1000)
    monkeypatch.setattr(P, "polish_planar", spy)
    ev = _window(7, n=5000)
    infer._alternatives(ev, np.zeros((*ev.sensor_size, 2), np.float32),
                        np.zeros(ev.sensor_size, bool), infer._pixels_and_times(ev),
                        planar=True, refine=False)
    assert seen and all(s == (1000, int(ev.t[0]), int(ev.t[-1])) for s in seen)


@pytest.mark.parametrize("shape", [(1, 200), (2, 2)])
def test_no_plane_where_the_focus_cannot_be_measured(shape):
    # under 3 px a side the Sobel focus is empty: the plane's smoothness alone must not
    # win (it did on a 1x200 sensor)
    ev = _window(8, shape=shape, n=500)
    assert P.window_loss(ev, np.zeros((*shape, 2))) == np.inf
    assert not estimate_flow_dnn(ev, with_iwes=False).meta["planar"]


def test_a_plane_the_networks_flow_bends_is_tried_again_from_its_median(monkeypatch):
    """Probe BD: one object moving 33 px over a still background; the plane fitted to the
    network's 20 %-short flow had quadratic terms the polish kept (loss 0.065 against the
    network flow's 0.044, so no plane), the translation of the flow's median polished to
    the motion (0.037)."""
    from evmotion.methods.dnn import infer

    win, gt, mask = _sim("translation", 33, n_max=8000)
    h, w = win.sensor_size
    yy, xx = np.mgrid[0:h, 0:w] / w
    bent = 0.8 * gt + 8.0 * np.stack([xx * xx, xx * yy], axis=-1)  # short, and bent
    # the network's flow, as sharp as the motion itself: a plane must find the motion
    reference = 1.02 * P.window_loss(win, gt.astype(np.float32))
    hot = np.zeros(win.sensor_size, bool)
    found = infer._planar(win, bent.astype(np.float32), hot, 1, reference)
    assert found is not None
    assert _aee(found[1], gt, mask) < 0.3, _aee(found[1], gt, mask)
    # from the bent plane alone there is none
    monkeypatch.setattr(P, "translation_start", lambda ev, disp: P.fit_planar(ev, disp))
    assert infer._planar(win, bent.astype(np.float32), hot, 1, reference) is None

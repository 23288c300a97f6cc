"""The network's flow refined on multicm's finest tiles (methods/dnn/tiles.py): its loss is
multicm's to the last digit, it lowers that loss, and estimate_flow_dnn keeps it only
where the loss prefers it and the events are no blurrier."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from evmotion.core import tileflow as tf  # noqa: E402
from evmotion.methods.dnn import infer  # noqa: E402
from evmotion.methods.dnn import planar as P  # noqa: E402
from evmotion.methods.dnn import tiles as T  # noqa: E402
from evmotion.methods.dnn.bfgs import bfgs  # noqa: E402
from evmotion.methods.dnn.focus import window_times  # noqa: E402
from evmotion.methods.multicm import MultiCMProblem  # noqa: E402
from test_dnn_planar import _aee, _sim, _window  # noqa: E402


@pytest.mark.parametrize("float_xy", [False, True])
@pytest.mark.parametrize("level", [1, 2, 3, 4])
def test_tile_loss_and_gradient_are_multicms(level, float_xy):
    ev = _window(level, shape=(37, 53), float_xy=float_xy)
    grid = tf.scale_grid(level, ev.sensor_size)
    params = np.random.default_rng(10 + level).normal(0, 3, (grid.ny, grid.nx, 2))
    prob = MultiCMProblem(np.asarray(ev.x, float), np.asarray(ev.y, float), window_times(ev),
                          ev.sensor_size, grid, duration_s=(ev.t[-1] - ev.t[0]) * 1e-6)
    want, want_grad = prob.value_grad(params.ravel())
    got, got_grad = T.tile_loss_grad(ev, params, grid)
    assert got == pytest.approx(want, rel=1e-12)
    np.testing.assert_allclose(got_grad, want_grad, rtol=1e-9,
                               atol=1e-12 * np.abs(want_grad).max())


def test_the_loss_weight_and_smoothing_are_multicms():
    from evmotion.methods import multicm

    assert P.LAM == multicm.MULTICM_DEFAULTS.lam and P.TV_EPS == multicm.TV_EPS


@pytest.mark.parametrize("scene", ["rotation", "zoom"])
def test_refinement_lowers_the_loss_from_a_rough_start(scene):
    win, gt, mask = _sim(scene, 31, n_max=8000)
    grid = tf.scale_grid(3, win.sensor_size)
    rough = tf.event_tile_means(gt * 0.7, win.x, win.y, grid)  # 30 % short
    out = T.refine_tiles(win, rough, grid)
    assert T.tile_loss_grad(win, out, grid)[0] < 0.97 * T.tile_loss_grad(win, rough, grid)[0]
    before = _aee(tf.dense_flow(rough, win.sensor_size), gt, mask)
    after = _aee(tf.dense_flow(out, win.sensor_size), gt, mask)
    # measured 2.05 -> 0.26 px (rotation), 2.01 -> 0.68 (zoom), 6-7 px over the window
    assert after < 0.5 * before, (before, after)


def test_network_flow_is_refined_where_an_object_moves_on_its_own():
    # no plane explains it; the refinement lowers the loss and the error (measured 4.05 ->
    # 2.92 px; on eight such windows it was kept on six, each time with a lower AEE)
    win, gt, mask = _sim("object", 41, n_max=8000)
    net = infer.estimate_flow_dnn(win, with_iwes=False, refine=False)
    res = infer.estimate_flow_dnn(win, with_iwes=False)
    assert not res.meta["planar"] and res.meta["refined"] and not net.meta["refined"]
    assert _aee(res.displacement(), gt, mask) < 0.85 * _aee(net.displacement(), gt, mask)
    assert P.window_loss(win, res.displacement()) < P.window_loss(win, net.displacement())


def test_a_refinement_that_blurs_the_events_is_not_kept(monkeypatch):
    # the loss made to prefer any refinement: the one that blurs (the zero flow, on a
    # moving scene) is refused by the sharpness, the network's own flow kept (the
    # sharpness' consent where a refinement is kept: the test above)
    win, gt, mask = _sim("object", 41, n_max=8000)
    net = infer.estimate_flow_dnn(win, with_iwes=False, refine=False).displacement()
    refined_ids = []

    def refine(events, params, grid, evaluations=T.REFINE_EVALUATIONS, binning=1, base=None):
        refined_ids.append(base is not None)
        return np.zeros_like(params)

    monkeypatch.setattr(T, "refine_tiles", refine)
    monkeypatch.setattr(P, "window_loss",
                        lambda events, flow, lam=P.LAM, binning=1: float(np.abs(flow).sum()))
    xys = infer._pixels_and_times(win)
    hot = np.zeros(win.sensor_size, bool)
    assert infer._alternatives(win, net, hot, xys, planar=False, refine=True)[1] is None
    # (and the tiles' correction of the network's flow, which is that flow itself here:
    # no lower loss, refused too)
    assert refined_ids[-1]


def test_a_correction_of_a_flow_is_the_tile_loss_of_the_sum():
    # with a uniform base the correction's objective is multicm's at base + correction
    ev = _window(3, shape=(37, 53), float_xy=False)
    grid = tf.scale_grid(3, ev.sensor_size)
    corr = np.random.default_rng(4).normal(0, 2, (grid.ny, grid.nx, 2))
    base = np.zeros((*ev.sensor_size, 2))
    base[..., 0], base[..., 1] = 2.5, -1.5
    prob = T._problem(ev, grid, 1, base)
    got, got_grad = T._loss_grad(prob, corr.ravel(), P.LAM)
    want, want_grad = T.tile_loss_grad(ev, corr + base[0, 0], grid)
    assert got == pytest.approx(want, rel=1e-12)
    np.testing.assert_allclose(got_grad, want_grad, rtol=1e-9,
                               atol=1e-12 * np.abs(want_grad).max())


def _moving_rows(speeds, width: int = 64, seed: int = 3):
    """Events of dots on every row y moving ``speeds[y]`` px right over the window, on a
    ``len(speeds)`` x ``width`` sensor; and that exact displacement (H, W, 2)."""
    from evmotion.events import EventArray

    rng = np.random.default_rng(seed)
    h = len(speeds)
    xs, ys, ss = [], [], []
    s = np.linspace(0.0, 1.0, 60)
    for row, v in enumerate(speeds):
        for x0 in rng.uniform(12, width - 12, 6):
            xs.append(np.rint(x0 + v * (s - 0.5)))
            ys.append(np.full(s.size, row))
            ss.append(s)
    order = np.argsort(np.concatenate(ss), kind="stable")
    t = np.rint(np.concatenate(ss)[order] * 20_000).astype(np.int64)
    ev = EventArray(x=np.concatenate(xs)[order], y=np.concatenate(ys)[order], t=t,
                    p=np.ones(t.size, int), sensor_size=(h, width))
    disp = np.zeros((h, width, 2))
    disp[..., 0] = np.asarray(speeds, float)[:, None]
    return ev, disp


def test_a_flow_finer_than_the_tiles_is_corrected_not_averaged(monkeypatch):
    # rows moving apart: averaged over a tile the flow is ~0 and the events blur, so
    # only the tiles' correction of the flow is tried; it removes the flow's 1.5 px
    # offset and keeps its row-by-row detail
    win, exact = _moving_rows(np.resize([8.0, -8.0], 32))  # even rows right, odd left
    disp = (exact + [1.5, 0.0]).astype(np.float32)
    bases = []
    real = T.refine_tiles

    def spy(*args, base=None, **kw):
        bases.append(base is not None)
        return real(*args, base=base, **kw)

    monkeypatch.setattr(T, "refine_tiles", spy)
    xys = infer._pixels_and_times(win)
    hot = np.zeros(win.sensor_size, bool)
    flow = infer._alternatives(win, disp, hot, xys, planar=False, refine=True)[1]
    assert bases == [True]
    assert flow is not None
    before = np.abs(disp - exact)[..., 0].mean()
    after = np.abs(flow - exact)[..., 0].mean()
    assert after < 0.3 * before, (before, after)


def test_the_planes_flow_is_corrected_where_the_scene_has_depth():
    # two depths (the top half moves 8 px, the bottom 3): from the network's flow with
    # 2 px of noise a plane is kept, and the tiles' correction of it finds the step
    # (measured: network 1.60, plane 0.54, corrected 0.20 px)
    win, exact = _moving_rows(np.repeat([8.0, 3.0], 24), seed=5)
    disp = (exact + np.random.default_rng(0).normal(0, 2.0, exact.shape)).astype(np.float32)
    xys = infer._pixels_and_times(win)
    plane, refined = infer._alternatives(win, disp, np.zeros(win.sensor_size, bool), xys,
                                         planar=True, refine=True)
    assert plane is not None and refined is not None
    assert np.abs(refined - exact).mean() < 0.5 * np.abs(plane[1] - exact).mean()


@pytest.mark.parametrize("seed", [5, 7])
def test_a_plane_that_is_the_motion_is_not_corrected(seed):
    # one depth: the plane is the exact motion, and a correction only fits the events'
    # noise (it was kept on these two scenes when it was only asked to be no blurrier)
    win, exact = _moving_rows(np.full(48, 6.0), seed=seed)
    disp = (exact + np.random.default_rng(0).normal(0, 2.0, exact.shape)).astype(np.float32)
    plane, refined = infer._alternatives(win, disp, np.zeros(win.sensor_size, bool),
                                         infer._pixels_and_times(win), planar=True,
                                         refine=True)
    assert plane is not None and np.abs(plane[1] - exact).mean() < 0.05
    assert refined is None


def test_no_refinement_without_the_option():
    win, *_ = _sim("object", 41, n_max=8000)
    assert not infer.estimate_flow_dnn(win, with_iwes=False, refine=False).meta["refined"]
    rot, *_ = _sim("rotation", 32, (180, 240))
    res = infer.estimate_flow_dnn(rot, with_iwes=False, refine=False)
    assert res.meta["planar"] and not res.meta["refined"]


def test_bfgs_update_is_the_textbook_one():
    # the O(n^2) expansion of (I - rho s y')H(I - rho y s') + rho s s' converges on a
    # quadratic as BFGS does: to the minimizer, within n + a few line searches
    rng = np.random.default_rng(0)
    a = rng.normal(size=(12, 12))
    q = a @ a.T + 12 * np.eye(12)
    b = rng.normal(size=12)
    calls = []

    def f(x):
        calls.append(1)
        return 0.5 * x @ q @ x - b @ x, q @ x - b

    x = bfgs(f, np.zeros(12), 200, step_px=0.5, xtol=1e-10)
    np.testing.assert_allclose(x, np.linalg.solve(q, b), atol=1e-7)
    assert len(calls) < 60


def test_refinement_is_deterministic_and_leaves_torchs_threads():
    # the refinement's float32 sums depend on the thread count: it runs under the call's
    # (one by default), and the process's count is restored after
    win, *_ = _sim("object", 41, n_max=8000)
    before = torch.get_num_threads()
    a = infer.estimate_flow_dnn(win, with_iwes=False)
    b = infer.estimate_flow_dnn(win, with_iwes=False)
    assert a.meta["refined"] and torch.get_num_threads() == before
    np.testing.assert_array_equal(a.flow, b.flow)


def test_binned_refinement_finds_the_same_motion():
    # a large sensor's focus is measured on binned images (planar.binning): the tiles'
    # flow found is the one found on the pixels, in the sensor's px (measured: the start's
    # AEE 0.49 px, refined 0.16 on the pixels, 0.24 binned 2 x 2)
    win, gt, mask = _sim("rotation", 33, (240, 320), n_max=12_000)
    grid = tf.scale_grid(3, win.sensor_size)
    start = tf.event_tile_means(gt * 0.8, win.x, win.y, grid)
    fields = [tf.dense_flow(T.refine_tiles(win, start, grid, binning=k), win.sensor_size)
              for k in (1, 2)]
    errors = [_aee(f, gt, mask) for f in fields]
    assert errors[1] < 1.5 * errors[0] + 0.1, errors
    assert errors[1] < 0.6 * _aee(tf.dense_flow(start, win.sensor_size), gt, mask)

"""The training loss is multicm's objective (4.9): value and gradient to 1e-6 (float64)."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from evmotion.core import tileflow as tf  # noqa: E402
from evmotion.events import EventArray  # noqa: E402
from evmotion.methods.dnn.loss import (  # noqa: E402
    MultiCMLoss,
    WindowLoss,
    multiscale_loss,
    window_problem,
)
from evmotion.methods.multicm import MultiCMProblem  # noqa: E402

H, W = 24, 32


def _events(n=3000, seed=0, subpixel=False):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 20_000, n))
    x = rng.uniform(0, W - 1, n) if subpixel else rng.integers(0, W, n)
    y = rng.uniform(0, H - 1, n) if subpixel else rng.integers(0, H, n)
    return EventArray(x=x, y=y, t=t, p=rng.integers(0, 2, n), sensor_size=(H, W))


def _reference(ev, flow, objective):
    """multicm's own problem built independently of window_problem: its tile flow at
    tile resolution = pixels, sampled by multicm's interpolation at the events."""
    t0, t1 = int(ev.t[0]), int(ev.t[-1])
    s = (ev.t - t0) / (t1 - t0)
    prob = MultiCMProblem(ev.x.astype(np.float64), ev.y.astype(np.float64), s, (H, W),
                          tf.TileGrid(H, W, (H, W)), objective=objective, lam=0.0025,
                          p=ev.p, duration_s=(t1 - t0) * 1e-6)
    return prob.value_grad(flow.ravel())


def _dense_reference_value(ev, flow, objective):
    """1/f + lam TV straight from the IWE kernels and the bilinear sample of the dense
    flow at each event (not through MultiCMProblem.value_grad)."""
    from evmotion.core.objectives import objective_value_grad

    x, y = ev.x.astype(np.float64), ev.y.astype(np.float64)
    t0, t1 = int(ev.t[0]), int(ev.t[-1])
    s = (ev.t - t0) / (t1 - t0)
    x0 = np.clip(np.floor(x).astype(int), 0, W - 2)
    y0 = np.clip(np.floor(y).astype(int), 0, H - 2)
    fx, fy = x - x0, y - y0
    fe = ((1 - fy) * (1 - fx))[:, None] * flow[y0, x0] + ((1 - fy) * fx)[:, None] * flow[y0, x0 + 1] \
        + (fy * (1 - fx))[:, None] * flow[y0 + 1, x0] + (fy * fx)[:, None] * flow[y0 + 1, x0 + 1]

    def g(fl, r):
        return objective_value_grad(objective, tf.iwe_forward(x, y, fl, np.ascontiguousarray(r - s),
                                                              (H, W)))[0]

    g0 = g(np.zeros_like(fe), 0.0)
    f = (g(fe, 0.0) + 2 * g(fe, 0.5) + g(fe, 1.0)) / (4 * g0)
    v = flow / ((t1 - t0) * 1e-6)
    tv = 0.0
    for c in range(2):
        dx = np.zeros((H, W))
        dy = np.zeros((H, W))
        dx[:, :-1] = np.diff(v[..., c], axis=1)
        dy[:-1, :] = np.diff(v[..., c], axis=0)
        tv += np.sqrt(dx ** 2 + dy ** 2 + 1e-4).mean()
    return 1.0 / f + 0.0025 * tv


@pytest.mark.parametrize("objective", ["gradient_magnitude", "variance", "avg_timestamp",
                                       "avg_timestamp_norm"])
@pytest.mark.parametrize("seed", [0, 1])
def test_loss_and_gradient_equal_multicm(objective, seed):
    ev = _events(seed=seed, subpixel=seed == 1)
    rng = np.random.default_rng(10 + seed)
    flow = rng.normal(0, 2.0, (H, W, 2)) + np.array([3.0, -1.0])
    val_ref, grad_ref = _reference(ev, flow, objective)
    ft = torch.tensor(flow, dtype=torch.float64, requires_grad=True)
    loss = MultiCMLoss.apply(ft, window_problem(ev, objective=objective))
    loss.backward()
    assert abs(float(loss.detach()) - val_ref) <= 1e-6 * abs(val_ref)
    g = ft.grad.numpy().ravel()
    assert np.linalg.norm(g - grad_ref) <= 1e-6 * np.linalg.norm(grad_ref)
    assert np.linalg.norm(grad_ref) > 0


@pytest.mark.parametrize("subpixel", [False, True])
def test_loss_is_focus_of_bilinearly_sampled_flow(subpixel):
    ev = _events(seed=3, subpixel=subpixel)
    flow = np.random.default_rng(4).normal(0, 1.5, (H, W, 2))
    val = float(MultiCMLoss.apply(torch.tensor(flow), window_problem(ev)))
    ref = _dense_reference_value(ev, flow, "gradient_magnitude")
    assert val == pytest.approx(ref, rel=1e-9)


def test_gradient_matches_finite_differences():
    ev = _events(seed=5)
    prob = window_problem(ev)
    flow = np.random.default_rng(6).normal(0, 1.0, (H, W, 2))
    ft = torch.tensor(flow, requires_grad=True)
    MultiCMLoss.apply(ft, prob).backward()
    rng = np.random.default_rng(7)
    d = rng.normal(size=flow.shape)
    eps = 1e-5
    num = (prob.value_grad((flow + eps * d).ravel())[0]
           - prob.value_grad((flow - eps * d).ravel())[0]) / (2 * eps)
    assert float((ft.grad.numpy() * d).sum()) == pytest.approx(num, rel=1e-4)


def test_multiscale_loss_sums_scales_and_crops_padding():
    ev = _events(seed=8)
    prob = window_problem(ev)
    rng = np.random.default_rng(9)
    flows = [torch.tensor(rng.normal(size=(1, 2, 32, 48)), requires_grad=True) for _ in range(2)]
    loss = multiscale_loss(flows, [WindowLoss(prob, (H, W))])
    loss.backward()
    ref = sum(prob.value_grad(f.detach()[0, :, :H, :W].permute(1, 2, 0).numpy().ravel())[0]
              for f in flows)
    assert float(loss.detach()) == pytest.approx(ref, rel=1e-12)
    # the padding gets no gradient
    assert float(flows[0].grad[..., H:, :].abs().sum()) == 0.0
    assert float(flows[0].grad[..., :H, :W].abs().sum()) > 0.0

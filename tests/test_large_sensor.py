"""The checks of an estimate cost what its events cost, not what its sensor does (probe DB:
4,292 events on 4096x4096 spent 10.6 s in the ego-motion diagnostics, 0.01 s on 60x80).

Each sparse computation is held against the plain whole-sensor one it replaced (kept
here as the reference): the verdicts -- valid, collapsed, poor fit, explained share, the
contrast and chance gains -- must come out the same on simulated, real and noise windows,
and on a small scene placed on a large sensor.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from evmotion.events import EventArray
from evmotion.methods import diagnostics, egomotion
from evmotion.methods.diagnostics import effective_pixels, event_support, image_variance
from evmotion.methods.egomotion import estimate_egomotion
from evmotion.methods.flowresult import event_box_counts
from evmotion.sim import simulate

SHAPE = (180, 240)


# ------------------------------------------------------------ plain whole-sensor references

def _top_share_plain(iwe, k):
    """The whole image partitioned (the code before the change)."""
    a = np.clip(np.asarray(iwe, dtype=np.float64).ravel(), 0.0, None)
    total = a.sum()
    if total <= 0:
        return 0.0
    k = min(max(1, int(k)), a.size)
    return float(np.partition(a, a.size - k)[a.size - k:].sum() / total)


def _effective_pixels_plain(x, y, shape):
    h, w = shape
    xi = np.rint(np.asarray(x, dtype=np.float64)).astype(np.int64)
    yi = np.rint(np.asarray(y, dtype=np.float64)).astype(np.int64)
    ok = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    counts = np.bincount(yi[ok] * w + xi[ok], minlength=h * w).astype(np.float64)
    ss = float(np.dot(counts, counts))
    return float(counts.sum()) ** 2 / ss if ss > 0 else 0.0


def _box_counts_plain(x, y, shape, radius):
    h, w = shape
    xi, yi = np.rint(x).astype(int), np.rint(y).astype(int)
    ok = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    cnt = np.zeros(shape)
    np.add.at(cnt, (yi[ok], xi[ok]), 1.0)
    pad = np.pad(cnt, radius)
    n = 2 * radius + 1
    return sum(pad[dy:dy + h, dx:dx + w] for dy in range(n) for dx in range(n))


# ------------------------------------------------------------------------------ windows

def _sim(kind, sensor=SHAPE, offset=(0, 0)):
    sim = simulate(kind, duration_s=0.03, sensor_size=(120, 160), seed=1,
                   show_progress=False)
    ev = sim.events
    K = np.array(sim.gt.K, dtype=np.float64)
    K[0, 2] += offset[0]
    K[1, 2] += offset[1]
    placed = EventArray(np.asarray(ev.x) + offset[0], np.asarray(ev.y) + offset[1], ev.t,
                        ev.p, sensor)
    return placed, K


def _noise(sensor, n=8000):
    rng = np.random.default_rng(3)
    return EventArray(rng.integers(0, sensor[1], n), rng.integers(0, sensor[0], n),
                      np.sort(rng.integers(0, 30_000, n)), rng.integers(0, 2, n), sensor)


CASES = {
    "translation": lambda: (*_sim("translation"), "translation"),
    "rotation": lambda: (*_sim("rotation"), "rotation"),
    "zoom": lambda: (*_sim("zoom"), "zoom"),
    "noise": lambda: (_noise(SHAPE), None, "translation"),
    "translation on 1280x720": lambda: (*_sim("translation", (720, 1280), (500, 300)),
                                        "translation"),
    "rotation on 1280x720": lambda: (*_sim("rotation", (720, 1280), (500, 300)),
                                     "rotation"),
    "noise on 1280x720": lambda: (_noise((720, 1280)), None, "translation"),
}


def _verdicts(ev, K, warp):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = estimate_egomotion(ev, warp, K=K, maps=False)
    d = r.diagnostics
    c = d["collapse"]
    return {"valid": r.valid, "collapsed": r.collapsed, "poor_fit": r.poor_fit,
            "explained_share": d["fit"].get("explained_share", np.nan),
            "chance_gain": d["chance_gain"], "contrast_gain": d["contrast_gain"],
            "top_share_before": c.get("top_share_before"),
            "top_share_after": c.get("top_share_after"),
            "warnings": len(d["warnings"])}


def _plain(monkeypatch):
    """Put the whole-sensor computations back in place of the sparse ones."""
    monkeypatch.setattr(diagnostics, "_top_share", _top_share_plain)
    monkeypatch.setattr(egomotion, "image_variance", lambda img: float(np.var(img)))


def _assert_same(new, ref):
    for key, want in ref.items():
        got = new[key]
        if isinstance(want, float) and not isinstance(want, bool):
            assert (math.isnan(got) and math.isnan(want)) or got == pytest.approx(
                want, rel=1e-12, abs=1e-15), key
        else:
            assert got == want, key


@pytest.mark.parametrize("case", list(CASES))
def test_egomotion_verdicts_equal_the_whole_sensor_reference(case, monkeypatch):
    ev, K, warp = CASES[case]()
    new = _verdicts(ev, K, warp)
    _plain(monkeypatch)
    _assert_same(new, _verdicts(ev, K, warp))


def test_real_1280x720_verdicts_equal_the_whole_sensor_reference(shared_data, monkeypatch):
    """Three 30k-event windows of the shared Prophesee Gen4 recording."""
    from evmotion.io import read_events

    path = shared_data / "formats" / "evt3.raw"
    if not path.exists():
        pytest.skip(f"{path} not found")
    ev = read_events(path)
    wins = ev.windows_by_count(30_000)
    picks = [ev.window(wins[i]) for i in (2, len(wins) // 2, len(wins) - 3)]
    new = [_verdicts(w, None, "translation") for w in picks]
    _plain(monkeypatch)
    for got, w in zip(new, picks, strict=True):
        _assert_same(got, _verdicts(w, None, "translation"))


# ------------------------------------------------------------------ the pieces, one by one

def test_sparse_pieces_equal_their_plain_references():
    rng = np.random.default_rng(0)
    for shape, n in (((60, 80), 4000), ((720, 1280), 3000), ((720, 1280), 1)):
        x = rng.normal(300, 40, n) % shape[1]
        y = rng.normal(200, 30, n) % shape[0]
        img = np.zeros(shape)
        np.add.at(img, (y.astype(int), x.astype(int)), rng.uniform(-0.2, 1.0, n))
        assert image_variance(img) == pytest.approx(np.var(img), rel=1e-12)
        for k in (1, 7, n, 10 * n):
            assert diagnostics._top_share(img, k) == pytest.approx(
                _top_share_plain(img, k), rel=1e-12)
        assert effective_pixels(x, y, shape) == pytest.approx(
            _effective_pixels_plain(x, y, shape), rel=1e-12)
        xe = np.concatenate([x, [-3.0, shape[1] + 2.0, 0.0, shape[1] - 1.0]])
        ye = np.concatenate([y, [5.0, 5.0, 0.0, shape[0] - 1.0]])
        for r in (0, 2, 5):
            ref = _box_counts_plain(xe, ye, shape, r)
            np.testing.assert_array_equal(event_box_counts(xe, ye, shape, r), ref)
            np.testing.assert_array_equal(event_support(xe, ye, shape, r), ref >= 1.0)
    # a collapsed estimate: the events squeezed onto a few pixels of a 1280x720 sensor
    from evmotion.core.warps import make_warp

    before = np.zeros((720, 1280))
    np.add.at(before, (rng.integers(300, 400, 5000), rng.integers(500, 700, 5000)), 1.0)
    after = np.zeros_like(before)
    after[350, 600], after[351, 600] = 4000.0, 1000.0
    warp = make_warp("translation", (720, 1280))
    got = diagnostics.collapse_diagnostics(warp, np.zeros(2), (0.0, 0.03), before, after)
    k = math.ceil(diagnostics.TOP_SHARE_FRAC * np.count_nonzero(before > 0))
    assert got["top_share_after"] == pytest.approx(_top_share_plain(after, k), rel=1e-12)
    assert got["top_share_before"] == pytest.approx(_top_share_plain(before, k), rel=1e-12)
    assert got["collapsed"]
    assert image_variance(np.zeros((3, 4))) == 0.0
    assert diagnostics._top_share(np.zeros((3, 4)), 1) == 0.0
    assert np.isnan(image_variance(np.full((2, 2), np.nan)))


@pytest.mark.parametrize("sensor", [(120, 160), (360, 480)])
def test_multicm_support_and_verdicts_equal_the_whole_sensor_reference(sensor, monkeypatch):
    """multicm's validity mask (event_support over the events' bounding box) and its
    checks, against the whole sensor's integral image."""
    from evmotion.methods import flowresult
    from evmotion.methods.multicm import estimate_flow

    ev, _ = _sim("translation", sensor, (0, 0) if sensor == (120, 160) else (200, 150))

    def run():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return estimate_flow(ev)

    new = run()
    monkeypatch.setattr(flowresult, "event_box_counts",
                        lambda x, y, shape, radius=2: _box_counts_plain(x, y, shape, radius))
    ref = run()
    np.testing.assert_array_equal(new.valid, ref.valid)
    np.testing.assert_array_equal(new.flow, ref.flow)
    for key in ("no_focus", "chance_gain", "halves_correlation"):
        a, b = new.meta[key], ref.meta[key]
        assert a == b or (np.isnan(a) and np.isnan(b)), key

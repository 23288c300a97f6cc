"""Triplet matching on real recordings (ECD): literal-reference equality, chunk invariance,
and sharper-than-zero-flow warps (FWL > 1)."""

from __future__ import annotations

import numpy as np
import pytest

from _triplet_reference import triplet_reference
from evmotion.events import EventArray
from evmotion.methods.triplet import (
    TripletFlow,
    TripletMatcher,
    estimate_flow_triplet,
    event_fwl,
)

pytestmark = pytest.mark.realdata


def _ecd_txt(path) -> EventArray:
    a = np.loadtxt(path, dtype=np.float64)
    return EventArray(a[:, 1].astype(np.uint16), a[:, 2].astype(np.uint16),
                      np.rint(a[:, 0] * 1e6).astype(np.int64), a[:, 3], (180, 240))


@pytest.fixture(scope="module")
def shapes(shared_data) -> EventArray:
    import scipy.io

    path = shared_data / "ecd_shapes_rotation_first120k" / "shapes_rotation.mat"
    if not path.exists():
        pytest.skip(f"{path} not found")
    e = scipy.io.loadmat(path)["events"]["e_data"][0, 0]
    return EventArray(e[1].astype(np.uint16), e[2].astype(np.uint16),
                      np.rint(e[0] * 1e6).astype(np.int64), e[3], (180, 240))


def test_real_events_match_literal_algorithm1(shapes):
    ev = shapes[40_000:43_000]
    m = TripletMatcher(ev.sensor_size, depth=64)
    flow = m.process(ev)
    assert m.overflow == 0
    vx, vy, valid, n = triplet_reference(ev.x, ev.y, ev.t, ev.p)
    np.testing.assert_array_equal(flow.n_triplets, n)
    np.testing.assert_array_equal(flow.valid, valid)
    np.testing.assert_allclose(flow.vx, vx, rtol=1e-5, atol=1e-3)
    np.testing.assert_allclose(flow.vy, vy, rtol=1e-5, atol=1e-3)
    assert valid.sum() > 500


def test_real_stream_chunking_is_bit_identical(shapes):
    whole = TripletMatcher(shapes.sensor_size).process(shapes)
    m = TripletMatcher(shapes.sensor_size)
    cuts = np.sort(np.random.default_rng(0).choice(len(shapes), 25, replace=False))
    parts = [m.process(shapes[a:b]) for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(shapes)],
                                                    strict=True)]
    joined = TripletFlow.concatenate(parts)
    np.testing.assert_array_equal(joined.vx, whole.vx)
    np.testing.assert_array_equal(joined.n_triplets, whole.n_triplets)


def test_fwl_above_one_on_shapes_rotation(shapes):
    wins = [w for w in shapes.windows_by_duration(50_000) if w.count >= 1000]
    res = estimate_flow_triplet(shapes, wins)
    fwls = [event_fwl(shapes.window(w), TripletFlow(*(a[w.start:w.stop] for a in (
        res.events.vx, res.events.vy, res.events.valid, res.events.n_triplets))))
        for w in wins]
    assert np.median(fwls) > 1.2


@pytest.mark.parametrize("scene", ["dynamic_translation", "shapes_translation"])
def test_fwl_above_one_on_ecd_translation(shared_data, scene):
    from evmotion.eval.metrics import fwl

    path = shared_data / "ecd_30k_windows" / scene / "events.txt"
    if not path.exists():
        pytest.skip(f"{path} not found")
    ev = _ecd_txt(path)
    res = estimate_flow_triplet(ev)
    assert event_fwl(ev, res.events) > 1.2
    assert fwl(ev, res.flow[0]) > 1.5

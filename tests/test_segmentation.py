"""Motion segmentation by EM (Sec. 3.6.6): two independently moving halves are separated,
each warp recovers its motion, labels are right, seeded runs repeat exactly."""

from __future__ import annotations

import numpy as np
import pytest

from evmotion.errors import ParameterError, PoorFitWarning
from evmotion.events import EventArray
from evmotion.methods.segmentation import MIN_CLUSTER_GAIN, segment_motion


def two_motions(seed=0, n=6000):
    rng = np.random.default_rng(seed)
    dots = np.concatenate([rng.uniform([10, 10], [50, 70], (40, 2)),
                           rng.uniform([80, 10], [120, 70], (40, 2))])
    k = rng.integers(0, 80, n)
    t = np.sort(rng.integers(0, 40_000, n))
    vx = np.where(k < 40, 300.0, -250.0)
    vy = np.where(k < 40, 0.0, 100.0)
    ev = EventArray(dots[k, 0] + vx * t * 1e-6, dots[k, 1] + vy * t * 1e-6, t,
                    np.ones(n, int), (80, 130), validate=False)
    return ev, (k >= 40).astype(int)


def test_two_translations_are_separated():
    ev, truth = two_motions()
    seg = segment_motion(ev, n_warps=2, warp="translation", seed=0)
    order = np.argsort(seg.params[:, 0])  # cluster moving left first
    np.testing.assert_allclose(seg.params[order[0]], [-250.0, 100.0], atol=10)
    np.testing.assert_allclose(seg.params[order[1]], [300.0, 0.0], atol=10)
    labels = (seg.labels == order[0]).astype(int)
    assert np.mean(labels == truth) > 0.95
    np.testing.assert_allclose(seg.probabilities.sum(axis=1), 1.0)
    assert seg.iwes.shape == (2, 80, 130)
    again = segment_motion(ev, n_warps=2, warp="translation", seed=0)
    np.testing.assert_array_equal(again.params, seg.params)
    assert seg.valid.all() and (seg.gains > MIN_CLUSTER_GAIN).all()


def object_on_background(seed: int, object_share: float) -> EventArray:
    """Dots of a 90 px square object moving at (-80, 60) px/s, ``object_share`` of the
    events, over dots of the whole 320 x 240 sensor moving at (50, 0), for 40 ms."""
    rng = np.random.default_rng(seed)
    n, span = 20_000, 40_000
    parts = []
    for share, per_dot, lo, hi, v in ((object_share, 40, (115, 75), (205, 165), (-80, 60)),
                                      (1 - object_share, 20, (0, 0), (320, 240), (50, 0))):
        p0 = rng.uniform(lo, hi, (int(share * n) // per_dot, 2))
        t = rng.uniform(0, span, (len(p0), per_dot))
        parts.append((p0[:, :1] + v[0] * t * 1e-6, p0[:, 1:] + v[1] * t * 1e-6, t))
    x, y, t = (np.concatenate([q[i].ravel() for q in parts]) for i in range(3))
    keep = (x >= 0) & (x <= 319) & (y >= 0) & (y <= 239)
    o = np.argsort(t[keep], kind="stable")
    return EventArray(np.round(x[keep][o]), np.round(y[keep][o]), t[keep][o].astype(np.int64),
                      np.ones(o.size, int), (240, 320))


@pytest.mark.parametrize(("seed", "share"), [(0, 0.7), (1, 0.5), (2, 0.5)])
def test_an_object_that_gathers_the_spatial_split_leaves_the_background_found(seed, share):
    """Probe BJ: the k-means of the events' positions put both clusters on a fast,
    textured object; each took a part of it and its motion, and the background's motion
    was never found. The default split also starts from the dominant motion's best
    aligned half, and keeps the clusters that together sharpen the events most."""
    ev = object_on_background(seed, share)
    spatial = segment_motion(ev, 2, "translation", split="spatial")
    assert np.abs(spatial.params[:, 0] - 50).min() > 10  # this scene defeats it
    seg = segment_motion(ev, 2, "translation")
    assert seg.split == "dominant"
    got = seg.params[np.argsort(seg.params[:, 0])]
    np.testing.assert_allclose(got, [[-80, 60], [50, 0]], atol=6)
    assert seg.valid.all()
    with pytest.raises(ParameterError, match="split must be one of"):
        segment_motion(ev, 2, "translation", split="kmeans")


def test_one_motion_split_in_two_is_one_measurement():
    # three clusters for two motions came back as three valid ones, two of them
    # (306, 0.5) and (301, -0.9) px/s: one object cut in half (probe T)
    ev, _ = two_motions()
    with pytest.warns(PoorFitWarning, match="moves its events as cluster"):
        seg = segment_motion(ev, n_warps=3, warp="translation", seed=0)
    assert seg.valid.sum() == 2 and (seg.same_as >= 0).sum() == 1
    dup = int(np.flatnonzero(seg.same_as >= 0)[0])
    assert seg.valid[seg.same_as[dup]] and not seg.valid[dup]
    two = segment_motion(ev, n_warps=2, warp="translation", seed=0)
    assert (two.same_as == -1).all() and two.valid.all()
    # of the two halves the sharper stands as the measurement
    assert seg.gains[seg.same_as[dup]] >= seg.gains[dup]


def test_of_two_clusters_of_one_motion_the_sharper_is_the_measurement():
    # kept by size, a cluster mixing an object's events into the background's motion
    # (gain 1.23) stood as the measurement, the pure background (gain 1.99) as its
    # duplicate (probe); here the smaller cluster is the sharper
    from evmotion.core.warps import make_warp
    from evmotion.methods.segmentation import _duplicates

    ev, _ = two_motions()
    w = make_warp("translation", ev.sensor_size)

    class Cost:
        x = np.asarray(ev.x, float)
        y = np.asarray(ev.y, float)
        dt = (ev.t - ev.t[0]) * 1e-6

    labels = (np.arange(len(ev)) % 3 == 0).astype(int)  # cluster 0 twice cluster 1's size
    params = np.array([[300.0, 0.0], [300.0, 0.1]])
    same = _duplicates(w, Cost, params, labels, np.array([True, True]),
                       np.array([1.23, 1.99]))
    assert same.tolist() == [1, -1]


@pytest.mark.parametrize("kind", ["noise", "static"])
def test_clusters_of_noise_or_no_motion_are_not_measurements(kind):
    """On noise the clusters used to come back valid with parameters of tens of px/s."""
    rng = np.random.default_rng(3)
    n = 6000
    t = np.sort(rng.integers(0, 40_000, n))
    if kind == "noise":
        x, y = rng.integers(0, 130, n), rng.integers(0, 80, n)
    else:  # flickering dots that do not move
        dots = rng.uniform([5, 5], [125, 75], (80, 2)).round()
        k = rng.integers(0, 80, n)
        x, y = dots[k, 0], dots[k, 1]
    ev = EventArray(x, y, t, rng.integers(0, 2, n), (80, 130))
    with pytest.warns(PoorFitWarning, match="no focus: cluster"):
        seg = segment_motion(ev, n_warps=2, warp="translation", seed=0)
    assert not seg.valid.any() and (seg.gains < MIN_CLUSTER_GAIN).all()


def test_single_cluster_and_errors():
    ev, _ = two_motions(n=2000)
    one = segment_motion(ev, n_warps=1, warp="translation", n_iter=2)
    assert one.labels.max() == 0
    with pytest.raises(ParameterError):
        segment_motion(ev, n_warps=0)
    with pytest.raises(ParameterError):
        segment_motion(ev, objective="avg_timestamp")


def test_regularizer_reaches_every_cluster_cost():
    # Sec. 3.6.6: the collapse penalty is part of each cluster's cost. From a start near the
    # collapse of a forward-motion window, plain CMax stays collapsed, divergence recovers it
    from evmotion.sim import simulate

    sim = simulate("zoom", duration_s=0.05, sensor_size=(120, 160), seed=0, texture="noise",
                   show_progress=False)
    ev = sim.events
    T = (int(ev.t[-1]) - int(ev.t[0])) * 1e-6
    hz = sim.gt.params(int(ev.t[0]))["hz"]
    init = [[0.85 / T]]
    plain = segment_motion(ev, 1, "zoom", init=init, n_iter=1)
    reg = segment_motion(ev, 1, "zoom", init=init, n_iter=1, regularizer="divergence",
                         dataset="dsec")
    assert plain.params[0, 0] * T > 0.8
    assert plain.collapsed[0] and not plain.valid[0]
    assert reg.params[0, 0] == pytest.approx(hz, abs=0.2)
    assert not reg.collapsed[0]
    with pytest.raises(ParameterError):
        segment_motion(ev, regularizer="whitening")


def test_a_cluster_whose_warp_collapses_its_events_is_no_measurement():
    # a homography cluster squeezed 14k events onto a line (gain 999) and was valid, in
    # clusters.csv and its picture, without a word (probe DA)
    import warnings

    from evmotion.errors import CollapseWarning
    from evmotion.sim import simulate

    sim = simulate("object", duration_s=0.1, sensor_size=(120, 160), seed=0,
                   show_progress=False)
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        seg = segment_motion(sim.events[:15000], 3, "homography", n_iter=3, seed=0)
    collapsed = np.flatnonzero(seg.collapsed)
    assert collapsed.size and (seg.gains[collapsed] > 100).all()
    assert not seg.valid[collapsed].any()
    said = [str(w.message) for w in said if issubclass(w.category, CollapseWarning)]
    assert [m.split(":")[0] for m in said] == [f"cluster {j}" for j in collapsed]
    assert all(m.split(": ", 1)[1].startswith("event collapse") for m in said)
    ok, _ = two_motions()
    assert not segment_motion(ok, n_warps=2, warp="translation", seed=0).collapsed.any()


def test_many_clusters_leave_none_empty_at_the_split():
    # the dominant split took half of the free events each time: the later of 50 clusters
    # got none, and numpy said "Mean of empty slice" on every window (probe CE)
    import warnings

    ev, _ = two_motions(n=3000)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        warnings.simplefilter("ignore", PoorFitWarning)
        seg = segment_motion(ev, n_warps=20, warp="translation", seed=0, n_iter=2,
                             split="dominant")
    assert seg.params.shape == (20, 2) and np.isfinite(seg.params).all()


def test_invalid_clusters_of_many_windows_are_said_in_a_few_lines():
    # one line per window (dozens on a 34-window run), 4 KB for 50 clusters (probe CE)
    import warnings

    from evmotion.cli.segment import WARN_CLUSTERS, WARN_WINDOWS, _warn_invalid

    rows = [{"window": w, "cluster": c, "n_events": 10, "contrast_gain": 1.0, "same_as": -1,
             "valid": False, "collapsed": False, "chance_z": float("nan"),
             "chance_gain": float("nan")}
            for w in range(10) for c in range(9)]
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        _warn_invalid(rows)
    lines = [str(w.message) for w in said]
    assert len(lines) == WARN_WINDOWS + 1
    assert f"and {9 - WARN_CLUSTERS} more: not a measurement" in lines[0]
    assert lines[-1].startswith("7 more windows (windows 3..9) hold clusters")


def small_sensor_noise(seed: int, side: int, n: int = 3000) -> EventArray:
    """``n`` events of uniform noise over 30 ms on a ``side`` x ``side`` sensor."""
    rng = np.random.default_rng(seed)
    return EventArray(rng.integers(0, side, n), rng.integers(0, side, n),
                      np.sort(rng.integers(0, 30_000, n)), rng.integers(0, 2, n),
                      (side, side))


def small_sensor_two_motions(seed: int, side: int, n: int = 3000) -> EventArray:
    """Two groups of 12 dots, the left half's moving right at 150 px/s and the right
    half's left, on a ``side`` x ``side`` sensor for 30 ms."""
    rng = np.random.default_rng(seed)
    dots = np.concatenate([rng.uniform([2, 2], [side / 2 - 2, side - 2], (12, 2)),
                           rng.uniform([side / 2 + 2, 2], [side - 2, side - 2], (12, 2))])
    k = rng.integers(0, 24, n)
    t = np.sort(rng.integers(0, 30_000, n))
    x = dots[k, 0] + np.where(k < 12, 150.0, -150.0) * t * 1e-6
    return EventArray(np.round(x), np.round(dots[k, 1]), t, np.ones(n, int), (side, side),
                      validate=False)


@pytest.mark.parametrize("side", [8, 16, 32])
def test_clusters_fitted_to_noise_on_a_small_sensor_are_not_measurements(side):
    """Probe DB: on uniform noise of a small sensor the EM sharpened its clusters by
    1.2-8x (many events a pixel, memberships chosen to line up), valid with made-up
    motions of 100-500 px/s in 12 of 12 windows on 8x8 and 16x16, 7 of 8 on 32x32. A
    cluster's warp must align all the window's events beyond the scatter of the same
    motions with their times shuffled."""
    import warnings

    ev = small_sensor_noise(0, side)
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        seg = segment_motion(ev, n_warps=2, warp="translation", seed=0)
    assert not seg.valid.any()
    from evmotion.methods.measured import MIN_CHANCE_Z

    tested = np.isfinite(seg.chance_z)
    assert tested.any() and (seg.chance_z[tested] < MIN_CHANCE_Z).all()
    assert any("times shuffled" in str(w.message) for w in said
               if issubclass(w.category, PoorFitWarning))


@pytest.mark.parametrize("side", [16, 32])
def test_two_motions_on_a_small_sensor_stay_measurements(side):
    import warnings

    from evmotion.methods.measured import MIN_CHANCE_Z

    ev = small_sensor_two_motions(0, side, n=2000 if side == 16 else 3000)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PoorFitWarning)
        seg = segment_motion(ev, n_warps=2, warp="translation", seed=0)
    assert seg.valid.all() and (seg.chance_z > 4 * MIN_CHANCE_Z).all()
    np.testing.assert_allclose(np.sort(seg.params[:, 0]), [-150, 150], atol=20)


def test_a_cluster_no_better_than_chance_is_said_so():
    # the line had listed every cause but that one (noise on 16x16: "it sharpens
    # nothing, holds too few events, ...", gains 2.7-3.0; review DR)
    import warnings

    from evmotion.cli.segment import _warn_invalid

    rows = [{"window": 0, "cluster": 0, "n_events": 1680, "contrast_gain": 3.29,
             "same_as": -1, "valid": False, "collapsed": False, "chance_z": 1.27,
             "chance_gain": 1.2},
            # a gain under the 5 % bar with a high z: said too (probe DF: an evt2 cluster
            # at gain 1.045, z 12.9, given no cause)
            {"window": 0, "cluster": 1, "n_events": 3254, "contrast_gain": 1.25,
             "same_as": -1, "valid": False, "collapsed": False, "chance_z": 12.9,
             "chance_gain": 1.045}]
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        _warn_invalid(rows)
    text = str(said[0].message)
    assert "no better than its events with shuffled times: chance z 1.3, gain 1.200" in text
    assert "shuffled times: chance z 12.9, gain 1.045" in text


@pytest.mark.parametrize(("seed", "share"), [(0, 0.1), (1, 0.2), (0, 0.3)])
def test_a_small_object_gets_a_cluster_of_its_own(seed, share):
    """The dominant split gave the second motion half of all events, most of them the
    background's: an object of 10-30 % of the events was never found (both clusters
    followed the background, one flagged as its duplicate or unfocused). The second
    motion now starts from the events the background's warp leaves blurrier than
    unwarped."""
    ev = object_on_background(seed, share)
    seg = segment_motion(ev, n_warps=2, warp="translation", seed=0)
    order = np.argsort(seg.params[:, 0])
    np.testing.assert_allclose(seg.params[order[0]], [-80.0, 60.0], atol=6)
    np.testing.assert_allclose(seg.params[order[1]], [50.0, 0.0], atol=3)
    assert seg.valid.all()
    assert np.mean(seg.labels == order[0]) == pytest.approx(share, abs=0.05)


def test_an_object_moving_against_the_background_is_a_measurement():
    """Probe DG: an object of 16 % of the events moving at (-100, 0) px/s over a
    background at (100, 0) was found, yet refused: warped by the object's motion, the
    background's events scatter beyond their time shuffles, so all the window's events
    aligned worse than chance (z -6.5 to -19.7). The events of the cluster's territory
    are tried too."""
    from evmotion.methods.measured import MIN_CHANCE_Z

    rng = np.random.default_rng(11)
    span = 30_000
    parts = []
    for n_dots, lo, hi, vx in ((60, (110, 70), (190, 150), -100.0), (700, (0, 0), (320, 240),
                                                                        100.0)):
        p0 = rng.uniform(lo, hi, (n_dots, 2))
        t = rng.uniform(0, span, (n_dots, 25))
        parts.append((p0[:, :1] + vx * t * 1e-6, np.broadcast_to(p0[:, 1:], t.shape), t))
    x, y, t = (np.concatenate([q[i].ravel() for q in parts]) for i in range(3))
    keep = (x >= 0) & (x <= 319) & (y <= 239)
    o = np.argsort(t[keep], kind="stable")
    ev = EventArray(np.round(x[keep][o]), np.round(y[keep][o]), t[keep][o].astype(np.int64),
                    np.ones(o.size, int), (240, 320))
    seg = segment_motion(ev, n_warps=2, warp="translation", seed=0)
    order = np.argsort(seg.params[:, 0])
    np.testing.assert_allclose(seg.params[order[0]], [-100.0, 0.0], atol=5)
    np.testing.assert_allclose(seg.params[order[1]], [100.0, 0.0], atol=5)
    assert seg.valid.all()
    assert (seg.chance_z >= MIN_CHANCE_Z).all()

"""evmotion.methods.bos_run: one contrast threshold per sequence, warm-started intervals."""

import numpy as np
import pytest

from evmotion.errors import ParameterError
from evmotion.io.bosinput import frame_intervals, load_bos_input
from evmotion.methods.bos import estimate_bos, estimate_contrast_threshold
from evmotion.methods.bos_run import sequence_contrast_threshold, solve_bos_input


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    from evmotion.sim.schlieren import simulate_schlieren, write_schlieren

    d = tmp_path_factory.mktemp("run") / "jet"
    write_schlieren(simulate_schlieren("jet", sensor_size=(48, 40), duration_s=4 / 120,
                                       seed=1), d)
    return load_bos_input(d)


def test_frame_intervals_select_overlap_and_limits():
    ft = np.array([0, 10, 20, 30, 40])
    assert frame_intervals(ft, 12, 40).tolist() == [[1, 10, 20], [2, 20, 30], [3, 30, 40]]
    assert frame_intervals(ft, 0, 40, t0=10, t1=30).tolist() == [[1, 10, 20], [2, 20, 30]]
    assert frame_intervals(ft, 0, 40, max_intervals=1).tolist() == [[0, 0, 10]]
    assert frame_intervals(ft, 41, 50).shape == (0, 3)


def test_max_intervals_must_be_a_count(data):
    """-1 used to drop the last interval silently (a slice)."""
    from evmotion.errors import ParameterError

    for bad in (-1, 0, 1.5):
        with pytest.raises(ParameterError, match="max_intervals"):
            load_bos_input(data.source, max_intervals=bad)


def test_iter_bos_input_checks_start_and_workers(data):
    from evmotion.errors import ParameterError
    from evmotion.methods.bos_run import iter_bos_input

    for kw in ({"start": float("nan")}, {"start": 1.5}, {"start": -1}, {"workers": 0},
               {"workers": float("nan")}, {"workers": 1.5}):
        with pytest.raises(ParameterError, match=next(iter(kw))):
            iter_bos_input(data, 0.2, **kw)


def test_sequence_c_is_the_median_of_the_intervals(data):
    c, est = sequence_contrast_threshold(data, samples=3)
    picks = [0, 2, 3]  # round(linspace(0, 3, 3))
    ref = [estimate_contrast_threshold(data.events, data.frames[i], data.frames[i + 1],
                                       t0_us=int(data.frame_times[i]),
                                       t1_us=int(data.frame_times[i + 1]))
           for i in picks]
    np.testing.assert_allclose(est, ref)
    assert c == pytest.approx(np.median(ref))
    with pytest.raises(ParameterError, match="samples"):
        sequence_contrast_threshold(data, samples=0)


def test_one_worker_warm_starts_in_order(data):
    run = solve_bos_input(data, contrast_threshold=0.2, iterations=10, scales=(32, 16, 8))
    assert run.c_source == "given" and len(run.results) == len(data.intervals) == 4
    prev = None
    for (i, t0, t1), res in zip(data.intervals, run.results, strict=True):
        ref = estimate_bos(data.events, data.frames[i], t0_us=int(t0), t1_us=int(t1),
                           frame_next=data.frames[i + 1], init=prev, contrast_threshold=0.2,
                           iterations=10, scales=(32, 16, 8))
        np.testing.assert_array_equal(res.flow, ref.flow)
        prev = ref
    with pytest.raises(ParameterError, match="workers"):
        solve_bos_input(data, workers=0)

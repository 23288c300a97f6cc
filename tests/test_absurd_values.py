"""Values no user means (1e30, 1e-30) get one clear error or a warning from the library,
never a hang, a numpy traceback or a result that is silently empty (probe OPT)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from evmotion.errors import EvmotionWarning, ParameterError
from evmotion.events import EventArray


def test_slice_time_takes_bounds_past_int64():
    # a Python int past int64 raised numpy's TypeError ("ufunc 'isfinite' not supported")
    ev = EventArray(x=[0, 1], y=[0, 0], t=[0, 2500], p=[1, 1], sensor_size=(2, 2))
    assert len(ev.slice_time(0, 10**30)) == 2
    assert len(ev.slice_time(-(10**30), 10**30)) == 2
    assert len(ev.slice_time(10**30, None)) == 0
    assert len(ev.slice_time(0, 2000)) == 1


def test_evaluation_windows_past_int64_are_refused_in_one_line():
    from evmotion.eval.windows import evaluate_windows
    from evmotion.sim import simulate

    sim = simulate("translation", duration_s=0.02, sensor_size=(20, 24), show_progress=False)
    flow = np.zeros((1, 20, 24, 2))
    windows = sim.gt.flow_sequence([0], [10_000])
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # "invalid value encountered in cast"
        with pytest.raises(ParameterError, match=r"window 0: .* \(at most 2\^62\)"):
            evaluate_windows(flow, [0], [1e30], windows)
        with pytest.raises(ParameterError, match=r"t1s must be a whole number in"):
            evaluate_windows(flow, [0], [1e30], sim.gt)  # an OverflowError


def test_a_schlieren_scene_without_events_is_flagged():
    from evmotion.sim import simulate_schlieren

    with pytest.warns(EvmotionWarning, match="no event in .* contrast threshold 1e"):
        sim = simulate_schlieren("plume", (24, 24), duration_s=2 / 120, seed=0,
                                 contrast_threshold=1e30, show_progress=False)
    assert len(sim.events) == 0


def test_air_too_fast_for_the_scene_is_refused():
    # 1e30 px/s reached numpy's "Maximum allowed size exceeded" (puff births)
    from evmotion.sim.schlieren import make_field

    with pytest.raises(ParameterError, match=r"puffs of warm air, at most 1e\+06"):
        make_field("plume", (48, 40), 0.05, speed_px_s=1e30)
    assert make_field("plume", (48, 40), 0.05, speed_px_s=1e5).birth.size < 1_000_000


@pytest.mark.parametrize("params, match", [
    ({"fg_x": 1e30}, r"fg_x must be in \[-3460, 3806\] px"),  # never ended
    ({"fg_y": -1e5}, r"fg_y must be in"),
    ({"radius": 0.0}, r"radius must be in \[0.5, 3460\] px"),  # a scene of no object
    ({"radius": -5.0}, r"radius must be in"),
])
def test_object_scene_refuses_a_disc_of_no_size_or_far_away(params, match):
    from evmotion.sim.scenes import resolve_params

    with pytest.raises(ParameterError, match=match):
        resolve_params("object", params, (260, 346))
    resolve_params("object", {"fg_x": -100.0, "radius": 20.0}, (260, 346))


def test_one_ground_truth_frame_is_flagged():
    from evmotion.sim import simulate

    with pytest.warns(EvmotionWarning, match="gives one ground-truth frame over 0.02 s"):
        sim = simulate("translation", duration_s=0.02, sensor_size=(20, 24), frame_rate=1e-30,
                       show_progress=False)
    assert len(sim.gt.frame_times_us) == 1


def test_training_epochs_stay_within_the_seed_scheme():
    pytest.importorskip("torch")
    from evmotion.methods.dnn.train import TrainConfig

    with pytest.raises(ParameterError, match=r"epochs must be at most 100"):
        TrainConfig(epochs=101, sim_windows=1).check()
    with pytest.raises(ParameterError, match=r"seed must be below 2000"):
        TrainConfig(seed=2000, sim_windows=1).check()


@pytest.fixture(scope="module")
def small_events():
    from evmotion.sim import simulate

    return simulate("translation", duration_s=0.03, sensor_size=(40, 48), seed=0,
                    show_progress=False).events


def _call(name: str, events):
    """The probe API calls, by name (each raised a foreign error or never ended)."""
    import evmotion
    from evmotion.methods import triplet
    from evmotion.methods.dnn import voxel

    return {
        "sigma_int": lambda: evmotion.estimate_egomotion(events, "translation", sigma=10**30),
        "starts_number": lambda: evmotion.estimate_egomotion(events, "translation",
                                                             starts=1e30),
        "finest_level": lambda: evmotion.estimate_flow(events, finest_level=10**30),
        "voxel_bins_float": lambda: voxel.voxel_grid(events, n_bins=1e30),
        "voxel_bins_int64": lambda: voxel.voxel_grid(events, n_bins=2**63),
        "voxel_bins_nan": lambda: voxel.network_inputs(events, (1,), n_bins=float("nan")),
        "triplet_dx": lambda: triplet.estimate_flow_triplet(events, dx=10**30),
        "triplet_filter": lambda: triplet.estimate_flow_triplet(events, filter_size=np.nan),
        "triplet_kappa": lambda: triplet.estimate_flow_triplet(events, normal_kappa=np.nan),
    }[name]


@pytest.mark.parametrize("name, match", [
    ("sigma_int", r"sigma=10+ applies to kernel='gaussian' only"),  # numpy's TypeError
    ("starts_number", r"starts must be a list of parameter vectors"),  # not iterable
    ("finest_level", r"makes 2\^9+ tiles per side"),  # 2 ** (10**30 - 1) never ended
    ("voxel_bins_float", r"n_bins must be a whole number in 2..1024"),  # a cast error
    ("voxel_bins_int64", r"n_bins must be a whole number in 2..1024"),  # OverflowError
    ("voxel_bins_nan", r"n_bins must be a whole number in 2..1024"),
    ("triplet_dx", r"dx must be"),  # numpy's TypeError
    ("triplet_filter", r"filter size must be an odd number"),  # NaN to integer
    ("triplet_kappa", r"normal_kappa must be a power of two"),
])
def test_absurd_keywords_of_the_methods_are_named(small_events, name, match):
    with pytest.raises(ParameterError, match=match) as info:
        _call(name, small_events)()
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("seed", [-1, float("nan"), 0.5])
def test_segmentation_names_a_bad_seed(small_events, seed):
    from evmotion.methods.segmentation import segment_motion

    # numpy's SeedSequence had raised a TypeError or ValueError (probe API); 1e30, a whole
    # number, is taken as one
    with pytest.raises(ParameterError, match=r"seed must be a whole number >= 0"):
        segment_motion(small_events, n_warps=2, seed=seed)
    assert segment_motion(small_events, n_warps=2, seed=1e30, n_iter=1).labels.shape == (
        len(small_events),)


@pytest.mark.parametrize("kw, match", [
    ({"iterations": 1e30}, r"iterations must be whole numbers in 1..100000"),  # numpy's
    ({"iterations": 2**63}, r"iterations must be whole numbers in 1..100000"),  # dimension
    ({"sigma_weight": 1e30}, r"sigma_weight must be at most 1000 px"),  # scipy's size
    ({"sigma_meas": 10**30}, r"sigma_meas must be at most 1000 px"),  # numpy's TypeError
    ({"contrast_threshold": 10**30}, r"contrast_threshold must be in \[0.001, 10\]"),
    ({"contrast_threshold": 1e-30}, r"contrast_threshold must be in \[0.001, 10\]"),
])
def test_bos_options_name_absurd_values(kw, match):
    from evmotion.methods.bos import BosOptions

    with pytest.raises(ParameterError, match=match):
        BosOptions(**kw)


def test_bos_options_take_whole_floats_and_big_ints_as_numbers():
    from evmotion.methods.bos import BosOptions

    # seed 1e30 had failed in numpy's SeedSequence, log_eps 10**30 in np.isfinite
    o = BosOptions(seed=1e30, log_eps=10**30)
    assert o.seed == int(1e30) and isinstance(o.seed, int)
    assert o.log_eps == 1e30 and isinstance(o.log_eps, float)


def test_event_array_times_past_int64_or_nan_are_named():
    # numpy's OverflowError / "cannot convert float NaN to integer" (probe API)
    ev = EventArray(x=[0, 1], y=[0, 0], t=[0, 2500], p=[1, 1], sensor_size=(2, 2))
    with pytest.raises(ParameterError, match=r"window duration .* whole number in 1\.\."):
        ev.windows_by_duration(1e30)
    with pytest.raises(ParameterError, match=r"t0 \(µs\) must be a whole number"):
        ev.windows_by_duration(1000, t0=float("nan"))
    for t_ref in (1e30, float("nan")):
        with pytest.raises(ParameterError, match=r"t_ref \(µs\) must be a whole number"):
            ev.t_seconds(t_ref)
    assert ev.t_seconds(0).tolist() == [0.0, 0.0025]


def test_simulator_building_blocks_name_absurd_values():
    from evmotion.sim.simulator import simulate_log_function
    from evmotion.sim.textures import make_texture

    def ramp(t, pix):
        return np.full((2, 2) if pix is None else len(pix), t * 1e-3)

    with pytest.raises(ParameterError, match=r"duration_us must be a whole number in 1\.\."):
        simulate_log_function(ramp, (2, 2), 1e30)  # ran on
    with pytest.raises(ParameterError, match=r"duration_us must be a whole number"):
        simulate_log_function(ramp, (2, 2), float("nan"))  # NaN to integer
    with pytest.raises(ParameterError, match=r"max_step_us must be finite and in \[1, "):
        simulate_log_function(ramp, (2, 2), 1000, max_step_us=1e30)
    for seed in (-1, float("nan"), 0.5):  # numpy's SeedSequence errors
        with pytest.raises(ParameterError, match=r"seed must be a whole number >= 0"):
            make_texture("dots", (8, 8), (0.0, 0.0), seed=seed)
    assert make_texture("dots", (8, 8), (0.0, 0.0), seed=1e30).log_i.shape == (8, 8)


def test_flow_metrics_name_an_out_threshold_past_int64():
    from evmotion.eval import flow_metrics

    est = np.zeros((4, 5, 2))
    with pytest.raises(ParameterError, match=r"out_px must be a finite number of px > 0"):
        flow_metrics(est, est, out_px=10**400)  # numpy's TypeError past int64 (probe API)
    assert flow_metrics(est, est, out_px=10**30).aee == 0.0


@pytest.mark.parametrize("bad", [1e30, 10**30, float("nan")])
def test_frame_times_of_the_baselines_are_named(small_events, bad):
    from evmotion.errors import EvmotionError
    from evmotion.methods.baselines import multicm_intervals

    # numpy's OverflowError / "cannot convert float NaN to integer" (probe API)
    with pytest.raises(EvmotionError, match=r"frame_times_us"):
        multicm_intervals(small_events, [0, bad])


@pytest.fixture(scope="module")
def small_kymogram(small_events):
    from evmotion.methods.kymogram import KymoLine, kymogram_from_events

    return kymogram_from_events(small_events, KymoLine(5, 20, 40, 20))


@pytest.mark.parametrize("name, match", [
    ("ridge_sigma", r"'sigma_px' must be finite and in \[0, 10000\]"),  # scipy's size
    ("correlation_sigma", r"'sigma_px' must be finite and in \[0, 10000\]"),
    ("correlation_stationary", r"'stationary_px' must be finite and in \[0, 10000\]"),
    ("ridge_bins_nan", r"'sigma_bins' must be finite"),  # NaN to integer
    ("correlation_blocks_nan", r"'n_blocks' must be an integer >= 2"),
    ("line_width_nan", r"line width must be an integer in \[1, 10000\] px"),
    ("t0_nan", r"t0_us must be a whole number"),
])
def test_kymogram_names_absurd_values(small_events, small_kymogram, name, match):
    from evmotion.methods.kymogram import (
        KymoLine,
        fit_correlation,
        fit_ridge,
        kymogram_from_events,
    )

    k = small_kymogram
    call = {
        "ridge_sigma": lambda: fit_ridge(k, sigma_px=1e30),
        "correlation_sigma": lambda: fit_correlation(k, sigma_px=10**30),
        "correlation_stationary": lambda: fit_correlation(k, stationary_px=1e30),
        "ridge_bins_nan": lambda: fit_ridge(k, sigma_bins=float("nan")),
        "correlation_blocks_nan": lambda: fit_correlation(k, n_blocks=float("nan")),
        "line_width_nan": lambda: KymoLine(5, 20, 40, 20, width=float("nan")),
        "t0_nan": lambda: kymogram_from_events(small_events, KymoLine(5, 20, 40, 20),
                                               t0_us=float("nan")),
    }[name]
    with pytest.raises(ParameterError, match=match):
        call()


def test_landscape_names_a_parameter_index_that_is_no_index(small_events):
    from evmotion.methods.egomotion import cost_landscape

    # 1e-30 passed the range test and failed as an index: numpy's IndexError (probe API)
    with pytest.raises(ParameterError, match=r"param index 1e-30 must be a whole number"):
        cost_landscape(small_events, "translation", 1e-30, [1.0])


def test_a_bos_flow_that_never_moved_is_flagged():
    from evmotion.errors import UnderfitWarning
    from evmotion.methods.bos import estimate_bos
    from evmotion.sim import simulate_schlieren

    sch = simulate_schlieren("plume", sensor_size=(48, 40), duration_s=3 / 120, seed=0,
                             show_progress=False)
    f0, f1 = sch.frames.images[:2]
    t0, t1 = (int(t) for t in sch.frames.t[:2])
    # lr=1e-30 left flow, q and p at zero with fit_gain NaN, unsaid (probe API)
    with pytest.warns(UnderfitWarning, match="predicts no increment where the events fired"):
        res = estimate_bos(sch.events, f0, t0_us=t0, t1_us=t1, frame_next=f1, lr=1e-30,
                           contrast_threshold=0.2)
    assert not np.any(res.flow)


@pytest.mark.parametrize("kw", [{"photons": 1e-30}, {"photons": 100.0, "gain": 1e-30},
                                {"photons": 100.0, "gain": 1e30}])
def test_frames_that_show_no_background_are_flagged(kw):
    from evmotion.sim import simulate_schlieren

    # black or saturated frames, unsaid (probe API)
    with pytest.warns(EvmotionWarning, match=r"every frame is \d+ everywhere"):
        simulate_schlieren("plume", sensor_size=(24, 24), duration_s=2 / 120, seed=0,
                           show_progress=False, **kw)


def test_a_time_unit_that_rounds_every_time_to_zero_is_refused():
    ev = EventArray(x=[0, 1], y=[0, 0], t=[100, 2500], p=[1, 1], sensor_size=(2, 2))
    with pytest.raises(ParameterError, match=r"time_unit_us must be finite and in \[1e-06, "):
        EventArray.from_structured(ev.to_structured(), (2, 2), time_unit_us=1e-30)
    ns = EventArray.from_structured(ev.to_structured(), (2, 2), time_unit_us=1e-3)
    assert ns.t.tolist() == [0, 2]


@pytest.mark.parametrize("sigma", [float("nan"), -1.0, 0.0])
def test_fwl_refuses_a_bad_sigma_whatever_the_kernel(small_events, sigma):
    from evmotion.eval import fwl

    flow = np.zeros((*small_events.sensor_size, 2), np.float32)
    with pytest.raises(ParameterError, match=r"sigma must be finite and >= 0.1 \(px\)"):
        fwl(small_events, flow, sigma=sigma)  # ignored under bilinear (probe API)

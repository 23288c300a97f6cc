"""multicm on the simulator (ground truth) and on real ECD windows (../shared/data)."""

import numpy as np
import pytest

from evmotion.events import EventArray
from evmotion.methods.multicm import estimate_flow


def _aee(res, gt_disp, ev):
    mask = np.zeros(ev.sensor_size, bool)
    mask[np.round(ev.y).astype(int), np.round(ev.x).astype(int)] = True
    e = np.linalg.norm(res.displacement().astype(np.float64) - gt_disp, axis=-1)
    return float(e[mask & np.isfinite(e)].mean())


def test_simulated_translation_30k_aee_below_0p2():
    from evmotion.sim import simulate

    sim = simulate("translation", duration_s=0.04, sensor_size=(260, 346), seed=0,
                   show_progress=False)
    ev = sim.events[: 30_000]
    res = estimate_flow(ev)
    gt = sim.gt.displacement(int(ev.t[0]), int(ev.t[-1]))
    assert _aee(res, gt, ev) <= 0.2


def _read_ecd(path):
    a = np.loadtxt(path)
    return EventArray(x=a[:, 1].astype(np.uint16), y=a[:, 2].astype(np.uint16),
                      t=np.round(a[:, 0] * 1e6).astype(np.int64), p=a[:, 3].astype(np.uint8),
                      sensor_size=(180, 240))


@pytest.mark.realdata
def test_ecd_rotation_window_against_imu_flow(shared_data):
    from evmotion.io.calibration import read_ecd

    d = shared_data / "ecd_rotation_windows" / "poster_rotation"
    if not d.is_dir():
        pytest.skip(f"{d} missing")
    ev = read_ecd(d / "calib.txt").undistort_events(_read_ecd(d / "events.txt"))
    gt = np.load(d / "flow.npy")[0].transpose(1, 2, 0).astype(np.float64)
    res = estimate_flow(ev)
    assert _aee(res, gt, ev) < 1.0  # measured 0.58 px (benchmarks/results)
    assert res.focus > 1.5


@pytest.mark.realdata
def test_ecd_30k_window_sharpens(shared_data):
    from evmotion.io.calibration import read_ecd

    d = shared_data / "ecd_30k_windows" / "boxes_translation"
    if not d.is_dir():
        pytest.skip(f"{d} missing")
    ev = read_ecd(d / "calib.txt").undistort_events(_read_ecd(d / "events.txt"))
    res = estimate_flow(ev, time_aware="burgers")
    fwl = np.var(res.iwes["tmid"]) / np.var(res.iwes["identity"])
    assert fwl > 1.2

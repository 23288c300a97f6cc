"""BOS output files: flow + q + p round trip, ROI masking, resume, and flow readers."""

import h5py
import numpy as np
import pytest

from evmotion.errors import FormatError, ParameterError
from evmotion.io.bosfiles import BosWriter, read_bos_h5, roi_mask
from evmotion.io.flowfiles import read_flow_h5


def _fields(rng, h=6, w=7):
    return (rng.normal(size=(h, w, 2)).astype(np.float32),
            rng.normal(size=(h, w)).astype(np.float32),
            rng.normal(size=(h, w, 2)).astype(np.float32))


def test_round_trip_and_flow_reader(tmp_path):
    rng = np.random.default_rng(0)
    path = tmp_path / "bos.h5"
    windows = [_fields(rng) for _ in range(3)]
    with BosWriter(path, (6, 7), attrs={"method": "bos"}, q_units="px^2/s") as bw:
        for i, (v, q, p) in enumerate(windows):
            bw.append(v, 1000 * i, 1000 * (i + 1), q=q, p=p,
                      scalars={"loss": 0.5 + i, "contrast_threshold": 0.2})
        assert not path.exists()  # atomic: only the .part file until close
    bos = read_bos_h5(path)
    assert len(bos) == 3
    for i, (v, q, p) in enumerate(windows):
        np.testing.assert_array_equal(bos.flow.flow[i], v)
        np.testing.assert_array_equal(bos.q[i], q)
        np.testing.assert_array_equal(bos.p[i], p)
    np.testing.assert_array_equal(bos.flow.t0, [0, 1000, 2000])
    np.testing.assert_array_equal(bos.scalars["loss"], [0.5, 1.5, 2.5])
    assert bos.attrs["method"] == "bos" and bos.attrs["q_units"] == "px^2/s"
    assert bos.flow.valid.all()
    # the plain flow reader sees an ordinary flow file
    seq = read_flow_h5(path, index=1)
    np.testing.assert_array_equal(seq.flow[0], windows[1][0])
    assert seq.t0[0] == 1000 and seq.t1[0] == 2000
    with h5py.File(path) as f:
        assert f["p"].attrs["units"] == "px"
        assert f["q"].attrs["units"] == "px^2/s"


def test_roi_outside_is_nan_and_invalid(tmp_path):
    rng = np.random.default_rng(1)
    v, q, p = _fields(rng)
    path = tmp_path / "roi.h5"
    with BosWriter(path, (6, 7), roi=(2, 1, 3, 4)) as bw:
        bw.append(v, 0, 10, q=q, p=p)
    bos = read_bos_h5(path)
    inside = roi_mask((6, 7), (2, 1, 3, 4))
    assert inside.sum() == 12 and inside[1:5, 2:5].all()
    np.testing.assert_array_equal(bos.flow.valid[0], inside)
    np.testing.assert_array_equal(bos.q[0][inside], q[inside])
    assert np.isnan(bos.q[0][~inside]).all()
    assert np.isnan(bos.flow.flow[0][~inside]).all()
    assert np.isnan(bos.p[0][~inside]).all()
    np.testing.assert_array_equal(bos.attrs["roi"], [2, 1, 3, 4])


def test_resume_trims_unfinished_window(tmp_path):
    rng = np.random.default_rng(2)
    path = tmp_path / "r.h5"
    bw = BosWriter(path, (6, 7))
    v, q, p = _fields(rng)
    bw.append(v, 0, 10, q=q, p=p, scalars={"loss": 1.0})
    # a crash after q was written but before the window was complete
    bw.f["q"].resize(2, axis=0)
    bw.f["window/loss"].resize(2, axis=0)
    bw.abort()
    bw = BosWriter(path, (6, 7), resume=True)
    assert bw.n_done == 1 and bw.f["q"].shape[0] == 1 and bw.f["window/loss"].shape[0] == 1
    bw.append(v, 10, 20, q=q, p=p, scalars={"loss": 2.0})
    bw.close()
    np.testing.assert_array_equal(read_bos_h5(path).scalars["loss"], [1.0, 2.0])


def test_bad_inputs(tmp_path):
    with pytest.raises(ParameterError, match="roi"):
        BosWriter(tmp_path / "a.h5", (6, 7), roi=(5, 0, 3, 3))
    bw = BosWriter(tmp_path / "b.h5", (6, 7))
    with pytest.raises(ParameterError, match="q has shape"):
        bw.append(np.zeros((6, 7, 2)), 0, 1, q=np.zeros((6, 6)), p=np.zeros((6, 7, 2)))
    bw.abort()
    flow_only = tmp_path / "flow.h5"
    from evmotion.io.flowfiles import FlowWriter

    with FlowWriter(flow_only, (6, 7)) as fw:
        fw.append(np.zeros((6, 7, 2)), 0, 1)
    with pytest.raises(FormatError, match="not a BOS file"):
        read_bos_h5(flow_only)

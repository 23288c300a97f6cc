"""Per-event flow files (:mod:`evmotion.io.eventflow`) and the fast HDF5 codecs of the flow
container: round trips, self-description, atomic writes."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from evmotion.errors import FormatError, ParameterError
from evmotion.io.eventflow import EVENT_FLOW_COLUMNS, EventFlowWriter, read_event_flow
from evmotion.io.flowfiles import FlowWriter, h5_compression, read_flow_h5

BLOSC = "32001"  # the HDF5 filter id of Blosc


def columns(n: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    return {"t": np.sort(rng.integers(0, 10**7, n)), "x": rng.integers(0, 640, n),
            "y": rng.integers(0, 480, n), "p": rng.integers(0, 2, n),
            "vx": rng.normal(0, 100, n), "vy": rng.normal(0, 100, n),
            "nx": rng.normal(0, 50, n), "ny": rng.normal(0, 50, n),
            "valid": rng.random(n) < 0.6, "n_triplets": rng.integers(0, 40, n)}


@pytest.mark.parametrize("suffix", [".h5", ".npz"])
def test_round_trip_in_chunks(tmp_path, suffix):
    parts = [columns(n, s) for s, n in enumerate((1000, 0, 2345))]
    out = tmp_path / f"ev{suffix}"
    with EventFlowWriter(out, (480, 640), attrs={"method": "triplet", "triplet_dx": 1.5}) as w:
        for part in parts:
            w.append(**part)
        assert not out.exists()  # renamed onto its name only when complete
    got = read_event_flow(out)
    assert len(got) == 3345 and got.sensor_size == (480, 640)
    for name, dt in EVENT_FLOW_COLUMNS:
        want = np.concatenate([p[name] for p in parts]).astype(dt)
        assert got[name].dtype == np.dtype(dt)
        np.testing.assert_array_equal(got[name], want)
    assert got.attrs["units"] == "px/s" and got.attrs["time_units"] == "us"
    assert got.attrs["method"] == "triplet" and got.attrs["triplet_dx"] == 1.5
    assert [p.name for p in tmp_path.iterdir()] == [out.name]


def test_h5_columns_are_blosc_compressed_and_npz_loads_without_pickle(tmp_path):
    c = columns(5000, 3)
    with EventFlowWriter(tmp_path / "a.h5", (480, 640)) as w:
        w.append(**c)
    with h5py.File(tmp_path / "a.h5") as f:
        assert all(BLOSC in f[k]._filters for k, _ in EVENT_FLOW_COLUMNS)
        assert f.attrs["format"] == "evmotion-event-flow"
    with EventFlowWriter(tmp_path / "a.npz", (480, 640)) as w:
        w.append(**c)
    with np.load(tmp_path / "a.npz", allow_pickle=False) as z:
        np.testing.assert_array_equal(z["vx"], c["vx"].astype(np.float32))
        assert int(z["height"]) == 480 and "px/s" in str(z["meta"])


@pytest.mark.parametrize("suffix", [".h5", ".npz"])
def test_abort_leaves_nothing(tmp_path, suffix):
    w = EventFlowWriter(tmp_path / f"x{suffix}", (10, 10))
    w.append(**columns(10, 0))
    w.abort()
    assert list(tmp_path.iterdir()) == []


def test_bad_input_is_reported(tmp_path):
    with pytest.raises(ParameterError, match="ends in .h5 or .npz"):
        EventFlowWriter(tmp_path / "x.flo", (10, 10))
    w = EventFlowWriter(tmp_path / "x.h5", (10, 10))
    c = columns(10, 0)
    with pytest.raises(ParameterError, match="missing"):
        w.append(**{k: v for k, v in c.items() if k != "vx"})
    with pytest.raises(ParameterError, match="different lengths"):
        w.append(**{**c, "vx": c["vx"][:5]})
    w.abort()
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(FormatError, match="other.npz"):
        read_event_flow(tmp_path / "other.npz")
    with FlowWriter(tmp_path / "dense.h5", (4, 5)) as fw:
        fw.append(np.zeros((4, 5, 2), np.float32), 0, 10)
    with pytest.raises(FormatError, match="dense.h5"):
        read_event_flow(tmp_path / "dense.h5")


@pytest.mark.parametrize("codec", ["lz4", "zstd", "gzip", None])
def test_flow_writer_codecs_round_trip(tmp_path, codec):
    rng = np.random.default_rng(1)
    flows = rng.normal(0, 50, (3, 20, 30, 2)).astype(np.float32)
    valid = rng.random((3, 20, 30)) < 0.5
    out = tmp_path / "f.h5"
    with FlowWriter(out, (20, 30), with_valid=True, compression=codec) as fw:
        for i in range(3):
            fw.append(flows[i], 10 * i, 10 * i + 10, valid=valid[i])
    seq = read_flow_h5(out)
    np.testing.assert_array_equal(seq.flow, flows)
    np.testing.assert_array_equal(seq.valid, valid)
    with h5py.File(out) as f:
        assert (BLOSC in f["flow"]._filters) == (codec in ("lz4", "zstd"))
    with pytest.raises(ParameterError, match="compression must be one of"):
        h5_compression("snappy")


@pytest.mark.parametrize("suffix", [".h5", ".npz"])
def test_per_event_files_describe_themselves(tmp_path, suffix, capsys):
    from evmotion.cli import main
    from evmotion.io.flowread import describe_flow

    cols = columns(500, 3)
    out = tmp_path / f"ev{suffix}"
    with EventFlowWriter(out, (480, 640), attrs={"method": "triplet", "grid": "sensor"}) as w:
        w.append(**cols)
    d = describe_flow(out)
    assert d["format"] == "evmotion-event-flow" and d["container"] == suffix[1:]
    assert d["events"] == 500 and d["sensor_size"] == [480, 640] and d["units"] == "px/s"
    assert d["t_first_us"] == cols["t"][0] and d["t_last_us"] == cols["t"][-1]
    assert d["valid_fraction"] == pytest.approx(cols["valid"].mean())
    assert d["method"] == "triplet" and d["grid"] == "sensor"
    assert main(["info", str(out)]) == 0
    shown = capsys.readouterr().out
    assert "evmotion-event-flow" in shown and "500" in shown

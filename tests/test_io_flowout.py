"""The flow output layer: every container round-trips flow (px/s), t0/t1 and the valid
mask; per-window patterns; .npy refused; atomic writes; .h5 resume; describe_flow."""

from __future__ import annotations

import json
import re
import sys

import numpy as np
import pytest

from evmotion.errors import FormatError, ParameterError
from evmotion.io import flowout as fo
from evmotion.io.flowfiles import FlowWriter, read_flo
from evmotion.io.flowread import describe_flow, read_flow

H, W = 6, 7
T0 = [1_000, 21_000, 41_000]
T1 = [21_000, 41_000, 66_000]  # the last window is 25 ms: per-window dt is used


def _windows(n=3, seed=0):
    rng = np.random.default_rng(seed)
    # multiples of 1/128 px over each window survive the DSEC PNG's quantisation
    flows, valids = [], []
    for i in range(n):
        dt = (T1[i] - T0[i]) * 1e-6
        disp = np.round(rng.normal(0, 3, (H, W, 2)) * 128) / 128
        flows.append((disp / dt).astype(np.float32))
        v = rng.random((H, W)) > 0.3
        v[0, 0], v[0, 1] = False, True
        valids.append(v)
    return flows, valids


def _write(path, n=3, **kw):
    flows, valids = _windows(n)
    with fo.open_flow_output(path, (H, W), {"method": "test", "lam": 0.5}, **kw) as out:
        for i in range(n):
            out.append(flows[i], T0[i], T1[i], valid=valids[i])
    return flows, valids


@pytest.mark.parametrize("name,units,rtol", [
    ("f.h5", "px/s", 0), ("f.npz", "px/s", 0), ("f_{:05d}.flo", "px", 1e-6),
    ("f_{:05d}.png", "px", 1e-6)])
def test_round_trip_units_times_valid(tmp_path, name, units, rtol):
    flows, valids = _write(tmp_path / name)
    seq = read_flow(tmp_path / name)
    assert seq.t0.tolist() == T0 and seq.t1.tolist() == T1
    np.testing.assert_array_equal(seq.valid, np.stack(valids))
    v = np.stack(valids)
    np.testing.assert_allclose(seq.flow[v], np.stack(flows)[v], rtol=rtol, atol=1e-3)
    assert seq.attrs["method"] == "test" and seq.attrs["grid"] == "sensor"
    d = describe_flow(tmp_path / name)
    assert d["windows"] == 3 and d["sensor_size"] == [H, W]
    assert d["t_first_us"] == T0[0] and d["t_last_us"] == T1[-1]
    assert d["units"].startswith(units) and d["method"] == "test"
    assert d["valid_fraction"] == pytest.approx(v.mean())


def test_flo_is_displacement_with_dt_in_its_sidecar(tmp_path):
    flows, valids = _write(tmp_path / "f_{:05d}.flo")
    for i in range(3):
        path = tmp_path / f"f_{i:05d}.flo"
        side = json.loads(path.with_name(path.name + ".json").read_text())
        dt = (T1[i] - T0[i]) * 1e-6
        assert side["t0_us"] == T0[i] and side["t1_us"] == T1[i]
        assert side["dt_s"] == pytest.approx(dt) and side["units"] == "px"
        disp = read_flo(path)  # Middlebury: displacement, NaN (unknown) where not valid
        np.testing.assert_array_equal(np.isfinite(disp).all(2), valids[i])
        np.testing.assert_allclose(disp[valids[i]], flows[i][valids[i]] * dt, rtol=1e-6)
    raw = (tmp_path / "f_00000.flo").read_bytes()
    assert np.frombuffer(raw[12:16], "<f4")[0] == np.float32(1e10)  # pixel (0, 0): unknown


def test_png_is_dsec_displacement(tmp_path):
    from evmotion.io.flowfiles import read_dsec_flow_png

    flows, valids = _write(tmp_path / "g_{:05d}.png")
    disp, valid = read_dsec_flow_png(tmp_path / "g_00002.png")
    np.testing.assert_array_equal(valid, valids[2])
    np.testing.assert_allclose(disp[valid], flows[2][valid] * 0.025, atol=1e-6)


def test_one_window_plain_name_and_explicit_interval(tmp_path):
    flows, valids = _write(tmp_path / "one.flo", n=1)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["one.flo", "one.flo.json"]
    seq = read_flow(tmp_path / "one.flo")
    assert seq.t0.tolist() == [T0[0]] and len(seq) == 1
    with pytest.raises(ParameterError, match="carries"):
        read_flow(tmp_path / "one.flo", t0_us=0, t1_us=5)
    (tmp_path / "one.flo.json").unlink()
    with pytest.raises(ParameterError, match="one.flo.*no one.flo.json"):
        read_flow(tmp_path / "one.flo")
    seq = read_flow(tmp_path / "one.flo", t0_us=0, t1_us=10_000)
    np.testing.assert_allclose(seq.flow[0][valids[0]], flows[0][valids[0]] * 2, rtol=1e-5)


def test_pattern_rules(tmp_path):
    with pytest.raises(ParameterError, match=r"3 windows but one .flo file.*f_\{:05d\}.flo"):
        fo.check_flow_output(tmp_path / "f.flo", n_windows=3)
    assert fo.check_flow_output(tmp_path / "f.flo", n_windows=1) == "flo"
    with pytest.raises(ParameterError, match="holds every window"):
        fo.check_flow_output(tmp_path / "f_{:05d}.h5")
    with pytest.raises(ParameterError, match="must number the windows"):
        fo.check_flow_output(tmp_path / "f_{{x}}.png")
    with pytest.raises(ParameterError, match="not a file-name pattern"):
        fo.check_flow_output(tmp_path / "f_{name}.flo")
    with pytest.raises(ParameterError, match="file name only"):
        fo.check_flow_output(tmp_path / "d{:02d}" / "f.flo")
    assert fo.window_path(tmp_path / "f_{:05d}.flo", 7).name == "f_00007.flo"
    # a streaming writer that did not know the count: the second window is refused, and
    # nothing is left behind
    with pytest.raises(ParameterError, match="several windows but one .flo file"):
        _write(tmp_path / "s.flo", n=2)
    assert not list(tmp_path.iterdir())


def test_npy_is_refused_for_npz(tmp_path):
    with pytest.raises(ParameterError, match=r"f.npy: a bare .npy .* write .npz"):
        fo.open_flow_output(tmp_path / "f.npy", (H, W))
    with pytest.raises(FormatError, match="f.npy"):
        read_flow(tmp_path / "f.npy")
    with pytest.raises(ParameterError, match="f.txt: not a flow output"):
        fo.check_flow_output(tmp_path / "f.txt")


@pytest.mark.parametrize("name", ["f.h5", "f.npz", "f_{:05d}.flo", "f_{:05d}.png"])
def test_an_exception_mid_run_leaves_no_complete_looking_file(tmp_path, name):
    flows, valids = _windows()
    with pytest.raises(RuntimeError, match="boom"):
        with fo.open_flow_output(tmp_path / name, (H, W)) as out:
            out.append(flows[0], T0[0], T1[0], valid=valids[0])
            out.append(flows[1], T0[1], T1[1], valid=valids[1])
            raise RuntimeError("boom")
    left = sorted(p.name for p in tmp_path.iterdir())
    # only the resumable .h5 keeps its .part file; nothing has a final name
    assert left == (["f.h5.part"] if name == "f.h5" else [])


def test_rerun_with_fewer_windows_replaces_the_pattern_set(tmp_path):
    _write(tmp_path / "f_{:05d}.flo", n=3)
    _write(tmp_path / "f_{:05d}.flo", n=2)
    assert len(read_flow(tmp_path / "f_{:05d}.flo")) == 2
    assert not (tmp_path / "f_00002.flo").exists()
    assert not (tmp_path / "f_00002.flo.json").exists()


def test_h5_resume_continues_and_checks(tmp_path):
    path = tmp_path / "r.h5"
    flows, valids = _windows()
    out = fo.open_flow_output(path, (H, W), {"method": "m", "lam": 1.0})
    out.append(flows[0], T0[0], T1[0], valid=valids[0])
    out.abort()  # an interrupted run
    assert not path.exists() and (tmp_path / "r.h5.part").exists()
    with pytest.raises(ParameterError, match="lam=1.0.*2.0"):
        fo.open_flow_output(path, (H, W), {"method": "m", "lam": 2.0}, resume=True)
    out = fo.open_flow_output(path, (H, W), {"method": "m", "lam": 1.0}, resume=True)
    assert out.done == [(T0[0], T1[0])]
    out.check_count(3)
    out.check_done(0, T0[0], T1[0])
    np.testing.assert_array_equal(out.stored_flow(0), flows[0])
    for i in (1, 2):
        out.append(flows[i], T0[i], T1[i], valid=valids[i])
    out.close()
    seq = read_flow(path)
    np.testing.assert_array_equal(seq.flow, np.stack(flows))
    np.testing.assert_array_equal(seq.valid, np.stack(valids))
    out = fo.open_flow_output(path, (H, W), {"method": "m", "lam": 1.0}, resume=True)
    with pytest.raises(ParameterError, match=r"window 0 .* \[1000, 21000\)"):
        out.check_done(0, 0, 21_000)
    assert path.exists()  # the finished file reopened is put back
    with pytest.raises(ParameterError, match="only an .h5 output can be resumed"):
        fo.open_flow_output(tmp_path / "f.npz", (H, W), resume=True)


def test_npz_holds_named_arrays(tmp_path):
    flows, valids = _write(tmp_path / "f.npz")
    with np.load(tmp_path / "f.npz", allow_pickle=False) as z:
        assert set(z.files) == {"flow", "valid", "t0", "t1", "units", "format", "attrs"}
        assert z["flow"].dtype == np.float32 and z["flow"].shape == (3, H, W, 2)
        assert z["t0"].dtype == np.int64 and str(z["units"]) == "px/s"
        assert json.loads(str(z["attrs"]))["lam"] == 0.5


def test_bad_windows_are_refused(tmp_path):
    with fo.open_flow_output(tmp_path / "f.npz", (H, W)) as out:
        with pytest.raises(ParameterError, match="shape"):
            out.append(np.zeros((H + 1, W, 2)), 0, 1)
        with pytest.raises(ParameterError, match="not after"):
            out.append(np.zeros((H, W, 2)), 5, 5)
        with pytest.raises(ParameterError, match="valid has shape"):
            out.append(np.zeros((H, W, 2)), 0, 5, valid=np.ones((2, 2), bool))


def test_describe_flow_is_none_for_other_files(tmp_path):
    from evmotion.events import EventArray
    from evmotion.io import write_events

    ev = EventArray(np.arange(5), np.arange(5), np.arange(5) * 10, np.ones(5, np.uint8),
                    sensor_size=(8, 8))
    write_events(tmp_path / "ev.h5", ev)
    write_events(tmp_path / "ev.npz", ev)
    assert describe_flow(tmp_path / "ev.h5") is None
    assert describe_flow(tmp_path / "ev.npz") is None
    assert describe_flow(tmp_path / "nothing_{:05d}.flo") is None


def test_per_event_npz_is_described_not_read_as_windows(tmp_path):
    n = 4
    np.savez(tmp_path / "ev.npz", t=np.arange(n, dtype=np.int64) * 100, x=np.zeros(n),
             y=np.zeros(n), vx=np.ones(n), vy=np.ones(n), valid=np.array([1, 1, 0, 0], bool))
    d = describe_flow(tmp_path / "ev.npz")
    assert d["format"] == "per-event-flow" and d["events"] == n and d["valid_fraction"] == 0.5
    with pytest.raises(FormatError, match="per-event"):
        read_flow(tmp_path / "ev.npz")


def test_a_fresh_process_reads_the_compressed_h5_output(tmp_path):
    """The .h5 output is Blosc-LZ4 compressed: ``info`` (which reads the masks) and the
    reader must register hdf5plugin's filters themselves. In a fresh process, since this
    one may have imported hdf5plugin already."""
    import subprocess
    import sys

    import h5py

    path = tmp_path / "flow.h5"
    yy, xx = np.mgrid[0:60, 0:80]
    flow = np.stack([xx, yy], -1).astype(np.float32)
    # compressible data: Blosc is an optional filter, which HDF5 skips on chunks it does
    # not shrink (those would read without the plugin)
    with fo.open_flow_output(path, (60, 80), {"method": "x"}) as out:
        out.append(flow, 0, 10_000, valid=xx < 50)
    with h5py.File(path, "r") as f:
        assert f["flow"].id.get_create_plist().get_filter(0)[0] == 32001  # Blosc
    code = ("import sys; from evmotion.io.flowread import describe_flow, read_flow; "
            "p = sys.argv[1]; d = describe_flow(p); s = read_flow(p); "
            "print(d['windows'], round(d['valid_fraction'], 4), s.flow.shape)")
    res = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    seq = read_flow(path)
    assert res.stdout.split()[0] == "1"
    assert float(res.stdout.split()[1]) == pytest.approx(seq.valid.mean(), abs=1e-4)


def test_without_hdf5plugin_blosc_outputs_fall_back_to_gzip(tmp_path):
    """Where hdf5plugin cannot be imported, the Blosc defaults of the event and flow files
    (LZ4) are written with gzip instead, and read back, rather than failing on an import
    (a fresh process: this one has imported hdf5plugin)."""
    import subprocess
    import textwrap

    code = textwrap.dedent(f"""
        import sys
        sys.modules["hdf5plugin"] = None  # as if it were not installed
        import h5py, numpy as np
        from evmotion.events import EventArray
        from evmotion.io import read_events, write_events
        from evmotion.io.flowfiles import FlowWriter, read_flow_h5
        from evmotion.io.h5filters import h5_compression
        assert h5_compression("zstd")["compression"] == "gzip"
        n = 5000
        ev = EventArray(np.arange(n) % 32, np.arange(n) % 24, np.arange(n), np.arange(n) % 2,
                        sensor_size=(24, 32))
        write_events({str(tmp_path / "ev.h5")!r}, ev)
        assert len(read_events({str(tmp_path / "ev.h5")!r})) == n
        with FlowWriter({str(tmp_path / "f.h5")!r}, (24, 32)) as w:
            w.append(np.ones((24, 32, 2), np.float32), 0, 1000)
        for name, key in (("ev.h5", "events/x"), ("f.h5", "flow")):
            with h5py.File({str(tmp_path)!r} + "/" + name) as f:
                print(name, f[key].compression)
        print(float(read_flow_h5({str(tmp_path / "f.h5")!r}).flow.sum()))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["ev.h5", "gzip", "f.h5", "gzip", "1536.0"], out.stdout


def test_a_gap_in_a_pattern_is_named(tmp_path):
    """Deleting f_01.flo made the pattern read as one window, f_02.flo ignored."""
    import pytest

    from evmotion.errors import FormatError
    from evmotion.io.flowout import open_flow_output
    from evmotion.io.flowread import read_flow

    pat = tmp_path / "f_{:02d}.flo"
    sink = open_flow_output(pat, (4, 5), {"method": "test"}, n_windows=3)
    for k in range(3):
        sink.append(np.full((4, 5, 2), float(k), np.float32), 10 * k, 10 * k + 10)
    sink.close()
    assert len(read_flow(pat).t0) == 3
    (tmp_path / "f_01.flo").unlink()
    with pytest.raises(FormatError, match="f_01.flo is missing but f_02.flo exists"):
        read_flow(pat)


@pytest.mark.parametrize("mutate, match", [
    (lambda d, a: d.update(flow=d["flow"][..., 0]), r"'flow' has shape \(2, 6, 8\)"),
    (lambda d, a: d.update(t0=d["t0"][:1]), "'t0' has 1 and 't1' 2 values for 2"),
    (lambda d, a: d.update(valid=d["valid"][:, :3]), "'valid' has shape"),
    (lambda d, a: d.update(t1=d["t0"]), "window 0 has t1 = .* not after t0"),
    (lambda d, a: a.update(units="px"), "attribute 'units' is 'px'"),
    (lambda d, a: d.update({k: d[k][:0] for k in ("flow", "t0", "t1", "valid")}),
     "holds no flow window"),
])
def test_a_malformed_flow_file_is_one_line_in_eval_and_view(tmp_path, capsys, mutate, match):
    """eval, view and kymogram met them with numpy's tracebacks (broadcast, zip, an empty
    minimum), and scored a flow stated in px as px/s."""
    import h5py

    from evmotion.cli import main
    from evmotion.io.flowfiles import write_flow_group

    rng = np.random.default_rng(0)
    with h5py.File(tmp_path / "ok.h5", "w") as f:
        write_flow_group(f, rng.normal(size=(2, 6, 8, 2)).astype(np.float32),
                         np.array([0, 1000]), np.array([1000, 2000]),
                         valid=np.ones((2, 6, 8), bool), compression=None)
    with h5py.File(tmp_path / "ok.h5") as f:
        data = {k: f[k][()] for k in f}
        attrs = dict(f.attrs)
    mutate(data, attrs)
    with h5py.File(tmp_path / "bad.h5", "w") as f:
        f.attrs.update(attrs)
        for k, v in data.items():
            f[k] = v
    for argv in (["eval", str(tmp_path / "bad.h5"), "--gt", str(tmp_path / "ok.h5")],
                 ["view", str(tmp_path / "bad.h5"), "--out", str(tmp_path / "v.png")]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "bad.h5" in err
        assert re.search(match, err), err


def test_an_output_removed_during_the_run_stops_it_at_the_next_window(tmp_path):
    """Its folder deleted mid-run, flow wrote every window into the unlinked file and
    failed only at the end, on the rename (probe X): the next window now stops it."""
    from evmotion.errors import EvmotionError

    out = fo.open_flow_output(tmp_path / "f.h5", (4, 6), {"method": "test"})
    flow = np.zeros((4, 6, 2), np.float32)
    out.append(flow, 0, 10)
    (tmp_path / "f.h5.part").unlink()
    with pytest.raises(EvmotionError, match=r"f\.h5\.part was removed during the run"):
        out.append(flow, 10, 20)
    out.abort()
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("left", "said"), [
    ("", "does not exist"),
    (b"\x89HDF\r\n\x1a\n" + bytes(88), "held no finished window"),
    (None, "held no finished window")], ids=["none", "cut-in-its-header", "no-window"])
def test_resume_with_nothing_to_continue_is_said(tmp_path, left, said):
    # probe AM: --resume on a mistyped --out started from the first window without a
    # word; probe BH: a run killed before its first window left a .part (a 96-byte HDF5
    # start, or a file with no window), which --resume dropped without a word
    from evmotion.errors import EvmotionWarning

    path = tmp_path / "f.h5"
    if left is None:
        FlowWriter(path, (4, 5)).f.close()
    elif left:
        (tmp_path / "f.h5.part").write_bytes(left)
    with pytest.warns(EvmotionWarning, match=r"no interrupted run to continue \(.*f\.h5\.part "
                                             + said):
        out = fo.open_flow_output(path, (4, 5), {}, n_windows=1, resume=True)
    out.append(np.zeros((4, 5, 2), np.float32), t0=0, t1=10)
    out.close()
    assert read_flow(path).flow.shape == (1, 4, 5, 2)


@pytest.mark.parametrize("left", [None, "header-only"])
def test_a_file_made_afresh_on_resume_has_the_callers_compression(tmp_path, left):
    # with no .part at all it took FlowWriter's default (lz4), with an empty one the
    # caller's (review of the previous session)
    import h5py

    path = tmp_path / "f.h5"
    if left:
        FlowWriter(path, (4, 5)).f.close()
    with pytest.warns(Warning, match="no interrupted run to continue"):
        out = fo.H5FlowOutput(path, (4, 5), {}, resume=True, compression="gzip")
    out.append(np.zeros((4, 5, 2), np.float32), t0=0, t1=10)
    out.close()
    with h5py.File(path) as f:
        assert f["flow"].compression == "gzip"

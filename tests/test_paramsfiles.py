"""Parameters files (egomotion's params.h5, segment's clusters.h5): a table that says its
units, each row's [t0, t1) µs, warp, grid and validity; written, read back and described
(``evmotion info``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from egomotion_synth import synth
from evmotion.cli import main
from evmotion.errors import FormatError, ParameterError
from evmotion.io import write_events
from evmotion.io.paramsfiles import ParamsTable, describe_params, read_params, write_params_h5


def _table(n=3):
    rng = np.random.default_rng(0)
    return ParamsTable(
        params=rng.normal(size=(n, 3)), names=("wx", "wy", "wz"),
        units=("rad/s", "rad/s", "rad/s"), t0=np.arange(n) * 1000,
        t1=np.arange(n) * 1000 + 700, valid=np.array([True, False, True][:n]),
        columns={"collapsed": np.array([False, True, False][:n]),
                 "n_events": np.array([10, 20, 30][:n])},
        column_units={"n_events": "events"}, column_meanings={"collapsed": "flag"},
        attrs={"warp": "rotation", "grid": "distorted sensor", "method": "egomotion"})


def test_round_trip_and_describe(tmp_path):
    t = _table()
    path = tmp_path / "p.h5"
    write_params_h5(path, t)
    back = read_params(path)
    np.testing.assert_array_equal(back.params, t.params)
    np.testing.assert_array_equal(back.t0, t.t0)
    np.testing.assert_array_equal(back.t1, t.t1)
    np.testing.assert_array_equal(back.valid, t.valid)
    np.testing.assert_array_equal(back.columns["n_events"], [10, 20, 30])
    assert back.names == t.names and back.units == t.units
    assert back.column_units["n_events"] == "events"
    assert back.column_meanings["collapsed"] == "flag"
    assert back.attrs["warp"] == "rotation" and back.attrs["grid"] == "distorted sensor"
    assert json.loads(back.attrs["units"]) == {"wx": "rad/s", "wy": "rad/s", "wz": "rad/s"}
    d = describe_params(path)
    assert d["rows"] == 3 and d["windows"] == 3
    assert d["t_first_us"] == 0 and d["t_last_us"] == 2700
    assert d["parameters"] == {"wx": "rad/s", "wy": "rad/s", "wz": "rad/s"}
    assert d["valid_fraction"] == pytest.approx(2 / 3) and d["flags"] == {"collapsed": 1}


def test_bad_tables_and_files(tmp_path):
    t = _table()
    with pytest.raises(ParameterError, match="'grid'"):
        write_params_h5(tmp_path / "a.h5", ParamsTable(t.params, t.names, t.units, t.t0, t.t1,
                                                      t.valid, attrs={"warp": "rotation"}))
    with pytest.raises(ParameterError, match="t1 > t0"):
        write_params_h5(tmp_path / "a.h5", ParamsTable(t.params, t.names, t.units, t.t1, t.t0,
                                                      t.valid, attrs=t.attrs))
    with pytest.raises(ParameterError, match="'n_events' has shape"):
        write_params_h5(tmp_path / "a.h5", ParamsTable(
            t.params, t.names, t.units, t.t0, t.t1, t.valid, {"n_events": np.zeros(2)},
            attrs=t.attrs))
    assert not (tmp_path / "a.h5").exists()
    from evmotion.io.flowfiles import FlowWriter

    with FlowWriter(tmp_path / "flow.h5", (2, 3)) as fw:
        fw.append(np.zeros((2, 3, 2)), 0, 1)
    assert describe_params(tmp_path / "flow.h5") is None
    with pytest.raises(FormatError, match="not an evmotion parameters file"):
        read_params(tmp_path / "flow.h5")


def test_egomotion_params_h5_describes_itself(tmp_path, capsys):
    ev, _ = synth("translation", [300.0, -150.0], n_events=6000, seed=0)
    ev = type(ev)(np.round(ev.x).astype(np.uint16), np.round(ev.y).astype(np.uint16), ev.t,
                  ev.p, ev.sensor_size)
    rec = tmp_path / "rec.h5"
    write_events(rec, ev)
    out = tmp_path / "ego"
    assert main(["egomotion", str(rec), "--warp", "translation", "--window-us", "20000",
                 "--max-windows", "2", "--max-png", "0", "--out", str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    t = read_params(out / "params.h5")
    assert t.units == ("px/s", "px/s") and t.names == ("vx", "vy")
    np.testing.assert_array_equal(t.t0, [w["t0_us"] for w in doc["windows"]])
    np.testing.assert_array_equal(t.t1, [w["t1_us"] for w in doc["windows"]])
    np.testing.assert_array_equal(t.params[:, 0], [w["params"]["vx"] for w in doc["windows"]])
    assert t.attrs["warp"] == "translation" and t.attrs["grid"] == doc["grid"]
    np.testing.assert_array_equal(t.valid, ~t.columns["collapsed"] & ~t.columns["poor_fit"])
    assert t.column_units["t_ref_us"] == "us"
    rc = main(["info", str(out / "params.h5"), "--json"])
    info = json.loads(capsys.readouterr().out)
    assert rc == 0 and info["format"] == "evmotion-params" and info["windows"] == 2
    assert info["parameters"] == {"vx": "px/s", "vy": "px/s"}
    assert info["warp"] == "translation" and info["grid"] == doc["grid"]
    assert set(info["flags"]) == {"collapsed", "poor_fit"}
    rc = main(["info", str(out / "params.h5")])
    assert rc == 0 and "parameters:  vx=px/s, vy=px/s" in capsys.readouterr().out
    seg = tmp_path / "seg"
    assert main(["segment", str(rec), "--warp", "translation", "--warps", "2",
                 "--window-us", "20000", "--max-windows", "1", "--iterations", "2",
                 "--out", str(seg)]) == 0
    capsys.readouterr()
    c = read_params(seg / "clusters.h5")
    assert len(c) == 2 and c.columns["cluster"].tolist() == [0, 1]
    assert c.attrs["method"] == "segment" and c.units == ("px/s", "px/s")
    assert c.columns["n_events"].sum() == int(np.sum((ev.t >= c.t0[0]) & (ev.t < c.t1[0])))

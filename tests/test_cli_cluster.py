"""``--scheduler ADDRESS``: the per-window commands on a Dask cluster give the files of the
local run, and a bad or unreachable address ends in one line."""

from __future__ import annotations

import json
import socket
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from egomotion_synth import synth
from evmotion.cli import main
from evmotion.events import concatenate
from evmotion.io import write_events

distributed = pytest.importorskip("distributed", reason="needs the 'dask' extra")


@pytest.fixture(scope="module")
def cluster():
    """Two single-threaded workers on TCP (threads of this process: fast to start, but
    every task and result still goes through the network layer, pickled)."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  protocol="tcp", dashboard_address=":0") as c:
        yield c.scheduler_address


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    a, _ = synth("translation", [300.0, -150.0], n_events=6000, seed=0)
    b, _ = synth("translation", [-200.0, 100.0], n_events=6000, seed=1)
    b = type(b)(b.x, b.y, b.t + 50_000, b.p, b.sensor_size, validate=False)
    ev = concatenate([a, b], validate=False)
    # timestamps on a 20 µs grid, as a camera's clock can give: events share a timestamp
    # across window boundaries, which a cut by time instead of by index would move
    ev = type(ev)(np.round(ev.x).astype(np.uint16), np.round(ev.y).astype(np.uint16),
                  ev.t // 20 * 20, ev.p, ev.sensor_size)
    w = ev.windows_by_count(3000)[1]
    assert len(ev.slice_time(w.t0, w.t1)) != w.count
    path = tmp_path_factory.mktemp("rec") / "rec.h5"
    write_events(path, ev)
    return path


def _json(argv, capsys) -> dict:
    """The run's JSON summary without its "warnings": the tests run the local and the
    cluster command in one process, where Python shows a warning of one text and place
    once (a command has a process of its own), so the second run's list can lack what the
    first one's holds where the estimates agree."""
    assert main([str(a) for a in argv]) == 0
    doc = json.loads(capsys.readouterr().out)
    doc.pop("warnings", None)
    return doc


def _h5(path: Path) -> dict:
    with h5py.File(path) as f:
        return {k: np.asarray(f[k]) for k in f}


TIMINGS = {"seconds", "compile_s", "estimate_s"}


def _estimates(doc: dict) -> list[dict]:
    return [{k: v for k, v in w.items() if k not in TIMINGS} for w in doc["windows"]]


def test_egomotion_on_cluster_matches_local_run(rec, cluster, tmp_path, capsys):
    base = ["egomotion", rec, "--warp", "translation", "--window-events", "3000",
            "--max-png", "0", "--json", "--out"]
    local = _json([*base, tmp_path / "local"], capsys)
    remote = _json([*base, tmp_path / "remote", "--scheduler", cluster], capsys)
    assert len(local["windows"]) == 4 and not local["failed"] and not remote["failed"]
    assert _estimates(remote) == _estimates(local)
    a, b = _h5(tmp_path / "local" / "params.h5"), _h5(tmp_path / "remote" / "params.h5")
    assert a.keys() == b.keys()
    for key in a:
        assert a[key].tobytes() == b[key].tobytes(), key
    # the windows really are estimates: the two halves move differently
    vx = [w["params"]["vx"] for w in local["windows"]]
    assert vx[0] == pytest.approx(300, abs=15) and vx[-1] == pytest.approx(-200, abs=15)


def test_flow_multicm_on_cluster_matches_local_chunks(rec, cluster, tmp_path, capsys):
    base = ["flow", rec, "--method", "multicm", "--window-events", "3000", "--scales", "2",
            "--max-iter", "5", "--json"]
    local = _json([*base, "--workers", "2", "--out", tmp_path / "local.h5"], capsys)
    # the cluster's 2 worker threads make the same 2 chunks of windows as --workers 2
    remote = _json([*base, "--scheduler", cluster, "--out", tmp_path / "remote.h5"], capsys)
    assert local["n_windows"] == remote["n_windows"] == 4
    assert _estimates(remote) == _estimates(local)
    a, b = _h5(tmp_path / "local.h5"), _h5(tmp_path / "remote.h5")
    assert a.keys() == b.keys() and {"flow", "valid"} <= a.keys()
    for key in a:
        assert a[key].tobytes() == b[key].tobytes(), key
    assert np.abs(a["flow"]).max() > 50  # a real flow, not zeros
    # one chunk on the cluster (--workers 1) is the serial run's warm-started sequence
    one = _json([*base, "--scheduler", cluster, "--workers", "1", "--out",
                 tmp_path / "one.npz"], capsys)
    serial = _json([*base, "--out", tmp_path / "serial.npz"], capsys)
    assert _estimates(one) == _estimates(serial)
    a, b = np.load(tmp_path / "one.npz"), np.load(tmp_path / "serial.npz")
    assert a["flow"].tobytes() == b["flow"].tobytes() and a["valid"].tobytes() == b["valid"].tobytes()


def test_segment_on_cluster_matches_local_run(rec, cluster, tmp_path, capsys):
    base = ["segment", rec, "--warp", "translation", "--warps", "2", "--iterations", "3",
            "--window-events", "6000", "--json", "--out"]
    local = _json([*base, tmp_path / "local"], capsys)
    remote = _json([*base, tmp_path / "remote", "--scheduler", cluster], capsys)
    assert remote == {**local, "file": remote["file"]} and len(local["clusters"]) == 4
    la, lb = np.load(tmp_path / "local" / "labels.npz"), np.load(tmp_path / "remote" / "labels.npz")
    assert sorted(la) == sorted(lb) == sorted(
        f"window_0000{k}{part}" for k in (0, 1)
        for part in ("", "_t_us", "_x", "_y", "_valid", "_same_as"))
    for key in la:
        assert np.array_equal(la[key], lb[key])
    assert ((tmp_path / "local" / "clusters.csv").read_text()
            == (tmp_path / "remote" / "clusters.csv").read_text())


def test_bos_on_cluster_matches_local_chunks(cluster, tmp_path_factory, tmp_path, capsys):
    from evmotion.sim.schlieren import simulate_schlieren, write_schlieren

    scene = tmp_path_factory.mktemp("bos") / "plume"
    write_schlieren(simulate_schlieren("plume", sensor_size=(48, 40), duration_s=3 / 120,
                                       seed=0), scene)
    base = ["bos", scene, "--iterations", "20", "--contrast-threshold", "0.2", "--json"]
    local = _json([*base, "--workers", "2", "--out", tmp_path / "local.h5"], capsys)
    remote = _json([*base, "--scheduler", cluster, "--out", tmp_path / "remote.h5"], capsys)
    assert local["n_intervals"] == remote["n_intervals"] >= 2
    a, b = _h5(tmp_path / "local.h5"), _h5(tmp_path / "remote.h5")
    for key in ("flow", "q", "p"):
        assert a[key].tobytes() == b[key].tobytes(), key
    # one chunk on the cluster (--workers 1) is the serial run (it had been taken for the
    # default, a chunk per cluster thread: probe BB)
    _json([*base, "--out", tmp_path / "serial.h5"], capsys)
    _json([*base, "--scheduler", cluster, "--workers", "1", "--out", tmp_path / "one.h5"],
          capsys)
    a, b = _h5(tmp_path / "serial.h5"), _h5(tmp_path / "one.h5")
    for key in ("flow", "q", "p"):
        assert a[key].tobytes() == b[key].tobytes(), key


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _one_line_error(argv, capsys) -> str:
    rc = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert rc != 0 and "Traceback" not in err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize("command", ["egomotion", "flow", "segment"])
def test_unreachable_scheduler_is_one_line(rec, tmp_path, capsys, monkeypatch, command):
    from evmotion.cli import options

    monkeypatch.setattr(options, "SCHEDULER_TIMEOUT_S", 0.5)
    address = f"tcp://127.0.0.1:{_closed_port()}"
    extra = {"egomotion": ["--warp", "translation", "--window-events", "3000", "--out",
                           tmp_path / "o"],
             "flow": ["--method", "multicm", "--out", tmp_path / "f.h5"],
             "segment": ["--warp", "translation", "--out", tmp_path / "s"]}[command]
    line = _one_line_error([command, rec, *extra, "--scheduler", address], capsys)
    assert f"cannot reach the Dask scheduler at {address}" in line
    # nothing written, not even a partial file (egomotion's journal of finished windows
    # was left empty, and refused the next run as an interrupted one)
    assert not list(tmp_path.glob("f.h5*")) and not list(tmp_path.glob("*/params.part"))


def test_scheduler_without_workers_is_one_line(rec, tmp_path, capsys, monkeypatch):
    from evmotion.cli import options

    monkeypatch.setattr(options, "SCHEDULER_TIMEOUT_S", 0.5)
    with distributed.LocalCluster(n_workers=0, processes=False, protocol="tcp",
                                  dashboard_address=":0") as empty:
        line = _one_line_error(["egomotion", rec, "--warp", "translation", "--window-events",
                                "3000", "--out", tmp_path / "o", "--scheduler",
                                empty.scheduler_address], capsys)
    assert "has no worker" in line and empty.scheduler_address in line


@pytest.mark.parametrize("address", ["8786", "tcp://host", "tcp://host:99999", "http://h:1",
                                     "tcp://a b:1"])
def test_malformed_address_rejected_at_parse_time(rec, tmp_path, capsys, address):
    line = _one_line_error(["egomotion", rec, "--warp", "translation", "--window-events",
                            "3000", "--out", tmp_path / "o", "--scheduler", address], capsys)
    assert "argument --scheduler" in line and repr(address) in line


def test_scheduler_rejected_where_it_cannot_apply(rec, tmp_path, capsys):
    address = "tcp://127.0.0.1:8786"  # never contacted: the options are checked first
    line = _one_line_error(["flow", rec, "--method", "triplet", "--out", tmp_path / "f.h5",
                            "--scheduler", address], capsys)
    assert "--scheduler" in line and "--method triplet" in line
    line = _one_line_error(["egomotion", rec, "--warp", "translation", "--window-events",
                            "3000", "--workers", "2", "--out", tmp_path / "o",
                            "--scheduler", address], capsys)
    assert "--workers 2 does not apply with --scheduler" in line
    line = _one_line_error(["flow", rec, "--method", "multicm", "--resume", "--out",
                            tmp_path / "f.h5", "--scheduler", address], capsys)
    assert "--scheduler" in line and "--resume" in line


def test_missing_dask_extra_is_one_line(rec, tmp_path, capsys, monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "distributed" else real(name, *a))
    line = _one_line_error(["segment", rec, "--warp", "translation", "--out", tmp_path / "s",
                            "--scheduler", "tcp://127.0.0.1:8786"], capsys)
    assert "argument --scheduler" in line and "pip install 'evmotion[dask]'" in line


def test_workers_with_malloc_trim_threshold_get_one_warning(rec, cluster, tmp_path, capsys,
                                                            monkeypatch):
    # the test cluster's workers are threads of this process: they see its environment
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "65536")
    assert main(["egomotion", str(rec), "--warp", "translation", "--window-events", "6000",
                 "--max-png", "0", "--out", str(tmp_path / "o"), "--scheduler", cluster]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines()
                if "MALLOC_TRIM_THRESHOLD_=65536" in line]
    assert len(warnings) == 1 and warnings[0].startswith("evmotion: warning:")
    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_")
    assert main(["egomotion", str(rec), "--warp", "translation", "--window-events", "6000",
                 "--max-png", "0", "--out", str(tmp_path / "o"), "--scheduler", cluster]) == 0
    assert "MALLOC_TRIM_THRESHOLD_" not in capsys.readouterr().err


def _flatten(tree: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def test_docs_worker_yaml_is_dask_configuration_and_what_the_benchmark_uses():
    """The worker.yaml of docs/cluster.rst, as a user copies it: every key is one Dask
    knows (a misspelt key would be ignored without a word), and it is the configuration
    benchmarks/bench_cluster.py measures."""
    import dask
    import yaml

    root = Path(__file__).resolve().parents[1]
    text = (root / "docs" / "cluster.rst").read_text()
    block = text.split("holds::\n\n", 1)[1].split("\n\n", 1)[0]
    settings = _flatten(yaml.safe_load(block))
    assert len(settings) >= 5, settings
    for key in settings:
        dask.config.get(key)  # raises KeyError for a key Dask does not have
    sys.path.insert(0, str(root / "benchmarks"))
    try:
        import bench_cluster
    finally:
        sys.path.remove(str(root / "benchmarks"))
    assert settings == bench_cluster.DOCS


@pytest.mark.parametrize("reply", [b"", b"HTTP/1.0 400 Bad request\r\n\r\n"])
def test_a_server_that_is_not_a_scheduler(reply):
    """An HTTP server at the address hung the Client past any timeout, or its reply was
    read as a frame of 3 EiB ('out of memory'); it is named in one line within the
    timeout (probe O)."""
    import threading
    import time

    from evmotion.errors import ParameterError
    from evmotion.parallel import connect_scheduler

    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)

    def serve():
        conn, _ = srv.accept()
        conn.sendall(reply)
        time.sleep(3)
        conn.close()

    threading.Thread(target=serve, daemon=True).start()
    t0 = time.perf_counter()
    with pytest.raises(ParameterError, match="not as a Dask scheduler"):
        connect_scheduler(f"tcp://127.0.0.1:{srv.getsockname()[1]}", timeout_s=1.0)
    assert time.perf_counter() - t0 < 3
    srv.close()

"""HDF5 attributes that cannot hang: fixed-length text from the writers, variable-length
attributes read in a child with a time limit (a corrupt global heap makes libhdf5 loop)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time

import h5py
import numpy as np
import pytest

from evmotion.errors import FormatError
from evmotion.events import EventArray
from evmotion.io import h5
from evmotion.io.h5attrs import read_attrs, read_attrs_many, text_attr


def _events() -> EventArray:
    rng = np.random.default_rng(3)
    n = 500
    return EventArray(rng.integers(0, 64, n), rng.integers(0, 48, n),
                      np.sort(rng.integers(0, 100_000, n)), rng.integers(0, 2, n), (48, 64))


def _vlen_file(path, corrupt: bool) -> None:
    """An events file whose text attributes are variable-length (as evmotion wrote them
    before), written before the events so the global heap is at its usual early place;
    ``corrupt`` sets the heap's free-space object size to 1, the byte change fuzzing
    found to send libhdf5 into an endless loop."""
    h5.write(path.with_suffix(".src.h5"), _events(), provenance={"tool": "test"})
    with h5py.File(path, "w") as out, h5py.File(path.with_suffix(".src.h5"), "r") as f:
        for k, v in f.attrs.items():
            out.attrs[k] = v.decode() if isinstance(v, bytes) else v
        f.copy("events", out)
    if corrupt:
        data = bytearray(path.read_bytes())
        at = data.find(b"GCOL")
        assert at > 0
        # header (16 bytes), then objects: index 2, refcount 2, reserved 4, size 8, data
        pos = at + 16
        while int.from_bytes(data[pos:pos + 2], "little") != 0:
            size = int.from_bytes(data[pos + 8:pos + 16], "little")
            pos += 16 + (size + 7) // 8 * 8
        data[pos + 8:pos + 16] = (1).to_bytes(8, "little")  # the free-space object
        path.write_bytes(bytes(data))


def test_writer_stores_text_fixed_length(tmp_path):
    path = tmp_path / "ev.h5"
    h5.write(path, _events(), provenance={"tool": "test"}, calibration={"K": [[1, 0, 0]]},
             attrs={"note": "hello", "extra": {"a": 1}})
    with h5py.File(path, "r") as f:
        for key in ("format", "provenance", "calibration", "note", "extra"):
            tid = f.attrs.get_id(key).get_type()
            assert isinstance(tid, h5py.h5t.TypeStringID) and not tid.is_variable_str(), key
        got = read_attrs(path, f)
    assert got["format"] == h5.FORMAT_NAME and got["note"] == "hello"
    assert h5.describe(path)["provenance"] == {"tool": "test"}


def test_read_attrs_decodes_every_kind(tmp_path):
    path = tmp_path / "a.h5"
    with h5py.File(path, "w") as f:
        f.attrs["fixed"] = text_attr("px/s é")
        f.attrs["vlen"] = "variable"
        f.attrs["names"] = np.array(["wx", "wy"], dtype=h5py.string_dtype())
        f.attrs["n"] = 7
        f.attrs["v"] = np.arange(3.0)
    with h5py.File(path, "r") as f:
        got = read_attrs(path, f)
        assert read_attrs(path, f, ("n", "missing")) == {"n": 7}
    assert got["fixed"] == "px/s é" and got["vlen"] == "variable" and got["n"] == 7
    assert list(got["names"]) == ["wx", "wy"]
    np.testing.assert_array_equal(got["v"], [0.0, 1.0, 2.0])


def test_variable_length_file_of_an_older_writer_reads(tmp_path):
    path = tmp_path / "old.h5"
    _vlen_file(path, corrupt=False)
    assert h5.describe(path)["provenance"] == {"tool": "test"}
    np.testing.assert_array_equal(h5.read(path).t, _events().t)


def test_corrupt_global_heap_gives_one_line_not_a_hang(tmp_path):
    # In a subprocess with a hard limit: before the guard, this describe never returned.
    path = tmp_path / "corrupt.h5"
    _vlen_file(path, corrupt=True)
    code = textwrap.dedent(f"""
        import evmotion.io as io
        from evmotion.errors import FormatError
        try:
            io.describe({str(path)!r})
        except FormatError as exc:
            print("ERROR", exc)
        """)
    t0 = time.perf_counter()
    try:
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             timeout=120)
    except subprocess.TimeoutExpired:
        pytest.fail("describe of a file with a corrupt global heap hung")
    assert out.returncode == 0, out.stderr
    line = out.stdout.strip()
    assert line.startswith("ERROR") and str(path) in line and "'provenance'" in line, line
    assert "\n" not in line
    assert time.perf_counter() - t0 < 60


def test_child_time_limit_is_reported(tmp_path):
    path = tmp_path / "corrupt.h5"
    _vlen_file(path, corrupt=True)
    with h5py.File(path, "r") as f, pytest.raises(FormatError, match="did not finish in 0.5 s"):
        read_attrs(path, f, ("provenance",), timeout_s=0.5)


def test_read_attrs_many_forks_once_for_all_objects(tmp_path, monkeypatch):
    import os

    path = tmp_path / "many.h5"
    with h5py.File(path, "w") as f:
        for name, unit in (("q", "1/s"), ("p", "px"), ("n", "count")):
            ds = f.create_dataset(name, data=np.zeros(3))
            ds.attrs["units"] = unit            # variable-length, as h5py writes a str
            ds.attrs["scale"] = 2.0
    forks = []
    real_fork = os.fork

    def counting_fork():
        pid = real_fork()
        if pid:
            forks.append(pid)
        return pid

    monkeypatch.setattr(os, "fork", counting_fork)
    with h5py.File(path, "r") as f:
        got = read_attrs_many(path, [f["q"], f["p"], f["n"]], ("units", "scale", "absent"))
    assert got == [{"units": "1/s", "scale": 2.0}, {"units": "px", "scale": 2.0},
                   {"units": "count", "scale": 2.0}]
    assert len(forks) == 1


@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), float("inf")])
def test_time_limit_must_be_a_finite_positive_number(tmp_path, bad):
    from evmotion.errors import ParameterError

    path = tmp_path / "t.h5"
    with h5py.File(path, "w") as f:
        f.attrs["a"] = "x"
    with h5py.File(path, "r") as f, pytest.raises(ParameterError, match="timeout_s must be"):
        read_attrs(path, f, timeout_s=bad)

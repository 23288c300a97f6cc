"""Fuzzing the readers with hypothesis: every corrupt file gets one line naming it.

Each seed (a cut of a real sample from ../shared/data, or a file of evmotion's own
writers, made in a temporary folder) is mutated by byte flips, inserts, deletes,
truncation, numeric header fields set to huge / negative / NaN / non-numeric values and
extreme binary integers; the case runs what ``evmotion info`` and the API do (detect,
describe, read, stream). Allowed outcomes: the file reads (streaming equals reading whole,
polarity 0/1, sensor within limits) or an EvmotionError on one line naming the file.

hypothesis rather than atheris: pure Python (no libFuzzer build, installs from a wheel
on every platform CI runs), it shrinks a failing case to its smallest mutation list, and
``derandomize=True`` makes the cases the same on every run, so CI is deterministic. The
on-demand run of 100,000 cases is ``benchmarks/bench_fuzz.py``.
"""

from __future__ import annotations

import re
import struct
import tracemalloc
import zlib

import numpy as np
import pytest

import evmotion.io as eio
import fuzzing
from _helpers import SHARED_DATA
from evmotion.errors import EventDataError, EvmotionError, FormatError, one_line
from evmotion.events import EventArray
from evmotion.io import aedat4, dat, evt3, h5, npy
from evmotion.io.guard import MAX_SENSOR_SIDE, guard_iter
from fuzz_cases import run_mutations

SEED_NAMES = ("evt3", "evt2", "evt21", "dat", "aedat2", "aedat3", "aedat4", "ecd", "mat",
              "h5", "h5_vlen", "dsec", "mvsec", "npy", "npz", "rosbag")
# seeds cut only from a real sample of ../shared/data (the others are made here when absent)
REAL_SEEDS = ("evt3", "evt2", "dat", "aedat2", "aedat4", "ecd")
# 16 seeds x 240 cases: about 3,800 cases, 15-40 s on one core
CASES_PER_SEED = 240


@pytest.fixture(scope="module")
def seeds(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fuzz_seeds")
    shared = SHARED_DATA if SHARED_DATA.is_dir() else None
    found, missing = fuzzing.make_seeds(folder, shared)
    return {s.name: s for s in found}, missing


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.realdata)
                                  if n in REAL_SEEDS else n for n in SEED_NAMES])
def test_corrupt_files_give_one_line_naming_the_file(name, seeds, tmp_path_factory):
    found, missing = seeds
    if name not in found:
        pytest.skip(f"no seed for {name}: {missing.get(name, 'not made')}")
    seed = found[name]
    assert fuzzing.run_case(seed.path, seed.fmt).kind == "ok", "the unmutated seed must read"
    out_dir = tmp_path_factory.mktemp(f"fuzz_{name}")
    seen = {"cases": 0, "ok": 0}

    def check(path, ops):
        out = fuzzing.run_case(path, seed.fmt, timeout_s=20)
        seen["cases"] += 1
        seen["ok"] += out.kind == "ok"
        assert out.kind not in fuzzing.FINDINGS, (out.kind, out.step, out.exc_type,
                                                  out.message, ops)

    run_mutations(seed, CASES_PER_SEED, out_dir, check)
    # the mutations must reach the readers' error paths, not only leave files readable
    assert seen["cases"] >= CASES_PER_SEED // 2 and seen["ok"] < seen["cases"]


@pytest.mark.realdata
@pytest.mark.parametrize("name", ["evt3", "evt2", "dat"])
def test_numpy_and_numba_decoders_agree_on_corrupt_files(name, seeds, tmp_path_factory,
                                                          monkeypatch):
    """A small file is decoded by numpy, a large one by the numba kernels (binary.
    PLAIN_WORDS): on every mutated copy of a seed both give the same events, or the same
    one-line error."""
    from evmotion.io import binary

    found, missing = seeds
    if name not in found:
        pytest.skip(f"no seed for {name}: {missing.get(name, 'not made')}")
    seed = found[name]
    out_dir = tmp_path_factory.mktemp(f"fuzz_decoders_{name}")
    small = binary.PLAIN_WORDS

    def outcome(path, limit):
        monkeypatch.setattr(binary, "PLAIN_WORDS", limit)
        try:
            ev = eio.read_events(path, format=seed.fmt)
        except EvmotionError as exc:
            return str(exc)
        return ev.sensor_size, ev.x, ev.y, ev.t, ev.p

    def check(path, ops):
        plain, kernel = outcome(path, small), outcome(path, -1)
        if isinstance(plain, str) or isinstance(kernel, str):
            assert plain == kernel, ops
            return
        assert plain[0] == kernel[0], ops
        for a, b in zip(plain[1:], kernel[1:], strict=True):
            np.testing.assert_array_equal(a, b, err_msg=str(ops))

    run_mutations(seed, CASES_PER_SEED // 2, out_dir, check)


def test_mutations_are_deterministic():
    data = bytes(range(256)) * 4
    ops = [("flip", 10, 3, 0), ("insert", 7, 5, 9), ("field", 0, 1, 2), ("int", 9, 2, 10)]
    assert fuzzing.mutate(data, 64, ops) == fuzzing.mutate(data, 64, ops)
    assert fuzzing.mutate(data, 64, ops) != data
    assert fuzzing.mutate(b"% Height 180\n", 13, [("field", 0, 0, 0)]) == b"% Height 99999999\n"


# ------------------------------------------------------------- regression: each finding
def _events(n=500, size=(180, 240), seed=0) -> EventArray:
    rng = np.random.default_rng(seed)
    return EventArray(x=rng.integers(0, size[1], n), y=rng.integers(0, size[0], n),
                      t=np.sort(rng.integers(0, 100_000, n)), p=rng.integers(0, 2, n),
                      sensor_size=size)


def _one_line_naming(exc: BaseException, path) -> None:
    msg = str(exc)
    assert str(path) in msg and "\n" not in msg, msg
    assert isinstance(exc, EvmotionError)


def _read_fails_without_allocating(path, match: str) -> None:
    """``read_events(path)`` raises a one-line FormatError naming the file and matching
    ``match``, with a Python allocation peak under 50 MB on the way."""
    tracemalloc.start()
    try:
        with pytest.raises(FormatError, match=match) as e:
            eio.read_events(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    _one_line_naming(e.value, path)
    assert peak < 50e6, peak


def test_dat_huge_height_is_rejected_before_allocating(tmp_path):
    path = tmp_path / "tall.dat"
    dat.write(path, _events())
    path.write_bytes(path.read_bytes().replace(b"% Height 180", b"% Height 99999999"))
    for call in (lambda: eio.read_events(path), lambda: eio.describe(path),
                 lambda: list(eio.iter_events(path, 100))):
        with pytest.raises(FormatError, match=rf"99999999.*1\.\.{MAX_SENSOR_SIDE}") as e:
            call()
        _one_line_naming(e.value, path)


def test_polarity_255_is_an_error_wherever_events_are_built(tmp_path):
    with pytest.raises(EventDataError, match="p=255"):
        EventArray(x=[1, 2], y=[1, 2], t=[1, 2], p=np.array([1, 255], np.uint8),
                   sensor_size=(4, 4))
    with pytest.raises(EventDataError, match="p=255"):  # even unvalidated
        EventArray(x=[1], y=[1], t=[1], p=np.array([255], np.uint8), sensor_size=(4, 4),
                   validate=False)
    for bad in (np.array([2], np.int64), np.array([0.5]), np.array([np.nan])):
        with pytest.raises(EventDataError, match="polarity"):
            EventArray(x=[1], y=[1], t=[1], p=bad, sensor_size=(4, 4))
    # -1, 0 and +1 together are no polarity convention (read as 0, 0, 1 unsaid, probe BQ)
    with pytest.raises(EventDataError, match="neither 0/1 nor -1/\\+1"):
        EventArray(x=[1, 1, 1], y=[1, 1, 1], t=[1, 2, 3], p=np.array([-1, 0, 1]),
                   sensor_size=(4, 4))
    assert EventArray(x=[1], y=[1], t=[1], p=np.array([True]), sensor_size=(4, 4)).p[0] == 1
    # a file whose polarity bytes read 255 (the evmotion HDF5 stores them as they are)
    path = tmp_path / "p255.h5"
    h5.write(path, _events())
    import h5py

    with h5py.File(path, "r+") as f:
        f["events/p"][7] = 255
    with pytest.raises(FormatError, match=r"p=255") as e:
        eio.read_events(path)
    _one_line_naming(e.value, path)


@pytest.mark.parametrize("offset", ["99999999999999999999999", str(1 << 62),
                                    str(-(1 << 62)), "abc"])
def test_evt3_time_offset_out_of_range(tmp_path, offset):
    path = tmp_path / "off.raw"
    evt3.write(path, _events())
    data = path.read_bytes().replace(b"% end\n", f"% evmotion_time_offset_us {offset}\n"
                                                 "% end\n".encode(), 1)
    path.write_bytes(data)
    with pytest.raises(FormatError, match="evmotion_time_offset_us") as e:
        eio.read_events(path)
    _one_line_naming(e.value, path)


def test_aedat4_non_numeric_size(tmp_path):
    path = tmp_path / "bad.aedat4"
    aedat4.write(path, _events(), compression="none")
    data = path.read_bytes()
    good = b'<attr key="sizeY" type="int">180</attr>'
    assert good in data
    path.write_bytes(data.replace(good, good.replace(b"180", b"1a0")))
    for call in (lambda: eio.read_events(path), lambda: eio.describe(path)):
        with pytest.raises(FormatError, match=r"sizeY.*'1a0'") as e:
            call()
        _one_line_naming(e.value, path)


def test_npz_bad_crc(tmp_path):
    path = tmp_path / "ev.npz"
    npy.write(path, _events())
    data = bytearray(path.read_bytes())
    at = data.index(b"x.npy") + 200  # inside the stored (uncompressed) member 'x'
    data[at] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(FormatError, match="BadZipFile") as e:
        eio.read_events(path)
    _one_line_naming(e.value, path)


def test_mat_corrupt_zlib_stream(tmp_path):
    import scipy.io

    path = tmp_path / "ev.mat"
    ev = _events()
    scipy.io.savemat(path, {"seq": np.stack([ev.t, ev.x, ev.y, ev.p], axis=1).astype(float)},
                     do_compression=True)
    data = bytearray(path.read_bytes())
    data[200] ^= 0x55  # inside the deflate stream of 'seq'
    path.write_bytes(bytes(data))
    with pytest.raises(FormatError) as e:
        eio.read_events(path)
    _one_line_naming(e.value, path)
    assert isinstance(e.value.__cause__, zlib.error)


def test_hdf5_one_byte_in_the_shape_costs_no_memory(tmp_path):
    import h5py

    ev = _events(3000)
    path = tmp_path / "ev.h5"
    h5.write(path, ev)
    data = path.read_bytes()
    n = struct.pack("<Q", 3000)
    for m in re.finditer(re.escape(n), data):
        bad = bytearray(data)
        bad[m.start() + 4] = 1  # one byte: 3000 rows become 3000 + 2**32
        path.write_bytes(bytes(bad))
        try:
            with h5py.File(path, "r") as f:
                if f["events/t"].shape[0] != 3000:
                    break
        except (OSError, KeyError, RuntimeError):
            continue
    else:
        pytest.fail("no byte of the file holds the shape of events/t")
    _read_fails_without_allocating(path, "events/.*chunks")


def test_errors_from_the_container_name_the_file(tmp_path):
    path = tmp_path / "unsorted.npz"
    np.savez(path, x=np.array([1, 2]), y=np.array([1, 2]), t=np.array([5, 1]),
             p=np.array([0, 1]), sensor_size=np.array([4, 4]))
    with pytest.raises(FormatError, match="not sorted") as e:
        eio.read_events(path)
    _one_line_naming(e.value, path)


def test_format_error_is_one_line():
    e = FormatError("/a/b.raw", "bad header line '% x\r\ny\x00z'" + "w" * 5000, "hint\nhere")
    text = str(e)
    assert "\n" not in text and "\r" not in text and "\x00" not in text
    assert text.startswith("/a/b.raw: bad header line '% x y z'") and len(text) < 700
    assert one_line("a\n\n b") == "a b"


def test_guarded_iterator_names_the_file_and_closes(tmp_path):
    closed = []

    def chunks(path, n):
        try:
            yield 1
            raise KeyError("Unable to open object (bad symbol table)")
        finally:
            closed.append(True)

    it = guard_iter(chunks, "h5")(tmp_path / "f.h5", 3)
    assert next(it) == 1
    with pytest.raises(FormatError, match=r"f\.h5: cannot read as h5: KeyError"):
        next(it)
    assert closed
    early = guard_iter(chunks, "h5")(tmp_path / "g.h5", 3)
    next(early)
    early.close()
    assert len(closed) == 2


def test_cli_info_on_a_corrupt_file_prints_one_line(tmp_path, capsys):
    from evmotion.cli import main

    path = tmp_path / "cut.h5"
    h5.write(path, _events(3000))
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2])
    assert main(["info", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("evmotion info: error:") and str(path) in err and "\n" not in err


def test_calibration_of_a_corrupt_hdf5_names_the_file(tmp_path):
    path = tmp_path / "cal.h5"
    h5.write(path, _events(), calibration={"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]})
    import h5py

    with h5py.File(path, "r+") as f:
        f.attrs["calibration"] = "{not json"
    with pytest.raises(FormatError) as e:
        eio.read_calibration(path)
    _one_line_naming(e.value, path)


def test_npy_header_that_is_not_python_syntax(tmp_path):
    # case 4348 of bench_fuzz's npy seed: one flipped header byte made numpy's header
    # parser raise SyntaxError, which the guard let through as if it were a bug
    found, _ = fuzzing.make_seeds(tmp_path / "seeds", None)
    seed = next(s for s in found if s.name == "npy")
    path = fuzzing.write_case(seed, [("flip", 11242098, 31178, 24745)], tmp_path / "case")
    for call in (lambda: eio.read_events(path), lambda: eio.describe(path)):
        with pytest.raises(FormatError, match="SyntaxError") as e:
            call()
        _one_line_naming(e.value, path)


def test_mat_dimension_beyond_the_file_is_rejected_before_loading(tmp_path):
    import scipy.io

    path = tmp_path / "ev.mat"
    ev = _events(100)
    seq = np.stack([ev.t, ev.x, ev.y, ev.p], axis=1).astype(float)
    scipy.io.savemat(path, {"seq": seq})
    data = path.read_bytes()
    dims = struct.pack("<iiii", 5, 8, 100, 4)  # miINT32 dims tag: 100 x 4
    assert dims in data
    path.write_bytes(data.replace(dims, struct.pack("<iiii", 5, 8, 1 << 30, 4)))
    _read_fails_without_allocating(path, r"declares shape \(1073741824, 4\)")


def test_blosc_chunk_header_checked_before_decompressing(tmp_path):
    import h5py
    import hdf5plugin  # noqa: F401  (registers the Blosc filter)

    path = tmp_path / "ev.h5"
    h5.write(path, _events(3000))
    with h5py.File(path, "r") as f:
        pl = f["events/t"].id.get_create_plist()
        if pl.get_filter(pl.get_nfilters() - 1)[0] != 32001:
            pytest.skip("events not Blosc-compressed")
        offset = f["events/t"].id.get_chunk_info(0).byte_offset
    data = bytearray(path.read_bytes())
    data[offset + 4:offset + 8] = struct.pack("<I", 0xFFFFFFF0)  # nbytes: ~4 GiB
    path.write_bytes(bytes(data))
    with pytest.raises(FormatError, match=r"events/t.*Blosc chunk.*4294967280") as e:
        eio.read_events(path)
    _one_line_naming(e.value, path)

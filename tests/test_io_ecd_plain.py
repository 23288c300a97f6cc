"""ECD text without numba: small plain texts are parsed by numpy to exactly the kernel's
integers; anything else goes to the kernel (which reports bad lines)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from evmotion.errors import FormatError
from evmotion.io import ecd


def _kernel(data: bytes, monkeypatch):
    with monkeypatch.context() as m:
        m.setattr(ecd, "PLAIN_TEXT_BYTES", -1)
        return ecd.parse_text(data)


def _random_text(rng, n: int) -> bytes:
    lines = []
    for _ in range(n):
        sec = int(rng.integers(0, 5000))
        nd = int(rng.integers(0, 13))  # 0..12 decimals: the kernel keeps 9
        frac = "".join(str(d) for d in rng.integers(0, 10, nd))
        t = f"{sec}.{frac}" if nd or rng.random() < 0.3 else str(sec)  # "5." and "5" too
        if rng.random() < 0.05:  # exact halves of a microsecond
            t = f"{sec}.{int(rng.integers(0, 10**6)):06d}5"
        sep = rng.choice([" ", "  ", "\t", " \t "])
        cols = [t, str(rng.integers(0, 1280)), str(rng.integers(0, 720)),
                str(rng.integers(0, 2))]
        end = rng.choice(["\n", "\r\n", " \n"])
        lines.append(sep.join(cols) + end)
        if rng.random() < 0.05:
            lines.append(rng.choice(["\n", "   \n", "\r\n"]))
    text = "".join(lines)
    return (text.rstrip("\n") if rng.random() < 0.5 else text).encode()


@pytest.mark.parametrize("seed", range(6))
def test_plain_parse_equals_the_kernel(seed, monkeypatch):
    data = _random_text(np.random.default_rng(seed), 2000)
    plain = ecd._parse_plain(data)
    assert plain is not None
    for got, ref in zip(plain, _kernel(data, monkeypatch), strict=True):
        assert got.dtype == np.int64
        np.testing.assert_array_equal(got, ref)
    for got, ref in zip(ecd.parse_text(data), plain, strict=True):
        np.testing.assert_array_equal(got, ref)


def test_plain_parse_rounds_like_the_kernel(monkeypatch):
    data = (b"1.0000005 1 2 1\n1.0000004999 1 2 1\n2. 3 4 0\n\n  \n7 1 1 1\n"
            b"0.123456789123 1 2 1\r\n0.0000015\r1 1 0")  # a lone CR separates, as in the kernel
    t = ecd._parse_plain(data)[2]
    assert t.tolist() == [1_000_001, 1_000_000, 2_000_000, 7_000_000, 123_457, 2]
    np.testing.assert_array_equal(t, _kernel(data, monkeypatch)[2])


@pytest.mark.parametrize("text", [b"1,2,3,1\n", b"0.5 -1 2 1\n", b".5 1 2 1\n",
                                  b"1.2.3 1 2 1\n", b"1 2 3\n", b"1 2 3 4 5\n",
                                  b"0.5 1.5 2 1\n", b"1e-3 1 2 1\n",
                                  b"1234567890123456789 1 2 1\n"])
def test_other_texts_go_to_the_kernel(text, monkeypatch, tmp_path):
    assert ecd._parse_plain(text) is None
    path = tmp_path / "events.txt"  # the kernel's error names the file's line
    path.write_bytes(text)
    try:
        with monkeypatch.context() as m:
            m.setattr(ecd, "PLAIN_TEXT_BYTES", -1)
            ref = ecd.parse_text(text, path)
    except FormatError as exc:
        with pytest.raises(FormatError) as got:
            ecd.parse_text(text, path)
        assert str(got.value) == str(exc)
    else:
        for got, r in zip(ecd.parse_text(text, path), ref, strict=True):
            np.testing.assert_array_equal(got, r)


def test_empty_and_blank_texts():
    for text in (b"", b"\n\n", b"  \r\n"):
        out = ecd.parse_text(text)
        assert [a.size for a in out] == [0, 0, 0, 0]


def test_a_small_ecd_folder_is_read_without_numba(tmp_path):
    # format detection imports every reader; their kernels load numba on first use only
    (tmp_path / "events.txt").write_bytes(b"0.000001 3 4 1\n0.5 5 6 0\n")
    code = ("import sys; from evmotion.io import read_events; ev = read_events(sys.argv[1]); "
            "print(len(ev), 'numba' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True,
                         text=True, check=True).stdout.split()
    assert out == ["2", "False"]


def test_lazy_kernels_calling_lazy_kernels():
    from evmotion.events import EventArray

    # ecd's text writer kernel calls another kernel of its module
    ev = EventArray(x=[3, 10], y=[4, 0], t=[1_500_000, 2_000_001], p=[1, 0],
                    sensor_size=(20, 20))
    text = ecd.format_text(ev)
    assert text == b"1.500000 3 4 1\n2.000001 10 0 0\n"
    assert [a.tolist() for a in ecd.parse_text(text)] == [[3, 10], [4, 0],
                                                          [1_500_000, 2_000_001], [1, 0]]


def test_bad_line_in_bytes_names_the_line_without_a_file():
    # in-memory text (no file to reopen for the line count): still one FormatError
    with pytest.raises(FormatError, match=r"<bytes>: line 3 has 3 column"):
        ecd.parse_text(b"0.1 1 2 1\n0.2 1 3 0\n0.3 1 3\n")

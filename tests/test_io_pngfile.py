"""evmotion.io.pngfile: the package's one PNG reader/writer, checked against OpenCV's
decoder and on corrupt files."""

from __future__ import annotations

import numpy as np
import pytest

from evmotion.errors import FormatError, ParameterError
from evmotion.io.pngfile import png_header, read_png, write_png


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("planes", [None, 1, 2, 3, 4])
def test_round_trip_and_opencv_agree(tmp_path, dtype, planes):
    cv2 = pytest.importorskip("cv2")
    rng = np.random.default_rng(planes or 0)
    shape = (7, 9) if planes is None else (7, 9, planes)
    img = rng.integers(0, np.iinfo(dtype).max, shape, endpoint=True).astype(dtype)
    path = tmp_path / "a.png"
    write_png(path, img)
    got, info = read_png(path)
    assert got.dtype == dtype and info["bitdepth"] == (16 if dtype == np.uint16 else 8)
    np.testing.assert_array_equal(got, img.reshape(7, 9, -1))
    assert png_header(path) == ((7, 9), info["bitdepth"])
    ref = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if planes in (3, 4):
        ref = ref[..., [2, 1, 0, 3][:planes]]  # OpenCV gives BGR(A)
    if planes != 2:  # OpenCV expands grey + alpha to BGRA
        np.testing.assert_array_equal(ref.reshape(7, 9, -1), img.reshape(7, 9, -1))


def test_write_is_atomic_and_checks_input(tmp_path):
    with pytest.raises(ParameterError, match="uint8 or uint16"):
        write_png(tmp_path / "f.png", np.zeros((3, 3), np.float32))
    with pytest.raises(ParameterError, match=r"\(H, W\)"):
        write_png(tmp_path / "f.png", np.zeros((3, 3, 5), np.uint8))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("cut", [0, 8, 40, -20])
def test_corrupt_file_one_line_naming_it(tmp_path, cut):
    good = tmp_path / "good.png"
    write_png(good, np.arange(64 * 64, dtype=np.uint16).reshape(64, 64))
    bad = tmp_path / "bad.png"
    data = good.read_bytes()
    bad.write_bytes(data[:cut] if cut > 0 else data[:cut] + b"\0" * 12 if cut else b"")
    with pytest.raises(FormatError, match="cannot read PNG") as e:
        read_png(bad)
    assert "bad.png" in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(FormatError, match="decode DSEC"):
        read_png(bad, what="cannot decode DSEC flow PNG")

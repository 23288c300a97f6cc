"""Co-captured frames: readers against files of known content, AEDAT4 frames of the shared
recording, the published BOS layout, image folders with timestamps, and bad input."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import png
import pytest

from evmotion.errors import FormatError, ParameterError
from evmotion.io import describe
from evmotion.io.frames import Frames, describe_frames, find_frames, read_frames


def _png(path, img):
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        png.Writer(width=img.shape[1], height=img.shape[0], greyscale=True,
                   bitdepth=16 if img.dtype == np.uint16 else 8).write(fh, img)


def _images(n=3, h=6, w=7, dtype=np.uint8, seed=0):
    hi = 65535 if dtype == np.uint16 else 255
    return np.random.default_rng(seed).integers(0, hi + 1, (n, h, w)).astype(dtype)


def _ecd(folder, imgs, times):
    lines = []
    for i, (t, img) in enumerate(zip(times, imgs, strict=True)):
        name = f"images/frame_{i:08d}.png"
        _png(folder / name, img)
        lines.append(f"{t} {name}\n")
    (folder / "images.txt").write_text("".join(lines))


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_ecd_folder(tmp_path, dtype):
    imgs = _images(dtype=dtype)
    _ecd(tmp_path, imgs, ["0.5", "0.508333", "0.516667"])
    fr = read_frames(tmp_path)
    np.testing.assert_array_equal(fr.images, imgs)
    assert fr.images.dtype == dtype and fr.bit_depth == (16 if dtype == np.uint16 else 8)
    assert fr.t.tolist() == [500_000, 508_333, 516_667]
    assert fr.sensor_size == (6, 7) and fr.fps == pytest.approx(120.0, rel=1e-4)
    assert read_frames(tmp_path / "images.txt").t.tolist() == fr.t.tolist()
    np.testing.assert_allclose(fr.as_float().max(), imgs.max() / (2 ** fr.bit_depth - 1))
    d = describe_frames(tmp_path)
    assert d == {"count": 3, "size": "7x6", "bit_depth": fr.bit_depth, "t_first_us": 500_000,
                 "t_last_us": 516_667, "span_s": pytest.approx(0.016667),
                 "fps": pytest.approx(120.0, rel=1e-3)}


def test_colour_png_is_averaged(tmp_path):
    rgb = np.zeros((4, 5, 3), np.uint8)
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 30, 60, 91
    path = tmp_path / "images" / "a.png"
    path.parent.mkdir()
    with open(path, "wb") as fh:
        png.Writer(width=5, height=4, greyscale=False).write(fh, rgb.reshape(4, 15))
    (tmp_path / "images.txt").write_text("0.0 images/a.png\n")
    fr = read_frames(tmp_path)
    assert fr.images.shape == (1, 4, 5) and np.all(fr.images == 60)


def test_image_folder_with_timestamps(tmp_path):
    imgs = _images(4)
    for i, img in enumerate(imgs):
        _png(tmp_path / f"img_{i:03d}.png", img)
    (tmp_path / "timestamps.txt").write_text("# ms\n10\n20\n30.5\n40\n")
    fr = read_frames(tmp_path, time_unit="ms")
    np.testing.assert_array_equal(fr.images, imgs)
    assert fr.t.tolist() == [10_000, 20_000, 30_500, 40_000]
    assert find_frames(tmp_path) == "folder"
    # default unit: seconds; explicit timestamps file elsewhere, 't path' lines
    other = tmp_path / "meta" / "stamps.txt"
    other.parent.mkdir()
    other.write_text("".join(f"{t} ../img_{i:03d}.png\n" for i, t in
                             enumerate([1.0, 1.5, 2.0, 2.5])))
    fr2 = read_frames(tmp_path, timestamps=other)
    assert fr2.t.tolist() == [1_000_000, 1_500_000, 2_000_000, 2_500_000]
    np.testing.assert_array_equal(fr2.images, imgs)
    d = describe_frames(tmp_path, time_unit="ms")
    assert d["count"] == 4 and d["size"] == "7x6"
    info = describe(tmp_path)
    assert info["format"] == "frames" and info["frames_info"]["count"] == 4


def test_images_subfolder_and_us(tmp_path):
    imgs = _images(2)
    for i, img in enumerate(imgs):
        _png(tmp_path / "images" / f"{i}.png", img)
    (tmp_path / "times.txt").write_text("100\n8433\n")
    fr = read_frames(tmp_path, time_unit="us")
    assert fr.t.tolist() == [100, 8433]


def _ccs(root, imgs, trig_text, homography=None):
    for i, img in enumerate(imgs):
        _png(root / "basler_0" / "frames" / f"{i:06d}.png", img)
    (root / "prophesee_0").mkdir(parents=True, exist_ok=True)
    (root / "prophesee_0" / "trigger_events.txt").write_text(trig_text)
    if homography is not None:
        np.savetxt(root / "homography.txt", homography)


def test_published_bos_layout(tmp_path):
    imgs = _images(3, h=10, w=12)
    # Metavision trigger log 't id p': a frame per rising edge (p = 1)
    trig = "1000 0 1\n3000 0 0\n9333 0 1\n11000 0 0\n17667 0 1\n19000 0 0\n"
    _ccs(tmp_path / "seq", imgs, trig)
    assert find_frames(tmp_path / "seq") == "ccs"
    fr = read_frames(tmp_path / "seq")
    assert fr.t.tolist() == [1000, 9333, 17667]
    np.testing.assert_array_equal(fr.images, imgs)
    # newer Metavision: 'p,id,t'; homography shifts the frame 2 px right, 1 down onto a
    # smaller event sensor
    trig2 = "1,0,1000\n0,0,3000\n1,0,9333\n0,0,11000\n1,0,17667\n"
    H = np.array([[1.0, 0, 2], [0, 1, 1], [0, 0, 1]])
    _ccs(tmp_path / "seq2", imgs, trig2, H)
    fr2 = read_frames(tmp_path / "seq2", sensor_size=(8, 9))
    assert fr2.t.tolist() == [1000, 9333, 17667] and fr2.images.shape == (3, 8, 9)
    np.testing.assert_array_equal(fr2.images[:, 1:, 2:], imgs[:, :7, :7])
    assert describe_frames(tmp_path / "seq2", sensor_size=(8, 9))["size"] == "9x8"
    fr3 = read_frames(tmp_path / "seq2", warp=False)
    np.testing.assert_array_equal(fr3.images, imgs)


def test_aedat4_frames(shared_data):
    path = shared_data / "formats" / "davis346.aedat4"
    fr = read_frames(path)
    assert isinstance(fr, Frames) and len(fr) == 59
    assert fr.images.shape == (59, 260, 346) and fr.images.dtype == np.uint8
    assert np.all(np.diff(fr.t) > 0) and fr.images[10].std() > 1
    assert fr.exposure_start.shape == (59,) and np.all(fr.exposure_end >= fr.exposure_start)
    d = describe_frames(path)
    assert d["count"] == 59 and d["size"] == "346x260" and d["bit_depth"] == 8
    assert describe(path)["frames_info"]["count"] == 59
    out = subprocess.run([sys.executable, "-m", "evmotion", "info", str(path), "--json"],
                         capture_output=True, text=True, check=True)
    assert json.loads(out.stdout)["frames_info"]["count"] == 59


def test_recording_without_frames(shared_data):
    with pytest.raises(FormatError, match="holds no APS frames"):
        read_frames(shared_data / "formats" / "gen4.dat")
    assert describe_frames(shared_data / "formats" / "gen4.dat") is None


# ---------------------------------------------------------------------------------------
# bad input: one line naming the file


def _one_line(exc_info, name):
    msg = str(exc_info.value)
    assert "\n" not in msg and name in msg, msg


def test_missing_frame_file(tmp_path):
    _ecd(tmp_path, _images(2), ["0.0", "0.1"])
    (tmp_path / "images" / "frame_00000001.png").unlink()
    with pytest.raises(FormatError, match="missing frame file") as e:
        read_frames(tmp_path)
    _one_line(e, "images.txt")


def test_bare_names_of_files_in_images_are_found_there(tmp_path):
    # probe BN: images.txt naming 'frame_00000000.png' for images/frame_00000000.png (a
    # tool writing the ECD layout without the folder) was "a missing frame file", and the
    # events' sensor size came from their largest coordinates, not the frames
    imgs = _images(2)
    _ecd(tmp_path, imgs, ["0.0", "0.1"])
    (tmp_path / "images.txt").write_text("0.0 frame_00000000.png\n0.1 frame_00000001.png\n")
    (tmp_path / "events.txt").write_text("0.01 1 2 1\n0.05 3 4 0\n")
    fr = read_frames(tmp_path)
    np.testing.assert_array_equal(fr.images, imgs)
    assert describe(tmp_path)["sensor_size"] == (6, 7)
    # a stray copy of one frame beside the list: the others are still found (probe BR)
    (tmp_path / "frame_00000000.png").write_bytes(
        (tmp_path / "images" / "frame_00000000.png").read_bytes())
    np.testing.assert_array_equal(read_frames(tmp_path).images, imgs)


@pytest.mark.parametrize("second, match", [(np.zeros((5, 5), np.uint8), "7x6"),
                                           (np.zeros((6, 7), np.uint16), "16-bit")],
                         ids=["different_sizes", "mixed_bit_depths"])
def test_second_image_unlike_the_first(tmp_path, second, match):
    _ecd(tmp_path, _images(2), ["0.0", "0.1"])
    _png(tmp_path / "images" / "frame_00000001.png", second)
    with pytest.raises(FormatError, match=match) as e:
        read_frames(tmp_path)
    _one_line(e, "frame_00000001.png")


@pytest.mark.parametrize("times, what", [(["0.1", "0.1"], "duplicate"),
                                         (["0.1", "inf"], "line 2: time 'inf' is not a finite"),
                                         (["nan", "0.1"], "line 1: time 'nan'"),
                                         (["0.1", "1e400"], "line 2: time '1e400'"),
                                         (["0.1", "1e30"], "line 2: time '1e30'"),
                                         (["0.1", "soon"], "line 2: 'soon' is not a time")])
def test_bad_timestamps(tmp_path, times, what):
    """Every time field that is not a finite number within +-2^62 us is one line naming
    the file and the line, in images.txt and in a timestamps file alike (an infinite one
    used to raise OverflowError, and one past int64 to wrap silently)."""
    _ecd(tmp_path, _images(2), times)
    with pytest.raises(FormatError, match=what) as e:
        read_frames(tmp_path)
    _one_line(e, "images.txt")
    folder = tmp_path / "folder"
    for i, img in enumerate(_images(2)):
        _png(folder / f"{i}.png", img)
    (folder / "timestamps.txt").write_text("".join(f"{t}\n" for t in times))
    with pytest.raises(FormatError, match=what) as e:
        read_frames(folder)
    _one_line(e, "timestamps.txt")


def test_t_path_lines_out_of_time_order_are_read_in_time_order(tmp_path):
    """Each 't path' line carries its own time: lines out of order were refused with no fix
    named (probe BC). Times alone, one a line in name order, are still refused."""
    from evmotion.errors import EvmotionWarning

    imgs = _images(3)
    _ecd(tmp_path, imgs, ["0.2", "0.0", "0.1"])
    with pytest.warns(EvmotionWarning, match="out of time order .*read in time order"):
        fr = read_frames(tmp_path)
    assert fr.t.tolist() == [0, 100_000, 200_000]
    np.testing.assert_array_equal(fr.images, imgs[[1, 2, 0]])
    folder = tmp_path / "folder"
    for i, img in enumerate(imgs):
        _png(folder / f"{i}.png", img)
    (folder / "timestamps.txt").write_text("".join(f"{t} {i}.png\n" for i, t in
                                                   enumerate(["0.2", "0.0", "0.1"])))
    with pytest.warns(EvmotionWarning, match="out of time order"):
        assert read_frames(folder).t.tolist() == [0, 100_000, 200_000]
    (folder / "timestamps.txt").write_text("0.2\n0.0\n0.1\n")
    with pytest.raises(FormatError, match="unsorted frame timestamps") as e:
        read_frames(folder)
    _one_line(e, "timestamps.txt")


def test_count_mismatch(tmp_path):
    for i, img in enumerate(_images(3)):
        _png(tmp_path / f"{i}.png", img)
    (tmp_path / "timestamps.txt").write_text("0\n1\n")
    with pytest.raises(FormatError, match="2 timestamps but 3 images") as e:
        read_frames(tmp_path)
    _one_line(e, "timestamps.txt")
    _ccs(tmp_path / "seq", _images(2), "1000 0 1\n2000 0 1\n3000 0 1\n")
    with pytest.raises(FormatError, match="3 rising trigger edges but 2 images") as e:
        read_frames(tmp_path / "seq")
    _one_line(e, "trigger_events.txt")


def test_corrupt_png(tmp_path):
    _ecd(tmp_path, _images(2), ["0.0", "0.1"])
    f = tmp_path / "images" / "frame_00000001.png"
    whole = f.read_bytes()
    f.write_bytes(whole[:40])
    with pytest.raises(FormatError, match=r"corrupt PNG: truncated at byte 33 \(no IEND") as e:
        read_frames(tmp_path)
    _one_line(e, "frame_00000001.png")
    f.write_bytes(b"not a png at all")
    with pytest.raises(FormatError, match="not a PNG file"):
        read_frames(tmp_path)
    # probe AO: a header declaring 100000 x 100000 px (valid CRC) was a cv2.error
    # traceback; a flipped bit, OpenCV's own log line before ours
    import struct
    import zlib

    ihdr = b"IHDR" + struct.pack(">II", 100_000, 100_000) + whole[24:29]
    f.write_bytes(whole[:12] + ihdr + struct.pack(">I", zlib.crc32(ihdr)) + whole[33:])
    with pytest.raises(FormatError, match=r"declares 100000x100000 px .*\(1-16384 px"):
        read_frames(tmp_path)
    flipped = bytearray(whole)
    flipped[45] ^= 4  # in the image data
    f.write_bytes(bytes(flipped))
    with pytest.raises(FormatError, match="chunk IDAT at byte 33 fails its CRC"):
        read_frames(tmp_path)


def test_a_png_with_fewer_rows_than_declared_is_named(tmp_path):
    # probe AO: a ValueError traceback from the reshape of pypng's rows
    import struct
    import zlib

    from evmotion.io.pngfile import read_png

    path = tmp_path / "f.png"
    _png(path, np.zeros((8, 6), np.uint8))
    data = path.read_bytes()
    ihdr = b"IHDR" + struct.pack(">II", 6, 16) + data[24:29]  # 16 rows declared, 8 stored
    path.write_bytes(data[:12] + ihdr + struct.pack(">I", zlib.crc32(ihdr)) + data[33:])
    with pytest.raises(FormatError, match="f.png: cannot read PNG"):
        read_png(path)


def test_other_bad_input(tmp_path):
    with pytest.raises(FormatError, match="no such file"):
        read_frames(tmp_path / "nope")
    _png(tmp_path / "a" / "x.png", np.zeros((3, 3), np.uint8))
    with pytest.raises(FormatError, match="images without timestamps"):
        read_frames(tmp_path / "a")
    (tmp_path / "a" / "timestamps.txt").write_text("0.1\n")
    with pytest.raises(ParameterError, match="time_unit"):
        read_frames(tmp_path / "a", time_unit="h")
    (tmp_path / "a" / "timestamps.txt").write_text("0.1 x.png\n0.2\n")
    with pytest.raises(FormatError, match="mixes"):
        read_frames(tmp_path / "a")
    (tmp_path / "a" / "timestamps.txt").write_text("soon\n")
    with pytest.raises(FormatError, match="not a time") as e:
        read_frames(tmp_path / "a")
    _one_line(e, "timestamps.txt")
    (tmp_path / "e").mkdir()
    (tmp_path / "e" / "events.txt").write_text("0.1 1 1 1\n")
    with pytest.raises(FormatError, match="no frames"):
        read_frames(tmp_path / "e")
    assert describe_frames(tmp_path / "e") is None


def test_frames_container_checks():
    with pytest.raises(FormatError, match="2 images but 1 timestamps"):
        Frames(np.zeros((2, 3, 3), np.uint8), [0])
    with pytest.raises(FormatError, match="uint8 or uint16"):
        Frames(np.zeros((1, 3, 3), np.float32), [0])
    with pytest.raises(FormatError, match="duplicate"):
        Frames(np.zeros((2, 3, 3), np.uint8), [5, 5], source="x")
    assert np.isnan(Frames(np.zeros((1, 3, 3), np.uint8), [0]).fps)
    # a bit depth the dtype cannot hold made as_float() inf/NaN (0) or zeros (40)
    for depth, dtype in ((0, np.uint8), (12, np.uint8), (40, np.uint16), (2.5, np.uint16)):
        with pytest.raises(FormatError, match="bit_depth"):
            Frames(np.zeros((1, 3, 3), dtype), [0], bit_depth=depth)
    with pytest.raises(FormatError, match="finite"):
        Frames(np.zeros((2, 3, 3), np.uint8), [0, float("nan")])
    big = 1_589_163_147_365_215  # DAVIS timestamps: us since 1970, kept exact
    assert Frames(np.zeros((1, 3, 3), np.uint8), [big]).t[0] == big


def test_published_bos_events(tmp_path):
    """Events of the published layout (prophesee_0/events.hdf5, group raw_events) with
    their frames: read, streamed, time-restricted, detected, described."""
    import h5py

    import evmotion.io as eio

    seq = tmp_path / "hot_plate1"
    imgs = _images(2, h=10, w=12)
    _ccs(seq, imgs, "100 0 1\n8433 0 1\n")
    rng = np.random.default_rng(1)
    n = 1000
    t = np.sort(rng.integers(0, 10_000, n))
    x, y, p = rng.integers(0, 1280, n), rng.integers(0, 720, n), rng.integers(0, 2, n)
    with h5py.File(seq / "prophesee_0" / "events.hdf5", "w") as f:
        g = f.create_group("raw_events")
        g["x"], g["y"] = x.astype(np.int16), y.astype(np.int16)
        g["t"], g["p"] = t.astype(np.int64), p.astype(bool)
    assert eio.detect_format(seq) == "ccs"
    ev = eio.read_events(seq)
    assert ev.sensor_size == (720, 1280) and len(ev) == n
    np.testing.assert_array_equal(ev.x, x)
    np.testing.assert_array_equal(ev.t, t)
    np.testing.assert_array_equal(ev.p, p)
    part = eio.read_events(seq, t0=2000, t1=5000)
    np.testing.assert_array_equal(part.t, t[(t >= 2000) & (t < 5000)])
    chunks = list(eio.iter_events(seq, 300))
    assert [len(c) for c in chunks] == [300, 300, 300, 100]
    fr = read_frames(seq)
    assert fr.t.tolist() == [100, 8433]
    assert len(eio.read_frames(seq / "prophesee_0" / "events.hdf5")) == 2
    info = describe(seq)
    assert info["format"] == "ccs" and info["n_events"] == n
    assert info["frames_info"]["count"] == 2
    with pytest.raises(FormatError, match="outside the 8x6 sensor") as e:
        eio.read_events(seq, sensor_size=(6, 8))
    _one_line(e, "events.hdf5")


def test_video_with_timestamps(tmp_path):
    cv2 = pytest.importorskip("cv2")
    path = tmp_path / "frames.avi"
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 120, (32, 24),
                         isColor=False)
    levels = [0, 40, 80, 120, 160]
    for v in levels:
        vw.write(np.full((24, 32), v, np.uint8))
    vw.release()
    with pytest.raises(FormatError, match="video frames need timestamps") as e:
        read_frames(path)
    _one_line(e, "frames.avi")
    (tmp_path / "frames.txt").write_text("".join(f"{i * 8.333:.3f}\n" for i in range(5)))
    fr = read_frames(path, time_unit="ms")
    assert fr.images.shape == (5, 24, 32) and fr.t.tolist()[:2] == [0, 8333]
    np.testing.assert_allclose(fr.images.mean(axis=(1, 2)), levels, atol=2)
    assert describe_frames(path, time_unit="ms")["count"] == 5
    assert describe(path)["format"] == "frames"  # evmotion info on a video
    (tmp_path / "frames.txt").write_text("0\n1\n")
    with pytest.raises(FormatError, match="2 timestamps but 5 frames"):
        read_frames(path)


@pytest.mark.parametrize("kind", ["grey8", "grey16", "rgb8", "rgba16", "grey_alpha8"])
def test_png_frames_read_alike_by_opencv_and_pypng(tmp_path, kind, monkeypatch):
    """Frames are decoded by OpenCV when installed (a 1000-frame folder took 14-32 s with
    pypng, 2.7 s now); pypng, the fallback, gives the same grey image."""
    import builtins

    from evmotion.io.frames import read_image
    from evmotion.io.pngfile import write_png

    pytest.importorskip("cv2")
    rng = np.random.default_rng(0)
    depth = np.uint16 if kind.endswith("16") else np.uint8
    planes = {"grey8": 1, "grey16": 1, "rgb8": 3, "rgba16": 4, "grey_alpha8": 2}[kind]
    img = rng.integers(0, np.iinfo(depth).max, (12, 17, planes)).astype(depth)
    write_png(tmp_path / "f.png", img if planes > 1 else img[..., 0])
    fast = read_image(tmp_path / "f.png")
    real_import = builtins.__import__

    def no_cv2(name, *a, **k):
        if name == "cv2":
            raise ImportError(name)
        return real_import(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_cv2)
    slow = read_image(tmp_path / "f.png")
    assert fast[1] == slow[1] and fast[0].dtype == slow[0].dtype
    np.testing.assert_array_equal(fast[0], slow[0])


def test_images_txt_in_whole_microseconds_is_read_as_such(tmp_path):
    """Events in whole microseconds were read as such (with a warning), the same folder's
    images.txt in whole microseconds stopped the run ('frames are 8333 s apart')."""
    import warnings

    from evmotion.errors import EvmotionWarning
    from evmotion.io.ecd import read_image_list
    from evmotion.io.pngfile import write_png

    (tmp_path / "images").mkdir()
    for k in range(3):
        write_png(tmp_path / "images" / f"f{k}.png", np.full((4, 5), 100, np.uint8))
    lines = [f"{1_700_000_000_000_000 + 8333 * k} images/f{k}.png" for k in range(3)]
    (tmp_path / "images.txt").write_text("\n".join(lines) + "\n")
    with pytest.warns(EvmotionWarning, match="whole number: read as microseconds"):
        got = read_image_list(tmp_path / "images.txt")
    assert np.diff(got["t"]).tolist() == [8333, 8333]
    # past 1e17: nanoseconds since the epoch, as events.txt reads them (probe AM)
    lines = [f"{1_700_000_000_000_000_000 + 8_333_000 * k} images/f{k}.png" for k in range(3)]
    (tmp_path / "images.txt").write_text("\n".join(lines) + "\n")
    with pytest.warns(EvmotionWarning, match="read as nanoseconds since the epoch"):
        got = read_image_list(tmp_path / "images.txt")
    assert got["t"][0] == 1_700_000_000_000_000 and np.diff(got["t"]).tolist() == [8333, 8333]
    # a header line, as other labs write one (probe AM: 'timestamp' is not a time)
    (tmp_path / "images.txt").write_text("timestamp,filename\n0.0,images/f0.png\n"
                                         "0.008333,images/f1.png\n")
    assert read_image_list(tmp_path / "images.txt")["t"].tolist() == [0, 8333]
    (tmp_path / "images.txt").write_text("0.0 images/f0.png\n0.008333 images/f1.png\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_image_list(tmp_path / "images.txt")["t"].tolist() == [0, 8333]


def test_images_txt_in_whole_seconds_takes_the_time_unit(tmp_path):
    """Frames at 1 fps stamped 0, 1, 2 (whole seconds) were read as microseconds, and
    --time-unit, the events', did not reach them; the refusal blamed events.txt (probe)."""
    import warnings

    from evmotion.errors import EvmotionWarning
    from evmotion.events import EventArray
    from evmotion.io import write_events
    from evmotion.io.bosinput import load_bos_input
    from evmotion.io.ecd import read_image_list
    from evmotion.io.pngfile import write_png

    (tmp_path / "images").mkdir()
    for k in range(3):
        write_png(tmp_path / "images" / f"f{k}.png", np.full((4, 5), 100 + k, np.uint8))
    (tmp_path / "images.txt").write_text("".join(f"{k} images/f{k}.png\n" for k in range(3)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_image_list(tmp_path / "images.txt", "s")["t"].tolist() == [
            0, 1_000_000, 2_000_000]
    # a unit given reads decimal times too (--frames-time-unit ms had been ignored for
    # "10.000", the refusal that named it repeated, probe BOSIN); the events' --time-unit
    # reaches only whole numbers (load_bos_input, below)
    (tmp_path / "images.txt").write_text("0.0 images/f0.png\n1.5 images/f1.png\n")
    assert read_image_list(tmp_path / "images.txt", "ms")["t"].tolist() == [0, 1_500]
    assert read_image_list(tmp_path / "images.txt")["t"].tolist() == [0, 1_500_000]
    (tmp_path / "images.txt").write_text("".join(f"{k} images/f{k}.png\n" for k in range(3)))
    write_events(tmp_path / "events.txt", EventArray(
        x=[1, 2, 3], y=[1, 2, 3], t=[100_000, 900_000, 1_900_000], p=[1, 0, 1],
        sensor_size=(4, 5)))
    with pytest.warns(EvmotionWarning, match="whole number"), \
            pytest.raises(ParameterError, match="images.txt's whole numbers were read as "
                                                "microseconds; --time-unit s"):
        load_bos_input(tmp_path)
    data = load_bos_input(tmp_path, time_unit="s")
    assert data.frame_times.tolist() == [0, 1_000_000, 2_000_000]


def test_unpadded_names_sort_as_numbers(tmp_path):
    # frame_0 .. frame_11 sorted as text put frame_10 third: the flow of scrambled
    # intervals, silently
    imgs = _images(12)
    for i, img in enumerate(imgs):
        _png(tmp_path / f"frame_{i}.png", img)
    (tmp_path / "timestamps.txt").write_text("".join(f"{i / 120:.6f}\n" for i in range(12)))
    np.testing.assert_array_equal(read_frames(tmp_path).images, imgs)
    # the timestamps file named instead of its folder (probe AM: "format not recognised")
    named = read_frames(tmp_path / "timestamps.txt")
    np.testing.assert_array_equal(named.images, imgs)
    assert named.t.tolist() == read_frames(tmp_path).t.tolist()


def test_timestamps_in_whole_microseconds_and_with_a_header(tmp_path):
    from evmotion.errors import EvmotionWarning

    imgs = _images(3)
    for i, img in enumerate(imgs):
        _png(tmp_path / f"img_{i}.png", img)
    (tmp_path / "timestamps.txt").write_text("0\n8333\n16667\n")
    with pytest.warns(EvmotionWarning, match="whole number: read as microseconds"):
        assert read_frames(tmp_path).t.tolist() == [0, 8333, 16667]
    assert read_frames(tmp_path, time_unit="ms").t.tolist() == [0, 8_333_000, 16_667_000]
    (tmp_path / "timestamps.txt").unlink()
    (tmp_path / "timestamps.csv").write_text("timestamp, filename\n0.0, img_0.png\n"
                                             "0.008333, img_1.png\n0.016667, img_2.png\n")
    assert read_frames(tmp_path).t.tolist() == [0, 8333, 16667]


def test_a_truncated_png_is_named_in_one_line(tmp_path, capfd):
    # probe AM: OpenCV's libpng printed "libpng error: Read Error" before our line
    from evmotion.io.frames import read_image
    from evmotion.io.pngfile import write_png

    path = tmp_path / "f.png"
    write_png(path, np.random.default_rng(0).integers(0, 255, (40, 50), dtype=np.uint8))
    whole = path.read_bytes()
    assert read_image(path)[0].shape == (40, 50)
    path.write_bytes(whole[:len(whole) // 2])
    with pytest.raises(FormatError, match="f.png"):
        read_image(path)
    assert "libpng" not in capfd.readouterr().err


def test_a_frame_of_another_size_is_refused_before_it_is_decoded(tmp_path, monkeypatch):
    # probe AO: a 20000 x 20000 frame among 128 x 96 ones was decoded (0.9 GB, 7 s) first
    import cv2

    _ecd(tmp_path, _images(3), ["0.0", "0.1", "0.2"])
    _png(tmp_path / "images" / "frame_00000002.png", np.zeros((300, 400), np.uint8))
    decoded = []
    real_imread = cv2.imread
    monkeypatch.setattr(cv2, "imread", lambda p, *a: decoded.append(p) or real_imread(p, *a))
    with pytest.raises(FormatError, match=r"frame_00000002.png: image is 400x300 px \(WxH\) "
                                          r"but frame_00000000.png is"):
        read_frames(tmp_path)
    assert len(decoded) == 2 and not any("frame_00000002" in str(p) for p in decoded)


def test_frames_of_a_low_jpeg_quality_are_said(tmp_path):
    """Probe BC: JPEG frames of quality 40 gave BOS magnitudes 1.09-1.14x, unsaid (60-90:
    1.00-1.02x)."""
    import warnings

    cv2 = pytest.importorskip("cv2")
    from evmotion.errors import EvmotionWarning
    from evmotion.io.frames import jpeg_quality

    imgs = _images(2, 32, 40)
    for q in (40, 90):
        folder = tmp_path / f"q{q}"
        (folder / "images").mkdir(parents=True)
        for i, img in enumerate(imgs):
            cv2.imwrite(str(folder / "images" / f"{i}.jpg"), img, [cv2.IMWRITE_JPEG_QUALITY, q])
        (folder / "images.txt").write_text("0.0 images/0.jpg\n0.01 images/1.jpg\n")
        assert jpeg_quality(folder / "images" / "0.jpg") == q
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            read_frames(folder)
        lossy = [w for w in said if issubclass(w.category, EvmotionWarning)
                 and "JPEGs of quality" in str(w.message)]
        assert len(lossy) == (q < 50)
    assert jpeg_quality(tmp_path / "q40" / "images.txt") is None


def _listed_frames(folder, n=3, value=100):
    from evmotion.io.pngfile import write_png

    (folder / "images").mkdir(parents=True, exist_ok=True)
    for k in range(n):
        write_png(folder / "images" / f"f{k}.png", np.full((4, 5), value + k, np.uint8))


@pytest.mark.parametrize("text, times", [
    # 'path t' lines: every one had been skipped as a header ("lists no frames")
    ("images/f0.png 0.0\nimages/f1.png 0.01\nimages/f2.png 0.02\n", [0, 10_000, 20_000]),
    # a header naming the unit (it had been ignored: ms read as seconds or as µs)
    ("timestamp[ms] filename\n0.000 images/f0.png\n10.000 images/f1.png\n"
     "20.000 images/f2.png\n", [0, 10_000, 20_000]),
    ("t[ms],filename\n0,images/f0.png\n10,images/f1.png\n20,images/f2.png\n",
     [0, 10_000, 20_000]),
    ("timestamp [us] filename\n0 images/f0.png\n10000 images/f1.png\n20000 images/f2.png\n",
     [0, 10_000, 20_000]),
])
def test_other_labs_image_lists_are_read_as_they_say(tmp_path, text, times):
    """Layouts of images.txt other tools write (probe BOSIN), read with no warning."""
    import warnings

    from evmotion.io.ecd import read_image_list

    _listed_frames(tmp_path)
    (tmp_path / "images.txt").write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = read_image_list(tmp_path / "images.txt")
    assert got["t"].tolist() == times
    assert got["files"] == [f"images/f{k}.png" for k in range(3)]
    assert not got["whole_numbers"]


def test_a_first_line_naming_a_frame_is_no_header(tmp_path):
    from evmotion.io.ecd import read_image_list

    _listed_frames(tmp_path)
    (tmp_path / "images.txt").write_text("images/f0.png 0.0\nimages/f1.png 0.01\n")
    assert read_image_list(tmp_path / "images.txt")["files"][0] == "images/f0.png"
    (tmp_path / "images.txt").write_text("name 0.0\nimages/f1.png 0.01\n")  # a header
    assert read_image_list(tmp_path / "images.txt")["files"] == ["images/f1.png"]
    (tmp_path / "images.txt").write_text("0.0 images/f0.png\nimages/f1.png x\n")
    with pytest.raises(FormatError, match="line 2"):
        read_image_list(tmp_path / "images.txt")


def test_a_png_named_jpg_is_summarized_as_read(tmp_path):
    """The summary judged a frame's end by its name ("truncated JPG") where the reader
    decodes it by its content (probe BOSIN); an empty one is still truncated."""
    _ecd(tmp_path, _images(), ["0.0", "0.01", "0.02"])
    lines = (tmp_path / "images.txt").read_text().replace(".png", ".jpg")
    for k in range(3):
        (tmp_path / "images" / f"frame_{k:08d}.png").rename(
            tmp_path / "images" / f"frame_{k:08d}.jpg")
    (tmp_path / "images.txt").write_text(lines)
    assert describe_frames(tmp_path)["count"] == 3
    (tmp_path / "images" / "frame_00000002.jpg").write_bytes(b"")
    with pytest.raises(FormatError, match="frame_00000002.jpg: truncated JPEG"):
        describe_frames(tmp_path)


def test_an_unreadable_calib_txt_does_not_hide_the_folder(tmp_path):
    """``info`` refused the whole folder for its calib.txt where the events' reader warns
    and reads on (probe BOSIN); a comment line naming the numbers is skipped."""
    from evmotion.events import EventArray
    from evmotion.io import write_events
    from evmotion.io.ecd import describe as describe_ecd
    from evmotion.io.ecd import parse_calib

    write_events(tmp_path / "events.txt", EventArray(x=[1, 2], y=[1, 2], t=[0, 10],
                                                     p=[1, 0], sensor_size=(4, 5)))
    (tmp_path / "calib.txt").write_text("# fx fy cx cy k1 k2 p1 p2 k3\n"
                                        "199.0 198.0 132.0 110.0 -0.3 0.1 0 0 0\n")
    assert parse_calib(tmp_path / "calib.txt")[:4].tolist() == [199.0, 198.0, 132.0, 110.0]
    (tmp_path / "calib.txt").write_text("this is not calibration\n")
    got = describe_ecd(tmp_path)
    assert "calibration" not in got and "must hold numbers" in got["calibration_error"]


def _bos_folder(folder, lines, n_events=200, span_us=20_000, value=100, dtype=np.uint8):
    from evmotion.events import EventArray
    from evmotion.io import write_events
    from evmotion.io.pngfile import write_png

    rng = np.random.default_rng(0)
    (folder / "images").mkdir(parents=True, exist_ok=True)
    for k in range(len(lines)):
        write_png(folder / "images" / f"f{k}.png", rng.integers(
            0, value + 1, (8, 10)).astype(dtype) if value else np.zeros((8, 10), dtype))
    (folder / "images.txt").write_text("".join(lines))
    t = np.sort(rng.integers(0, span_us, n_events))
    write_events(folder / "events.txt", EventArray(
        x=rng.integers(0, 10, n_events), y=rng.integers(0, 8, n_events), t=t,
        p=rng.integers(0, 2, n_events), sensor_size=(8, 10)))


def test_whole_milliseconds_beside_events_in_seconds_are_read_as_such(tmp_path):
    """images.txt in whole ms (0, 10, 20) read as µs put 100 fps frames 10 us apart, and
    the run was refused for a contrast threshold it could not estimate (probe BOSIN). The
    list's own guess of µs is not said beside the warning that reads them as ms (both had
    been, one contradicting the other), but where they stay µs, and where the run is then
    refused."""
    import warnings

    from evmotion.errors import EmptyWindowError, EvmotionWarning, TimeUnitGuessWarning
    from evmotion.io.bosinput import load_bos_input

    _bos_folder(tmp_path, [f"{10 * k} images/f{k}.png\n" for k in range(3)])
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        data = load_bos_input(tmp_path)
    assert data.frame_times.tolist() == [0, 10_000, 20_000]
    texts = [str(w.message) for w in said]
    assert any("read as milliseconds, which span the events" in m for m in texts)
    assert not any("read as microseconds (images.txt" in m for m in texts), texts
    # whole µs of a camera's rate stay µs
    _bos_folder(tmp_path, [f"{10_000 * k} images/f{k}.png\n" for k in range(3)])
    with pytest.warns(TimeUnitGuessWarning, match="whole number: read as microseconds"):
        assert load_bos_input(tmp_path).frame_times.tolist() == [0, 10_000, 20_000]
    (tmp_path / "events.txt").write_text("")
    with pytest.warns(EvmotionWarning, match="whole number: read as microseconds"), \
            pytest.raises(EmptyWindowError, match="no events"):
        load_bos_input(tmp_path)


def test_decimal_microseconds_read_as_seconds_are_named_in_the_hint(tmp_path):
    """10000.0 us apart read as seconds: the hint had named ms, which read them 10 s apart
    (probe BOSIN)."""
    from evmotion.io.bosinput import load_bos_input

    _bos_folder(tmp_path, [f"{10_000 * k}.0 images/f{k}.png\n" for k in range(3)])
    with pytest.raises(FormatError, match="--frames-time-unit us"):
        load_bos_input(tmp_path)
    assert load_bos_input(tmp_path, frames_time_unit="us").frame_times.tolist() == [
        0, 10_000, 20_000]


def test_frames_clipped_at_their_bit_depths_full_scale_are_said(tmp_path):
    """12-bit frames in 16-bit PNGs clip at 4095, which a full scale of 65535 never counted
    (the flow came out 1.4-1.7x too large unsaid, probe BOSIN)."""
    from evmotion.errors import EvmotionWarning
    from evmotion.io.bosinput import full_scale, load_bos_input

    assert [full_scale(np.array([v], np.uint16)) for v in (200, 1023, 4095, 4096, 65520)] \
        == [255, 1023, 4095, 8191, 65535]
    _bos_folder(tmp_path, [f"0.0{k} images/f{k}.png\n" for k in range(3)], span_us=30_000,
                value=0, dtype=np.uint16)
    from evmotion.io.pngfile import write_png

    for k in range(3):  # 12 bits, 90 % at full scale
        img = np.full((8, 10), 4095, np.uint16)
        img[:, :1] = np.arange(8)[:, None] * 100 + k
        write_png(tmp_path / "images" / f"f{k}.png", img)
    with pytest.warns(EvmotionWarning, match="more than 75 % clipped at full scale"):
        load_bos_input(tmp_path)

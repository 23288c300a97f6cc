"""Videos: frames in, the same frames (up to H.264 loss) out; a clear error without the extra."""

import sys

import numpy as np
import pytest

from evmotion.errors import MissingDependencyError, ParameterError
from evmotion.events import EventArray
from evmotion.viz import flow_picture, write_flow_video, write_video


def _frames(n=6, h=31, w=45):
    colours = [(255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0), (0, 0, 0), (255, 255, 255)]
    return [np.broadcast_to(np.array(colours[k % 6], np.uint8), (h, w, 3)).copy()
            for k in range(n)]


def _read_back(path):
    iio = pytest.importorskip("imageio_ffmpeg")
    gen = iio.read_frames(str(path))
    meta = gen.__next__()
    w, h = meta["size"]
    frames = [np.frombuffer(f, np.uint8).reshape(h, w, 3) for f in gen]
    return meta, frames


def test_write_video_round_trip(tmp_path):
    pytest.importorskip("imageio_ffmpeg", reason="the 'video' extra (imageio-ffmpeg) is absent")
    frames = _frames()
    path = tmp_path / "v.mp4"
    assert write_video(iter(frames), path, fps=5) == 6
    meta, back = _read_back(path)
    assert meta["fps"] == pytest.approx(5.0)
    assert len(back) == 6
    assert back[0].shape == (32, 46, 3)  # odd sizes padded to even for yuv420p
    for a, b in zip(frames, back, strict=True):
        err = np.abs(b[:31, :45].astype(int) - a.astype(int)).mean()
        assert err < 12, err
    assert [p.name for p in tmp_path.iterdir()] == ["v.mp4"]


def test_write_video_rejects_bad_frames_and_leaves_no_file(tmp_path):
    pytest.importorskip("imageio_ffmpeg", reason="the 'video' extra (imageio-ffmpeg) is absent")
    frames = _frames(3)
    frames.append(np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(ParameterError, match="frame 3"):
        write_video(frames, tmp_path / "v.mp4")
    with pytest.raises(ParameterError, match="no frames"):
        write_video([], tmp_path / "v.mp4")
    with pytest.raises(ParameterError, match="fps"):
        write_video(_frames(1), tmp_path / "v.mp4", fps=0)
    assert not list(tmp_path.iterdir())


def test_missing_extra_is_one_clear_line(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # import fails as if absent
    with pytest.raises(MissingDependencyError) as info:
        write_video(_frames(1), tmp_path / "v.mp4")
    msg = str(info.value)
    assert "\n" not in msg and "evmotion[video]" in msg and "imageio-ffmpeg" in msg
    assert not list(tmp_path.iterdir())


def test_write_flow_video_one_frame_per_window(tmp_path):
    pytest.importorskip("imageio_ffmpeg", reason="the 'video' extra (imageio-ffmpeg) is absent")
    rng = np.random.default_rng(1)
    n = 4000
    t = np.sort(rng.integers(0, 40_000, n))
    x = (10 + rng.integers(0, 5, n) * 20 + 800e-6 * t).astype(np.float32)
    ev = EventArray(x, rng.uniform(2, 78, n).astype(np.float32), t, rng.integers(0, 2, n),
                    sensor_size=(80, 160))
    windows = ev.windows_by_duration(10_000)
    flows = [np.full((80, 160, 2), (800.0 * (k + 1), 0.0), np.float32)
             for k in range(len(windows))]
    path = tmp_path / "flow.mp4"
    assert write_flow_video(path, ev, windows, flows, fps=4) == len(windows) == 4
    _, back = _read_back(path)
    assert len(back) == 4
    # one colour scale for the sequence (rim = 3200 px/s, the fastest window): the flow
    # panel's saturation grows 1/4, 2/4, 3/4, 1 frame after frame
    k = flow_picture(flows[0]).scale
    col = 2 * (160 * k + 4) + 80 * k  # centre of the flow panel, after events and IWE
    sat = [1.0 - f[-40 * k, col - 5:col + 5].astype(float).min(axis=-1).mean() / 255.0
           for f in back]
    np.testing.assert_allclose(sat, [0.25, 0.5, 0.75, 1.0], atol=0.06)
    with pytest.raises(ParameterError, match="flows for"):
        write_flow_video(path, ev, windows, flows[:-1])

"""``evmotion flow --png-dir --max-speed --video``: the CLI's flow pictures carry the legend
on the asked scale, grey where no events, and the multicm video has one frame per window."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from evmotion.cli import main
from evmotion.viz import GREY, flow_picture, read_png
from test_multicm import constant, synth

FLOW = (-250.0, 120.0)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    from evmotion.events import concatenate
    from evmotion.io.registry import get_format

    d = tmp_path_factory.mktemp("rec")
    parts = [synth(constant(*FLOW), n=6000, shape=(90, 120), seed=s, t_start=0.02 * s)
             for s in range(2)]
    path = d / "rec.dat"
    get_format("dat").write(path, concatenate(parts))
    return path


def test_multicm_pictures_and_video(recording, tmp_path):
    want_video = pytest.importorskip("imageio_ffmpeg", reason="the 'video' extra is absent")
    png, video = tmp_path / "png", tmp_path / "flow.mp4"
    rc = main(["flow", str(recording), "--method", "multicm", "--window-us", "20000",
               "--scales", "2", "--out", str(tmp_path / "f.h5"), "--png-dir", str(png),
               "--max-speed", "1000", "--video", str(video)])
    assert rc == 0
    img = read_png(png / "flow_00000.png")[..., :3]
    masked = read_png(png / "flow_masked_00000.png")[..., :3]
    ref = flow_picture(np.broadcast_to(np.float32(FLOW), (90, 120, 2)), max_speed=1000.0)
    assert img.shape == ref.rgb.shape  # flow upscaled to a legible size + legend strip
    # the legend says "rim 1000 px/s, fixed; darker: beyond": the strip equals the reference's
    np.testing.assert_array_equal(img[:, ref.legend_box[2]:], ref.rgb[:, ref.legend_box[2]:])
    k = ref.scale
    assert np.all(masked[:90 * k, :120 * k] == GREY, axis=-1).mean() > 0.05
    assert not np.all(img[:90 * k, :120 * k] == GREY, axis=-1).any()
    frames = list(want_video.read_frames(str(video)))[1:]
    assert len(frames) == 2


def test_bad_max_speed_and_video_with_triplet_are_one_line_errors(recording, tmp_path, capsys):
    rc = main(["flow", str(recording), "--method", "multicm", "--window-us", "20000",
               "--scales", "1", "--max-iter", "2", "--out", str(tmp_path / "f.h5"),
               "--png-dir", str(tmp_path / "png"), "--max-speed", "-5"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "--max-speed" in err and "-5" in err and "\n" not in err
    rc = main(["flow", str(recording), "--method", "triplet", "--out", str(tmp_path / "t.h5"),
               "--video", str(tmp_path / "t.mp4")])
    err = capsys.readouterr().err.strip()
    assert rc != 0 and "--video" in err and "multicm" in err and "\n" not in err


def test_unmeasured_window_pictures_say_so(recording, tmp_path, monkeypatch, capsys):
    # probe BX: a 500-event window (too few: valid all False) was drawn as a saturated
    # field under a plain title, its masked twin all grey over "grey: no events"
    import evmotion.viz as viz

    drawn = {}
    save = viz.save_flow_png

    def spy(path, *a, title=None, **kw):
        drawn[Path(path).name] = (title, save(path, *a, title=title, **kw))
        return drawn[Path(path).name][1]

    monkeypatch.setattr(viz, "save_flow_png", spy)
    rc = main(["flow", str(recording), "--method", "multicm", "--window-events", "300",
               "--max-windows", "1", "--scales", "2", "--out", str(tmp_path / "f.h5"),
               "--png-dir", str(tmp_path / "png")])
    assert rc == 0 and "too few events" in capsys.readouterr().err
    for name in ("flow_00000.png", "flow_masked_00000.png"):
        assert "NOT A MEASUREMENT" in drawn[name][0]
    assert drawn["flow_masked_00000.png"][1].texts[4] == "grey: nothing measured"

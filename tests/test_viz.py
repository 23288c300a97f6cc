"""Colour wheel conventions, IWE and event images, PNG/panel output and the HTML report."""

from __future__ import annotations

import colorsys
import io
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from evmotion.errors import ParameterError
from evmotion.events import EventArray
from evmotion.viz import (
    HtmlReport,
    colorwheel,
    colorwheel_image,
    event_histogram,
    flow_to_rgb,
    iwe_to_rgb,
    read_png,
    save_flow_png,
    save_flow_summary,
    save_panel,
    save_png,
)


def _hue_deg(rgb) -> float:
    r, g, b = (c / 255.0 for c in rgb)
    return colorsys.rgb_to_hsv(r, g, b)[0] * 360.0


def _one(u: float, v: float, max_magnitude: float = 1.0) -> np.ndarray:
    return flow_to_rgb(np.array([[[u, v]]], np.float32), max_magnitude)[0, 0]


def test_cardinal_directions_follow_the_middlebury_wheel():
    # u right, v down (image axes): right red, down yellow-orange, left cyan-blue, up violet.
    right, down, left, up = _one(1, 0), _one(0, 1), _one(-1, 0), _one(0, -1)
    assert right.tolist() == [255, 0, 0]
    assert 40 <= _hue_deg(down) <= 65 and down[2] == 0
    assert 175 <= _hue_deg(left) <= 200 and left[0] == 0
    assert 250 <= _hue_deg(up) <= 280 and up[1] == 0
    # Going round the wheel right -> down -> left -> up, the hue increases monotonically.
    hues = [_hue_deg(_one(np.cos(a), np.sin(a))) for a in np.linspace(0.05, 2 * np.pi - 0.3, 40)]
    assert np.all(np.diff(hues) >= -1e-6)


def test_wheel_is_the_55_colour_baker_wheel():
    w = colorwheel()
    assert w.shape == (55, 3)
    np.testing.assert_array_equal(w[0], [1, 0, 0])
    np.testing.assert_array_equal(w[15], [1, 1, 0])
    np.testing.assert_array_equal(w[21], [0, 1, 0])
    np.testing.assert_array_equal(w[25], [0, 1, 1])
    np.testing.assert_array_equal(w[36], [0, 0, 1])
    np.testing.assert_array_equal(w[49], [1, 0, 1])


def test_zero_flow_white_and_magnitude_normalization():
    rng = np.random.default_rng(0)
    flow = rng.normal(0, 3, (16, 20, 2)).astype(np.float32)
    flow[0, 0] = 0
    rgb = flow_to_rgb(flow)
    assert rgb.shape == (16, 20, 3) and rgb.dtype == np.uint8
    assert rgb[0, 0].tolist() == [255, 255, 255]
    # Scaling the flow and the maximum together changes nothing.
    np.testing.assert_array_equal(flow_to_rgb(flow, 5.0), flow_to_rgb(10 * flow, 50.0))
    # Default maximum: the longest vector is fully saturated (one channel reaches 0).
    mag = np.hypot(flow[..., 0], flow[..., 1])
    r, c = np.unravel_index(np.argmax(mag), mag.shape)
    assert rgb[r, c].min() == 0
    # Half the maximum: half saturated; beyond it: darkened.
    assert _one(0.5, 0).tolist() == [255, 128, 128]
    assert _one(2.0, 0).tolist() == [191, 0, 0]


def test_mask_and_nan_are_drawn_in_the_invalid_colour():
    flow = np.ones((3, 4, 2), np.float32)
    flow[0, 0] = np.nan
    mask = np.ones((3, 4), bool)
    mask[2, 3] = False
    rgb = flow_to_rgb(flow, mask=mask, invalid_color=(10, 20, 30))
    assert rgb[0, 0].tolist() == [10, 20, 30]
    assert rgb[2, 3].tolist() == [10, 20, 30]
    assert rgb[1, 1].min() == 0  # fully saturated: max magnitude taken over valid pixels
    with pytest.raises(ParameterError, match="shape"):
        flow_to_rgb(flow[..., 0])
    with pytest.raises(ParameterError, match="max_magnitude"):
        flow_to_rgb(flow, max_magnitude=0.0)


def test_float32_flow_draws_as_its_float64_copy():
    """The default scale (the largest |flow|) put a float32 flow's fastest pixels just
    beyond the rim, drawn at 75 %."""
    f = np.zeros((4, 4, 2), np.float32)
    f[..., 0], f[..., 1] = 30, -10
    assert flow_to_rgb(f)[0, 0].tolist() == flow_to_rgb(f.astype(np.float64))[0, 0].tolist()
    assert flow_to_rgb(f)[0, 0].max() == 255


def test_colorwheel_image_legend():
    img = colorwheel_image(101)
    assert img.shape == (101, 101, 3)
    assert img[50, 50].tolist() == [255, 255, 255]
    assert img[50, 100].tolist() == [255, 0, 0]  # rim on the right: +u at full scale
    assert img[0, 0].tolist() == [255, 255, 255]  # outside the disc: background


def test_event_histogram_matches_loop():
    rng = np.random.default_rng(1)
    n = 2000
    ev = EventArray(rng.integers(0, 30, n), rng.integers(0, 20, n),
                    np.sort(rng.integers(0, 10_000, n)), rng.integers(0, 2, n),
                    sensor_size=(20, 30))
    ref = np.zeros((20, 30))
    ref_signed = np.zeros((20, 30))
    for x, y, p in zip(ev.x, ev.y, ev.p, strict=True):
        ref[y, x] += 1
        ref_signed[y, x] += 1 if p else -1
    np.testing.assert_array_equal(event_histogram(ev), ref)
    np.testing.assert_array_equal(event_histogram(ev, signed=True), ref_signed)
    assert event_histogram(ev[:0]).shape == (20, 30)


def test_iwe_to_rgb():
    iwe = np.array([[0.0, 1.0, 2.0, 100.0]])
    g = iwe_to_rgb(iwe, vmax=2.0)
    assert g[0, :, 0].tolist() == [255, 128, 0, 0]
    assert (g[..., 0] == g[..., 1]).all() and (g[..., 1] == g[..., 2]).all()
    assert iwe_to_rgb(iwe, vmax=2.0, invert=False)[0, 0].tolist() == [0, 0, 0]
    s = iwe_to_rgb(np.array([[2.0, -2.0, 0.0, 1.0]]), polarity=True, vmax=2.0)
    assert s[0, 0].tolist() == [255, 0, 0]
    assert s[0, 1].tolist() == [0, 0, 255]
    assert s[0, 2].tolist() == [255, 255, 255]
    assert s[0, 3].tolist() == [255, 128, 128]
    # Default scale: a robust percentile, so one hot pixel does not wash out the rest.
    hot = np.ones((50, 50))
    hot[0, 0] = 1e6
    assert iwe_to_rgb(hot)[5, 5, 0] < 10
    with pytest.raises(ParameterError, match="2-D"):
        iwe_to_rgb(np.zeros((2, 2, 2)))


@pytest.mark.parametrize("shape", [(7, 9), (7, 9, 3), (7, 9, 4)])
def test_save_png_round_trip(tmp_path, shape):
    img = np.random.default_rng(2).integers(0, 256, shape).astype(np.uint8)
    path = tmp_path / "sub" / "img.png"
    save_png(path, img)
    np.testing.assert_array_equal(read_png(path), img)
    assert [p.name for p in path.parent.iterdir()] == ["img.png"]


def test_save_png_rejects_bad_images(tmp_path):
    with pytest.raises(ParameterError, match="uint8"):
        save_png(tmp_path / "a.png", np.zeros((4, 4)))
    with pytest.raises(ParameterError, match="shape|must be"):
        save_png(tmp_path / "a.png", np.zeros((4, 4, 2), np.uint8))
    assert not list(tmp_path.iterdir())


def test_flow_png_with_and_without_legend(tmp_path):
    flow = np.random.default_rng(3).normal(0, 100, (40, 40, 2)).astype(np.float32)
    save_flow_png(tmp_path / "bare.png", flow, max_speed=200.0, legend=False)
    np.testing.assert_array_equal(read_png(tmp_path / "bare.png"), flow_to_rgb(flow, 200.0))
    save_flow_png(tmp_path / "legend.png", flow, unit="px/s", title="flow")
    img = read_png(tmp_path / "legend.png")
    assert img.ndim == 3 and img.shape[2] in (3, 4)
    assert img.shape[1] > img.shape[0]  # side panel with the wheel


def test_panel_decodes_and_grows_with_images(tmp_path):
    a = iwe_to_rgb(np.eye(30))
    b = flow_to_rgb(np.ones((30, 30, 2)))
    save_panel(tmp_path / "one.png", [a], ["IWE"])
    save_panel(tmp_path / "three.png", [a, b, np.eye(30)], ["IWE", "flow", "raw"])
    one, three = read_png(tmp_path / "one.png"), read_png(tmp_path / "three.png")
    assert three.shape[1] == pytest.approx(3 * one.shape[1], rel=0.05)
    save_panel(tmp_path / "grid.png", [a, b, a, b], ncols=2)
    grid = read_png(tmp_path / "grid.png")
    assert grid.shape[0] > one.shape[0] * 1.5
    with pytest.raises(ParameterError, match="titles"):
        save_panel(tmp_path / "x.png", [a, b], ["only one"])


def test_no_pyplot_global_state():
    code = ("import sys, numpy as np; from evmotion.viz import save_panel, save_flow_png; "
            "import tempfile, os; d = tempfile.mkdtemp(); "
            "save_panel(os.path.join(d, 'p.png'), [np.eye(5)]); "
            "save_flow_png(os.path.join(d, 'f.png'), np.ones((5, 5, 2))); "
            "print('matplotlib.pyplot' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"


def test_html_report(tmp_path):
    fig_dir = tmp_path / "figs"
    save_png(fig_dir / "iwe.png", iwe_to_rgb(np.eye(8)))
    rep = HtmlReport("Results <sim>")
    rep.add_heading("Window 0")
    rep.add_text("AEE in px & FWL.\n\nSecond paragraph.")
    rep.add_figure(fig_dir / "iwe.png", caption="IWE, window 0")
    rep.add_table([{"method": "multicm", "AEE": 0.812345, "FWL": float("nan")},
                   {"method": "zero", "AEE": 4.0, "n": np.int64(3)}], caption="Accuracy")
    out = rep.write(tmp_path / "report.html")
    text = out.read_text()
    assert '<img src="data:image/png;base64,' in text
    assert "IWE, window 0" in text
    assert "Results &lt;sim&gt;" in text and "AEE in px &amp; FWL." in text
    assert "<p>Second paragraph.</p>" in text
    assert "<td>0.8123</td>" in text and "<th>n</th>" in text and "<td>3</td>" in text
    # Linked instead of embedded, written elsewhere: the path stays relative to the page.
    rep.embed = False
    assert '<img src="figs/iwe.png"' in rep.write(tmp_path / "report.html").read_text()
    text2 = rep.write(fig_dir / "deep" / "r.html").read_text()
    assert '<img src="../iwe.png"' in text2
    with pytest.raises(ParameterError):
        rep.add_table([])


def test_flow_summary_png(tmp_path):
    from evmotion.eval import event_mask, fwl

    rng = np.random.default_rng(5)
    n = 2000
    t = np.sort(rng.integers(0, 20_000, n))
    x = (5 + rng.integers(0, 4, n) * 5 + 500e-6 * t).astype(np.float32)
    y = rng.uniform(2, 28, n).astype(np.float32)
    ev = EventArray(x, y, t, rng.integers(0, 2, n), sensor_size=(30, 40))
    flow = np.zeros((30, 40, 2), np.float32)
    flow[..., 0] = 500.0
    for polarity in (False, True):
        path = tmp_path / f"s{int(polarity)}.png"
        value = save_flow_summary(path, ev, flow, polarity=polarity, valid=event_mask(ev),
                                  title="window 0")
        assert value == pytest.approx(fwl(ev, flow)) and value > 1.5
        img = read_png(path)
        assert img.ndim == 3 and img.shape[1] > 2.5 * img.shape[0]


SENSORS = [(180, 240), (260, 346), (480, 640), (720, 1280)]


def _png_rgb(png: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


def _stripes_drawn(rgb: np.ndarray, n: int, k: int) -> bool:
    """Whether a row of ``rgb`` holds ``n`` one-pixel stripes (dark first) each drawn
    exactly ``k`` picture pixels wide: every column of the image, none merged or doubled."""
    dark = (rgb.astype(int).sum(axis=-1) < 200).astype(np.uint8)
    pattern = ((b"\x01" * k + b"\x00" * k) * (n // 2))[:n * k]
    return any(pattern in row.tobytes() for row in dark)


def _stripes(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    cols, rows = np.zeros((h, w)), np.zeros((h, w))
    cols[:, ::2] = 5.0
    rows[::2] = 5.0
    return cols, rows


@pytest.mark.parametrize("h,w", SENSORS)
def test_event_pictures_draw_every_sensor_pixel(h, w):
    # probe DA: a 1280-px sensor was drawn ~1205 px wide (79 column pairs merged), a 240-px
    # one unevenly doubled (1.19x): lone events and hot pixels vanished or aliased
    from evmotion.viz.images import event_picture_png, picture_factor

    k = picture_factor(w)[0]
    assert k == (2 if w < 480 else 1)
    cols, rows = _stripes(h, w)
    pic = _png_rgb(event_picture_png(cols, title="one-pixel stripes"))
    assert _stripes_drawn(pic, w, k)
    assert _stripes_drawn(_png_rgb(event_picture_png(rows)).transpose(1, 0, 2), h, k)
    # a sensible size: the image, its axes and colour bar
    assert w * k < pic.shape[1] < w * k + 250 and h * k < pic.shape[0] < h * k + 120


@pytest.mark.parametrize("h,w", SENSORS)
def test_panels_draw_every_image_pixel(h, w):
    # probe DA: egomotion's 2 x 2 panels of a 1280 x 720 sensor drew each image ~585 px wide
    from evmotion.viz.images import panel_png

    cols, rows = _stripes(h, w)
    k = 2 if w < 300 else 1
    pic = _png_rgb(panel_png([iwe_to_rgb(cols, vmax=5.0), iwe_to_rgb(rows, vmax=5.0), cols,
                              iwe_to_rgb(cols, vmax=5.0)], ["a\ntwo-line title"] * 4,
                             ncols=2, suptitle="window 0"))
    assert _stripes_drawn(pic, w, k)
    assert _stripes_drawn(pic.transpose(1, 0, 2), h, k)
    assert 2 * w * k < pic.shape[1] < 2 * w * k + 150


def test_a_row_too_wide_is_reduced_keeping_every_lone_event():
    # segment draws its clusters in one row: four 1280-px images at 1x would be 5,000 px
    # wide; halved by blocks, each lone event (red on white) stays one red pixel
    from evmotion.viz.images import MAX_PANEL_ROW_PX, panel_png

    rng = np.random.default_rng(1)
    images = []
    for _ in range(4):
        im = np.full((720, 1280, 3), 255, np.uint8)
        im[rng.integers(0, 360, 30) * 2, rng.integers(0, 640, 30) * 2] = (255, 0, 0)
        images.append(im)
    pic = _png_rgb(panel_png(images, [f"cluster {i}" for i in range(4)]))
    assert MAX_PANEL_ROW_PX // 2 <= pic.shape[1] <= MAX_PANEL_ROW_PX + 200
    red = (pic[..., 0] == 255) & (pic[..., 1] == 0) & (pic[..., 2] == 0)
    assert red.sum() == sum(int((im[..., 1] == 0).sum()) for im in images)


def test_a_sensor_wider_than_a_picture_is_reduced_keeping_its_events():
    from evmotion.viz.images import _reduced_values, event_picture_png, picture_factor

    img = np.zeros((100, 4096))
    img[np.arange(0, 100, 10), np.arange(5, 4096, 410)] = [1, -2, 3, 1, 1, -1, 7, 1, 1, 1]
    k, r = picture_factor(4096)
    assert (k, r) == (1, 3)
    small = _reduced_values(img, r)
    assert small.shape == (34, 1366)
    assert sorted(small[small != 0].tolist()) == sorted(img[img != 0].tolist())
    assert _png_rgb(event_picture_png(img, polarity=True)).shape[1] < 1366 + 250


def test_panel_titles_wider_than_their_panel_wrap():
    # segment's cluster titles ran into each other and off the picture (probe AD): a long
    # line wraps to the panel's width, and the picture grows to hold it
    from evmotion.viz.images import MIN_PANEL_PX, TITLE_CHARS_PER_INCH, panel_png

    img = np.zeros((180, 240))
    long = ("cluster 0: wx=1.76 wy=-0.667 wz=1.65 rad/s and more words to wrap around its "
            "panel")
    short, wrapped = (Image.open(io.BytesIO(panel_png([img, img], [t, t])))
                      for t in ("cluster 0", long))
    assert wrapped.size[0] == short.size[0] and wrapped.size[1] > short.size[1]
    assert len(long) > 2 * MIN_PANEL_PX / 100 * TITLE_CHARS_PER_INCH


def test_panels_name_their_pixel_axes(monkeypatch):
    # probe BX: the ticks 0 and W - 1 had no unit
    import evmotion.viz.images as vi

    figs = []
    real = vi._picture_png
    monkeypatch.setattr(vi, "_picture_png",
                        lambda fig, pastes, dpi: figs.append(fig) or real(fig, pastes, dpi))
    vi.panel_png([np.zeros((12, 16)), np.ones((12, 16))], ["a", "b"])
    axes = figs[0].axes
    assert [(a.get_xlabel(), a.get_ylabel()) for a in axes] == [("x [px]", "y [px]")] * 2


def test_a_title_in_capitals_fits_its_picture():
    """'NOT A MEASUREMENT' was cut at both ends of a 336-px flow picture: its capitals are
    wider than the width the lines were counted by (probe CK). Each line is drawn and its
    width measured against the picture's."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from evmotion.viz.titles import wrap_title

    title = "window 0: 0.0002-0.0094 s: NOT A MEASUREMENT (no valid pixel)"
    fig = plt.figure(figsize=(3.36, 1), dpi=100)
    try:
        renderer = fig.canvas.get_renderer()
        for line in wrap_title(title, 336, 7.5):
            text = fig.text(0.5, 0.5, line, fontsize=10, ha="center")
            assert text.get_window_extent(renderer).width < 336, line
    finally:
        plt.close(fig)


def test_a_tall_narrow_image_is_not_magnified_past_a_picture():
    # magnified by its width alone, a (720, 3) image became 629 x 115,276 px (review DR)
    import io

    from PIL import Image

    from evmotion.viz.images import event_picture_png, panel_png

    img = np.ones((720, 3))
    for png in (event_picture_png(img), panel_png([img, img])):
        h, w = np.asarray(Image.open(io.BytesIO(png))).shape[:2]
        assert h < 3000 and w < 3000, (h, w)

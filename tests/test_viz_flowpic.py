"""Flow pictures: the legend (wheel, arrows, rim speed) is drawn, max_speed fixes the colour
scale, unsupported pixels are grey, and the events | IWE | flow panel."""

import numpy as np
import pytest

from evmotion.errors import ParameterError
from evmotion.events import EventArray
from evmotion.viz import (
    GREY,
    MIN_HEIGHT,
    colorwheel,
    flow_panel,
    flow_picture,
    flow_to_rgb,
    picture_row,
    read_png,
    save_flow_png,
    sequence_max_speed,
)


def _radial(h=200, w=240, scale=1.0):
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    return np.stack([xx - w / 2, yy - h / 2], axis=-1) * scale


def _box(rgb, box):
    r0, r1, c0, c1 = box
    return rgb[r0:r1, c0:c1]


def test_flow_pixels_are_the_bare_picture_and_the_legend_is_drawn():
    flow = _radial()
    bare = flow_to_rgb(flow, 60.0)
    pic = flow_picture(flow, max_speed=60.0)
    assert pic.scale == 1 and pic.flow_box == (0, 200, 0, 240)
    np.testing.assert_array_equal(_box(pic.rgb, pic.flow_box), bare)
    legend = _box(pic.rgb, pic.legend_box)
    assert legend.shape[0] == 200 and 90 <= legend.shape[1] <= 200
    # the wheel is there: fully saturated red (rim, +u) and blue-ish (rim, -v) pixels
    px = legend.reshape(-1, 3).astype(int)
    assert np.any((px[:, 0] > 240) & (px[:, 1] < 40) & (px[:, 2] < 40))
    assert np.any((px[:, 2] > 240) & (px[:, 0] < 120) & (px[:, 1] < 60))
    # black ink: the arrows and the text
    assert np.sum(px.max(axis=1) < 60) > 50
    assert pic.texts == ("u", "v", "rim 60 px/s", "fixed; darker: beyond",
                         "unmasked: all pixels", "50 px")
    # the grey of a mask is said only where there is one (probe BK: "grey: no events"
    # over a picture coloured everywhere)
    assert flow_picture(flow, valid=np.ones(flow.shape[:2], bool)).texts[4] == "grey: no events"
    holed = flow.copy()
    holed[0, 0] = np.nan
    assert flow_picture(holed).texts[4] == "unmasked; grey: NaN"
    assert pic.max_speed == 60.0 and pic.fixed_scale


def test_the_scale_text_is_drawn_not_only_reported():
    flow = _radial()
    a = flow_picture(flow, max_speed=60.0)
    b = flow_picture(flow, max_speed=61.0)
    c = flow_picture(flow)
    np.testing.assert_array_equal(a.rgb[:, :240], flow_to_rgb(flow, 60.0))
    la, lb, lc = (_box(p.rgb, p.legend_box) for p in (a, b, c))
    diff = np.any(la != lb, axis=-1)
    rows = np.flatnonzero(diff.any(axis=1))
    # only the line with the number changes, below the wheel
    assert rows.size and rows.min() > la.shape[0] // 2
    assert c.texts[3] == "max of image" and not c.fixed_scale
    assert c.max_speed == pytest.approx(np.hypot(120, 100))
    assert np.any(la != lc)


def _ruler_length(pic) -> int:
    """Screen pixels of the legend's longest black horizontal run below the wheel."""
    legend = _box(pic.rgb, pic.legend_box).astype(int)
    black = legend.max(axis=-1) < 60
    best = 0
    for row in black[legend.shape[0] // 2:]:
        run = 0
        for b in row:
            run = run + 1 if b else 0
            best = max(best, run)
    return best


@pytest.mark.parametrize("shape, scale, ruler", [((200, 240), 1, 50), ((30, 40), 6, 10),
                                                 ((720, 1280), 1, 100), ((5, 7), 32, 2)])
def test_the_ruler_spans_the_pixels_it_names(shape, scale, ruler):
    # flow pictures had no pixel scale: an upscaled 30-row flow and a 720-row one looked
    # alike (probe BX); the bar spans `ruler` flow pixels at the picture's upscale
    flow = np.zeros((*shape, 2), np.float32)
    flow[..., 0] = 3.0
    pic = flow_picture(flow)
    assert pic.scale == scale and pic.texts[5] == f"{ruler} px"
    assert abs(_ruler_length(pic) - ruler * scale) <= 2


def test_a_flow_too_thin_for_a_ruler_draws_none():
    pic = flow_picture(np.ones((1, 30, 2), np.float32))
    assert pic.scale == 160 and pic.texts[5] == ""
    assert _ruler_length(pic) < 20  # letters only, no bar


def test_max_speed_fixes_the_colour_scale():
    flow = np.zeros((4, 4, 2), np.float32)
    flow[..., 0] = 40.0
    saturation = {}
    for m in (50.0, 200.0):
        rgb = flow_picture(flow, max_speed=m, legend=False).rgb
        saturation[m] = 1.0 - rgb[0, 0].min() / 255.0
    assert saturation[50.0] == pytest.approx(0.8, abs=0.01)
    assert saturation[200.0] == pytest.approx(0.2, abs=0.01)
    # two different flows on one scale: the same vector gets the same colour
    other = flow.copy()
    other[0, 0] = (500.0, 0.0)
    same = [flow_picture(f, max_speed=100.0, legend=False).rgb[2, 2] for f in (flow, other)]
    np.testing.assert_array_equal(same[0], same[1])
    auto = [flow_picture(f, legend=False).rgb[2, 2] for f in (flow, other)]
    assert not np.array_equal(auto[0], auto[1])  # per-image scales disagree
    with pytest.raises(ParameterError, match="max_speed"):
        flow_picture(flow, max_speed=0.0)
    with pytest.raises(ParameterError, match="max_speed"):
        flow_picture(flow, max_speed=float("nan"))


def test_pixels_without_support_are_grey_and_no_flow_colour_is():
    rng = np.random.default_rng(0)
    flow = rng.normal(0, 80, (60, 70, 2)).astype(np.float32)
    flow[5, 5] = np.nan
    valid = rng.random((60, 70)) > 0.3
    rgb = flow_picture(flow, valid=valid, max_speed=100.0, legend=False).rgb
    grey = np.all(rgb == np.array(GREY, np.uint8), axis=-1)
    expected = ~valid
    expected[5, 5] = True
    np.testing.assert_array_equal(grey, expected)
    # every colour of the wheel, inside and beyond the rim, differs from grey
    ang = np.linspace(-np.pi, np.pi, 2000)
    for r in (0.0, 0.3, 1.0, 3.0):
        f = np.stack([r * np.cos(ang), r * np.sin(ang)], axis=-1)[None].astype(np.float32)
        assert not np.any(np.all(flow_to_rgb(f, 1.0) == GREY, axis=-1))
    with pytest.raises(ParameterError, match="valid mask"):
        flow_picture(flow, valid=valid[:-1])


def test_colours_are_continuous_across_the_u_axis():
    eps = 1e-4
    f = np.array([[[1.0, -eps], [1.0, eps]]], np.float32)
    a, b = flow_to_rgb(f, 1.0)[0].astype(int)
    assert np.abs(a - b).max() <= 2
    assert len(colorwheel()) == 55


def test_small_flows_are_upscaled_so_the_legend_reads():
    flow = _radial(20, 30)
    pic = flow_picture(flow, max_speed=20.0)
    k = pic.scale
    assert k == -(-MIN_HEIGHT // 20) and pic.rgb.shape[0] == 20 * k
    np.testing.assert_array_equal(_box(pic.rgb, pic.flow_box)[::k, ::k],
                                  flow_to_rgb(flow, 20.0))


def test_save_flow_png_writes_the_picture(tmp_path):
    flow = _radial(50, 60)
    valid = np.zeros((50, 60), bool)
    valid[10:40] = True
    pic = save_flow_png(tmp_path / "f.png", flow, max_speed=30.0, valid=valid)
    np.testing.assert_array_equal(read_png(tmp_path / "f.png")[..., :3], pic.rgb)
    titled = save_flow_png(tmp_path / "t.png", flow, max_speed=30.0, title="window 3")
    assert read_png(tmp_path / "t.png").shape[0] > titled.rgb.shape[0]


def test_sequence_max_speed():
    a = np.zeros((3, 3, 2))
    b = np.ones((3, 3, 2))
    b[0, 0] = (30.0, 40.0)
    assert sequence_max_speed([a, b]) == 50.0
    mask = np.ones((3, 3), bool)
    mask[0, 0] = False
    assert sequence_max_speed([a, b], [mask, mask]) == pytest.approx(np.sqrt(2))
    assert sequence_max_speed([a]) == 1.0  # no motion: any positive scale
    with pytest.raises(ParameterError):
        sequence_max_speed([a, b], [mask])


def test_picture_row_keeps_pixels():
    a = np.full((20, 30, 3), 10, np.uint8)
    b = np.full((12, 8, 3), 200, np.uint8)
    row = picture_row([a, b])
    assert row.shape == (20, 30 + 4 + 8, 3)
    np.testing.assert_array_equal(row[:20, :30], a)
    np.testing.assert_array_equal(row[:12, 34:], b)
    assert np.all(row[12:, 34:] == 255)
    titled = picture_row([a, b], ["a", "b"], title="t")
    np.testing.assert_array_equal(titled[-20:], row)
    with pytest.raises(ParameterError, match="titles"):
        picture_row([a, b], ["a"])
    with pytest.raises(ParameterError, match="uint8"):
        picture_row([a[..., 0]])


def test_flow_panel_shows_the_sharpening():
    from evmotion.eval.metrics import fwl

    rng = np.random.default_rng(5)
    n = 3000
    t = np.sort(rng.integers(0, 20_000, n))
    x = (20 + rng.integers(0, 6, n) * 25 + 1000e-6 * t).astype(np.float32)
    y = rng.uniform(5, 115, n).astype(np.float32)
    ev = EventArray(x, y, t, rng.integers(0, 2, n), sensor_size=(120, 200))
    flow = np.zeros((120, 200, 2), np.float32)
    flow[..., 0] = 1000.0
    valid = np.zeros((120, 200), bool)
    valid[:, :100] = True
    rgb, info = flow_panel(ev, flow, max_speed=2000.0, valid=valid, title="window 0")
    assert info["fwl"] == pytest.approx(fwl(ev, flow)) and info["fwl"] > 2
    assert info["max_speed"] == 2000.0 and info["fixed_scale"]
    pic = flow_picture(flow, max_speed=2000.0, valid=valid)
    k = pic.scale
    body = rgb[-pic.rgb.shape[0]:]
    np.testing.assert_array_equal(body[:, -pic.rgb.shape[1]:], pic.rgb)
    # the warped IWE (middle) concentrates the same events on fewer pixels than the raw one
    w = 200 * k
    raw, warped = body[:, :w], body[:, w + 4:2 * w + 4]
    assert np.sum(warped.min(axis=-1) < 128) < 0.6 * np.sum(raw.min(axis=-1) < 128)
    same, _ = flow_panel(ev, flow, max_speed=2000.0, valid=valid, title="window 1")
    assert same.shape == rgb.shape  # frames of a sequence line up in a video
    with pytest.raises(ParameterError, match="sensor size"):
        flow_panel(ev, flow[:-1], max_speed=2000.0)


def test_bos_flow_picture_greys_the_pixels_the_output_does_not_claim(tmp_path):
    # bos --png-dir: the legend says "grey: no events", so the output's valid mask
    # (event support) is what is grey, as evmotion view draws it (probe: no pixel was
    # grey while 8-23 % of them were valid), and the rim is the valid pixels' largest
    from evmotion.viz.bos import save_bos_pngs

    flow = np.zeros((40, 40, 2))
    flow[..., 0] = 50.0
    flow[:20, :, 0] = 400.0  # the unsupported half moves fastest
    valid = np.zeros((40, 40), bool)
    valid[20:] = True

    def grey_share(folder, **kw):
        save_bos_pngs(folder, 0, flow, np.zeros((40, 40)), np.zeros((40, 40, 2)), **kw)
        rgb = read_png(folder / "flow_00000.png")
        return float((rgb == GREY).all(-1).mean())

    assert grey_share(tmp_path / "all") < 0.01
    assert grey_share(tmp_path / "valid", valid=valid) > 0.1


def test_a_window_with_no_valid_pixel_and_a_long_title_are_drawn_whole(tmp_path):
    # probe BK: evmotion view of a window with no valid pixel cut its title at both ends
    # and drew "rim 1 px/s", the scale of no flow
    from evmotion.viz.flowpic import picture_row
    from evmotion.viz.images import save_flow_png

    flow = _radial()
    none = np.zeros(flow.shape[:2], bool)
    assert flow_picture(flow, valid=none).texts[2] == "no flow drawn"
    assert flow_picture(flow, valid=none, max_speed=60.0).texts[2] == "rim 60 px/s"
    img = flow_picture(flow).rgb
    short = picture_row([img], ["flow"], title="window 6 of 7")
    long = picture_row([img], ["flow"], title="trans_mcm.h5: window 6 of 7, [0.246761, "
                                              "0.25) s: no valid pixel, no measurement")
    assert long.shape[0] > short.shape[0] and long.shape[1] == short.shape[1]
    # no ink at the left and right edges of the title rows: nothing was cut there
    rows = long[: long.shape[0] - short.shape[0] + 10]
    assert (rows[:, :3] > 200).all() and (rows[:, -3:] > 200).all()
    a = save_flow_png(tmp_path / "a.png", flow, title="x" * 10)
    b = save_flow_png(tmp_path / "b.png", flow, title="a long title " * 8)
    assert a.texts == b.texts
    from evmotion.viz.images import read_png

    assert read_png(tmp_path / "b.png").shape[0] > read_png(tmp_path / "a.png").shape[0]


def test_bos_p_picture_is_unmasked_and_greys_only_nan(tmp_path, monkeypatch):
    # probe BN: p_*.png's legend said "grey: no events" though p is solved at every pixel
    # and none was grey
    import evmotion.viz.bos as vb

    drawn = {}
    real = vb.save_bos_flow_png

    def spy(path, *a, **kw):
        drawn[str(path).rsplit("/", 1)[-1]] = pic = real(path, *a, **kw)
        return pic

    monkeypatch.setattr(vb, "save_bos_flow_png", spy)
    p = np.zeros((40, 40, 2))
    p[5:10, 5:10] = 0.3
    p[:2] = np.nan
    flow = np.full((40, 40, 2), 10.0)
    vb.save_bos_pngs(tmp_path, 0, flow, np.zeros((40, 40)), p, valid=flow[..., 0] > 0)
    assert drawn["p_00000.png"].texts[4] == "unmasked; grey: NaN"
    assert drawn["flow_00000.png"].texts[4] == "grey: no events"
    rgb = read_png(tmp_path / "p_00000.png")
    k = drawn["p_00000.png"].scale
    assert (rgb == GREY).all(-1).sum() >= 2 * 40 * k * k  # the NaN rows, grey


def test_bos_sequence_pictures_share_their_scales_and_say_what_is_unmeasured(tmp_path,
                                                                               monkeypatch):
    # probe BX: each interval's flow and q were scaled to their own maxima, and the
    # start-up interval (no valid pixel) was drawn like the others
    import evmotion.viz.bos as vb
    from evmotion.io.bosfiles import BosSequence
    from evmotion.io.flowfiles import FlowSequence

    calls = []
    real = vb.save_bos_pngs

    def spy(folder, k, flow, q, p, **kw):
        calls.append(kw)
        return real(folder, k, flow, q, p, **kw)

    monkeypatch.setattr(vb, "save_bos_pngs", spy)
    flow = np.zeros((3, 20, 20, 2), np.float32)
    flow[0] = 900.0  # unmeasured: its speed is no scale
    flow[1, ..., 0] = 10.0
    flow[2, ..., 0] = 40.0
    valid = np.ones((3, 20, 20), bool)
    valid[0] = False
    q = np.stack([np.full((20, 20), 50.0), np.full((20, 20), 1.0), np.full((20, 20), -3.0)])
    seq = FlowSequence(flow=flow, t0=np.array([0, 10, 20]), t1=np.array([10, 20, 30]),
                       valid=valid, attrs={})
    bos = BosSequence(flow=seq, q=q, p=np.zeros((3, 20, 20, 2)), scalars={},
                      attrs={"q_units": "px^2/s"})
    assert len(vb.save_bos_sequence_pngs(tmp_path, bos)) == 9
    assert [c["flow_max"] for c in calls] == [pytest.approx(40.0)] * 3
    assert [c["q_limit"] for c in calls] == [pytest.approx(3.0)] * 3
    assert ["NOT A MEASUREMENT" in c["label"] for c in calls] == [True, False, False]
    calls.clear()
    vb.save_bos_sequence_pngs(tmp_path, bos, max_speed=100.0)
    assert [c["flow_max"] for c in calls] == [100.0] * 3


def test_a_flow_window_draws_q_on_the_flows_pixels():
    # probe BX: view of a BOS window drew q in a figure of its own, larger than the flow
    # beside it and lower
    from evmotion.viz.bos import flow_window_picture

    flow = np.zeros((40, 50, 2), np.float32)
    flow[..., 0] = 3.0
    q = np.zeros((40, 50))
    q[-1] = np.nan  # its last row grey
    rgb = flow_window_picture(flow, q=q)
    flow_rows = np.flatnonzero((rgb[:, 0] != 255).any(-1))
    grey_rows = np.flatnonzero((rgb == GREY).all(-1).sum(1) >= 50 * 4)
    k = -(-MIN_HEIGHT // 40)
    assert flow_rows.size == 40 * k
    np.testing.assert_array_equal(grey_rows, flow_rows[-k:])


@pytest.mark.parametrize("height,width", [(120, 160), (180, 240), (260, 346), (480, 640),
                                          (720, 1280)])
def test_the_legend_words_fit_inside_their_strip(height, width):
    # probe DA: "grey: nothing measured" was cut at both sides of a 640 x 480 flow's strip
    # (its font grows with the wheel); a clipped word leaves ink at the strip's edges
    flow = np.zeros((height, width, 2), np.float32)
    flow[..., 0] = 30.0
    none, some = np.zeros((height, width), bool), np.eye(height, width, dtype=bool)
    holed = flow.copy()
    holed[0, 0] = np.nan
    for pic in (flow_picture(flow, valid=none), flow_picture(flow, valid=some),
                flow_picture(holed), flow_picture(flow, max_speed=123456.0, unit="px/s")):
        strip = _box(pic.rgb, pic.legend_box)
        assert (strip[:, :2] == 255).all() and (strip[:, -2:] == 255).all(), pic.texts


def test_a_legend_of_no_flow_gives_no_scale():
    # probe DA: "no flow drawn" stood over "max of image", the scale of what was not drawn
    flow = _radial()
    pic = flow_picture(flow, valid=np.zeros(flow.shape[:2], bool))
    assert pic.texts[2:5] == ("no flow drawn", "", "grey: nothing measured")
    assert "max of image" not in pic.texts
    assert flow_picture(flow).texts[3] == "max of image"


def _framed_box(rgb: np.ndarray, shape: tuple[int, int]) -> tuple[int, int, int, int]:
    """``(row0, row1, col0, col1)`` inside the grey frame of a BOS picture of a field of
    ``shape``: the rows and columns holding long runs of the frame's grey."""
    grey = (rgb == 153).all(-1)
    rows = np.flatnonzero(grey.sum(1) >= shape[1])
    cols = np.flatnonzero(grey.sum(0) >= shape[0])
    assert rows.size >= 2 and cols.size >= 2, "no frame"
    return rows[0] + 1, rows[-1], cols[0] + 1, cols[-1]


def test_bos_q_flow_and_p_pictures_share_one_pixel_scale_and_are_framed(tmp_path):
    # probe DA: q_*.png was drawn at 3.5x, resampled, with no axes, beside a 2x flow with
    # no frame (its white zero flow ran into the page)
    from evmotion.viz.bos import save_bos_pngs

    h, w = 40, 50
    q = np.zeros((h, w))
    q[10:20, 20:30] = 100.0  # one block, the rest white in every picture
    flow = np.zeros((h, w, 2))
    flow[10:20, 20:30, 0] = 50.0
    save_bos_pngs(tmp_path, 0, flow, q, flow / 100.0, q_limit=200.0, label="[0, 10) us")
    k = flow_picture(flow).scale  # the flow's magnification, 4 for 40 rows
    for name in ("q", "flow", "p"):
        rgb = read_png(tmp_path / f"{name}_00000.png")
        r0, r1, c0, c1 = _framed_box(rgb, (h, w))
        assert (r1 - r0, c1 - c0) == (h * k, w * k), name
        inside = rgb[r0:r1, c0:c1]
        ink = np.argwhere((inside != inside[0, 0]).any(-1))  # off q = 0 / zero flow
        # the block, pixel for pixel at k screen pixels a pixel
        assert ink.min(0).tolist() == [10 * k, 20 * k], name
        assert (ink.max(0) + 1).tolist() == [20 * k, 30 * k], name


def test_view_and_bos_png_dir_draw_q_on_one_range(tmp_path, capsys, monkeypatch):
    # probe DA: view --window 1 drew q over +-480 ("clipped"), bos --png-dir the same
    # interval over +-380 ("|q| up to 880"): each had its own rule
    import evmotion.viz.bos as vb
    from evmotion.cli import main
    from evmotion.io.bosfiles import BosWriter, read_bos

    path = tmp_path / "bos.h5"
    h, w = 20, 30
    rng = np.random.default_rng(0)
    with BosWriter(path, (h, w)) as bw:
        for i, amp in enumerate((10.0, 100.0, 1000.0)):
            bw.append(np.full((h, w, 2), 5.0), 1000 * i, 1000 * (i + 1),
                      q=amp * rng.standard_normal((h, w)), p=np.zeros((h, w, 2)))
    scales = []
    real = vb._q_scale

    def spy(q, limit=None):
        scales.append(real(q, limit))
        return scales[-1]

    monkeypatch.setattr(vb, "_q_scale", spy)
    assert main(["view", str(path), "--window", "1", "--out", str(tmp_path / "v.png")]) == 0
    capsys.readouterr()
    viewed = scales[-1]
    scales.clear()
    vb.save_bos_sequence_pngs(tmp_path / "png", read_bos(path))
    assert scales[1] == viewed
    assert viewed[0] == pytest.approx(vb.bos_q_limit(read_bos(path).q))
    assert not viewed[2]  # at the file's range window 1 lies within (its own 99th % clipped)


def test_field_scale_is_the_flow_pictures():
    from evmotion.viz.bos import field_scale

    for shape in ((8, 8), (40, 50), (128, 160), (180, 160), (720, 1280)):
        assert field_scale(shape) == flow_picture(np.zeros((*shape, 2))).scale

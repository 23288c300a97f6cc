"""Reports are self-contained: every image they reference is embedded or resolves relative to
the report file itself, wherever the process ran."""

import base64
import html.parser
from pathlib import Path

import numpy as np
import pytest

from evmotion.errors import FormatError
from evmotion.viz import HtmlReport, flow_picture, iwe_to_rgb, save_png


class _Refs(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.refs: list[str] = []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img" and "src" in a:
            self.refs.append(a["src"])
        if tag == "a" and "href" in a:
            self.refs.append(a["href"])


def check_report_images(path: Path) -> list[str]:
    """Every image/link of the report: a PNG data URI, or a file relative to the report."""
    parser = _Refs()
    parser.feed(path.read_text())
    for ref in parser.refs:
        if ref.startswith("data:"):
            head, _, data = ref.partition(",")
            assert head == "data:image/png;base64", head
            assert base64.b64decode(data)[:8] == b"\x89PNG\r\n\x1a\n"
        else:
            assert not Path(ref).is_absolute(), ref
            assert (path.parent / ref).is_file(), f"{ref} does not resolve from {path.parent}"
    return parser.refs


def _build(tmp_path, embed):
    figs = tmp_path / "run" / "figs"
    save_png(figs / "iwe.png", iwe_to_rgb(np.eye(16)))
    save_png(figs / "flow.png", flow_picture(np.ones((16, 16, 2)), max_speed=2.0).rgb)
    rep = HtmlReport("run", embed=embed)
    # as the demo does: figure paths relative to the current directory, page elsewhere
    rep.add_figure(Path("run/figs/iwe.png"), "IWE")
    rep.add_figure(figs / "flow.png", "flow")
    return rep


@pytest.mark.parametrize("embed", [True, False])
def test_every_referenced_image_resolves(tmp_path, monkeypatch, embed):
    monkeypatch.chdir(tmp_path)
    rep = _build(tmp_path, embed)
    for page in (tmp_path / "run" / "report.html", tmp_path / "elsewhere" / "deep" / "r.html"):
        rep.write(page)
        refs = check_report_images(page)
        assert len(refs) == (2 if embed else 4)  # links wrap linked images only
    # an embedded page survives its pictures being deleted
    if embed:
        for p in (tmp_path / "run" / "figs").iterdir():
            p.unlink()
        check_report_images(tmp_path / "run" / "report.html")


def test_the_checker_catches_the_old_bug(tmp_path):
    page = tmp_path / "out" / "report.html"
    save_png(tmp_path / "out" / "x.png", iwe_to_rgb(np.eye(4)))
    page.write_text('<img src="../x.png">')  # what make demo wrote: relative to the cwd
    with pytest.raises(AssertionError, match="does not resolve"):
        check_report_images(page)


def test_a_missing_figure_is_an_error_not_a_broken_image(tmp_path):
    rep = HtmlReport("r")
    rep.add_figure(tmp_path / "never_written.png")
    with pytest.raises(FormatError, match="never_written.png"):
        rep.write(tmp_path / "r.html")
    assert not (tmp_path / "r.html").exists()


@pytest.mark.slow
def test_demo_report_shows_every_picture(tmp_path, monkeypatch):
    """``make demo``'s report, written from another directory: its images resolve (they
    pointed to ``../x.png``, resolved against the working directory)."""
    import evmotion.viz.bos as vb
    from evmotion import demo

    monkeypatch.setattr(demo, "_zoom", lambda out, rep, seed: {})  # the slow part
    # probe BX: the IWE and input panels had no scale, the two q their own ones
    panels, limits = {}, {}
    save_panel, save_q_png = demo.save_panel, vb.save_q_png

    def panel_spy(path, images, titles, *a, **kw):
        panels[Path(path).name] = titles
        return save_panel(path, images, titles, *a, **kw)

    def q_spy(path, q, **kw):
        limits[Path(path).name] = save_q_png(path, q, **kw)
        return limits[Path(path).name]

    monkeypatch.setattr(demo, "save_panel", panel_spy)
    monkeypatch.setattr(vb, "save_q_png", q_spy)
    (tmp_path / "cwd").mkdir()
    monkeypatch.chdir(tmp_path / "cwd")
    assert demo.main(["--out", "../demo_out"]) == 0
    assert "events/px" in panels["rotation_iwe.png"][0]
    assert "8-bit" in panels["bos_input.png"][0] and "full at" in panels["bos_input.png"][1]
    assert limits["bos_q.png"] == limits["bos_gt_q.png"]
    page = tmp_path / "demo_out" / "report.html"
    refs = check_report_images(page)
    assert len(refs) >= 10 and all(r.startswith("data:image/png") for r in refs)
    # the embedded pictures are the written ones, every one of them
    written = {p.read_bytes() for p in page.parent.glob("*.png")}
    assert {base64.b64decode(r.partition(",")[2]) for r in refs} == written

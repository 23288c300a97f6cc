"""Pictures: colour-coded flow with legend, IWE and event images, panels, HTML reports."""

from evmotion.viz.colorwheel import colorwheel, colorwheel_image, flow_max_magnitude, flow_to_rgb
from evmotion.viz.images import (
    event_histogram,
    flow_figure,
    iwe_to_rgb,
    read_png,
    save_flow_png,
    save_flow_summary,
    save_panel,
    save_png,
)
from evmotion.viz.report import HtmlReport

__all__ = [
    "HtmlReport",
    "colorwheel",
    "colorwheel_image",
    "event_histogram",
    "flow_figure",
    "flow_max_magnitude",
    "flow_to_rgb",
    "iwe_to_rgb",
    "read_png",
    "save_flow_png",
    "save_flow_summary",
    "save_panel",
    "save_png",
]

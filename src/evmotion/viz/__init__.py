"""Pictures: colour-coded flow with legend, IWE and event images, panels, HTML reports."""

from evmotion.viz import colorwheel as _colorwheel
from evmotion.viz import images as _images
from evmotion.viz import report as _report
from evmotion.viz.colorwheel import *  # noqa: F403
from evmotion.viz.images import *  # noqa: F403
from evmotion.viz.report import *  # noqa: F403

__all__ = sorted([*_colorwheel.__all__, *_images.__all__, *_report.__all__])

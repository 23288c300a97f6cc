"""Pictures: colour-coded flow with legend, IWE and event images, panels, videos, HTML reports."""

from evmotion.viz import colorwheel as _colorwheel
from evmotion.viz import flowpic as _flowpic
from evmotion.viz import images as _images
from evmotion.viz import report as _report
from evmotion.viz import video as _video
from evmotion.viz.colorwheel import *  # noqa: F403
from evmotion.viz.flowpic import *  # noqa: F403
from evmotion.viz.images import *  # noqa: F403
from evmotion.viz.report import *  # noqa: F403
from evmotion.viz.video import *  # noqa: F403

__all__ = sorted([*_colorwheel.__all__, *_flowpic.__all__, *_images.__all__, *_report.__all__,
                  *_video.__all__])

"""Evaluation: accuracy and sharpness metrics (and dataset adapters with ground truth)."""

from evmotion.eval import eventflow as _eventflow
from evmotion.eval import metrics as _metrics
from evmotion.eval import windows as _windows
from evmotion.eval.eventflow import *  # noqa: F403  (the names of eventflow.__all__)
from evmotion.eval.metrics import *  # noqa: F403  (the names of metrics.__all__)
from evmotion.eval.windows import *  # noqa: F403  (the names of windows.__all__)

__all__ = list(_metrics.__all__) + list(_eventflow.__all__) + list(_windows.__all__)

"""Evaluation: accuracy and sharpness metrics (and dataset adapters with ground truth)."""

from evmotion.eval.metrics import (
    NPE_THRESHOLDS,
    FlowMetrics,
    RmsError,
    aggregate_flow_metrics,
    angular_error_deg,
    endpoint_error,
    event_mask,
    flow_metrics,
    fwl,
    rms_error,
    sample_flow_bilinear,
    valid_gt_mask,
    warp_by_flow,
)

__all__ = [
    "NPE_THRESHOLDS",
    "FlowMetrics",
    "RmsError",
    "aggregate_flow_metrics",
    "angular_error_deg",
    "endpoint_error",
    "event_mask",
    "flow_metrics",
    "fwl",
    "rms_error",
    "sample_flow_bilinear",
    "valid_gt_mask",
    "warp_by_flow",
]

"""Reading and writing events, frames, IMU and flow in every common format.

Formats are found by content (:func:`detect_format`), so ``read_events("anything")`` works
for ECD text folders, evmotion/MVSEC/DSEC HDF5, npy/npz, MATLAB excerpts, AEDAT, Prophesee
RAW/DAT and rosbags (whichever modules are installed). Every reader returns an
:class:`~evmotion.events.EventArray` with absolute int64 µs timestamps.

This package re-exports the public API; the code lives in modules named after what they
hold: :mod:`~evmotion.io.read` (read, stream), :mod:`~evmotion.io.write`,
:mod:`~evmotion.io.summary` (describe), :mod:`~evmotion.io.calibration`, :mod:`~evmotion.io.registry`
(detection, one module per format), :mod:`~evmotion.io.flowfiles` and
:mod:`~evmotion.io.aux` (frames, IMU).

Examples
--------
>>> import evmotion.io as eio
>>> from evmotion import EventArray
>>> eio.write_events("boxes_rotation/events.txt", EventArray(  # an ECD folder
...     x=[1, 2, 3, 4, 5], y=[0, 1, 2, 3, 4], t=[0, 5_000, 15_000, 25_000, 60_000],
...     p=[1, 0, 1, 0, 1], sensor_size=(180, 240)))
>>> ev = eio.read_events("boxes_rotation/", t0=0, t1=50_000)
>>> eio.write_events("big.h5", ev)
>>> for chunk in eio.iter_events("big.h5", window_us=10_000):
...     print(chunk.t_start, len(chunk))
0 2
15000 1
25000 1
"""

from evmotion.io.aux import FrameSequence, ImuSequence, read_frames, read_imu
from evmotion.io.base import FormatSpec
from evmotion.io.calibration import read_calibration
from evmotion.io.flowfiles import (
    FlowSequence,
    FlowWriter,
    read_dsec_flow_png,
    read_flo,
    read_flow_h5,
    read_gt_flow,
    write_dsec_flow_png,
    write_flo,
)
from evmotion.io.flowout import open_flow_output
from evmotion.io.flowread import read_flow
from evmotion.io.read import iter_events, read_events
from evmotion.io.registry import all_formats, detect_format
from evmotion.io.summary import describe
from evmotion.io.write import format_for_output, write_events

__all__ = [
    "FlowSequence",
    "FlowWriter",
    "FormatSpec",
    "FrameSequence",
    "ImuSequence",
    "all_formats",
    "describe",
    "detect_format",
    "format_for_output",
    "iter_events",
    "open_flow_output",
    "read_calibration",
    "read_dsec_flow_png",
    "read_events",
    "read_flo",
    "read_flow",
    "read_flow_h5",
    "read_frames",
    "read_gt_flow",
    "read_imu",
    "write_dsec_flow_png",
    "write_events",
    "write_flo",
]

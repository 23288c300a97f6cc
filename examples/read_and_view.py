"""Read a recording from a file, look at it, cut it into windows.

Writes a short simulated recording to a temporary folder in two formats (evmotion HDF5 and
Prophesee EVT3 RAW), reads it back with ``read_events`` (the format is detected from the
content), streams it window by window with ``iter_events`` and saves pictures of the
events: an event count image and a signed (ON - OFF) image of each of three windows.

Run: ``python examples/read_and_view.py [OUT_DIR]``. Point ``read_events`` at your own file
(ECD folder or text, MVSEC/DSEC HDF5, AEDAT4, AEDAT 2.0, EVT2/EVT3 RAW, DAT, ROS bag, npy/npz)
to view it the same way.
"""

import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from evmotion.io import detect_format, iter_events, read_events, write_events
from evmotion.sim import simulate
from evmotion.viz import event_histogram, iwe_to_rgb, save_panel

PNGS = ("read_view.png",)

out = Path(sys.argv[1] if len(sys.argv) > 1 else os.environ.get("EVMOTION_EXAMPLES_OUT",
                                                                 "examples_out"))
out.mkdir(parents=True, exist_ok=True)

sim = simulate("rotation", duration_s=0.03, sensor_size=(120, 160), seed=0,
               show_progress=False)
images, titles = [], []
with tempfile.TemporaryDirectory() as tmp:
    for name in ("recording.h5", "recording.raw"):
        path = Path(tmp) / name
        write_events(path, sim.events)
        events = read_events(path)
        assert np.array_equal(events.t, sim.events.t)   # every format keeps µs timestamps
        print(f"{name}: format {detect_format(path)}, {len(events)} events, "
              f"sensor {events.sensor_size}, {events.duration_us / 1e3:.1f} ms")
    for i, win in enumerate(iter_events(path, window_us=10_000)):   # bounded memory
        images.append(iwe_to_rgb(event_histogram(win, signed=True), polarity=True))
        titles.append(f"window {i}: {len(win)} events")
save_panel(out / PNGS[0], [iwe_to_rgb(event_histogram(events)), *images],
           ["all events (count)", *titles])
print(f"wrote {out / PNGS[0]}")

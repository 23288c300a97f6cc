"""Other tools' HDF5 layouts (evmotion.io.h5generic): read through read_events, each
against the events it was written with."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from evmotion.errors import EvmotionWarning
from evmotion.io import read_events

N = 500
RNG = np.random.default_rng(0)
T = np.sort(RNG.integers(0, 100_000, N)).astype(np.int64)
X = RNG.integers(0, 320, N).astype(np.uint16)
Y = RNG.integers(0, 200, N).astype(np.uint16)
P = RNG.integers(0, 2, N).astype(np.uint8)
X[0], Y[0] = 319, 199  # the largest coordinates: the inferred sensor is 320 x 200


def _fields(f, group, names):
    g = f.require_group(group) if group else f
    for key, name in names.items():
        g[name] = {"t": T, "x": X, "y": Y, "p": P}[key]


def _compound(f, name, attrs=None):
    data = np.zeros(N, dtype=[("x", "<u2"), ("y", "<u2"), ("p", "<i2"), ("t", "<i8")])
    data["x"], data["y"], data["p"], data["t"] = X, Y, P, T
    f[name] = data
    f.attrs.update(attrs or {})


LAYOUTS = {
    "root x y t p": lambda f: _fields(f, "", {k: k for k in "xytp"}),
    "events/ without sensor attributes": lambda f: _fields(f, "events",
                                                           {k: k for k in "xytp"}),
    "event_utils xs ys ts ps": lambda f: _fields(f, "events", {"x": "xs", "y": "ys",
                                                               "t": "ts", "p": "ps"}),
    "compound events": lambda f: _compound(f, "events"),
    "Metavision CD/events": lambda f: _compound(f, "CD/events", {"geometry": "640x480"}),
    "v2e N x 4": lambda f: f.create_dataset("events", data=np.stack(
        [T, X, Y, P], 1).astype(np.uint32)),
}


@pytest.mark.parametrize("name", LAYOUTS)
def test_layouts_read_exactly(tmp_path, name):
    path = tmp_path / "ev.h5"
    with h5py.File(path, "w") as f:
        LAYOUTS[name](f)
    if name == "Metavision CD/events":
        ev = read_events(path)
        assert ev.sensor_size == (480, 640)
    else:
        with pytest.warns(EvmotionWarning, match="taken as 320x200"):
            ev = read_events(path)
        assert ev.sensor_size == (200, 320)
    assert ev.meta["format"] == "h5generic"
    np.testing.assert_array_equal(ev.t, T)
    np.testing.assert_array_equal(ev.x, X)
    np.testing.assert_array_equal(ev.y, Y)
    np.testing.assert_array_equal(ev.p, P)


def test_float_seconds_and_evmotions_own_files_stay_theirs(tmp_path):
    """events/t in float seconds with height/width went to the evmotion reader, which
    refused its dtype; evmotion's own files are still read by it."""
    from evmotion.events import EventArray
    from evmotion.io import write_events

    path = tmp_path / "f.h5"
    with h5py.File(path, "w") as f:
        _fields(f, "events", {k: k for k in "xyp"})
        f["events/t"] = T * 1e-6
        f.attrs.update(height=200, width=320)
    ev = read_events(path)
    assert ev.meta["format"] == "h5generic" and ev.sensor_size == (200, 320)
    np.testing.assert_array_equal(ev.t, T)
    own = tmp_path / "own.h5"
    write_events(own, EventArray(X, Y, T, P, sensor_size=(200, 320)))
    assert read_events(own).meta["format"] == "h5"

"""The streaming writers (DAT, EVT 2.0/3.0, AEDAT4) refuse in chunks what they refuse whole
(probe DM)."""

from __future__ import annotations

import numpy as np
import pytest

from evmotion.errors import FormatError
from evmotion.events import EventArray
from evmotion.io import aedat4, write_events

FORMATS = ["dat", "evt2", "evt3", "aedat4"]


def _events(n=50, size=(48, 64)):
    rng = np.random.default_rng(1)
    return EventArray(x=rng.integers(0, size[1], n), y=rng.integers(0, size[0], n),
                      t=np.sort(rng.integers(0, 10_000, n)), p=rng.integers(0, 2, n),
                      sensor_size=size)


@pytest.mark.parametrize("fmt", FORMATS)
def test_an_empty_chunk_of_another_sensor_is_refused(tmp_path, fmt):
    """Joined whole, chunks of two sensors are refused; an empty one of another had
    passed the chunked writers (and gave its size to the header when it came first)."""
    ev = _events()
    other = EventArray(x=[], y=[], t=[], p=[], sensor_size=(100, 100))
    for parts in ([other, ev], [ev, other], [ev[:10], other, ev[10:]]):
        with pytest.raises(FormatError, match=r"sensor \(\d+, \d+\) after"):
            write_events(tmp_path / "o.x", iter(parts), format=fmt)
        assert not (tmp_path / "o.x").exists()
    write_events(tmp_path / "o.x", iter([ev[:0], ev, ev[:0]]), format=fmt)


def test_aedat4_refuses_events_out_of_time_order(tmp_path):
    """AEDAT4 wrote an unsorted array (or chunks stepping back) that it could not read
    back, where DAT and EVT refuse it."""
    back = EventArray(x=[1, 2], y=[1, 2], t=[20, 10], p=[1, 0], sensor_size=(8, 8),
                      validate=False)
    with pytest.raises(FormatError, match="AEDAT4 stores times in order"):
        aedat4.write(tmp_path / "u.aedat4", back)
    ev = _events()
    with pytest.raises(FormatError, match=r"AEDAT4 stores times in order: .*t\[24\]=\d+ > t\[25\]=\d+ us"):
        aedat4.write(tmp_path / "u.aedat4", iter([ev[25:], ev[:25]]))
    assert not (tmp_path / "u.aedat4").exists()

"""Ctrl-C while a streaming writer is created or aborted: no partial file is left.

An interrupt that landed in a writer's constructor after it had created its ``.part``
(writing the header) left that file: the caller never held the writer, so nothing could
abort it (``evmotion simulate`` interrupted near its end, one run in 40 on a loaded
machine). One that landed in ``abort`` left it half-removed.
"""

import signal

import h5py
import numpy as np
import pytest

from evmotion.io.bosfiles import BosWriter
from evmotion.io.eventflow import EventFlowWriter
from evmotion.io.flowfiles import FlowWriter
from evmotion.io.flowout import open_flow_output
from evmotion.io.h5 import EventWriter
from evmotion.utils import interrupts_deferred

SIZE = (12, 16)
WRITERS = {
    "events": lambda d: EventWriter(d / "ev.h5", SIZE),
    "flow.h5": lambda d: FlowWriter(d / "flow.h5", SIZE),
    "bos.h5": lambda d: BosWriter(d / "bos.h5", SIZE),
    "event-flow.h5": lambda d: EventFlowWriter(d / "ef.h5", SIZE),
    "event-flow.npz": lambda d: EventFlowWriter(d / "ef.npz", SIZE),
    "flow output .h5": lambda d: open_flow_output(d / "out.h5", SIZE),
    "flow output .npz": lambda d: open_flow_output(d / "out.npz", SIZE),
}


def _ctrl_c_after(monkeypatch, cls, name):
    """Ctrl-C right after ``cls.name`` first returns (the file made, not yet set up)."""
    real = getattr(cls, name)
    fired = []

    def then_interrupt(*args, **kwargs):
        out = real(*args, **kwargs)
        if not fired:
            fired.append(True)
            signal.raise_signal(signal.SIGINT)
        return out

    monkeypatch.setattr(cls, name, then_interrupt)
    return fired


@pytest.mark.parametrize("kind", list(WRITERS))
def test_ctrl_c_while_a_writer_is_created_leaves_nothing(tmp_path, monkeypatch, kind):
    if kind.endswith(".npz"):
        import tempfile

        fired = _ctrl_c_after(monkeypatch, tempfile, "mkstemp")
    else:
        fired = _ctrl_c_after(monkeypatch, h5py.File, "__init__")
    with pytest.raises(KeyboardInterrupt):
        WRITERS[kind](tmp_path)
    assert fired
    _nothing_but_a_part_to_resume(tmp_path, kind)


def _nothing_but_a_part_to_resume(folder, kind):
    """Nothing left, except the ``.part`` a flow or BOS writer keeps for ``resume``
    (removed where the command line's output wraps it): whole, closed, and holding no
    window, which a resumed run removes."""
    left = sorted(p.name for p in folder.iterdir())
    if kind not in ("flow.h5", "bos.h5"):
        assert left == []
        return
    assert left == [f"{kind}.part"]
    with h5py.File(folder / left[0], "r") as f:
        assert f["flow"].shape[0] == 0


@pytest.mark.parametrize("kind", [k for k in WRITERS if not k.endswith(".npz")])
def test_ctrl_c_while_a_writer_aborts_leaves_nothing(tmp_path, monkeypatch, kind):
    """An .h5 writer's abort closes the file, then removes it; the interrupt comes as the
    file is closed."""
    w = WRITERS[kind](tmp_path)
    fired = _ctrl_c_after(monkeypatch, h5py.File, "close")
    with pytest.raises(KeyboardInterrupt):
        w.abort()
    assert fired
    _nothing_but_a_part_to_resume(tmp_path, kind)


def test_a_writer_made_without_interruption_is_kept():
    """The deferral costs nothing when no signal comes: the handlers are put back."""
    before = signal.getsignal(signal.SIGINT)
    with interrupts_deferred() as held:
        assert held == []
        assert signal.getsignal(signal.SIGINT) is not before
        with interrupts_deferred() as inner:
            assert inner is None  # the outer block delivers
    assert signal.getsignal(signal.SIGINT) is before


def test_events_written_after_a_deferred_block_are_whole(tmp_path):
    from evmotion.events import EventArray
    from evmotion.io.h5 import read

    ev = EventArray(x=np.arange(5), y=np.zeros(5, int), t=np.arange(5) * 10, p=np.ones(5, int),
                    sensor_size=SIZE)
    with EventWriter(tmp_path / "ev.h5", SIZE) as w:
        w.append(ev)
    assert read(tmp_path / "ev.h5").t.tolist() == [0, 10, 20, 30, 40]


def test_ctrl_c_while_a_pattern_output_is_published_moves_it_whole(tmp_path, monkeypatch):
    """Probe BH: an interrupt among the moves of a .flo pattern's files left 3-15 of 18
    windows (one without its sidecar), or a new run's first window among an earlier run's
    others, a set that eval scored as complete. The moves now finish, then the interrupt
    lands."""
    import os

    pattern = tmp_path / "f_{:03d}.flo"
    with open_flow_output(pattern, SIZE, n_windows=4) as old:
        for k in range(4):
            old.append(np.zeros((*SIZE, 2), np.float32), k * 10, k * 10 + 10)
    out = open_flow_output(pattern, SIZE, n_windows=3)
    for k in range(3):
        out.append(np.ones((*SIZE, 2), np.float32), k * 10, k * 10 + 10)
    fired = _ctrl_c_after(monkeypatch, os, "replace")
    with pytest.raises(KeyboardInterrupt):
        out.close()
    assert fired
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == [f"f_{k:03d}.flo{s}" for k in range(3) for s in ("", ".json")]
    from evmotion.io.flowfiles import read_flo

    assert all(np.all(read_flo(tmp_path / f"f_{k:03d}.flo") != 0) for k in range(3))

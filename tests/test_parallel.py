"""map_windows: ordering, executors (serial, thread, process, Dask), failures, resume."""

from __future__ import annotations

import functools
import os
import re
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from evmotion.errors import EmptyWindowError, EvmotionWarning, ParameterError
from evmotion.events import EventArray
from evmotion.parallel import WindowResult, map_windows


def _events(n: int = 1000, seed: int = 0) -> EventArray:
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 100_000, n))
    return EventArray(rng.integers(0, 32, n), rng.integers(0, 24, n), t,
                      rng.integers(0, 2, n), sensor_size=(24, 32))


def count_and_span(ev: EventArray) -> tuple[int, int, int]:
    if not len(ev):
        return (0, -1, -1)
    return (len(ev), int(ev.t[0]), int(ev.t[-1]))


def slow_reverse(ev: EventArray) -> int:
    # Earlier windows finish later, so completion order differs from window order.
    time.sleep(0.02 * max(0, 5 - int(ev.t[0]) // 20_000) if len(ev) else 0)
    return len(ev)


def fail_in_middle(ev: EventArray, t0: int, t1: int) -> int:
    if t0 == 40_000:
        raise RuntimeError("deliberate failure")
    return len(ev)


def empty_in_middle(ev: EventArray, t0: int, t1: int) -> int:
    if t0 == 40_000:
        raise EmptyWindowError("window's 30000 events are all at one time (0 us)")
    return len(ev)


def counted(ev: EventArray, calls_dir: str, fail_from_us: int | None = None) -> int:
    """Record each call as a file (works across processes), optionally fail late windows."""
    t0 = int(ev.t[0]) // 20_000 * 20_000
    Path(calls_dir, f"call_{t0}_{os.getpid()}_{time.perf_counter_ns()}").touch()
    if fail_from_us is not None and t0 >= fail_from_us:
        raise RuntimeError("simulated interruption")
    return len(ev)


WINDOWS = [(k * 20_000, (k + 1) * 20_000) for k in range(5)]


def _expected(ev: EventArray) -> list[tuple[int, int, int]]:
    return [count_and_span(ev.slice_time(a, b)) for a, b in WINDOWS]


@pytest.mark.parametrize("executor,workers", [("process", 1), ("thread", 3), ("process", 2)])
def test_results_in_window_order(executor, workers):
    ev = _events()
    res = map_windows(count_and_span, ev, WINDOWS, workers=workers, executor=executor,
                      progress=False)
    assert [r.index for r in res] == list(range(5))
    assert [(r.t0, r.t1) for r in res] == WINDOWS
    assert all(r.ok for r in res)
    assert [r.value for r in res] == _expected(ev)


def test_order_kept_when_completion_order_differs():
    ev = _events()
    res = map_windows(slow_reverse, ev, WINDOWS, workers=3, executor="thread", progress=False)
    assert [r.value for r in res] == [len(ev.slice_time(a, b)) for a, b in WINDOWS]


def test_accepts_window_objects():
    ev = _events()
    wins = ev.windows_by_count(300)
    res = map_windows(len, ev, wins, progress=False)
    assert [r.value for r in res] == [w.count for w in wins]


def test_count_windows_keep_their_events_when_timestamps_repeat():
    ev = EventArray(np.zeros(6, int), np.zeros(6, int), [0, 10, 10, 10, 20, 30],
                    np.ones(6, int), sensor_size=(1, 1))
    wins = ev.windows_by_count(2)
    res = map_windows(count_and_span, ev, wins, progress=False)
    assert [r.value for r in res] == [(2, 0, 10), (2, 10, 10), (2, 20, 30)] == [
        count_and_span(ev.window(w)) for w in wins]


@pytest.mark.parametrize("executor,workers", [("process", 1), ("process", 2)])
def test_failing_window_reported_others_kept(executor, workers):
    ev = _events()
    res = map_windows(fail_in_middle, ev, WINDOWS, workers=workers, executor=executor,
                      with_window=True, progress=False)
    bad = [r for r in res if not r.ok]
    assert len(bad) == 1
    assert (bad[0].index, bad[0].t0, bad[0].t1) == (2, 40_000, 60_000)
    assert "RuntimeError: deliberate failure" in bad[0].error
    # evmotion's own errors by their message, no class name for the user to read (probe BJ)
    res = map_windows(empty_in_middle, ev, WINDOWS, workers=workers, executor=executor,
                      with_window=True, progress=False)
    line = next(r for r in res if not r.ok).error.splitlines()[0]
    assert line == "window's 30000 events are all at one time (0 us)"
    assert [r.value for r in res if r.ok] == [len(ev.slice_time(a, b))
                                             for a, b in WINDOWS if a != 40_000]


def die_in_middle(ev: EventArray, t0: int, t1: int) -> int:
    if t0 == 40_000:
        import signal

        os.kill(os.getpid(), signal.SIGKILL)  # as the out-of-memory killer ends a worker
    return len(ev)


def test_a_dead_worker_stops_the_run_in_one_line():
    """A worker killed mid-run: its windows came back as failed results, then the next
    submit raised BrokenProcessPool, a traceback; a caller journaling results for --resume
    had recorded the dead worker's windows as done, without rows (probe CH)."""
    from evmotion.errors import WorkerDiedError
    from evmotion.parallel import imap_windows

    got = []
    with pytest.raises(WorkerDiedError,
                       match=r"worker process died while the pool computed \[\d+, \d+\) us"
                       ) as died:
        for r in imap_windows(die_in_middle, _events(), WINDOWS, workers=2,
                              with_window=True, progress=False):
            got.append(r)
    assert all(r.ok for r in got) and 2 not in [r.index for r in got]
    # the span holds the window whose worker died (which of those running is not known)
    t0, t1 = map(int, re.search(r"\[(\d+), (\d+)\)", str(died.value)).groups())
    assert t0 <= 40_000 and 60_000 <= t1


def test_unpicklable_function_is_reported_clearly():
    ev = _events()
    res = map_windows(lambda e: len(e), ev, WINDOWS[:2], workers=2, executor="process",
                      progress=False)
    assert not any(r.ok for r in res)
    assert "picklable" in res[0].error


def test_resume_skips_finished_windows(tmp_path):
    ev = _events()
    calls = tmp_path / "calls"
    calls.mkdir()
    resume = tmp_path / "resume"
    first = map_windows(functools.partial(counted, calls_dir=str(calls), fail_from_us=60_000),
                        ev, WINDOWS, workers=2, executor="process", resume_dir=resume,
                        progress=False)
    assert [r.ok for r in first] == [True, True, True, False, False]
    assert len(list(calls.iterdir())) == 5
    assert len(list(resume.glob("*.pkl"))) == 3
    for f in calls.iterdir():
        f.unlink()
    second = map_windows(functools.partial(counted, calls_dir=str(calls)), ev, WINDOWS,
                         workers=2, executor="process", resume_dir=resume, progress=False)
    assert all(r.ok for r in second)
    assert [r.cached for r in second] == [True, True, True, False, False]
    assert [r.value for r in second] == [len(ev.slice_time(a, b)) for a, b in WINDOWS]
    recomputed = sorted(int(f.name.split("_")[1]) for f in calls.iterdir())
    assert recomputed == [60_000, 80_000]
    # A third run computes nothing at all.
    for f in calls.iterdir():
        f.unlink()
    third = map_windows(functools.partial(counted, calls_dir=str(calls)), ev, WINDOWS,
                        resume_dir=resume, progress=False)
    assert all(r.cached for r in third) and not list(calls.iterdir())


def warn_late(ev: EventArray, t0: int, t1: int) -> int:
    if t0 >= 40_000:
        warnings.warn(EvmotionWarning(f"window at {t0} us looks odd"), stacklevel=1)
    return len(ev)


@pytest.mark.parametrize("executor,workers", [("process", 1), ("thread", 2), ("process", 2)])
def test_warnings_of_worker_processes_reach_the_caller(executor, workers, tmp_path):
    """A window's warnings are issued here, where the caller's filters and summaries see
    them (also from worker processes), and again when it is resumed from resume_dir."""
    ev = _events()
    with pytest.warns(EvmotionWarning) as caught:
        res = map_windows(warn_late, ev, WINDOWS, workers=workers, executor=executor,
                          with_window=True, resume_dir=tmp_path, progress=False)
    said = sorted(str(w.message) for w in caught if issubclass(w.category, EvmotionWarning))
    assert said == [f"window at {t} us looks odd" for t in (40_000, 60_000, 80_000)]
    assert [r.value for r in res] == [len(ev.slice_time(a, b)) for a, b in WINDOWS]
    assert [len(r.warnings) for r in res] == [0, 0, 1, 1, 1]
    with pytest.warns(EvmotionWarning) as again:
        resumed = map_windows(warn_late, ev, WINDOWS, workers=workers, with_window=True,
                              resume_dir=tmp_path, progress=False)
    assert all(r.cached for r in resumed)
    assert sorted(str(w.message) for w in again) == said


def test_dask_local_cluster():
    distributed = pytest.importorskip("distributed")
    ev = _events()
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=":0") as cluster, \
            distributed.Client(cluster) as client:
        res = map_windows(fail_in_middle, ev, WINDOWS, scheduler=client, with_window=True,
                          progress=False)
        res2 = map_windows(count_and_span, ev, WINDOWS, scheduler=cluster.scheduler_address,
                           progress=False)
    assert [r.index for r in res] == list(range(5))
    assert [r.ok for r in res] == [True, True, False, True, True]
    assert "deliberate failure" in res[2].error
    assert [r.value for r in res2] == _expected(ev)


def test_path_source_reads_each_window(tmp_path, monkeypatch):
    import evmotion.io as evio

    ev = _events()
    seen = []

    def fake_read_events(path, t0=None, t1=None, **kw):
        seen.append((path, t0, t1, kw))
        return ev.slice_time(t0, t1)

    monkeypatch.setattr(evio, "read_events", fake_read_events, raising=False)
    res = map_windows(count_and_span, tmp_path / "rec.h5", WINDOWS, progress=False,
                      read_kwargs={"format": "h5"})
    assert [r.value for r in res] == _expected(ev)
    assert seen == [(str(tmp_path / "rec.h5"), a, b, {"format": "h5", "warn_empty": False})
                    for a, b in WINDOWS]


def test_bad_arguments():
    ev = _events()
    with pytest.raises(ParameterError, match="workers"):
        map_windows(len, ev, WINDOWS, workers=0)
    with pytest.raises(ParameterError, match=r"windows\[1\]"):
        map_windows(len, ev, [(0, 10), (20, 5)])
    with pytest.raises(ParameterError, match="executor"):
        map_windows(len, ev, WINDOWS, workers=2, executor="gpu")
    with pytest.raises(ParameterError, match="executor"):
        map_windows(len, ev, WINDOWS, executor="procs")


def test_window_result_ok():
    assert WindowResult(0, 0, 1, value=3).ok
    assert not WindowResult(0, 0, 1, error="x").ok


def interrupted(ev: EventArray, calls_dir: str, stop_at_us: int) -> int:
    t0 = int(ev.t[0]) // 20_000 * 20_000
    if t0 >= stop_at_us:
        raise KeyboardInterrupt
    Path(calls_dir, f"call_{t0}").touch()
    return len(ev)


def test_resume_after_keyboard_interrupt(tmp_path):
    """Ctrl-C stops the run; what finished before is on disk and is not recomputed."""
    ev = _events()
    calls = tmp_path / "calls"
    calls.mkdir()
    resume = tmp_path / "resume"
    with pytest.raises(KeyboardInterrupt):
        map_windows(functools.partial(interrupted, calls_dir=str(calls), stop_at_us=40_000),
                    ev, WINDOWS, resume_dir=resume, progress=False)
    assert sorted(f.name for f in calls.iterdir()) == ["call_0", "call_20000"]
    assert len(list(resume.glob("*.pkl"))) == 2
    assert not [p for p in resume.iterdir() if p.suffix != ".pkl"]  # no partial files
    for f in calls.iterdir():
        f.unlink()
    res = map_windows(functools.partial(interrupted, calls_dir=str(calls), stop_at_us=10**9),
                      ev, WINDOWS, resume_dir=resume, progress=False)
    assert [r.cached for r in res] == [True, True, False, False, False]
    assert sorted(int(f.name.split("_")[1]) for f in calls.iterdir()) == [40_000, 60_000, 80_000]
    assert [r.value for r in res] == [len(ev.slice_time(a, b)) for a, b in WINDOWS]


def test_workers_are_not_forked_from_a_threaded_process():
    import threading

    from evmotion.parallel import _process_context

    if threading.active_count() == 1:
        assert _process_context().get_start_method() in ("fork", "spawn")
    stop = threading.Event()
    th = threading.Thread(target=stop.wait)
    th.start()
    try:
        assert _process_context().get_start_method() in ("forkserver", "spawn")
    finally:
        stop.set()
        th.join()


def test_caller_managed_executor_is_left_running():
    from concurrent.futures import ThreadPoolExecutor

    ev = _events()
    with ThreadPoolExecutor(2) as pool:
        a = map_windows(count_and_span, ev, WINDOWS, workers=2, executor=pool, progress=False)
        b = map_windows(count_and_span, ev, WINDOWS, workers=2, executor=pool, progress=False)
        assert pool.submit(int, "7").result() == 7
    assert [r.value for r in a] == [r.value for r in b] == _expected(ev)


@pytest.mark.parametrize("executor,workers", [("process", 1), ("process", 2)])
def test_path_source_with_real_reader(tmp_path, executor, workers):
    """Each worker opens the recording itself and reads only its window."""
    import evmotion.io as eio

    ev = _events()
    path = tmp_path / "rec.h5"
    eio.write_events(path, ev)
    res = map_windows(count_and_span, path, WINDOWS, workers=workers, executor=executor,
                      progress=False)
    assert all(r.ok for r in res), [r.error for r in res if not r.ok]
    assert [r.value for r in res] == _expected(ev)


def _batches(batcher, elapsed_s: float, compile_s: float = 0.0) -> list[list[int]]:
    """Drain a batcher as the Dask loop does: the first ``limit`` batches go out before
    any result, then each result returned lets the next batch go."""
    from evmotion.parallel import WindowResult as Res

    out, inflight = [], []
    while len(inflight) < batcher.limit and (b := batcher.next()):
        inflight.append(b)
    while inflight:
        batch = inflight.pop(0)
        out.append([t.index for t in batch])
        for t in batch:
            batcher.record(Res(t.index, t.t0, t.t1, elapsed_s=elapsed_s + compile_s,
                               compile_s=compile_s))
        if b := batcher.next():
            inflight.append(b)
    return out


def test_batches_of_short_windows_fill_the_target_and_shrink_at_the_end():
    from evmotion.parallel import BATCH_TARGET_S, _Batcher, _Task

    tasks = [_Task(k, 10 * k, 10 * k + 10) for k in range(60)]
    window_s = BATCH_TARGET_S / 6.5
    out = _batches(_Batcher(tasks, limit=4), elapsed_s=window_s)
    assert [k for b in out for k in b] == list(range(60))  # every window once, in order
    sizes = [len(b) for b in out]
    # nothing known yet: one window a task; then the 6 windows that fit in the target;
    # then the windows left over the 4 tasks in flight, rounded up (20 left: 5, 15: 4,
    # ...), so that the last tasks are single windows and the workers finish together
    assert sizes == [1, 1, 1, 1, 6, 6, 6, 6, 6, 6, 5, 4, 3, 2, 2, 1, 1, 1, 1]
    # seconds spent compiling kernels are left out of the mean
    assert _batches(_Batcher(tasks, limit=4), elapsed_s=window_s, compile_s=2.0) == out
    # each fresh worker's first window (imports, cached kernels loaded) does not stop it
    slow_first = _Batcher(tasks, limit=4)
    for t in [slow_first.next()[0] for _ in range(2)]:
        slow_first.record(WindowResult(t.index, t.t0, t.t1, elapsed_s=1.5))
    sizes = [len(b) for b in _batches(slow_first, elapsed_s=window_s)]
    assert max(sizes) == 6 and len(sizes) < 25
    # windows as long as the target go one a task, as without batching
    long = _batches(_Batcher(tasks, limit=4), elapsed_s=BATCH_TARGET_S)
    assert long == [[k] for k in range(60)]


def test_broken_batch_goes_again_one_window_a_task():
    from evmotion.parallel import _Batcher, _Task

    b = _Batcher([_Task(k, k, k + 1) for k in range(5)], limit=1)
    first = b.next()
    b.again(first + b.next())  # nothing recorded yet: single windows
    assert [[t.index for t in b.next()] for _ in range(3)] == [[0], [1], [2]]


def short_window(ev: EventArray, t0: int, t1: int):
    if t0 == 36_000:
        return threading.Lock()  # does not pickle: the task of its batch breaks
    if t0 == 52_000:
        raise RuntimeError("deliberate failure")
    time.sleep(0.002)
    return count_and_span(ev)


def test_dask_batches_short_windows_and_keeps_failures_per_window(tmp_path):
    """Windows of 2 ms go several to a task; a window that raises or whose result does not
    pickle fails alone; the others give the serial results, saved for resume."""
    distributed = pytest.importorskip("distributed")
    ev = _events(4000)
    windows = [(k * 2000, (k + 1) * 2000) for k in range(50)]
    from distributed.diagnostics.plugin import SchedulerPlugin

    class Updates(SchedulerPlugin):
        """The number of tasks in each graph update the scheduler receives."""

        def __init__(self):
            self.sizes = []

        def update_graph(self, scheduler, *, keys, **kwargs):
            self.sizes.append(len(keys))

    updates = Updates()
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  protocol="tcp", dashboard_address=":0") as cluster, \
            distributed.Client(cluster) as client, \
            distributed.get_task_stream(client) as stream:
        cluster.scheduler.add_plugin(updates)
        res = map_windows(short_window, ev, windows, scheduler=client, with_window=True,
                          progress=False, resume_dir=tmp_path)
    assert [r.index for r in res] == list(range(50))
    assert [r.index for r in res if not r.ok] == [18, 26]
    assert "Could not serialize" in res[18].error and "picklable" in res[18].error
    assert "deliberate failure" in res[26].error
    expected = [count_and_span(ev.slice_time(a, b)) for a, b in windows]
    assert all(r.value == expected[r.index] for r in res if r.ok)
    tasks = len(stream.data)
    assert tasks < 40, tasks  # batched (without batching: 50 tasks)
    # the first fill (2 tasks per worker thread) reaches the scheduler as one graph update
    assert updates.sizes[0] == 4 and sum(updates.sizes) == tasks, updates.sizes
    assert len(list(tmp_path.glob("*.pkl"))) == 48


# ------------------------------------------------------------------ live progress of chunks
def two_steps(ev: EventArray) -> int:
    """A chunk of 3 progress units that reports 2 of them, the second 0.4 s after the first
    (the third is counted when it returns)."""
    from evmotion.parallel import report_progress

    report_progress()
    time.sleep(0.4)
    report_progress()
    time.sleep(0.4)
    return len(ev)


class _Bar:
    """Stands in for the tqdm bar: when each update came and how many units."""

    def __init__(self, *args, **kwargs):
        self.total = kwargs.get("total")
        self.disable = kwargs.get("disable") is True  # None: shown where stderr is a TTY
        self.updates: list[tuple[float, int]] = []
        _Bar.last = self

    def update(self, n):
        self.updates.append((time.perf_counter(), n))

    def close(self):
        pass


def _live_updates(monkeypatch, **kwargs) -> tuple[list[int], list[float]]:
    import evmotion.parallel as parallel

    monkeypatch.setattr(parallel, "progress_bar", _Bar)
    res = map_windows(two_steps, _events(), [(0, 50_000)], units=[3], unit="step", **kwargs)
    assert res[0].ok, res[0].error
    bar = _Bar.last
    assert bar.total == 3
    times = [t for t, _ in bar.updates]
    return [n for _, n in bar.updates], np.diff(times).tolist()


@pytest.mark.parametrize("executor,workers", [("process", 1), ("thread", 2), ("process", 2)])
def test_reports_reach_the_bar_while_the_window_runs(monkeypatch, executor, workers):
    """Each report_progress call advances the bar when it is made (0.4 s apart), not when
    the window returns; the rest of the window's units come with its result."""
    units, gaps = _live_updates(monkeypatch, executor=executor, workers=workers)
    assert units == [1, 1, 1]
    assert all(g > 0.25 for g in gaps), gaps


def test_reports_reach_the_bar_from_dask_workers(monkeypatch):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=":0") as cluster, \
            distributed.Client(cluster) as client:
        units, gaps = _live_updates(monkeypatch, scheduler=client)
    assert units == [1, 1, 1]
    assert all(g > 0.25 for g in gaps), gaps


def test_reports_are_clamped_to_each_window_units(monkeypatch):
    """A window reporting more than its units, or reports outside map_windows, never move
    the bar past its total."""
    from evmotion.parallel import report_progress

    report_progress(5)  # outside map_windows: nothing to report to
    units, _ = _live_updates(monkeypatch, executor="thread", workers=1)
    assert sum(units) == 3
    import evmotion.parallel as parallel

    monkeypatch.setattr(parallel, "progress_bar", _Bar)
    map_windows(two_steps, _events(), [(0, 50_000), (50_000, 100_000)], units=[1, 0],
                progress=True)
    assert [n for _, n in _Bar.last.updates] == [1]


def test_units_must_match_the_windows():
    with pytest.raises(ParameterError, match="units"):
        map_windows(count_and_span, _events(), WINDOWS, units=[1, 2], progress=False)
    with pytest.raises(ParameterError, match="units"):
        map_windows(count_and_span, _events(), WINDOWS, units=[1, 1, 1, 1, -1], progress=False)


def test_imap_yields_each_window_once_the_ones_before_it_are_done():
    """Window 1 finishes first, window 0 only once released, window 2 only after the
    caller has taken window 0: so the first result comes in window order, and before the
    last window is done (map_windows would hold it until all are)."""
    from evmotion.parallel import imap_windows

    one_done, release_zero, zero_taken = (threading.Event() for _ in range(3))
    finished = []

    def work(ev, t0, t1):
        if t0 == 0:
            assert one_done.wait(10) and release_zero.wait(10)
        elif t0 == 20_000:
            one_done.set()
        else:
            assert zero_taken.wait(10)
        finished.append(t0)
        return t0

    stream = imap_windows(work, _events(), [(0, 20_000), (20_000, 40_000), (40_000, 60_000)],
                          workers=2, executor="thread", with_window=True, progress=False)
    release_zero.set()
    first = next(stream)
    assert first.value == 0 and 40_000 not in finished
    zero_taken.set()
    assert [r.value for r in stream] == [20_000, 40_000]


def test_imap_yields_resumed_windows_first(tmp_path):
    from evmotion.parallel import imap_windows

    ev = _events()
    map_windows(count_and_span, ev, WINDOWS[:2], resume_dir=tmp_path, progress=False)
    got = list(imap_windows(count_and_span, ev, WINDOWS, resume_dir=tmp_path, progress=False))
    assert [r.cached for r in got] == [True, True, False, False, False]
    assert [r.t0 for r in got] == [a for a, _ in WINDOWS]


def test_imap_stopped_early_shuts_its_pool():
    from evmotion.parallel import imap_windows

    stream = imap_windows(count_and_span, _events(), WINDOWS, workers=2, executor="thread",
                          progress=False)
    before = threading.active_count()
    assert next(stream).ok
    assert threading.active_count() > before  # the pool's threads
    stream.close()
    deadline = time.monotonic() + 5
    while threading.active_count() > before and time.monotonic() < deadline:
        time.sleep(0.01)
    assert threading.active_count() <= before


def interrupted_inside_c(events):
    # what numba's dispatcher makes of a Ctrl-C that lands in it
    try:
        raise KeyboardInterrupt
    except KeyboardInterrupt as ki:
        raise SystemError("CPUDispatcher(<function vote_counts>) returned a result with an "
                          "exception set") from ki


def test_a_ctrl_c_turned_into_a_c_error_stops_the_run():
    # it was recorded as a failed window, the run went on and exited 0 with the window
    # missing, and --resume never estimated it again (probe AD)
    with pytest.raises(KeyboardInterrupt):
        map_windows(interrupted_inside_c, _events(), WINDOWS, progress=False)


def test_a_dask_worker_collects_a_windows_warning_on_every_run():
    """A long-lived Dask worker: Python's once-per-place registry had kept a window's
    warning from the second run on (probe BB: none of 8 on a cluster's second run)."""
    import warnings

    from evmotion.errors import PoorFitWarning
    from evmotion.events import EventArray
    from evmotion.parallel import _run_batch, _Task

    def odd(events):
        warnings.warn(PoorFitWarning("window 3 looks odd"), stacklevel=1)
        return len(events)

    ev = EventArray(x=[1, 2], y=[0, 1], t=[10, 20], p=[1, 0], sensor_size=(4, 5))
    with warnings.catch_warnings():
        warnings.resetwarnings()  # a worker process's: no filter, each place shown once
        said = [_run_batch(odd, [ev], [_Task(3, 10, 21)], False, {})[0].warnings
                for _ in range(2)]
    assert [[m for _, m, _, _ in w] for w in said] == [["window 3 looks odd"]] * 2

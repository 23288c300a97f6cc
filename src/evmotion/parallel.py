"""Map a per-window function over a recording, in parallel and resumably.

:func:`map_windows` runs ``fn(events)`` for every window of a recording with a
:mod:`concurrent.futures` executor (processes by default) or a Dask ``distributed``
cluster, and returns one :class:`WindowResult` per window, in window order;
:func:`imap_windows` yields them in that order as soon as each is ready. A failing
window is reported (with its time range) without losing the others; with ``resume_dir``
each finished window is saved as soon as it arrives, so a rerun after an interruption only
computes what is missing.
"""

from __future__ import annotations

import asyncio
import concurrent.futures as cf
import contextlib
import os
import pickle
import re
import statistics
import sys
import threading
import time
import traceback
import uuid
import warnings
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from evmotion.errors import (
    EvmotionError,
    MissingDependencyError,
    ParameterError,
    WorkerDiedError,
)
from evmotion.events import EventArray, Window, window_bounds
from evmotion.utils import atomic_path
from evmotion.utils import progress as progress_bar

__all__ = ["BATCH_TARGET_S", "WindowResult", "collected_warnings", "connect_scheduler", "interrupted_by",
           "imap_window_blocks", "imap_windows", "map_windows", "reissue_warnings", "report_progress"]

#: Where :func:`report_progress` sends ``(window index, units)`` in a worker process of
#: :func:`map_windows`: a queue to the caller's bar (set by the pool's initializer).
_sink: Callable[[int, int], None] | None = None
#: What the calling thread runs: the window (``index``) and where its reports go
#: (``sink``: the caller's bar in the caller's own threads, a Dask event topic in a Dask
#: worker; :func:`_run_window` sets both for the length of the call).
_current = threading.local()


def report_progress(n: int = 1) -> None:
    """Inside a function that :func:`map_windows` runs: ``n`` more progress units of the
    current window are done (e.g. one frame interval of a chunk of several).

    The caller's progress bar counts ``map_windows(units=...)`` per window and advances as
    the reports arrive, from this process, worker processes or Dask workers; whatever a
    window has not reported is counted when it finishes. Outside :func:`map_windows` (or
    with an executor it did not make) this does nothing.

    Parameters
    ----------
    n : int
        Units done since the last report.

    Examples
    --------
    >>> def chunk(ev):
    ...     for _ in range(3):
    ...         report_progress()  # one of the chunk's 3 steps is done
    ...     return len(ev)
    >>> ev = EventArray(x=[0, 1], y=[0, 0], t=[0, 10], p=[1, 1], sensor_size=(1, 2))
    >>> [r.value for r in map_windows(chunk, ev, [(0, 20)], units=[3], progress=False)]
    [2]
    """
    sink = getattr(_current, "sink", None) or _sink
    index = getattr(_current, "index", None)
    if sink is not None and index is not None:
        sink(index, int(n))


class _Progress:
    """The caller's bar in progress units, fed from any thread: live reports (clamped to
    each window's units) and, when a window finishes, the rest of its units."""

    def __init__(self, units: dict[int, int], desc: str, unit: str, enabled: bool):
        self.units = units
        self.done = dict.fromkeys(units, 0)
        self.lock = threading.Lock()
        self.bar = progress_bar(None, total=sum(units.values()), desc=desc, unit=unit,
                                disable=None if enabled else True)

    def tick(self, index: int, n: int) -> None:
        with self.lock:
            if index not in self.done:
                return
            n = max(0, min(n, self.units[index] - self.done[index]))
            self.done[index] += n
            if n:
                self.bar.update(n)

    def finish(self, index: int) -> None:
        self.tick(index, self.units.get(index, 0))

    def close(self) -> None:
        self.bar.close()


@dataclass(frozen=True)
class WindowResult:
    """Outcome of one window.

    Attributes
    ----------
    index : int
        Position of the window in the input sequence.
    t0, t1 : int
        Time range ``[t0, t1)`` of the window in µs.
    value : Any
        What ``fn`` returned (None on error).
    error : str or None
        The error's line (``"ExceptionType: message"``, evmotion's own errors by their
        message alone) and the traceback when ``fn`` (or reading) failed.
    elapsed_s : float
        Wall time of ``fn`` (and reading the window) in the worker, in seconds.
    cached : bool
        True when the value was loaded from ``resume_dir`` instead of computed.
    compile_s : float
        Of ``elapsed_s``, the seconds spent compiling numba kernels on first use
        (:func:`evmotion.jitcache.compile_seconds`): a worker process compiles a kernel
        once (or loads it from the shared cache), so later windows on it report 0.
    warnings : tuple
        The warnings ``fn`` issued (where it ran: this process, a worker process, a
        Dask worker), as ``(category, message, filename, lineno)``. :func:`imap_windows`
        issues them in the calling process when the window arrives, and again when it is
        resumed from ``resume_dir``, so that the caller's filters and summaries see
        them.
    """

    index: int
    t0: int
    t1: int
    value: Any = None
    error: str | None = None
    elapsed_s: float = 0.0
    cached: bool = False
    compile_s: float = 0.0
    warnings: tuple = ()

    @property
    def ok(self) -> bool:
        return self.error is None


@dataclass(frozen=True)
class _Task:
    index: int
    t0: int
    t1: int
    start: int | None = None
    stop: int | None = None


def _normalize_windows(windows: Iterable[Window | tuple[int, int]]) -> list[_Task]:
    tasks = []
    for k, w in enumerate(windows):
        start = stop = None
        if isinstance(w, Window):
            t0, t1, start, stop = w.t0, w.t1, w.start, w.stop
        else:
            t0, t1 = window_bounds(w, k)
        if t1 < t0:
            raise ParameterError(f"windows[{k}] ends before it starts: t0={t0} > t1={t1} µs")
        tasks.append(_Task(k, int(t0), int(t1), start, stop))
    return tasks


def _run_window(fn: Callable, source: Any, task: _Task, with_window: bool,
                read_kwargs: dict, sink: Callable[[int, int], None] | None = None
                ) -> WindowResult:
    """Run in the worker: read (or take) the window's events and call ``fn``. The
    warnings it issues go back in the result (a worker process's stderr is not the
    caller's summary, and a resumed window has none)."""
    from evmotion.jitcache import compile_seconds

    c0 = compile_seconds()
    start = time.perf_counter()
    outer = getattr(_current, "index", None), getattr(_current, "sink", None)
    _current.index, _current.sink = task.index, sink or outer[1]
    try:
        with collected_warnings() as kept:
            if isinstance(source, EventArray):
                events = source
            else:
                from evmotion.io import read_events

                events = read_events(source, t0=task.t0, t1=task.t1, warn_empty=False,
                                     **read_kwargs)
            value = fn(events, task.t0, task.t1) if with_window else fn(events)
        error = None
    except Exception as exc:
        if interrupted_by(exc):
            raise KeyboardInterrupt from exc
        value, error = None, f"{_error_line(exc)}\n{traceback.format_exc()}"
    finally:
        _current.index, _current.sink = outer
    return WindowResult(task.index, task.t0, task.t1, value=value, error=error,
                        elapsed_s=time.perf_counter() - start,
                        compile_s=compile_seconds() - c0, warnings=tuple(kept))


def interrupted_by(exc: BaseException) -> bool:
    """Whether ``exc`` is a Ctrl-C in disguise: a KeyboardInterrupt raised inside a C
    call comes back as that call's error (numba's dispatcher: "SystemError: ...
    returned a result with an exception set"), the interrupt as its cause or context.

    Examples
    --------
    >>> try:
    ...     try:
    ...         raise KeyboardInterrupt
    ...     except KeyboardInterrupt as ki:
    ...         raise SystemError("returned a result with an exception set") from ki
    ... except SystemError as exc:
    ...     interrupted_by(exc)
    True
    """
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


@contextlib.contextmanager
def collected_warnings() -> Iterator[list[tuple]]:
    """Collect, instead of showing, the warnings this thread issues inside the block.

    Thread-safe, unlike ``warnings.catch_warnings`` (which swaps one process-wide
    function): threads and Dask workers run windows side by side. Yields the list that
    receives ``(category, message, filename, lineno)`` tuples, which pickle (a category
    defined in a worker's ``__main__`` goes as ``UserWarning``); :func:`reissue_warnings`
    issues them again, e.g. in the process that asked for the work. Filters apply as
    usual: a warning they ignore is not collected.

    Examples
    --------
    >>> import warnings
    >>> with collected_warnings() as said:
    ...     warnings.warn("window 3 looks odd", stacklevel=1)
    >>> [m for _, m, _, _ in said]
    ['window 3 looks odd']
    """
    if warnings.showwarning is not _show_or_keep:
        _shown[0] = warnings.showwarning
        warnings.showwarning = _show_or_keep
    outer = getattr(_current, "kept", None)
    _current.kept = kept = []
    try:
        yield kept
    finally:
        _current.kept = outer


def reissue_warnings(said: Iterable[tuple]) -> None:
    """Issue in this process the warnings :func:`collected_warnings` collected."""
    for category, message, filename, lineno in said:
        warnings.warn_explicit(message, category, filename, lineno)


def _show_or_keep(message, category, filename, lineno, file=None, line=None) -> None:
    kept = getattr(_current, "kept", None)
    if kept is None:
        _shown[0](message, category, filename, lineno, file, line)
        return
    try:  # a category the caller cannot import (a worker's __main__) goes as UserWarning
        pickle.loads(pickle.dumps(category))
    except Exception:
        category = UserWarning
    kept.append((category, str(message), filename, lineno))


_shown: list = [warnings.showwarning]


class _Store:
    """One pickle per finished window in ``resume_dir``, named by index and time range
    so that a rerun with other windows never picks up a stale result."""

    def __init__(self, folder: str | os.PathLike | None):
        self.folder = None if folder is None else Path(folder)
        if self.folder is not None:
            self.folder.mkdir(parents=True, exist_ok=True)

    def _path(self, task: _Task) -> Path:
        return self.folder / f"window_{task.index:06d}_{task.t0}_{task.t1}.pkl"

    def load(self, task: _Task) -> WindowResult | None:
        if self.folder is None:
            return None
        path = self._path(task)
        if not path.is_file():
            return None
        try:
            with open(path, "rb") as fh:
                value, elapsed, *said = pickle.load(fh)
        except (OSError, EOFError, pickle.UnpicklingError, ValueError, TypeError):
            return None
        return WindowResult(task.index, task.t0, task.t1, value=value, elapsed_s=elapsed,
                            cached=True, warnings=tuple(said[0]) if said else ())

    def save(self, res: WindowResult) -> None:
        if self.folder is None or not res.ok:
            return
        with atomic_path(self._path(_Task(res.index, res.t0, res.t1))) as tmp:
            with open(tmp, "wb") as fh:
                pickle.dump((res.value, res.elapsed_s, res.warnings), fh,
                            protocol=pickle.HIGHEST_PROTOCOL)


def _payload(source: Any, task: _Task) -> Any:
    """What a worker receives: the window's slice for in-memory events, else the path.

    A :class:`Window` is cut by its index range, so count windows keep exactly their
    events even where timestamps repeat across the boundary."""
    if not isinstance(source, EventArray):
        return source
    if task.start is not None and 0 <= task.start <= task.stop <= len(source):
        return source[task.start:task.stop]
    return source.slice_time(task.t0, task.t1)


def map_windows(fn: Callable[..., Any], source: str | os.PathLike | EventArray,
                windows: Sequence[Window | tuple[int, int]], **options: Any
                ) -> list[WindowResult]:
    """Apply ``fn`` to the events of every window; results in window order, as a list.

    Parameters
    ----------
    fn, source, windows, **options
        As :func:`imap_windows` (``workers``, ``executor``, ``scheduler``, ``resume_dir``,
        ``progress``, ``desc``, ``with_window``, ``read_kwargs``, ``units``, ``unit``).

    Returns
    -------
    list of WindowResult
        One per window, in the order of ``windows``; check ``.ok`` / ``.error``.

    Examples
    --------
    >>> ev = EventArray(x=[0, 1, 2], y=[0, 0, 0], t=[0, 10, 20], p=[1, 1, 0],
    ...                 sensor_size=(1, 3))
    >>> [r.value for r in map_windows(len, ev, [(0, 15), (15, 30)], progress=False)]
    [2, 1]
    """
    return list(imap_windows(fn, source, windows, **options))


def imap_windows(
    fn: Callable[..., Any],
    source: str | os.PathLike | EventArray,
    windows: Sequence[Window | tuple[int, int]],
    *,
    workers: int = 1,
    executor: str | cf.Executor = "process",
    scheduler: str | Any | None = None,
    resume_dir: str | os.PathLike | None = None,
    progress: bool = True,
    desc: str = "",
    with_window: bool = False,
    read_kwargs: dict | None = None,
    units: Sequence[int] | None = None,
    unit: str = "win",
) -> Iterator[WindowResult]:
    """Apply ``fn`` to the events of every window; yield each window's result in window
    order as soon as it and every window before it are done, so that a caller writes the
    first windows while the last are still computed (holding only those that arrived out
    of order). The work, and the checks of the options, start at the first ``next()``;
    stopping early (``close()``) ends the pool or the cluster's feed.

    Parameters
    ----------
    fn : callable
        ``fn(events) -> value`` (or ``fn(events, t0_us, t1_us)`` with ``with_window``).
        For processes and Dask it must be picklable (a module-level function of an
        importable module, or a :func:`functools.partial` of one) and so must its return
        value (workers forked from a multi-threaded caller start clean and import it).
    source : path or EventArray
        A recording path: each worker reads its own window with
        ``evmotion.io.read_events(path, t0=, t1=, **read_kwargs)``. An EventArray: each
        worker is sent only its window's slice.
    windows : sequence of Window or (t0, t1)
        Half-open time ranges ``[t0, t1)`` in µs (e.g. from ``EventArray.windows_by_*``).
        With an EventArray source, Window objects (made from that array) select their
        events by index range.
    workers : int
        Parallel workers for the local executor; 1 runs in this process (no pickling).
    executor : {"process", "thread"} or concurrent.futures.Executor
        Local executor kind, or an executor you manage (then ``workers`` only bounds the
        number of windows in flight).
    scheduler : str or distributed.Client, optional
        Run on a Dask cluster instead: a scheduler address (``"tcp://host:8786"``) or a
        connected ``distributed.Client``. Workers must be able to read ``source``. A
        worker process compiles each numba kernel once, on its first window that needs it
        (or loads it from numba's cache; workers sharing one ``NUMBA_CACHE_DIR`` share
        it): :attr:`WindowResult.compile_s` says which windows paid. Windows shorter than
        :data:`BATCH_TARGET_S` go several consecutive ones to a task (results, their
        order and ``resume_dir`` stay per window).
    resume_dir : path, optional
        Save each finished window there (pickle, atomically) and skip windows already
        saved. Failed windows are not saved, so a rerun retries them. Use one folder per
        computation: the files are keyed by window, not by ``fn``.
    progress : bool
        Show a progress bar with rate and ETA on stderr.
    desc : str
        Label of the progress bar.
    with_window : bool
        Also pass the window's ``t0, t1`` (µs) to ``fn``.
    read_kwargs : dict, optional
        Extra arguments of ``read_events`` (e.g. ``{"format": "h5"}``).
    units : sequence of int, optional
        Progress units of each window (default 1): the bar counts these, ``fn`` advances
        it live with :func:`report_progress`, and a finished window counts whole.
    unit : str
        Name of a progress unit on the bar.

    Yields
    ------
    WindowResult
        One per window, in the order of ``windows``; check ``.ok`` / ``.error``.

    Examples
    --------
    >>> def count(ev):
    ...     return len(ev)
    >>> ev = EventArray(x=[0, 1, 2], y=[0, 0, 0], t=[0, 10, 20], p=[1, 1, 0],
    ...                 sensor_size=(1, 3))
    >>> for r in imap_windows(count, ev, [(0, 15), (15, 30)], progress=False):
    ...     print(r.t0, r.value)
    0 2
    15 1
    """
    if workers < 1:
        raise ParameterError(f"workers must be >= 1, got {workers}")
    if isinstance(executor, str) and executor not in ("process", "thread"):
        raise ParameterError(f"executor must be 'process', 'thread' or an Executor, "
                             f"got {executor!r}")
    if not isinstance(source, EventArray):
        source = os.fspath(source)
    tasks = _normalize_windows(windows)
    if units is not None:
        units = [int(u) for u in units]
        if len(units) != len(tasks) or min(units, default=0) < 0:
            raise ParameterError(f"units must hold one count >= 0 per window ({len(tasks)}), "
                                 f"got {units}")
    read_kwargs = dict(read_kwargs or {})
    store = _Store(resume_dir)
    results: dict[int, WindowResult] = {}
    pending: list[_Task] = []
    for task in tasks:
        cached = store.load(task)
        if cached is not None:
            reissue_warnings(cached.warnings)
            results[task.index] = cached
        else:
            pending.append(task)
    if not pending:
        for t in tasks:
            yield results.pop(t.index)
        return

    bar = _Progress({t.index: 1 if units is None else units[t.index] for t in pending},
                    desc or "windows", unit, progress)
    # no live channel where nobody sees the bar (stderr not a terminal, progress=False)
    live = None if bar.bar.disable else bar.tick
    order = iter(tasks)
    nxt = next(order, None)

    def ready() -> list[WindowResult]:
        """The results now complete in window order (results keeps only the others)."""
        nonlocal nxt
        out = []
        while nxt is not None and nxt.index in results:
            out.append(results.pop(nxt.index))
            nxt = next(order, None)
        return out

    stream = None
    try:
        if scheduler is not None:
            stream = _run_dask(fn, source, pending, scheduler, with_window, read_kwargs, live)
        elif workers == 1 and isinstance(executor, str):
            stream = (_run_window(fn, _payload(source, t), t, with_window, read_kwargs, live)
                      for t in pending)
        else:
            stream = _run_local(fn, source, pending, workers, executor, with_window,
                                read_kwargs, live)
        yield from ready()  # windows resumed from resume_dir before the first pending one
        for res in stream:
            store.save(res)
            reissue_warnings(res.warnings)
            results[res.index] = res
            bar.finish(res.index)
            yield from ready()
    finally:
        if stream is not None:  # a caller that stops early ends the pool or the client
            stream.close()
        bar.close()



def imap_window_blocks(
    fn: Callable[..., Any],
    blocks: Iterable[tuple[EventArray, Sequence[Window], Sequence[int]]],
    *,
    total: int,
    workers: int = 1,
    scheduler: str | Any | None = None,
    progress: bool = True,
    desc: str = "",
    with_window: bool = False,
) -> Iterator[tuple[int, EventArray, WindowResult]]:
    """:func:`imap_windows` over windows whose events come a block at a time
    (:func:`evmotion.streamed_windows.window_blocks`): one progress bar over the ``total``
    windows and one pool of ``workers`` processes (or the ``scheduler``'s cluster) for
    every block; yields ``(position, window events, result)`` in window order, a block's
    windows as soon as they are done.

    Parameters
    ----------
    fn : callable
        As in :func:`imap_windows`.
    blocks : iterable of (EventArray, sequence of Window, sequence of int)
        Each block's events, its windows (``start``/``stop`` indexing them) and their
        positions, which are yielded back.
    total : int
        Windows in all the blocks, for the bar.
    workers, scheduler, progress, desc, with_window
        As in :func:`imap_windows`.

    Examples
    --------
    >>> ev = EventArray(x=[0, 1, 2], y=[0, 0, 0], t=[0, 10, 20], p=[1, 1, 0],
    ...                 sensor_size=(1, 3))
    >>> blocks = [(ev[:2], [Window(0, 0, 15, 0, 2)], [0]), (ev[2:], [Window(1, 15, 30, 0, 1)], [1])]
    >>> [(k, len(sub), r.value) for k, sub, r in imap_window_blocks(len, blocks, total=2,
    ...                                                               progress=False)]
    [(0, 2, 2), (1, 1, 1)]
    """
    if workers < 1:
        raise ParameterError(f"workers must be >= 1, got {workers}")
    bar = progress_bar(None, total=total, desc=desc or "windows", unit="win",
                       disable=None if progress else True)
    pool = None
    interrupted = False
    try:
        if scheduler is None and workers > 1 and total > 1:
            # one pool for every block: a pool a block had each worker load the kernels again
            pool = cf.ProcessPoolExecutor(max_workers=min(workers, total),
                                          mp_context=_process_context(),
                                          initializer=_install_queue, initargs=(None,))
        for events, windows, positions in blocks:
            results = imap_windows(fn, events, windows, workers=workers,
                                   executor=pool or "process", scheduler=scheduler,
                                   progress=False, with_window=with_window)
            with contextlib.closing(results):
                for k, w, r in zip(positions, windows, results, strict=True):
                    bar.update(1)
                    yield k, events.window(w), r
    except (KeyboardInterrupt, SystemExit):
        interrupted = True
        raise
    finally:
        if pool is not None:
            # (after Ctrl-C the workers are not waited for: see _drain)
            pool.shutdown(wait=not interrupted, cancel_futures=True)
        bar.close()

def _run_local(fn, source, tasks: list[_Task], workers: int, executor, with_window: bool,
               read_kwargs: dict, live) -> Iterator[WindowResult]:
    """Yield results as they complete, keeping at most ``2 * workers`` windows in flight so
    that in-memory slices are not all pickled at once. Worker processes send their
    :func:`report_progress` calls through a queue that a thread here passes to the bar
    (threads call the bar directly); that thread starts after the workers, so that a
    forked worker never copies a process with it running."""
    relay, sink = None, None
    workers = max(1, min(int(workers), len(tasks)))  # a process per window at the most
    if isinstance(executor, cf.Executor):
        pool, owned = executor, False
    elif executor == "process":
        context = _process_context()
        queue = context.SimpleQueue() if live else None
        pool, owned = cf.ProcessPoolExecutor(max_workers=workers, mp_context=context,
                                             initializer=_install_queue,
                                             initargs=(queue,)), True
        if live:
            try:
                pool.submit(int).result()  # starts the workers (with fork: all of them)
            except BaseException:
                pool.shutdown(wait=False, cancel_futures=True)
                raise
            relay = threading.Thread(target=_relay, args=(queue, live), daemon=True,
                                     name="evmotion-progress")
            relay.start()
    elif executor == "thread":
        pool, owned, sink = cf.ThreadPoolExecutor(max_workers=workers), True, live
    else:
        raise ParameterError(f"executor must be 'process', 'thread' or an Executor, "
                             f"got {executor!r}")
    try:
        yield from _drain(pool, owned, fn, source, tasks, 2 * workers, with_window,
                          read_kwargs, sink)
    finally:
        if relay is not None:
            queue.put(None)
            relay.join(timeout=1.0)


def _install_queue(queue) -> None:
    """Worker process initializer: :func:`report_progress` goes to ``queue``, and the
    worker ends with the process that started it."""
    global _sink
    _sink = None if queue is None else (lambda index, n: queue.put((index, n)))
    _die_with_parent()


def _die_with_parent() -> None:
    """Ask Linux to send SIGTERM to this process when its parent dies: a parent killed
    outright (``kill -9``, the out-of-memory killer) left its workers asleep forever,
    holding their memory. Elsewhere a no-op."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes
    import signal

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, int(signal.SIGTERM), 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _relay(queue, live) -> None:
    """Pass the workers' reports to the bar until the ``None`` that ends the run."""
    while (item := queue.get()) is not None:
        live(*item)


def _drain(pool: cf.Executor, owned: bool, fn, source, tasks: list[_Task], limit: int,
           with_window: bool, read_kwargs: dict, sink=None) -> Iterator[WindowResult]:
    queue = iter(tasks)
    running: dict[cf.Future, _Task] = {}
    interrupted = False
    try:
        while True:
            while len(running) < limit:
                task = next(queue, None)
                if task is None:
                    break
                try:
                    fut = pool.submit(_run_window, fn, _payload(source, task), task,
                                      with_window, read_kwargs, sink)
                except cf.BrokenExecutor:
                    raise _worker_died(None) from None  # one of the tasks running
                running[fut] = task
            if not running:
                return
            done, _ = cf.wait(running, return_when=cf.FIRST_COMPLETED)
            broken = []
            for fut in sorted(done, key=lambda f: running[f].index):
                task = running.pop(fut)
                if isinstance(fut.exception(), cf.BrokenExecutor):
                    broken.append(task)
                else:
                    yield _future_result(fut, task)
            if broken:
                # raised, not yielded as the window's error: a caller keeping its results
                # for --resume recorded it as done with no row, and resumed without it
                # (probe CH). Every task then running breaks with the pool: which one's
                # worker died is not known, so their span is named
                raise _worker_died(broken + list(running.values()))
    except (KeyboardInterrupt, SystemExit):
        interrupted = True
        raise
    finally:
        for fut in running:
            fut.cancel()
        if owned:
            # After Ctrl-C do not wait for the workers: one stopped while sending its result
            # leaves the pool's result pipe half-written, and joining then hangs for ever.
            pool.shutdown(wait=not interrupted, cancel_futures=True)


def _worker_died(tasks: list[_Task] | None) -> WorkerDiedError:
    """The error of a pool whose worker died while it ran ``tasks`` (None: not known; a
    task is a window, or a chunk of windows where the caller runs chunks)."""
    where = "" if not tasks else (f" while the pool computed [{min(t.t0 for t in tasks)}, "
                                  f"{max(t.t1 for t in tasks)}) us")
    return WorkerDiedError(
        f"a worker process died{where}: killed from outside (the out-of-memory killer, a "
        "signal) or crashed; what finished before it is kept where the run keeps it (a "
        "resumable output continues with --resume, with --workers 1 where the command "
        "asks for it), and fewer workers need less memory")


def _process_context():
    """Fork while this process runs a single thread (fast: workers inherit the imports
    and compiled kernels); otherwise start clean workers, since forking a process with
    other threads (a Dask client, a GUI) can deadlock the child on a lock held at fork."""
    import multiprocessing as mp
    import threading

    methods = mp.get_all_start_methods()
    # tqdm's monitor only sleeps and, rarely, takes tqdm's own lock, which workers do not use.
    others = [t for t in threading.enumerate()
              if t is not threading.main_thread() and t.name != "tqdm_monitor"]
    if "fork" in methods and not others:
        return mp.get_context("fork")
    return mp.get_context("forkserver" if "forkserver" in methods else "spawn")


def _future_result(fut, task: _Task) -> WindowResult:
    """The worker's result, or an error result when the worker itself broke (pickling,
    a crashed process) rather than ``fn``."""
    try:
        return fut.result()
    except Exception as exc:
        return _broken(exc, task)


def _error_line(exc: Exception) -> str:
    """An error as a window's result says it: evmotion's own by their message, which
    names what is wrong ("EmptyWindowError: window's 30000 events are all at one time"
    printed a class name to the user, probe BJ); others with their type."""
    return str(exc) if isinstance(exc, EvmotionError) else f"{type(exc).__name__}: {exc}"


def _broken(exc: Exception, task: _Task) -> WindowResult:
    """The error result of a window whose task broke (pickling, a crashed process)."""
    hint = ""
    if isinstance(exc, (pickle.PicklingError, AttributeError, TypeError)):
        hint = (" (with processes or Dask, fn, its arguments and its result must be "
                "picklable: use a module-level function, or executor='thread')")
    return WindowResult(task.index, task.t0, task.t1,
                        error=f"{type(exc).__name__}: {exc}{hint}")


def _collect_every_run() -> None:
    """A Dask worker outlives the run: Python's registry of the warnings each place has
    shown ("default": once) had kept a window's warning from the second run on the same
    cluster on (probe BB: none of a multicm run's 8 "no focus" warnings). evmotion's
    warnings are always issued there, to be collected; the filter is appended, so one
    the worker set before still rules."""
    from evmotion.errors import EvmotionWarning

    if ("always", None, EvmotionWarning, None, 0) not in warnings.filters:
        warnings.filterwarnings("always", category=EvmotionWarning, append=True)


def _run_batch(fn: Callable, payloads: list, tasks: list[_Task], with_window: bool,
               read_kwargs: dict, topic: str | None = None) -> list[WindowResult]:
    """Run in a Dask worker: :func:`_run_window` on each window of a batch, in order;
    :func:`report_progress` logs Dask events on ``topic``, which the client follows."""
    _collect_every_run()
    sink = None
    if topic is not None:
        from distributed import get_worker

        worker = get_worker()

        def sink(index: int, n: int) -> None:
            worker.log_event(topic, [index, n])

    return [_run_window(fn, payload, task, with_window, read_kwargs, sink)
            for payload, task in zip(payloads, tasks, strict=True)]


#: Seconds of work one Dask task is given when windows are shorter than this: as many
#: consecutive windows as fit, at their median time. A task costs a few ms of CPU in the
#: client and scheduler and in the worker (about 4 and 2 to 4 ms,
#: benchmarks/results/cluster.md): batching keeps that cost about 1 % of the work.
BATCH_TARGET_S = 0.5


class _Batcher:
    """Cuts the windows into consecutive batches, one batch a Dask task.

    Until a window's time is known every batch is one window. Then a batch holds as many
    windows as fit in :data:`BATCH_TARGET_S` at the median time of the last 64 windows
    (compile time left out; the median, because each fresh worker's first window also
    pays for imports and loading cached kernels), but never more than the windows left
    over ``limit`` (the tasks kept in flight), rounded up, so that the last batches are
    short and the workers finish together. Windows
    of ``BATCH_TARGET_S`` or more go one a task, as without batching. The windows of a
    batch whose task broke (a result that does not pickle, a worker that died) go again
    one a task, so that the failure stays the window's own.
    """

    def __init__(self, tasks: list[_Task], limit: int):
        self.queue = list(reversed(tasks))
        self.retry: list[_Task] = []
        self.limit = limit
        self.seconds: deque[float] = deque(maxlen=64)

    def record(self, res: WindowResult) -> None:
        self.seconds.append(max(res.elapsed_s - res.compile_s, 0.0))

    def again(self, batch: list[_Task]) -> None:
        self.retry.extend(reversed(batch))

    def size(self) -> int:
        if not self.seconds:
            return 1
        window_s = statistics.median(self.seconds)
        fit = int(BATCH_TARGET_S / window_s) if window_s > 0 else len(self.queue)
        return max(1, min(fit, -(-len(self.queue) // self.limit)))

    def next(self) -> list[_Task]:
        if self.retry:
            return [self.retry.pop()]
        return [self.queue.pop() for _ in range(min(self.size(), len(self.queue)))]


def _run_dask(fn, source, tasks: list[_Task], scheduler, with_window: bool,
              read_kwargs: dict, live) -> Iterator[WindowResult]:
    """Yield results as batches complete (:class:`_Batcher`), keeping ``2 *`` the cluster's
    threads tasks in flight, so that in-memory slices are not all shipped at once. The
    workers' :func:`report_progress` calls come back as Dask events on a topic of this
    run, which the client's event loop passes to ``live``."""
    try:
        from distributed import Client, as_completed
    except ImportError as exc:
        raise MissingDependencyError("distributed", "running on a Dask cluster",
                                     extra="dask") from exc
    client, owned = (scheduler, False) if isinstance(scheduler, Client) else (
        connect_scheduler(scheduler), True)
    limit = 2 * max(1, sum(client.nthreads().values()))
    batcher = _Batcher(tasks, limit)
    futures: dict[str, list[_Task]] = {}
    topic = f"evmotion-progress-{uuid.uuid4().hex}" if live else None

    def refill(stream=None) -> list:
        batches = []
        while len(futures) + len(batches) < limit and (batch := batcher.next()):
            batches.append(batch)
        if not batches:
            return []
        # One graph update for all the new tasks (the first fill is one per slot): separate
        # submits cost the scheduler one update each and reached the second worker 10 ms
        # later. pure=False: the same window must run again on a rerun, never be deduplicated.
        n = len(batches)
        with warnings.catch_warnings():
            # the in-memory slices travel in the graph on purpose, a few batches at a time
            # (above); distributed's 6-line "Sending large graph" advice is not the user's
            warnings.filterwarnings("ignore", message="Sending large graph")
            new = client.map(_run_batch, [fn] * n,
                             [[_payload(source, t) for t in batch] for batch in batches],
                             batches, [with_window] * n, [read_kwargs] * n, [topic] * n,
                             pure=False)
        for fut, batch in zip(new, batches, strict=True):
            futures[fut.key] = batch
            if stream is not None:
                stream.add(fut)
        return new

    if topic is not None:
        client.subscribe_topic(topic, lambda event: live(*event[1]))
    try:
        stream = as_completed(refill(), loop=client.loop)
        for fut in stream:
            batch = futures.pop(fut.key)
            try:
                results = fut.result()
            except Exception as exc:
                if len(batch) > 1:
                    batcher.again(batch)
                    results = []
                else:
                    results = [_broken(exc, batch[0])]
            for res in results:
                batcher.record(res)
                yield res
            refill(stream)
    finally:
        if topic is not None:
            # only the bar's feed: a lost connection is reported by the results, not here
            with contextlib.suppress(Exception):
                client.unsubscribe_topic(topic)
        if owned:
            client.close()


def connect_scheduler(address: str, timeout_s: float = 5.0) -> Any:
    """A ``distributed.Client`` connected to the Dask scheduler at ``address``.

    Parameters
    ----------
    address : str
        Scheduler address, ``"tcp://host:8786"`` (what ``dask scheduler`` prints).
    timeout_s : float
        Seconds to wait for the scheduler to answer before giving up.

    Returns
    -------
    distributed.Client
        Close it (``client.close()``) when done; pass it as ``map_windows(scheduler=)``
        to run several computations on one connection.

    Raises
    ------
    MissingDependencyError
        ``distributed`` is not installed (the ``dask`` extra).
    ParameterError
        No scheduler answered at ``address`` within ``timeout_s``: one line naming it.

    Examples
    --------
    >>> connect_scheduler("tcp://127.0.0.1:1", timeout_s=1)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    evmotion.errors.ParameterError: cannot reach the Dask scheduler at tcp://127.0.0.1:1 ...
    """
    try:
        from distributed import Client
    except ImportError as exc:
        raise MissingDependencyError("distributed", "running on a Dask cluster",
                                     extra="dask") from exc
    if timeout_s <= 0:
        raise ParameterError(f"timeout_s must be > 0 s, got {timeout_s}")
    hint = "start one with 'dask scheduler' and its workers with 'dask worker ADDRESS'"
    greeted = _speaks_dask(address, timeout_s)
    try:
        # Probe first: a Client that fails to connect spends seconds more closing itself
        # when collected and prints a traceback at exit.
        if not greeted:
            asyncio.run(_probe(address, timeout_s))
        client = Client(address, timeout=timeout_s, set_as_default=False)
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        # distributed raises OSError("Timed out trying to connect to ...") for a closed
        # port or an unknown host, ValueError for an address it cannot parse
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise ParameterError(f"cannot reach the Dask scheduler at {address} within "
                             f"{timeout_s:g} s ({reason}); {hint}") from exc
    try:
        # without workers the tasks would wait for ever
        client.wait_for_workers(1, timeout=timeout_s)
    except (OSError, TimeoutError) as exc:
        client.close()
        raise ParameterError(f"the Dask scheduler at {address} has no worker after "
                             f"{timeout_s:g} s; start them with 'dask worker {address}'"
                             ) from exc
    return client


def _speaks_dask(address: str, timeout_s: float) -> bool:
    """For a plain TCP address: True when the server there greets as a Dask scheduler
    does (it writes its handshake first: an 8-byte message length, then a frame count);
    a ParameterError when something else answers (an HTTP server made the Client hang,
    or read its reply as a frame of 3 EiB); False for other schemes (not checked here).

    Examples
    --------
    >>> _speaks_dask("inproc://1.2.3.4/1/2", 1.0)
    False
    """
    import socket
    import struct

    m = re.fullmatch(r"(?:tcp://)?\[?([^\[\]/]+?)\]?:(\d+)", address.strip())
    if m is None:
        return False
    try:
        conn = socket.create_connection((m.group(1), int(m.group(2))), timeout=timeout_s)
    except OSError:
        return False  # no connection (a closed port, an unknown host): _probe says so
    head = b""
    with conn:
        conn.settimeout(timeout_s)
        try:
            while len(head) < 16:
                part = conn.recv(16 - len(head))
                if not part:
                    break
                head += part
        except OSError:  # a timeout: the server waits for a request, as HTTP does
            pass
    if len(head) == 16:
        size, frames = struct.unpack("<QQ", head)
        if 0 < size < 1 << 24 and 1 <= frames <= 64:
            return True
    raise ParameterError(f"something answers at {address} but not as a Dask scheduler (no "
                         f"Dask greeting within {timeout_s:g} s): is it the scheduler's "
                         "address ('dask scheduler' prints it; port 8786 by default)?")


async def _probe(address: str, timeout_s: float) -> None:
    from distributed.comm import connect

    comm = await connect(address, timeout=timeout_s)
    await comm.close()

"""Where numba keeps the compiled kernels, how long a call spent compiling them, and
kernels compiled per case.

The kernels are compiled on first use and cached on disk (``@njit(cache=True)``). numba
caches next to the sources (``__pycache__``) or, failing that, in the user's cache folder;
an installation that can write to neither (a read-only site-packages and no writable HOME)
would fail at import. :func:`ensure_cache_dir` (run when :mod:`evmotion` is imported) then
points numba at a folder in the system's temporary directory and says so in one line.

:func:`compile_seconds` reports the seconds this thread has spent in numba compilation, from
numba's event API (``numba:compile`` events; a kernel loaded from the cache is not
compiled): the timings that evmotion reports subtract it, so a first call's compile time is
not reported as its estimate's.

Examples
--------
>>> c0 = compile_seconds()
>>> compile_seconds() - c0 >= 0.0
True
"""

from __future__ import annotations

import functools
import os
import sys
import tempfile
import threading
from pathlib import Path

__all__ = ["LazyKernel", "compile_seconds", "ensure_cache_dir", "kernel_case", "lazy_njit",
           "private_dir"]

_PACKAGE = Path(__file__).resolve().parent


def _writable_dir(path: Path) -> bool:
    """Whether ``path`` can be created and written, as numba's cache locators test it."""
    try:
        os.makedirs(path, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
    except OSError:
        return False
    return True


def _user_cache_dir() -> Path:
    """numba's user-wide cache folder (``AppDirs("numba").user_cache_dir``)."""
    from numba.misc.appdirs import AppDirs

    return Path(AppDirs(appname="numba", appauthor=False).user_cache_dir)


def ensure_cache_dir(package_dir: str | os.PathLike | None = None, stream=None) -> str | None:
    """Give numba a writable cache folder when neither of its defaults is.

    Nothing changes when ``NUMBA_CACHE_DIR`` is set or when numba can cache next to the
    package's sources or in the user's cache folder. Otherwise ``NUMBA_CACHE_DIR`` (and
    numba's loaded configuration) is set to ``<tmp>/evmotion-numba-cache-<uid>`` and one
    line saying so goes to ``stream`` (default stderr).

    Parameters
    ----------
    package_dir : path, optional
        The installed package (default: this one); every folder under it that holds
        Python sources must take a ``__pycache__``.
    stream : file, optional
        Where the one line goes (default ``sys.stderr``).

    Returns
    -------
    str or None
        The folder chosen, or None when nothing was changed.

    Examples
    --------
    >>> ensure_cache_dir() is None or "NUMBA_CACHE_DIR" in os.environ
    True
    """
    if os.environ.get("NUMBA_CACHE_DIR"):
        return None
    root = _PACKAGE if package_dir is None else Path(package_dir)
    dirs = sorted({p.parent for p in root.rglob("*.py")}) or [root]
    if all(_writable_dir(d / "__pycache__") for d in dirs):
        return None
    if _writable_dir(_user_cache_dir()):
        return None
    uid = os.getuid() if hasattr(os, "getuid") else "user"
    folder = os.path.join(tempfile.gettempdir(), f"evmotion-numba-cache-{uid}")
    new = not os.path.lexists(folder)
    if not private_dir(folder):
        # another user's or an open folder: numba unpickles its index, so a cache there
        # could run their code; a fresh private folder (compiled anew each run) instead
        folder, new = tempfile.mkdtemp(prefix="evmotion-numba-cache-"), True
    os.environ["NUMBA_CACHE_DIR"] = folder
    if "numba" in sys.modules:  # numba read its configuration at import
        from numba.core import config

        config.CACHE_DIR = folder
    if new:  # said when the folder is made, not at every command
        print(f"evmotion: cannot cache compiled kernels next to {root} or in the user "
              f"cache; caching them in {folder} (set NUMBA_CACHE_DIR to choose)",
              file=sys.stderr if stream is None else stream)
    return folder


def private_dir(folder: str | os.PathLike) -> bool:
    """Whether ``folder`` is (or now is, made with mode 700) a directory of this user
    that only this user can write."""
    import stat

    try:
        os.mkdir(folder, 0o700)
    except FileExistsError:
        pass
    except OSError:
        return False
    try:
        st = os.lstat(folder)
    except OSError:
        return False
    own = not hasattr(os, "getuid") or st.st_uid == os.getuid()
    return (stat.S_ISDIR(st.st_mode) and own and not st.st_mode & (stat.S_IWGRP | stat.S_IWOTH)
            and os.access(folder, os.W_OK | os.X_OK))


_CASES: dict = {}


def kernel_case(factory, *key):
    """The kernel ``factory(*key)``, built once per process; numba compiles it on its first
    call (or loads it from the cache).

    A hot kernel whose cases (series mode, weights or not, ...) must each be a loop of its
    own, with no branch inside, is written as a factory of one ``@njit`` closure per case,
    the case frozen in as constants: a call then compiles the case it runs, where one kernel
    branching to every case would compile them all on its first call.

    Examples
    --------
    >>> from numba import njit
    >>> def scaled(k):
    ...     @njit
    ...     def f(v):
    ...         return k * v
    ...     return f
    >>> kernel_case(scaled, 3)(2.0), kernel_case(scaled, 3) is kernel_case(scaled, 3)
    (6.0, True)
    """
    k = _CASES.get((factory, key))
    if k is None:
        k = _CASES[(factory, key)] = factory(*key)
    return k


class LazyKernel:
    """A ``numba.njit`` kernel that imports numba and compiles (or loads from the cache) on
    its first call, not when its module is imported: made by :func:`lazy_njit`.

    For the modules that every run imports but few runs execute (the file-format readers,
    all imported to detect a file's format): importing numba costs ~0.2 s, which a command
    that never runs one of their kernels should not pay.

    A kernel that calls another lazy kernel of its module works: on its first call the
    callees it names are compiled first and their module names rebound to their numba
    dispatchers (numba can type a call to a dispatcher, not to this wrapper).
    """

    def __init__(self, py_func, options: dict):
        self.py_func = py_func
        self._options = options
        self._dispatcher = None
        functools.update_wrapper(self, py_func)

    def dispatcher(self):
        """The numba dispatcher, made on the first call."""
        d = self._dispatcher
        if d is None:
            from numba import njit

            names = self.py_func.__globals__
            for name in self.py_func.__code__.co_names:
                callee = names.get(name)
                if isinstance(callee, LazyKernel):
                    names[name] = callee.dispatcher()
            d = self._dispatcher = njit(**self._options)(self.py_func)
        return d

    def __call__(self, *args):
        return self.dispatcher()(*args)


def lazy_njit(**options):
    """``numba.njit(**options)`` applied on the kernel's first call (:class:`LazyKernel`).

    Examples
    --------
    >>> @lazy_njit(cache=False)
    ... def twice(v):
    ...     return 2 * v
    >>> twice(21)
    42
    """
    def wrap(fn):
        return LazyKernel(fn, options)

    return wrap


# ---------------------------------------------------------------------------------------
# compile time per thread, from numba's "numba:compile" events (nested compilations of the
# callees of a kernel lie inside their caller's event and count once)

_LOCK = threading.Lock()
_TOTALS: dict[int, float] = {}
_listener = None


def _install_listener() -> None:
    global _listener
    import time

    from numba.core import event

    class _CompileListener(event.Listener):
        def __init__(self):
            self._local = threading.local()

        def on_start(self, ev):
            loc = self._local
            depth = getattr(loc, "depth", 0)
            if depth == 0:
                loc.t0 = time.perf_counter()
            loc.depth = depth + 1

        def on_end(self, ev):
            loc = self._local
            loc.depth -= 1
            if loc.depth == 0:
                tid = threading.get_ident()
                with _LOCK:
                    _TOTALS[tid] = _TOTALS.get(tid, 0.0) + time.perf_counter() - loc.t0

    _listener = _CompileListener()
    event.register("numba:compile", _listener)


def compile_seconds() -> float:
    """Seconds this thread has spent compiling numba kernels since the first call.

    The difference of two calls is the compile time of what ran between them (0 when every
    kernel was compiled already or loaded from the cache).

    Examples
    --------
    >>> compile_seconds() >= 0.0
    True
    """
    if _listener is None:
        if "numba" not in sys.modules:
            # nothing can have compiled; importing numba to listen costs a one-window dnn
            # command 0.4 s it otherwise never spends (a kernel that numba, imported
            # later in the same call, compiles is counted from the next call on)
            return 0.0
        with _LOCK:
            if _listener is None:
                _install_listener()
    return _TOTALS.get(threading.get_ident(), 0.0)

"""The ``evmotion`` command: one entry point, one module per subcommand.

Each module listed in :data:`COMMANDS` defines ``add_parser(subparsers)`` (registering its
sub-parser with ``set_defaults(func=run)``) and ``run(args) -> int``. Modules import their
heavy dependencies inside ``run`` so that ``evmotion --help`` stays fast.
"""

from __future__ import annotations

# Only what main() needs to take over Ctrl-C is imported here: the rest (argparse, json,
# the commands) after its handler is in place, so that an interrupt during those imports
# too ends in one line.
import os
import signal
import sys
import warnings

from evmotion.errors import EvmotionError

COMMANDS: tuple[str, ...] = (
    "info",
    "convert",
    "simulate",
    "view",
    "egomotion",
    "landscape",
    "segment",
    "flow",
    "eval",
    "train",
    "bos",
    "kymogram",
)

EPILOG = """examples:
  evmotion simulate rotation --out sim.h5           # events + ground truth
  evmotion info sim.h5 --json                       # what a file holds
  evmotion egomotion sim.h5 --warp rotation --reg rcad --window-events 30000 --out ego/
  evmotion flow sim.h5 --method multicm --max-windows 2 --out flow.h5
  evmotion flow sim.h5 --method triplet --out triplet.h5
every command's --help ends with examples of its own.
"""


def build_parser(commands: tuple[str, ...] = COMMANDS):
    """The ``evmotion`` parser (an :class:`argparse.ArgumentParser`) with ``commands``
    (default: every command).

    Examples
    --------
    >>> build_parser(("info",)).parse_args(["info", "x.h5"]).command
    'info'
    """
    import importlib

    from evmotion.cli.options import HelpFormatter, Parser

    parser = Parser(
        prog="evmotion",
        description="Estimate motion from event cameras.",
        epilog=EPILOG,
        formatter_class=HelpFormatter,
    )
    from evmotion import __version__

    parser.add_argument("--version", action="version", version=f"evmotion {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in commands:
        try:
            mod = importlib.import_module(f"evmotion.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"evmotion.cli.{name}":
                continue
            raise
        mod.add_parser(sub)
    return parser


def print_json(obj) -> None:
    """Machine-readable summary on stdout (numpy scalars and arrays converted; NaN and
    infinities, which strict JSON has not, written as null). A summary (a dict) also lists
    under ``"warnings"`` the warning lines this run has printed on stderr, so that a
    result flagged there is flagged for a program too (the warnings of worker processes
    and Dask workers come back with their windows' results and are printed here)."""
    import json

    import numpy as np

    if isinstance(obj, dict) and "warnings" not in obj:
        obj = {**obj, "warnings": list(_WARNED)}

    def plain(o):
        if isinstance(o, dict):
            return {k: plain(v) for k, v in o.items()}
        if isinstance(o, (list, tuple)):
            return [plain(v) for v in o]
        if isinstance(o, np.ndarray):
            return plain(o.tolist())
        if isinstance(o, np.generic):
            o = o.item()
        if isinstance(o, float) and not np.isfinite(o):
            return None
        return o

    json.dump(plain(obj), sys.stdout, indent=2, default=str, allow_nan=False)
    sys.stdout.write("\n")


def warn_line(message: str) -> None:
    """One warning line on stderr, ``evmotion: warning: ...`` (a result that may not be a
    measurement); the JSON summary (:func:`print_json`) lists them too."""
    line = " ".join(str(message).split())
    _WARNED.append(line)
    if "tqdm" in sys.modules:
        # a live progress bar is cleared, the line written, the bar drawn again below it:
        # printed as it was, the line had been glued onto the bar (probe BB)
        from tqdm.auto import tqdm

        tqdm.write(f"evmotion: warning: {line}", file=sys.stderr)
    else:
        print(f"evmotion: warning: {line}", file=sys.stderr)


def show_warning(message, category, filename, lineno, file=None, line=None):
    """A ``warnings.showwarning``: project warnings as one line each (:func:`warn_line`),
    others as Python prints them."""
    from evmotion.errors import EvmotionWarning

    if issubclass(category, EvmotionWarning):
        # once per run: a file read twice (its summary, then its events) says it once
        if str(message) not in _SAID:
            _SAID.add(str(message))
            warn_line(str(message))
    else:
        _PY_SHOWWARNING(message, category, filename, lineno, file, line)


_PY_SHOWWARNING = warnings.showwarning
# the project warnings this run has printed
_SAID: set[str] = set()
# every warning line of this run, in order (the JSON summary's "warnings")
_WARNED: list[str] = []


def _command_of(argv: list[str]) -> tuple[str, ...]:
    """The commands the parser needs for ``argv``: the one it names first (then the
    others' modules, which import e.g. the simulator's scenes, are not loaded: a tenth of
    a second off every run), or all of them (top-level options, no or an unknown
    command: the top-level help and errors list every command)."""
    return (argv[0],) if argv and argv[0] in COMMANDS else COMMANDS


def _build_and_run(argv: list[str] | None) -> int:
    parser = build_parser(_command_of(sys.argv[1:] if argv is None else argv))
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # a bad argument (its line is written), --help, --version
        return exc.code if isinstance(exc.code, int) else 2
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    _SAID.clear()
    _WARNED.clear()
    warnings.showwarning = show_warning
    try:
        from evmotion.cli.options import (
            check_outputs_spare_inputs,
            outputs_locked,
            resolve_relative_times,
        )

        check_outputs_spare_inputs(args)
        resolve_relative_times(args)
        with outputs_locked(args):
            return int(args.func(args) or 0)
    except EvmotionError as exc:
        print(f"evmotion {args.command}: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except MemoryError as exc:
        # sizes that passed the checks but not this machine's memory: one line, not a
        # traceback
        print(f"evmotion {args.command}: error: out of memory ({_one_line(exc)}); try "
              "smaller sizes, windows or batches", file=sys.stderr)
        return 1
    except BrokenPipeError:
        # the reader of stdout went away (``evmotion ... --json | head``): stop quietly,
        # with the status of a process that SIGPIPE ended, as other command-line tools do
        return 141
    except OSError as exc:
        # a file system refusal that the checks before the work could not foresee
        # (the disk filled up, a folder removed meanwhile): one line, not a traceback,
        # naming the output when the error names no file
        out = getattr(args, "out", None) or getattr(args, "output", None)
        where = f"{out}: " if exc.filename is None and out else ""
        if no_room(exc) is not None:
            _FAILED_WRITES.append(exc)  # (see the RuntimeError below)
        print(f"evmotion {args.command}: error: {where}{_one_line(exc)}{_dropped_parts(exc)}",
              file=sys.stderr)
        return 1
    except RuntimeError as exc:
        code = no_room(exc)
        if code is None:
            raise
        # h5py reports a failed write as RuntimeError ("... errno = 28 ..."). Its objects
        # stay referenced (by the traceback) until the process ends: libhdf5 crashes when
        # it closes a file whose write failed (h5py issue 914; rc 139 after the message)
        _FAILED_WRITES.append(exc)
        print(f"evmotion {args.command}: error: {_NO_ROOM[code]} while writing: "
              f"{_one_line(exc)[:300]}{_dropped_parts(exc)}", file=sys.stderr)
        return 1
    finally:
        warnings.showwarning = _PY_SHOWWARNING


# errno of a write that found no room, and how to say it: the device full, a file past
# the file system's or the process' size limit (FAT32's 4 GiB, ``ulimit -f``), a quota
_NO_ROOM = {28: "no space left on the device",
            27: "the file grew past the largest the file system or a file-size limit "
                "(ulimit -f) allows",
            122: "the disk quota is exceeded"}


def no_room(exc: BaseException | None) -> int | None:
    """The errno when ``exc`` (or an exception it was raised from) is a write that found
    no room (:data:`_NO_ROOM`: an OSError, or h5py's RuntimeError quoting the errno),
    else None."""
    import re

    seen = 0
    while exc is not None and seen < 10:
        if isinstance(exc, OSError) and exc.errno in _NO_ROOM:
            return exc.errno
        if isinstance(exc, RuntimeError):
            found = re.search(r"errno = (\d+)", str(exc))
            if found and int(found.group(1)) in _NO_ROOM:
                return int(found.group(1))
            if "No space left on device" in str(exc):
                return 28
        exc, seen = exc.__cause__ or exc.__context__, seen + 1
    return None


def _dropped_parts(exc: BaseException) -> str:
    """After a full device: remove the partial outputs kept for ``--resume`` (their last
    write failed, so they cannot be trusted) and say so."""
    utils = sys.modules.get("evmotion.utils")
    if no_room(exc) is None or utils is None:
        return ""
    if isinstance(exc, utils.NoRoomError):
        # stopped before the write that would not fit: what was written is intact
        kept = utils.kept_for_resume()
        room = ("free space" if exc.errno == 28 else "lift the limit (or write to another "
                "file system)")
        return (f"; the work done so far is kept in {', '.join(map(str, kept))}: {room} "
                "and run the same command with --resume" if kept else "")
    gone = []
    for path in utils.kept_for_resume():
        try:
            path.unlink()
            gone.append(str(path))
        except OSError:
            pass
    utils.forget_kept_for_resume()
    return (f"; removed the partial output {', '.join(gone)} (its last write failed): make "
            "room and run again" if gone else "")


# the longest error line printed (a 5 MB file name in images.txt was echoed whole, probe AO)
MAX_ERROR_CHARS = 600


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    if len(text) <= MAX_ERROR_CHARS:
        return text
    half = MAX_ERROR_CHARS // 2
    return f"{text[:half]} ... [{len(text) - 2 * half:,} characters] ... {text[-half:]}"


def _flush_std() -> None:
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe (``evmotion ... | head``)
            pass


# the exit code of an interrupted run: 130 after Ctrl-C (SIGINT), 143 after SIGTERM
_EXIT_CODE = [130]


def _interrupted(*_) -> None:
    """Ctrl-C in the command-line process: one line, exit code 130 (143 after SIGTERM),
    nothing else.

    Exits with ``os._exit`` once the work has unwound (outputs removed or kept for
    ``--resume`` by their ``finally`` blocks), so that no interpreter-shutdown hook
    (thread joins, pool shutdown, ``__del__``) can print "Exception ignored ..."."""
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # called by the watchdog thread
        pass
    _stop_children()
    _flush_std()
    try:
        os.write(2, _interrupted_line().encode("utf-8", "replace") + b"\n")
    finally:
        os._exit(_EXIT_CODE[0])


def _interrupted_line() -> str:
    """The line that reports an interruption, naming what the work kept for ``--resume``."""
    utils = sys.modules.get("evmotion.utils")
    kept = utils.kept_for_resume() if utils is not None else []
    note = utils.interrupt_note() if utils is not None else None
    if not kept:
        return "evmotion: interrupted" + (f"; {note[1]}" if note else "")
    return (f"evmotion: interrupted; the work done so far is kept in "
            f"{', '.join(str(p) for p in kept)}: "
            + (note[0] if note else "run the same command with --resume to continue"))


def _on_sigint(signum, frame) -> None:
    """First Ctrl-C: stop the worker processes and unwind the work (KeyboardInterrupt);
    a second one exits at once."""
    if os.getpid() != _MAIN_PID[0]:
        return  # a forked worker: its parent ends it
    signal.signal(signal.SIGINT, _on_later_sigint)
    if not _INTERRUPTED[0]:
        import _thread  # the documented low-level API

        _thread.start_new_thread(_watchdog, (UNWIND_TIMEOUT_S,))
    _INTERRUPTED[0] = True
    _stop_children()
    raise KeyboardInterrupt


def _on_sigterm(signum, frame) -> None:
    """``kill`` / ``timeout``: unwind as for Ctrl-C (partial outputs removed, or kept for
    ``--resume``); a worker process (forked, so it has this handler) ends at once, as
    SIGTERM's default action would, when its pool is terminated."""
    if os.getpid() != _MAIN_PID[0]:
        os._exit(128 + signum)
    _EXIT_CODE[0] = 128 + signum  # 143, as the shell reports a process SIGTERM ended
    _on_sigint(signum, frame)


def _stop_children() -> None:
    """End the worker processes (which ignore Ctrl-C, see :func:`_on_sigint`): none may
    outlive the command, nor keep its output pipes open."""
    mp = sys.modules.get("multiprocessing")
    if mp is not None and os.getpid() == _MAIN_PID[0]:
        for child in mp.active_children():
            child.terminate()


def _excepthook(exc_type, exc, tb) -> None:
    """After a Ctrl-C, a KeyboardInterrupt printed by C code that swallows it prints
    nothing: Cython's ``__dealloc__`` (h5py's objects, freed while the work unwinds)
    writes it with ``PyErr_PrintEx``, which calls this hook, as a bare traceback before
    the "Exception ignored" that :func:`_unraisable` turns into a redelivery."""
    if issubclass(exc_type, KeyboardInterrupt) and _INTERRUPTED[0] \
            and os.getpid() == _MAIN_PID[0]:
        return
    sys.__excepthook__(exc_type, exc, tb)


def _on_later_sigint(signum, frame) -> None:
    if _REDELIVER[0]:
        _REDELIVER[0] = False
        raise KeyboardInterrupt
    _interrupted()


def _unraisable(hook_args) -> None:
    """A Ctrl-C whose KeyboardInterrupt was raised where Python ignores exceptions (a
    weakref callback, ``__del__``): instead of "Exception ignored ..." and a run that
    goes on, deliver it again, to land in the work and unwind it."""
    if no_room(hook_args.exc_value) is not None:
        return  # an h5py object failing to flush on a full device: the error says so once
    if isinstance(hook_args.exc_value, KeyboardInterrupt) and os.getpid() == _MAIN_PID[0]:
        import _thread  # the documented low-level API: starts without waiting here

        _REDELIVER[0] = True
        # from another thread, so that the handler runs once this callback has returned
        _thread.start_new_thread(_signal_later, (os.getpid(),))
        return
    sys.__unraisablehook__(hook_args)


def _watchdog(seconds: float) -> None:
    """Exit after ``seconds`` if unwinding the interrupted work hangs (a library waiting
    on a process that is gone): Ctrl-C must end the command in any case."""
    import time

    time.sleep(seconds)
    _interrupted()


def _signal_later(pid: int) -> None:
    import time

    time.sleep(0.001)
    os.kill(pid, signal.SIGINT)


# h5py errors of failed writes, kept alive until os._exit (see _build_and_run)
_FAILED_WRITES: list = []
# longest wait for the interrupted work to unwind (remove or keep its partial outputs)
UNWIND_TIMEOUT_S = 10.0
_MAIN_PID = [0]
_INTERRUPTED = [False]
_REDELIVER = [False]


def main(argv: list[str] | None = None) -> int:
    """Run the ``evmotion`` command; returns its exit code.

    With ``argv=None`` (the installed script, ``python -m evmotion``) this is the whole
    process: Ctrl-C (or SIGTERM) at any moment prints one line "evmotion: interrupted"
    and exits with code 130. With a list (tests, scripts), Ctrl-C returns 130 after the same line.
    """
    utils = sys.modules.get("evmotion.utils")
    if utils is not None:
        utils.forget_kept_for_resume()  # an earlier call's, in this process
    if argv is not None:
        try:
            return _build_and_run(argv)
        except KeyboardInterrupt:
            print(_interrupted_line(), file=sys.stderr)
            return 130
    _MAIN_PID[0] = os.getpid()
    signal.signal(signal.SIGINT, _on_sigint)
    signal.signal(signal.SIGTERM, _on_sigterm)
    sys.unraisablehook = _unraisable
    sys.excepthook = _excepthook
    try:
        rc = _build_and_run(None)
    except BaseException:
        # C extensions may turn the KeyboardInterrupt into their own error (numpy's
        # import into an ImportError): after a Ctrl-C, any exception is the interrupt
        if _INTERRUPTED[0]:
            _interrupted()
        raise
    # The work is done and every output closed and renamed. Leave now rather than through
    # the interpreter's teardown: a Ctrl-C there (thread joins, pool and h5py shutdown,
    # after the signal handlers are reset) prints "Exception ignored ..." or kills the
    # process without a word.
    signal.signal(signal.SIGINT, _interrupted)
    _flush_std()
    os._exit(rc)


if __name__ == "__main__":
    sys.exit(main())

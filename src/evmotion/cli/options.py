"""Argument checks shared by every ``evmotion`` command.

Every bad command-line value must end in one line on stderr that names the option and the
value, and exit code 2, before any work starts. This module holds the pieces for that:

- :class:`Parser`, an :class:`argparse.ArgumentParser` whose errors are one line
  (``evmotion flow: error: argument --dt-ms: must be > 0 ms, got 'nan'``) instead of the
  usage block; sub-parsers made with ``add_subparsers`` inherit it.
- ``type=`` factories that check a value as it is parsed: :func:`finite_float`,
  :func:`positive_float`, :func:`nonnegative_float`, :func:`int_range`,
  :func:`positive_int`, :func:`seed_int`, :func:`float_list`, :func:`existing_input`,
  :func:`writable_output`, :func:`writable_folder`. argparse prefixes their message with
  ``argument --name:``, so a message says what is wrong with the value only.
- Checks made after parsing, when several options or the input decide (they raise
  :class:`~evmotion.errors.ParameterError`, which the CLI prints as one line):
  :func:`reject_unused` (options that do not apply to the chosen method),
  :func:`check_free_space`, :func:`check_output` and :func:`check_folder` (the same
  checks as :func:`writable_output` and :func:`writable_folder`, for a path whose kind or
  name is known only at run time).

Examples
--------
>>> p = Parser(prog="demo")
>>> _ = p.add_argument("--dt-ms", type=positive_float(unit="ms"), default=100.0)
>>> _ = p.add_argument("--bins", type=int_range(1, 64), default=1)
>>> p.parse_args(["--dt-ms", "2.5", "--bins", "3"])
Namespace(dt_ms=2.5, bins=3)
>>> positive_float(unit="ms")("nan")
Traceback (most recent call last):
...
argparse.ArgumentTypeError: must be a finite number > 0 ms, got 'nan'
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import re
import shutil
import sys
import tempfile
from collections.abc import Callable, Collection, Iterable
from fractions import Fraction
from pathlib import Path

from evmotion.catalog import FORMAT_NAMES, MAX_SENSOR_SIDE
from evmotion.errors import ParameterError
from evmotion.utils import MAX_TIME_US, missing_path_hint, nearest_existing, seconds_text

__all__ = [
    "FILE_SUFFIXES",
    "Parser",
    "add_scheduler_argument",
    "check_folder",
    "check_free_space",
    "check_output",
    "check_output_format",
    "event_format",
    "warn_late_start",
    "existing_input",
    "outputs_locked",
    "finite_float",
    "float_list",
    "format_bytes",
    "int_range",
    "nonnegative_float",
    "positive_float",
    "positive_int",
    "reject_unused",
    "remove_stale_results",
    "scheduler_address",
    "seed_int",
    "scheduler_client",
    "writable_folder",
    "writable_output",
]


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line on stderr and exit code 2, and which
    takes ``-5e-1``, ``-1e3``, ``-inf`` and ``-nan`` for (negative) numbers, not options:
    argparse's own test knows only ``-5`` and ``-0.5``, so ``--range -5e-1 5`` was
    "expected 2 arguments" and ``--t0 -inf`` escaped the option checks."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # the pattern argparse consults (an attribute of ArgumentParser since Python 3.2)
        self._negative_number_matcher = _NEGATIVE_NUMBER

    def parse_known_args(self, args=None, namespace=None):
        # kept for error(): an unknown option is reported by the top-level parser, which
        # must look up the command's options for a suggestion
        self._argv = [str(a) for a in (sys.argv[1:] if args is None else args)]
        empty = self._empty_argument()
        if empty:
            # an empty value ('--calib=', a shell variable never set) had been taken as the
            # option not given, the default running unsaid, and an empty path as '.'
            # (probe OPT)
            self.error(empty)
        return super().parse_known_args(args, namespace)

    def _empty_argument(self) -> str | None:
        """What is wrong with the first empty argument typed (``--calib=``,
        ``--calib ''``, a path ``''``), if any."""
        takes = {o for a in self._actions if a.option_strings and a.nargs != 0
                 for o in a.option_strings}
        # the top level leaves a command's arguments to the command's parser
        commands = any(isinstance(a, argparse._SubParsersAction) for a in self._actions)
        argv = self._argv
        for i, token in enumerate(argv):
            name, eq, value = token.partition("=")
            if not eq:  # its value, if any, is the next argument
                value = argv[i + 1] if i + 1 < len(argv) else None
            if name in takes and value is not None and not value.strip():
                return f"argument {name}: empty value (give one, or leave {name} out)"
            if not token.strip() and not commands and (i == 0 or argv[i - 1] not in takes):
                return f"an empty argument ({token!r}) where a path or value was expected"
        return None

    def error(self, message: str):
        text = " ".join(str(message).split())
        prog, hint = self.prog, ""
        unknown = re.match(r"unrecognized arguments: (.*)", text)
        choice = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)", text)
        if unknown:
            prog, hint = self._unknown_options(unknown.group(1).split())
        elif choice:
            hint = _did_you_mean([choice.group(1)], re.findall(r"'([^']*)'", choice.group(2)))
        elif text.startswith("the following arguments are required:"):
            # a misspelt required option is reported as missing, before as unknown
            hint = _did_you_mean(self._typed_unknown(),
                                 text.split(":", 1)[1].replace(",", " ").split(),
                                 name_typed=True)
        if not hint and self._typed_unknown() and not unknown and not any(
                isinstance(a, argparse._SubParsersAction) for a in self._actions):
            # a misspelt option's value was taken for the next positional argument and
            # checked as one ("train --epohcs 2": "argument recordings: 2: no such file")
            typed = self._typed_unknown()
            text = f"unrecognized arguments: {' '.join(typed)}"
            hint = _did_you_mean(typed, [o for a in self._actions for o in a.option_strings])
        sys.stderr.write(f"{prog}: error: {text}{hint} (see '{prog} --help')\n")
        sys.exit(2)

    def _typed_unknown(self) -> list[str]:
        """The ``--options`` typed that this parser does not know (typos)."""
        known = {o for a in self._actions for o in a.option_strings}
        return [a.split("=", 1)[0] for a in getattr(self, "_argv", [])
                if a.startswith("--") and a != "--" and a.split("=", 1)[0] not in known]

    def _unknown_options(self, tokens: list[str]) -> tuple[str, str]:
        """The command's parser name and a "did you mean" for the unknown ``tokens``,
        against that command's own options."""
        argv = getattr(self, "_argv", [])
        for action in self._actions:
            if isinstance(action, argparse._SubParsersAction):
                name = next((a for a in argv if a in action.choices), None)
                if name is not None:
                    sub = action.choices[name]
                    options = [o for a in sub._actions for o in a.option_strings]
                    return sub.prog, _did_you_mean(
                        [t.split("=", 1)[0] for t in tokens if t.startswith("-")], options)
        return self.prog, _did_you_mean(
            [t.split("=", 1)[0] for t in tokens if t.startswith("-")],
            [o for a in self._actions for o in a.option_strings])


_RST_ROLE = re.compile(r":[a-z]+:`~?([^`<]*?)(?:\s*<[^>]*>)?`")
_RST_LITERAL = re.compile(r"``([^`]+)``")


def plain_help(text: str) -> str:
    """``text`` with reStructuredText's inline markup taken off, for a terminal: roles
    (``:func:`a.b.c``` -> a.b.c, ``~`` dropped, an explicit title kept) and double
    back-quotes (the commands' help reuses their modules' docstrings, which Sphinx renders).

    Examples
    --------
    >>> plain_help("``evmotion eval FLOW`` (:func:`evmotion.io.read_flow`)")
    'evmotion eval FLOW (evmotion.io.read_flow)'
    """
    return _RST_LITERAL.sub(r"\1", _RST_ROLE.sub(r"\1", text))


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Every command's help formatter: descriptions and epilogs as written (their line
    breaks kept), their inline markup taken off (:func:`plain_help`)."""

    def _format_text(self, text: str) -> str:
        return super()._format_text(plain_help(text))


def _did_you_mean(words: list[str], known: list[str], name_typed: bool = False) -> str:
    """``" (did you mean --method?)"`` for the known names closest to ``words`` (typos);
    ``name_typed``: also say which word each is for, where the message does not show it.

    Examples
    --------
    >>> _did_you_mean(["--methd"], ["--method", "--out"])
    ' (did you mean --method?)'
    >>> _did_you_mean(["--outt"], ["--out"], name_typed=True)
    ' (did you mean --out for --outt?)'
    >>> _did_you_mean(["--zzz"], ["--method"])
    ''
    >>> _did_you_mean(["--max-iter"], ["--iterations", "--max-windows"])   # a counterpart
    ' (did you mean --iterations?)'
    """
    import difflib

    pairs = {}
    for w in words:
        # a counterpart first: --max-iter is nearer --max-windows than --iterations
        if COUNTERPARTS.get(w) in known:
            pairs[w] = COUNTERPARTS[w]
        elif m := difflib.get_close_matches(w, known, n=1, cutoff=0.6):
            pairs[w] = m[0]
    if not pairs:
        return ""
    if name_typed:
        return f" (did you mean {', '.join(f'{m} for {w}' for w, m in pairs.items())}?)"
    return f" (did you mean {', '.join(dict.fromkeys(pairs.values()))}?)"


# a negative number (scientific notation, inf, nan), with a unit suffix (-10ms) or as the
# first of a comma-separated list (--K -300,300,172,129): the option's own check judges it
_NUMBER = r"(?:(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|inf|infinity|nan)"
_NEGATIVE_NUMBER = re.compile(rf"^-{_NUMBER}(?:\s*[a-zµ]{{1,3}})?(?:,\s*[-+]?{_NUMBER})*$",
                              re.IGNORECASE)


def _unit(unit: str) -> str:
    return f" {unit}" if unit else ""


def _number_text(v: float | None) -> str:
    """An integer bound as it is typed (``4294967295``), a float's shortest (``1e-06``)."""
    return str(v) if v is None or isinstance(v, int) else f"{v:g}"


def _bound_text(lo, hi, lo_open: bool, hi_open: bool, unit: str) -> str:
    u = _unit(unit)
    lo_s, hi_s = _number_text(lo), _number_text(hi)
    if lo is not None and hi is not None:
        return (f"in {'(' if lo_open else '['}{lo_s}, {hi_s}{')' if hi_open else ']'}{u}")
    if lo is not None:
        return f"{'>' if lo_open else '>='} {lo_s}{u}"
    if hi is not None:
        return f"{'<' if hi_open else '<='} {hi_s}{u}"
    return f"finite{u}".strip()


def finite_float(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
                 hi_open: bool = False, unit: str = "") -> Callable[[str], float]:
    """``type=`` for a finite float in ``[lo, hi]`` (open ends with ``lo_open``/``hi_open``).

    Parameters
    ----------
    lo, hi : float, optional
        Bounds (None: unbounded on that side).
    lo_open, hi_open : bool
        Exclude the bound itself.
    unit : str
        Unit named in the message (``"ms"``, ``"px"``...).

    Examples
    --------
    >>> finite_float(0, 100, lo_open=True, unit="%")("99.5")
    99.5
    """
    want = _bound_text(lo, hi, lo_open, hi_open, unit)
    if lo is None and hi is None:  # "finite [unit]": the message says finite already
        want = f"in {unit}" if unit else ""
    want = f" {want}" if want else ""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(
                f"must be a number{want}, got {text!r}") from None
        bad = not math.isfinite(v)
        if lo is not None:
            bad |= v <= lo if lo_open else v < lo
        if hi is not None:
            bad |= v >= hi if hi_open else v > hi
        if bad:
            raise argparse.ArgumentTypeError(f"must be a finite number{want}, got {text!r}")
        return v

    parse.__name__ = "number"
    return parse


def positive_float(*, unit: str = "") -> Callable[[str], float]:
    """``type=`` for a finite float > 0 (``--dt-ms``, ``--duration``...)."""
    return finite_float(0.0, lo_open=True, unit=unit)


def nonnegative_float(*, unit: str = "") -> Callable[[str], float]:
    """``type=`` for a finite float >= 0 (weights, rates)."""
    return finite_float(0.0, unit=unit)


# the largest whole number an option without its own upper bound takes: every count, index
# or µs time fits numpy's int64 with room for sums (probe OPT: --seed 1e30 and
# --window-events 1e30 reached HDF5 as Python ints, "Object dtype has no native HDF5
# equivalent")
MAX_WHOLE = 2**62

# seeds as numpy's and torch's generators and every format's int64 store them
MAX_SEED = 2**32 - 1


def int_range(lo: int | None = None, hi: int | None = None, *, unit: str = ""
              ) -> Callable[[str], int]:
    """``type=`` for an integer in ``[lo, hi]`` (accepts ``1e6`` or ``1_000_000`` when the
    value is a whole number); without ``hi``, at most :data:`MAX_WHOLE`.

    Examples
    --------
    >>> int_range(1, 5)("3")
    3
    >>> int_range(1)("1e6")
    1000000
    >>> int_range(1)("1e30")
    Traceback (most recent call last):
    ...
    argparse.ArgumentTypeError: must be an integer >= 1 (at most 2^62), got '1e30'
    """
    want = _bound_text(lo, hi, False, False, unit)
    want = "an integer" + ("" if want.startswith("finite") else f" {want}")
    if hi is None:
        want += " (at most 2^62)"
        hi = MAX_WHOLE

    def parse(text: str) -> int:
        try:
            v = int(text)
        except (TypeError, ValueError):
            try:
                f = float(text)
            except (TypeError, ValueError):
                f = math.nan
            if not (math.isfinite(f) and f == int(f)):
                raise argparse.ArgumentTypeError(f"must be {want}, got {text!r}") from None
            v = int(f)
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise argparse.ArgumentTypeError(f"must be {want}, got {text!r}")
        return v

    parse.__name__ = "integer"
    return parse


def positive_int(*, unit: str = "") -> Callable[[str], int]:
    """``type=`` for an integer >= 1 (counts, durations in µs, workers)."""
    return int_range(1, unit=unit)


_SEED = int_range(0, MAX_SEED)


def seed_int(text: str) -> int:
    """``type=`` for ``--seed``: an integer in ``[0, 2^32 - 1]``.

    Examples
    --------
    >>> seed_int("42")
    42
    """
    return _SEED(text)


seed_int.__name__ = "seed"


def float_list(n: int | None = None, *, unit: str = "") -> Callable[[str], list[float]]:
    """``type=`` for comma-separated finite numbers, ``n`` of them when given.

    Examples
    --------
    >>> float_list(3)("0.1, 0, -2")
    [0.1, 0.0, -2.0]
    """
    count = f"{n} " if n else ""

    def parse(text: str) -> list[float]:
        try:
            vals = [float(v) for v in str(text).split(",")]
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"must be {count}comma-separated numbers{_unit(unit)}, got {text!r}") from None
        if not all(math.isfinite(v) for v in vals):
            raise argparse.ArgumentTypeError(f"must be finite numbers, got {text!r}")
        if n is not None and len(vals) != n:
            raise argparse.ArgumentTypeError(
                f"must be {n} comma-separated numbers, got {len(vals)} in {text!r}")
        return vals

    parse.__name__ = "list"
    return parse


def event_format(text: str) -> str:
    """``type=`` for an input's ``--format``: one of the readers' format names.

    Examples
    --------
    >>> event_format("evt3")
    'evt3'
    >>> event_format("evt")
    Traceback (most recent call last):
    ...
    argparse.ArgumentTypeError: unknown format 'evt' (did you mean evt3?; known formats: h5, mvsec, dsec, ecd, ccs, npy, mat, aedat4, aedat2, aedat3, evt3, evt2, evt21, dat, rosbag, h5generic)
    """
    if text in FORMAT_NAMES:
        return text
    hint = _did_you_mean([text], list(FORMAT_NAMES)).strip(" ()")
    raise argparse.ArgumentTypeError(f"unknown format {text!r} ({hint + '; ' if hint else ''}"
                                     f"known formats: {', '.join(FORMAT_NAMES)})")


event_format.__name__ = "format"


def existing_input(text: str) -> str:
    """``type=`` for an input file or folder that exists and can be read.

    Use it for inputs read late (a calibration, ground truth): the main recording is
    read first anyway, and its reader names a missing file in one line."""
    p = Path(text)
    if not p.exists():
        raise argparse.ArgumentTypeError(f"{text}: no such file or folder"
                                         f"{missing_path_hint(p)}")
    if not os.access(p, os.R_OK):
        raise argparse.ArgumentTypeError(f"{text}: cannot be read (permission denied)")
    return text


def _folder_problem(folder: Path) -> str | None:
    """Why files cannot be created in ``folder`` (created if missing), or None.

    Probes by creating and removing a file: permission bits say nothing for root, nor
    for read-only mounts, ACLs or pseudo file systems."""
    base = nearest_existing(folder)
    if not base.is_dir():
        return f"{base} is a file, not a folder"
    try:
        fd, probe = tempfile.mkstemp(prefix=".evmotion-probe-", dir=base)
    except OSError as exc:
        return f"cannot write in {base} ({exc.strerror or exc})"
    os.close(fd)
    os.unlink(probe)
    return None


def _output_problem(text: str | os.PathLike, suffixes: Iterable[str] | None,
                    what: str = "") -> str | None:
    name = os.fspath(text)
    if name.endswith(("/", os.sep)):
        # Path() drops the separator: 'flow --out o.h5/' wrote a file o.h5 where a folder
        # was typed
        return "a name ending in a path separator is a folder; the output is a file"
    path = Path(name)
    if suffixes is not None:
        suffixes = tuple(suffixes)
        if path.suffix.lower() not in suffixes:
            return f"{what or 'the name'} must end in {', '.join(suffixes)}"
    if path.is_dir():
        return f"{path} is a folder, not a file"
    if path.exists() and not os.access(path, os.W_OK):
        return f"{path} exists and cannot be overwritten (permission denied)"
    return _folder_problem(path.parent)


def writable_output(suffixes: Iterable[str] | None = None, what: str = ""
                    ) -> Callable[[str], str]:
    """``type=`` for an output file: the name ends in one of ``suffixes`` (when given;
    ``what`` names the kind of file in the message), it is not a folder, and its folder
    exists or can be made, and can be written.

    Examples
    --------
    >>> writable_output((".png",))("/tmp/evmotion-doc.png")
    '/tmp/evmotion-doc.png'
    """

    def parse(text: str) -> str:
        problem = _output_problem(text, suffixes, what)
        if problem:
            raise argparse.ArgumentTypeError(f"cannot write {text!r}: {problem}")
        return text

    parse.__name__ = "output"
    return parse


#: Suffixes of the files evmotion reads or writes: an output folder named so is a file name
#: taken for a folder (``egomotion --out e1.h5`` made a folder e1.h5/ holding params.csv)
FILE_SUFFIXES = (".h5", ".hdf5", ".csv", ".npz", ".npy", ".png", ".pt", ".flo", ".txt",
                 ".json", ".aedat4", ".aedat", ".raw", ".dat", ".bag")


def _folder_output_problem(text: str | os.PathLike, holds: str) -> str | None:
    if not os.fspath(text).strip():
        return "an empty name would write into the current folder"
    path = Path(text)
    if path.exists() and not path.is_dir():
        return "it is a file"
    suffix = path.suffix.lower()
    if suffix in FILE_SUFFIXES and not path.is_dir():
        return (f"the output is a folder of {holds}, and a name ending in {suffix} reads as "
                f"a file: give a folder name, e.g. {path.stem}/")
    return _folder_problem(path)


def writable_folder(holds: str) -> Callable[[str], str]:
    """``type=`` for an output folder of ``holds`` (what the command writes into it, named
    in the message): an existing folder or one that can be made, in which files can be
    created, and whose name, when no such folder exists yet, does not end in a file's
    suffix (:data:`FILE_SUFFIXES`).

    Examples
    --------
    >>> writable_folder("params.csv")("/tmp/evmotion-doc-ego")
    '/tmp/evmotion-doc-ego'
    >>> writable_folder("params.csv")("/tmp/evmotion-doc-ego.h5")
    Traceback (most recent call last):
    ...
    argparse.ArgumentTypeError: cannot write into '/tmp/evmotion-doc-ego.h5': the output is a folder of params.csv, and a name ending in .h5 reads as a file: give a folder name, e.g. evmotion-doc-ego/
    """

    def parse(text: str) -> str:
        problem = _folder_output_problem(text, holds)
        if problem:
            raise argparse.ArgumentTypeError(f"cannot write into {text!r}: {problem}")
        return text

    parse.__name__ = "folder"
    return parse


def check_output(path: str | os.PathLike, option: str,
                 suffixes: Iterable[str] | None = None) -> None:
    """:func:`writable_output` for a path known only at run time; raises ParameterError."""
    problem = _output_problem(path, suffixes)
    if problem:
        raise ParameterError(f"{option} {os.fspath(path)}: cannot write: {problem}")


def check_folder(path: str | os.PathLike, option: str, holds: str) -> None:
    """:func:`writable_folder` for a path known only at run time; raises ParameterError."""
    problem = _folder_output_problem(path, holds)
    if problem:
        raise ParameterError(f"{option} {os.fspath(path)}: cannot write into it: {problem}")


def check_output_format(path: str | os.PathLike, fmt: str, option: str) -> None:
    """A format named with ``option`` (``--format-out``, ``--format``) for the output
    ``path``: refused when the path's suffix is that of other formats only (``convert
    sim.h5 o.npy --format-out evt3`` wrote EVT3 bytes into a .npy file without a word); a
    suffix no writer knows (``o.bin``) is what the option is for. Raises ParameterError.

    Examples
    --------
    >>> check_output_format("o.npy", "evt3", "--format-out")
    Traceback (most recent call last):
    ...
    evmotion.errors.ParameterError: --format-out evt3: the output o.npy ends in .npy, the suffix of npy files; name it with evt3's suffix .raw, or leave out --format-out
    >>> check_output_format("o.raw", "evt2", "--format-out")
    """
    from evmotion.io.registry import get_format
    from evmotion.io.write import suffix_formats

    named = suffix_formats(path)
    if named and fmt not in named:
        suffix = Path(path).suffix.lower()
        raise ParameterError(
            f"{option} {fmt}: the output {os.fspath(path)} ends in {suffix}, the suffix of "
            f"{' or '.join(named)} files; name it with {fmt}'s suffix "
            f"{' or '.join(get_format(fmt).extensions)}, or leave out {option}")


def format_bytes(n: float) -> str:
    """``1536`` -> ``'1.5 KiB'``."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024
    return f"{n:.3g} EiB"  # pragma: no cover - the loop returns at PiB


def check_free_space(path: str | os.PathLike, nbytes: int, option: str, what: str = "") -> None:
    """Raise ParameterError when the file system of ``path`` has less than ``nbytes`` free.

    ``nbytes`` is a lower bound of what the output needs, so a refusal is certain to be
    right; call it before the work starts."""
    base = nearest_existing(Path(path).parent)
    free = shutil.disk_usage(base).free
    if nbytes > free:
        raise ParameterError(f"{option} {os.fspath(path)}: {what or 'the output'} needs at "
                             f"least {format_bytes(nbytes)} but {base} has "
                             f"{format_bytes(free)} free")


#: Options that name one idea under two spellings, each where the other is not an option:
#: a camera's frame rate (``simulate``: ``--frame-rate`` for the motion scenes' ground
#: truth, ``--fps`` for schlieren), time bins (``flow``: multicm's ``--time-bins``,
#: triplet's ``--bins``) and iterations (``flow``'s ``--max-iter``, ``segment`` and
#: ``bos``'s ``--iterations``). A refusal or a typo names the counterpart where it applies.
COUNTERPARTS = {"--frame-rate": "--fps", "--fps": "--frame-rate",
                "--time-bins": "--bins", "--bins": "--time-bins",
                "--max-iter": "--iterations", "--iterations": "--max-iter"}


def reject_unused(args: argparse.Namespace, options: dict[str, str], reason: str,
                  here: Collection[str] = ()) -> None:
    """Raise ParameterError if any of ``options`` (``{"--flag": "attribute"}``) was given.

    Options whose default is None (or False for switches) count as given when set; use it
    for options that do not apply to the chosen method, so that they are not silently
    ignored. ``here``: the options that do apply, of which a given flag's counterpart
    (:data:`COUNTERPARTS`) is named.

    Examples
    --------
    >>> ns = argparse.Namespace(time_aware="burgers", time_bins=3)
    >>> reject_unused(ns, {"--time-aware": "time_aware"}, "with --method triplet")
    Traceback (most recent call last):
    ...
    evmotion.errors.ParameterError: --time-aware 'burgers' does not apply with --method triplet
    >>> reject_unused(ns, {"--time-bins": "time_bins"}, "with --method triplet", ["--bins"])
    Traceback (most recent call last):
    ...
    evmotion.errors.ParameterError: --time-bins 3 does not apply with --method triplet (here: --bins)
    """
    for flag, attr in options.items():
        value = getattr(args, attr, None)
        if value is not None and value is not False:
            # (an nargs option as typed: "--sensor-size 10 10", not "[10, 10]")
            shown = "" if value is True else "".join(f" {v}" for v in value) \
                if isinstance(value, (list, tuple)) else f" {value!r}"
            other = COUNTERPARTS.get(flag)
            hint = f" (here: {other})" if other in here else ""
            raise ParameterError(f"{flag}{shown} does not apply {reason}{hint}")


# ----------------------------------------------------------------- time range and windows
# µs per unit (a Fraction for ns: a recording's own ns clock, as a DSEC or Prophesee
# user reads it, typed as is; probe BM found no way to give it)
_TIME_UNITS = {"ns": Fraction(1, 1000), "us": 1, "µs": 1, "ms": 1_000, "s": 1_000_000}


def _split_unit(text: str, default_scale: int) -> tuple[str, int | Fraction]:
    """``(number's text, us per unit)`` of a time with an optional ``ns``/``us``/``µs``/
    ``ms``/``s`` suffix (``default_scale`` without one)."""
    raw = str(text).strip()
    for suffix in ("ns", "us", "µs", "ms", "s"):  # "ns", "ms" and "us" before "s"
        if raw.lower().endswith(suffix):
            return raw[: -len(suffix)].strip(), _TIME_UNITS[suffix]
    return raw, default_scale


def _with_unit(text: str, default_scale: int) -> tuple[float, int | Fraction]:
    """``(number, us per unit)`` of a time with an optional ``ns``/``us``/``µs``/``ms``/
    ``s`` suffix (``default_scale`` without one); the number NaN when it is not one."""
    body, scale = _split_unit(text, default_scale)
    try:
        return float(body), scale
    except ValueError:
        return math.nan, scale


class FromStart(int):
    """A time option given as ``+TIME``: that many µs after the recording's first event,
    made absolute by :func:`resolve_relative_times` before the command runs."""


def time_us(text: str) -> int:
    """``type=`` for a time: seconds by default, or with an explicit ``ns``, ``us``/``µs``,
    ``ms`` or ``s`` suffix; returns integer microseconds (absolute: the recording's own clock).
    With a leading ``+``, the time after the recording's first event (a :class:`FromStart`).

    Examples
    --------
    >>> time_us("1.5"), time_us("1500000us"), time_us("250ms"), time_us("2s")
    (1500000, 1500000, 250000, 2000000)
    >>> t = time_us("+10ms"); (t, isinstance(t, FromStart))
    (10000, True)
    >>> time_us("0.0010185"), time_us("1018.5us"), time_us("1018.4us")  # next whole µs
    (1019, 1019, 1019)
    >>> time_us("1500000000ns"), time_us("1500000001ns")
    (1500000, 1500001)
    """
    from decimal import Decimal

    relative = isinstance(text, str) and text.strip().startswith("+")
    body, scale = _split_unit(text.strip()[1:] if relative else text, _TIME_UNITS["s"])
    v, _ = _with_unit(body, scale)
    if math.isfinite(v) and v * scale > MAX_TIME_US:
        raise argparse.ArgumentTypeError(
            f"must be a time of at most 2^62 µs (146,000 years), got {text!r}")
    if not math.isfinite(v) or v < 0:
        raise argparse.ArgumentTypeError(
            f"must be a time >= 0 in seconds, or with a unit (e.g. 1.5, 1500ms, 1500000us), "
            f"or +TIME after the first event, got {text!r}")
    # a fraction of a µs goes up to the next one, computed on the decimal text (a float
    # of '0.0010185' s is 1018.4999... µs): events have whole µs, so [t0, t1) holds those
    # at or after the next one, which '--t0 0.0010185' and '1018.5us' had rounded apart
    # (probe BL)
    us = math.ceil(Fraction(Decimal(body)) * scale)
    return FromStart(us) if relative else us


time_us.__name__ = "time"


def duration_us(text: str) -> int:
    """``type=`` for ``--window-us``: microseconds by default, or with a ``ns``, ``us``/
    ``µs``, ``ms`` or ``s`` suffix as ``--t0`` takes; a whole number of µs > 0.

    Examples
    --------
    >>> duration_us("10000"), duration_us("10ms"), duration_us("0.01s"), duration_us("1e7ns")
    (10000, 10000, 10000, 10000)
    """
    v, scale = _with_unit(text, _TIME_UNITS["us"])
    v = v * scale
    if not math.isfinite(v) or v < 1 or v > MAX_TIME_US or abs(v - round(v)) > 1e-6 * max(v, 1):
        raise argparse.ArgumentTypeError(
            f"must be a whole number of microseconds >= 1, or with a unit (e.g. 10000, "
            f"10ms, 0.01s), got {text!r}")
    return int(round(v))


duration_us.__name__ = "duration"


def format_time_us(t_us: int) -> str:
    """``1500000`` -> ``'1.5 s (1500000 µs)'``."""
    return f"{seconds_text(t_us)} s ({int(t_us)} µs)"


def warn_late_start(t0: int | None, first_us: int, last_us: int) -> None:
    """Say where the first event at or after ``--t0`` comes later than the slice it starts
    lasts (``first_us`` to ``last_us``): a ``--t0`` before the recording's clock starts
    (``20ms`` on a clock at 13.58 s, meant as ``+20ms``) drew the recording's first
    events without a word (probe AZ), as a long gap would."""
    if t0 is None or first_us - t0 <= max(last_us - first_us, 1000):
        return
    import warnings

    from evmotion.errors import EvmotionWarning

    warnings.warn(EvmotionWarning(
        f"--t0 {format_time_us(t0)}: the first event from there is at "
        f"{format_time_us(first_us)}, and the slice starts there; a time after the "
        f"recording's first event is written +{seconds_text(t0)}"), stacklevel=2)


def _span(t_start: int, t_end: int) -> str:
    return (f"[{seconds_text(t_start)}, {seconds_text(t_end)}] s "
            f"([{int(t_start)}, {int(t_end)}] µs)")


# the poor-fit warning lines a per-window run prints before it only counts them
POOR_FIT_LINES = 5
# said when half a run's windows or more warned: most often they were too short
SHORT_WINDOWS_HINT = ("; windows too short for the motion? try --window-events or --window-us a "
                      "few times longer")

# events per window where a command is given no window option (flow, egomotion), for a
# sensor up to the DAVIS346's 346 x 260 px; larger sensors get as many per pixel
DEFAULT_WINDOW_EVENTS = 30_000
DEFAULT_WINDOW_PIXELS = 346 * 260


def default_window_events(path, fmt: str | None = None,
                          sensor_size: tuple[int, int] | None = None) -> int:
    """The events per window of a recording given no window option: 30,000, times the
    sensor's area over the DAVIS346's where it is larger (``sensor_size``, the user's
    ``--sensor-size``, else from the header; 30,000 when it does not say). On a 1280 x 720
    sensor 30,000 events are ~2 ms at 15 M events/s, too short for the motion to show
    (most windows had no focus, some a wrong flow)."""
    import evmotion.io as eio
    from evmotion.errors import EvmotionError

    size = sensor_size
    try:
        # (--sensor-size was not read: a 640x480 text recording got the 30,000 of a
        # DAVIS346, its .npz with the size stated 102,000, probe BJ)
        size = size or eio.describe(path, format=fmt, stream=False).get("sensor_size")
    except EvmotionError:
        size = None
    if not size:
        return DEFAULT_WINDOW_EVENTS
    scale = max(1.0, int(size[0]) * int(size[1]) / DEFAULT_WINDOW_PIXELS)
    return int(round(DEFAULT_WINDOW_EVENTS * scale, -3))


def add_sensor_size_argument(parser) -> None:
    """``--sensor-size H W``: the input's sensor when its file does not state it (text
    events otherwise get the ECD's 240x180, which puts the centre of rotation and zoom
    warps in the wrong place) or states it wrongly."""
    parser.add_argument("--sensor-size", type=int_range(1, MAX_SENSOR_SIDE, unit="px"), nargs=2, default=None,
                        metavar=("H", "W"),
                        help="the input's sensor size (height width) when its file does not "
                             "state it (text events default to the ECD's 240 x 180), or in "
                             "place of the one it states (said in a warning)")


#: The input formats whose times ``--time-unit`` may state (the others carry their unit).
TIME_UNIT_FORMATS = ("ecd", "npy", "mat", "h5generic", "mvsec")


def add_time_unit_argument(parser) -> None:
    """``--time-unit s|ms|us|ns``: the unit of a text, NumPy, MATLAB, MVSEC-layout or other
    tool's HDF5 input's times, where the file does not state it and the reader's guess is
    wrong."""
    parser.add_argument("--time-unit", choices=("s", "ms", "us", "ns"), default=None,
                        help="unit of the input's times, for text, NumPy, MATLAB, MVSEC-layout "
                             "and other tools' HDF5 inputs (default: a unit in the time "
                             "column's name; else decimal seconds or whole microseconds in "
                             "text, by dtype in NumPy and HDF5, seconds in MVSEC's layout; "
                             "integers past 1e17 as ns)")


def check_time_unit(time_unit: str | None, path, fmt: str | None) -> None:
    """Refuse ``--time-unit`` for an input whose format carries its times' unit."""
    if time_unit is None or path is None:
        return
    import evmotion.io as eio

    fmt = fmt or eio.detect_format(path)
    if fmt not in TIME_UNIT_FORMATS:
        hint = ("; another tool's HDF5 read as evmotion's: add --format h5generic"
                if fmt == "h5" else "")
        raise ParameterError(f"--time-unit {time_unit}: {path} is '{fmt}', whose times "
                             "carry their unit; it applies to text, NumPy, MATLAB, MVSEC-layout "
                             f"and other tools' HDF5 inputs{hint}")


def warn_replaced_sensor_size(args, path) -> None:
    """Warn where ``--sensor-size`` replaces a size the file at ``path`` states (a
    header's, not a reader's default or guess): it did so without a word (probe CI)."""
    import warnings

    from evmotion.errors import EvmotionError, EvmotionWarning
    from evmotion.io.summary import describe

    given = getattr(args, "sensor_size", None)
    if path is None or not given:
        return
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the reader says them when it reads
            head = describe(path, getattr(args, "format", None), stream=False)
    except (EvmotionError, OSError):
        return  # the reader says what is wrong with the file
    stated = head.get("sensor_size")
    if stated and head.get("sensor_size_from") in (None, "header") \
            and tuple(stated) != tuple(given):
        warnings.warn(EvmotionWarning(
            f"--sensor-size {given[0]} {given[1]} replaces the {stated[1]} x {stated[0]} px "
            f"(W x H) that {path} states"), stacklevel=2)


def read_kwargs(args, path: str | os.PathLike | None = None) -> dict:
    """The reader options of ``--format``, ``--sensor-size`` and ``--time-unit``, as given
    (``--time-unit`` checked against the format of the recording: ``path``, default the
    command's positional one)."""
    kw = {}
    if getattr(args, "format", None):
        kw["format"] = args.format
    if path is None:
        path = next((getattr(args, n) for n in RECORDING_ATTRS
                     if isinstance(getattr(args, n, None), (str, os.PathLike))), None)
    if getattr(args, "sensor_size", None):
        kw["sensor_size"] = tuple(args.sensor_size)
        warn_replaced_sensor_size(args, path)
    if getattr(args, "time_unit", None):
        check_time_unit(args.time_unit, path, kw.get("format"))
        kw["time_unit"] = args.time_unit
    return kw


def add_time_arguments(parser, *, max_windows: bool = True, what: str = "windows") -> None:
    """``--t0``, ``--t1`` (seconds, or with a us/ms/s suffix; absolute, on the recording's
    clock) and, with ``max_windows``, ``--max-windows N``; check them against the recording
    with :func:`check_time_range`."""
    parser.add_argument("--t0", type=time_us, default=None, metavar="TIME",
                        help="start of the part to process: seconds on the recording's own "
                             "clock (what 'evmotion info' shows), or with a unit: 1.5, "
                             "1500ms, 1500000us; +TIME: after the first event, e.g. +0.5 "
                             "(default: the first event)")
    parser.add_argument("--t1", type=time_us, default=None, metavar="TIME",
                        help="end (exclusive), same units as --t0 (default: the last event)")
    if max_windows:
        parser.add_argument("--max-windows", type=positive_int(), default=None, metavar="N",
                            help=f"process at most the first N {what} (default: all)")


# the positional arguments that name a command's recording
RECORDING_ATTRS = ("file", "rec", "input")


def resolve_relative_times(args: argparse.Namespace) -> None:
    """Make ``--t0``/``--t1`` given as ``+TIME`` (:class:`FromStart`) absolute: the time of
    the recording's first event plus TIME. Reads only the first event."""
    names = [n for n in ("t0", "t1") if isinstance(getattr(args, n, None), FromStart)]
    if not names:
        return
    path = next((getattr(args, n) for n in RECORDING_ATTRS
                 if isinstance(getattr(args, n, None), (str, os.PathLike))), None)
    flags = " and ".join(f"--{n} +{format_time_us(getattr(args, n))}" for n in names)
    if path is None:
        raise ParameterError(f"{flags}: a time after the first event needs a recording")
    from evmotion.errors import EvmotionError
    from evmotion.io import iter_events

    kw = read_kwargs(args)
    if getattr(args, "format_in", None):  # convert's name of --format
        kw["format"] = args.format_in
    try:
        first = next(iter_events(path, 1, **kw), None)
    except EvmotionError as exc:
        if not os.path.exists(path):
            raise
        raise ParameterError(f"{flags}: cannot read the first event of {path} ({exc}); "
                             "give the time on the recording's clock") from None
    if first is None or not len(first):
        raise ParameterError(f"{flags}: {path} holds no event to count from")
    for n in names:
        setattr(args, n, int(first.t[0]) + int(getattr(args, n)))


def header_event_count(path, fmt: str | None, t0: int | None = None,
                       t1: int | None = None) -> int | None:
    """The event count a recording's header states, for a progress bar's total and ETA
    (None when it states none, or when ``t0``/``t1`` select part of it)."""
    if t0 is not None or t1 is not None:
        return None
    from evmotion.errors import EvmotionError
    from evmotion.io import describe

    try:
        n = describe(path, format=fmt, stream=False).get("n_events")
        return int(n) if n is not None and int(n) > 0 else None
    except (EvmotionError, TypeError, ValueError):
        return None


def check_time_order(args) -> None:
    """``--t1`` must be after ``--t0`` (before anything is read); raises ParameterError."""
    t0, t1 = getattr(args, "t0", None), getattr(args, "t1", None)
    if t0 is not None and t1 is not None and t1 <= t0:
        raise ParameterError(f"--t1 {format_time_us(t1)} must be after --t0 "
                             f"{format_time_us(t0)}")


def check_time_range(args, t_start: int, t_end: int, file: str | os.PathLike = "") -> None:
    """Refuse ``--t0``/``--t1`` that select nothing of a recording whose events span
    ``[t_start, t_end]`` µs: one line naming the option, its value and the recording's range.
    """
    check_time_order(args)
    t0, t1 = getattr(args, "t0", None), getattr(args, "t1", None)
    span = f"the recording{' ' + os.fspath(file) if file else ''} spans {_span(t_start, t_end)}"
    if t0 is not None and t0 > t_end:
        raise ParameterError(f"--t0 {format_time_us(t0)} is after the last event: {span}")
    if t1 is not None and t1 <= t_start:
        raise ParameterError(f"--t1 {format_time_us(t1)} is at or before the first event: "
                             f"{span}")
    import warnings

    from evmotion.errors import EvmotionWarning

    if t1 is not None and t1 - t_end > 1000 * max(t_end - t_start, 1000):
        # '--t1 60000' meant as µs reads as 60000 s: the whole recording, silently
        warnings.warn(EvmotionWarning(
            f"--t1 {format_time_us(t1)} lies more than 1000 times the recording's length "
            f"past its last event ({span}): seconds meant as µs? Give a unit (60000us)"),
            stacklevel=2)
    if t0 is not None and t_start - t0 > 1000 * max(t_end - t_start, 1000):
        # '--t0 0.5' on a recording whose clock is the Unix epoch (DV's AEDAT4): before
        # every event, so the whole recording, silently
        warnings.warn(EvmotionWarning(
            f"--t0 {format_time_us(t0)} lies more than 1000 times the recording's length "
            f"before its first event ({span}): a time after the first event is "
            f"+{seconds_text(t0)}"), stacklevel=2)


def empty_selection(args, file: str | os.PathLike, t_start: int, t_end: int, what: str
                    ) -> ParameterError:
    """The error for a selection that holds no usable window (``what`` says why)."""
    t0, t1 = getattr(args, "t0", None), getattr(args, "t1", None)
    chosen = " ".join(f"{flag} {format_time_us(v)}" for flag, v in (("--t0", t0), ("--t1", t1))
                      if v is not None)
    return ParameterError(f"{os.fspath(file)}: {what}" + (f" with {chosen}" if chosen else "")
                          + f"; the recording spans {_span(t_start, t_end)}")


def select_windows(args, events, *, file: str | os.PathLike = "", min_events: int = 1,
                   what: str = "", **window_kw) -> list:
    """The windows of ``events`` a per-window command processes: made by
    :func:`evmotion.events.make_windows` (``window_kw``: ``n_events``, ``duration_us`` or
    ``edges_us`` and ``dt``) within ``--t0``/``--t1``, at most ``--max-windows`` of those
    holding ``min_events`` events or more. Refuses a range outside the recording or a
    selection with no such window in one line (naming the options and the recording's range).
    """
    from evmotion.events import make_windows

    if not len(events):
        raise ParameterError(f"{os.fspath(file)}: the recording holds no events")
    t_start, t_end = events.t_start, int(events.t[-1])
    check_time_range(args, t_start, t_end, file)
    windows = make_windows(events, t0=getattr(args, "t0", None), t1=getattr(args, "t1", None),
                           max_windows=getattr(args, "max_windows", None),
                           min_events=min_events, **window_kw)
    checked_windows(args, windows, file=file, span=(t_start, t_end), min_events=min_events,
                    what=what)
    if len(windows) == 1:
        from evmotion.cli.calib import events_held

        # (the events undistortion moved off the image count as held: it said so itself;
        # probe AP was told a window file of 30,000 events "holds 22,949")
        w = windows[0]
        say_a_short_window(args, w, file=file, held=events_held(w.count, events),
                           last_t=int(events.t[w.stop - 1]) if w.count else None,
                           **window_kw)
    return windows


def checked_windows(args, windows: list, *, file: str | os.PathLike, span: tuple[int, int],
                    min_events: int, what: str = "") -> list:
    """``windows`` (cut within ``--t0``/``--t1`` from a recording whose events there span
    ``span``, µs): refused in one line when there is none, the windows left out for
    holding fewer than ``min_events`` events said in one."""
    if not windows:
        raise empty_selection(args, file, *span,
                              what or f"no window holds {min_events} events or more")
    skipped = windows[-1].index + 1 - len(windows)
    if skipped > 0:
        # windows of time (or of given edges) that hold too few events are left out of
        # the output, whose window numbers then skip them (egomotion's CSV went from
        # window 3 to 5 without a word: probe)
        from evmotion.cli import warn_line

        warn_line(f"{os.fspath(file)}: {skipped} of the first {windows[-1].index + 1} "
                  f"windows hold fewer than {min_events} event(s) and are left out (their "
                  "numbers are skipped in the output)")
    return windows


def say_a_short_window(args, w, *, file: str | os.PathLike, held: int, last_t: int | None,
                       n_events: int | None = None, duration_us: int | None = None,
                       **_) -> None:
    """One line when the only window ``w`` holds fewer events (``held``, those
    undistortion left out included) than ``--window-events`` asks (not a default's: a
    one-window command on a short file says nothing, probe W), or its events (the last at
    ``last_t``) span less time than ``--window-us`` (``--window-events 1e9`` into an
    ``.h5`` ran as one window of 30,000 events without a word, probe BK)."""
    from evmotion.cli import warn_line

    where = (" from --t0 to --t1" if getattr(args, "t0", None) is not None
             or getattr(args, "t1", None) is not None else "")
    if n_events is not None:
        given = getattr(args, "window_events_given", getattr(args, "window_events", None))
        if held < n_events and given:
            warn_line(f"{os.fspath(file)} holds {held:,} events{where}, fewer than "
                      f"--window-events {n_events}: one window of them all")
    elif duration_us is not None and last_t is not None:
        # (10 % slack: a 10 ms recording's events span a little less than 10 ms)
        span = last_t - w.t0
        if span < 0.9 * duration_us:
            warn_line(f"{os.fspath(file)}'s events{where} span {span * 1e-6:.6g} s, less "
                      f"than --window-us {duration_us * 1e-6:.6g} s: one window of them all")


__all__ += ["add_time_arguments", "check_time_order", "check_time_range", "empty_selection",
            "format_time_us", "select_windows", "time_us"]
# ---------------------------------------------------------------- Dask cluster
SCHEDULER_TIMEOUT_S = 5.0
_SCHEDULER_ADDRESS = re.compile(
    r"(?:(?:tcp|tls|ucx|ws|wss)://)?(?:\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})"
    r"|inproc://\S+")


def scheduler_address(text: str) -> str:
    """``type=`` for a Dask scheduler address: ``[tcp|tls|ucx|ws|wss://]host:port`` (what
    ``dask scheduler`` prints) or an in-process ``inproc://`` one; also checks that the
    ``dask`` extra is installed.

    Examples
    --------
    >>> scheduler_address("tcp://10.0.0.5:8786")
    'tcp://10.0.0.5:8786'
    """
    import importlib.util

    m = _SCHEDULER_ADDRESS.fullmatch(text.strip())
    port = m.group(1) if m else None
    if m is None or (port is not None and not 1 <= int(port) <= 65535):
        raise argparse.ArgumentTypeError(
            f"must be a Dask scheduler address such as tcp://host:8786, got {text!r}")
    if importlib.util.find_spec("distributed") is None:
        raise argparse.ArgumentTypeError(
            f"{text}: running on a Dask cluster needs the package 'distributed', which is "
            "not installed: pip install 'evmotion[dask]'")
    return text.strip()


def add_scheduler_argument(p, what: str = "windows") -> None:
    """Add ``--scheduler ADDRESS`` (attribute ``scheduler``, default None) to a parser or
    argument group: run the ``what`` on a Dask ``distributed`` cluster. The client
    ships each task's events to the workers (see docs/cluster.rst)."""
    p.add_argument("--scheduler", type=scheduler_address, default=None, metavar="ADDRESS",
                   help=f"run the {what} on the Dask cluster whose scheduler is at ADDRESS "
                        "(tcp://host:8786, from 'dask scheduler'; needs the 'dask' extra); "
                        "this process reads the recording and sends each task its events, "
                        "so the workers need no access to the file")


@contextlib.contextmanager
def scheduler_client(address: str | None, timeout_s: float | None = None):
    """A ``distributed.Client`` connected to ``address`` for the ``with`` block (None
    without an address); raises ParameterError, one line naming the address, when no
    scheduler with workers answers within ``timeout_s`` seconds (default
    ``SCHEDULER_TIMEOUT_S``)."""
    if address is None:
        yield None
        return
    import logging

    from evmotion.parallel import connect_scheduler

    client = connect_scheduler(address, SCHEDULER_TIMEOUT_S if timeout_s is None else timeout_s)
    # a scheduler lost mid-run is reported in one line by the command; distributed's own
    # log of it (tens of traceback lines) would come first
    quiet = [logging.getLogger(name) for name in list(logging.root.manager.loggerDict)
             if name.split(".")[0] == "distributed"]
    was = [lg.disabled for lg in quiet]
    for lg in quiet:
        lg.disabled = True
    try:
        _warn_slow_workers(client, address)
        yield client
    finally:
        try:
            client.close()
        finally:
            for lg, disabled in zip(quiet, was, strict=True):
                lg.disabled = disabled


def cluster_threads(client) -> int:
    """Worker threads of a connected Dask cluster (at least 1)."""
    return max(1, sum(client.nthreads().values()))


def _warn_slow_workers(client, address: str) -> None:
    """One warning line when the workers run with ``MALLOC_TRIM_THRESHOLD_`` set, as Dask's
    nanny sets it by default: glibc then stops adapting its mmap threshold, every large
    temporary array is mapped and zeroed afresh, and the estimates ran 3-4x slower
    (flow multicm, benchmarks/results/cluster.md)."""
    from evmotion.cli import warn_line

    values = sorted({v for v in client.run(os.getenv, "MALLOC_TRIM_THRESHOLD_").values()
                     if v is not None})
    if values:
        warn_line(f"the Dask workers at {address} run with MALLOC_TRIM_THRESHOLD_="
                  f"{','.join(values)} (Dask's default), which made the estimates 3-4x "
                  "slower; start them with distributed.nanny.pre-spawn-environ."
                  "MALLOC_TRIM_THRESHOLD_ set to null (see docs/cluster.rst)")


def check_flow_out(out: str | os.PathLike, n_windows: int | None = None) -> str:
    """``--out`` names a flow output (:func:`evmotion.io.flowout.check_flow_output`: no bare
    ``.npy``, a pattern for several ``.flo``/``.png`` windows); returns its container. Every
    command writing flow windows checks its ``--out`` with this."""
    from evmotion.io.flowout import check_flow_output

    try:
        return check_flow_output(out, n_windows)
    except ParameterError as exc:
        raise ParameterError(f"--out {exc}") from None


__all__ += ["check_flow_out"]


# the attributes naming what a command reads, and what it writes
INPUT_ATTRS = ("file", "rec", "flow", "input", "gt", "events", "frames", "checkpoint",
               "calib")
OUTPUT_ATTRS = ("out", "output", "out_option", "video", "csv", "png_dir")


def _output_flag(name: str) -> str:
    """How the command line names the output attribute ``name`` (convert's ``--out`` is
    kept as ``out_option``: it was neither locked nor checked against the inputs, probe
    BR)."""
    return {"output": "OUTPUT", "out_option": "--out"}.get(name,
                                                             "--" + name.replace("_", "-"))


def note_parallel_interrupt(args: argparse.Namespace, unit: str) -> None:
    """For a resumable run (``--out`` .h5) on several workers or a cluster: what an
    interruption keeps, said as it is (``--resume`` needs one worker; the ``unit``s are
    written a chunk at a time)."""
    from evmotion.utils import set_interrupt_note

    if str(getattr(args, "out", "")).lower().endswith((".h5", ".hdf5")) and (
            (getattr(args, "workers", None) or 1) > 1 or getattr(args, "scheduler", None)):
        set_interrupt_note(
            f"continue it with --resume and --workers 1 (no --scheduler): the {unit}s after "
            "those kept then run as one worker runs them",
            f"with several workers the {unit}s are written a chunk at a time, as each chunk "
            "ends, and none had ended: nothing is kept")


@contextlib.contextmanager
def outputs_locked(args: argparse.Namespace):
    """Hold a lock on each of the command's outputs while it runs: a second run writing
    the same output is refused in one line (two runs into one ``--out`` left one's result
    under the other's name, the first reporting success). The locks are advisory
    (``fcntl.flock``, released by the system when a process dies, so a killed run leaves
    none held) on files in the temporary folder, named after the output's real path.

    Examples
    --------
    >>> ns = argparse.Namespace(out="flow.h5")
    >>> with outputs_locked(ns):
    ...     with outputs_locked(ns):
    ...         pass
    Traceback (most recent call last):
    ...
    evmotion.errors.ParameterError: --out flow.h5 is being written by another evmotion run (process ...): wait for it to end, or choose another --out
    """
    try:
        import fcntl
    except ImportError:  # no flock (Windows): no lock
        yield
        return
    import hashlib

    held, seen = [], set()
    try:
        for name in OUTPUT_ATTRS:
            v = getattr(args, name, None)
            if not isinstance(v, (str, os.PathLike)) or not os.fspath(v):
                continue
            real = os.path.realpath(v)
            if real in seen:
                continue
            seen.add(real)
            folder = _lock_folder()
            if folder is None:
                continue  # advisory: no private folder for it, no lock (never a failure)
            lock = folder / (hashlib.sha1(real.encode()).hexdigest()[:20] + ".lock")
            flag = _output_flag(name)
            fd = _take_lock(fcntl, lock, f"{flag} {v}", flag)
            if fd is not None:
                held.append((fd, lock))
        yield
    finally:
        for fd, lock in held:
            # removed while still held, then released: each output path had left its file
            # behind, 38,500 of them in a shared temporary folder (probe BP)
            with contextlib.suppress(OSError):
                os.unlink(lock)
            os.close(fd)


def _take_lock(fcntl, lock: Path, what: str, flag: str) -> int | None:
    """The descriptor of ``lock``, created and locked (``flock``, not waiting), or None
    where it cannot be opened; a ParameterError naming ``what`` when another run holds it.
    A file its last holder removed as this run opened it is opened again."""
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o600)
        except OSError:
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            other = os.read(fd, 32).decode(errors="replace").strip() or "?"
            os.close(fd)
            raise ParameterError(f"{what} is being written by another evmotion run "
                                 f"(process {other}): wait for it to end, or choose "
                                 f"another {flag}") from None
        try:
            current = os.stat(lock).st_ino == os.fstat(fd).st_ino
        except OSError:
            current = False
        if current:
            os.ftruncate(fd, 0)
            os.write(fd, str(os.getpid()).encode())
            return fd
        os.close(fd)  # a removed file's lock guards nothing: take the new one


def _lock_folder() -> Path | None:
    """This user's folder of output locks in the temporary folder (``evmotion-locks-UID``,
    mode 700; one shared by all users was created by the first and refused every other's
    locks: 'Permission denied', exit 1), or None where it cannot be had."""
    from evmotion.jitcache import private_dir

    folder = Path(tempfile.gettempdir()) / f"evmotion-locks-{os.getuid()}"
    return folder if private_dir(folder) else None


def check_outputs_spare_inputs(args: argparse.Namespace) -> None:
    """Refuse an output that is one of the command's inputs (``flow rec.h5 --out rec.h5``
    replaced the recording with its flow).

    Examples
    --------
    >>> ns = argparse.Namespace(file="rec.h5", out="./rec.h5")
    >>> check_outputs_spare_inputs(ns)
    Traceback (most recent call last):
    ...
    evmotion.errors.ParameterError: --out ./rec.h5 is the command's input rec.h5: it would be overwritten; choose another --out
    """
    from evmotion.errors import ParameterError

    positional = ("file", "rec", "flow", "input")
    inputs = {}
    for name in INPUT_ATTRS:
        v = getattr(args, name, None)
        if isinstance(v, (str, os.PathLike)):
            label = "" if name in positional else "--" + name + " "
            inputs[os.path.realpath(v)] = f"{label}{v}"
    folders = [p for p in inputs if os.path.isdir(p)]
    for name in OUTPUT_ATTRS:
        v = getattr(args, name, None)
        if not isinstance(v, (str, os.PathLike)):
            continue
        flag = _output_flag(name)
        real = os.path.realpath(v)
        if real in inputs:
            raise ParameterError(f"{flag} {v} is the command's input "
                                 f"{inputs[real]}: it would be overwritten; "
                                 f"choose another {flag}")
        for folder in folders:
            members = _members(folder) if real.startswith(folder + os.sep) else []
            if real in members:
                # a frame, the events or the ground truth of an input folder (probe BP)
                raise ParameterError(f"{flag} {v} is part of the command's input "
                                     f"{inputs[folder]}: it would be overwritten; "
                                     f"choose another {flag}")
            held = [m for m in members if os.path.dirname(m) == real]
            if held and os.path.isdir(real):
                # an output folder (pictures, results) holding them: its files written
                # over them, its stale pictures removed (bos --png-dir scene/images
                # replaced frames and deleted one; probe BR)
                raise ParameterError(f"{flag} {v} holds files of the command's input "
                                     f"{inputs[folder]} ({os.path.basename(held[0])}"
                                     f"{' ...' if len(held) > 1 else ''}): what is written "
                                     f"there could overwrite or remove them; choose another "
                                     f"{flag}")


def _members(folder: str) -> list[str]:
    """The real paths of the files the recording or frames folder ``folder`` is made of
    (:func:`evmotion.io.frames.folder_members`)."""
    from evmotion.io.frames import folder_members

    return [os.path.realpath(p) for p in folder_members(folder)]


def remove_stale_results(folder, names: tuple[str, ...]) -> None:
    """Delete the result files ``names`` an earlier run left in ``folder`` as a new run
    (not a resume) starts in it: interrupted, it left them, complete-looking but another
    run's, beside its own pictures and ``.part``."""
    from pathlib import Path

    for name in names:
        p = Path(folder) / name
        if p.is_file():
            p.unlink()


def remove_stale_pictures(folder, prefixes: tuple[str, ...]) -> int:
    """Delete the per-window pictures (``PREFIX00012.png``) an earlier run left in
    ``folder``, so that a run with fewer windows does not leave the old ones looking like
    its own; other files are kept. Returns how many were removed.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> for name in ("window_00003.png", "notes.png"):
    ...     _ = (d / name).write_bytes(b"")
    >>> remove_stale_pictures(d, ("window_",)), sorted(p.name for p in d.iterdir())
    (1, ['notes.png'])
    """
    from pathlib import Path

    folder = Path(folder)
    if not folder.is_dir():
        return 0
    pattern = re.compile(r"(?:" + "|".join(map(re.escape, prefixes)) + r")\d{5}\.png")
    stale = [p for p in folder.iterdir() if pattern.fullmatch(p.name) and p.is_file()]
    for p in stale:
        p.unlink()
    return len(stale)

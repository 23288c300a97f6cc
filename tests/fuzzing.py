"""Fuzzing the readers: seed files per format, mutations, and the check of one case.

Used by ``tests/test_fuzz_readers.py`` (hypothesis draws the mutations, a few thousand
cases) and ``benchmarks/bench_fuzz.py`` (numpy-seeded, >= 100,000 cases on demand).

A *case* is a seed file of one format with 1-3 mutations (bytes flipped, inserted,
deleted, the file truncated, a numeric header field set to a huge / negative / NaN /
non-numeric value, a binary integer field overwritten with an extreme value). It is run
through what ``evmotion info`` and the API do with a file: :func:`detect_format`,
``describe`` (header), ``read_events`` and ``iter_events``. The outcome is ``ok`` (the
file still reads, streaming equals reading whole, the events keep the container's
invariants) or ``error`` (an EvmotionError on one line naming the file); anything else
is a finding: ``leak`` (another exception), ``unnamed`` (an EvmotionError that does not
name the file or spans several lines), ``mismatch`` or ``invalid`` (bad events read
"fine"), ``hang`` (over the time limit), ``crash`` (the process died: only the
benchmark, which runs cases in worker processes, can see it).
"""

from __future__ import annotations

import itertools
import re
import signal
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evmotion.errors import EvmotionError
from evmotion.events import EventArray
from evmotion.io.guard import MAX_SENSOR_SIDE

FINDINGS = ("leak", "unnamed", "mismatch", "invalid", "hang", "crash")


@dataclass(frozen=True)
class Seed:
    """A valid file of format ``fmt`` at ``path``; mutations aim at its first
    ``header_len`` bytes half of the time (where sizes and offsets live)."""

    name: str
    fmt: str
    path: Path
    header_len: int


@dataclass
class Outcome:
    kind: str                       # "ok", "error" or one of FINDINGS
    exc_type: str = ""              # type of the exception (its cause for a FormatError)
    message: str = ""
    step: str = ""                  # detect / describe / read / iter
    notes: list = field(default_factory=list)


# ----------------------------------------------------------------------------- seeds
def _sim_events(n: int = 3000, size=(180, 240), seed: int = 7) -> EventArray:
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 200_000, n)) + 1_700_000_000
    return EventArray(x=rng.integers(0, size[1], n), y=rng.integers(0, size[0], n), t=t,
                      p=rng.integers(0, 2, n), sensor_size=size)


def _cut_text_header(src: Path, marker: bytes, dst: Path, payload: int, word: int,
                     extra: int = 0) -> int:
    """Copy the ``marker`` text header of ``src`` (plus ``extra`` bytes after it) and
    ``payload`` bytes (a multiple of ``word``) of what follows into ``dst``; returns the
    header length."""
    data = src.read_bytes()
    pos = 0
    while data.startswith(marker, pos):
        nl = data.index(b"\n", pos)
        pos = nl + 1
        if data[pos - 7:pos].rstrip(b"\r\n") == b"% end":
            break
    hdr = pos + extra
    payload -= payload % word
    dst.write_bytes(data[:hdr + payload])
    return hdr


def _cut_aedat4(src: Path, dst: Path, budget: int) -> int:
    data = src.read_bytes()
    hsize = struct.unpack_from("<i", data, 14)[0]
    pos = 18 + hsize
    header_end = pos
    while pos + 8 <= len(data) and pos < header_end + budget:
        size = struct.unpack_from("<i", data, pos + 4)[0]
        pos += 8 + size
    dst.write_bytes(data[:min(pos, len(data))])
    return header_end


def make_seeds(workdir: Path, shared: Path | None) -> tuple[list[Seed], dict[str, str]]:
    """Seeds in ``workdir``: cuts of the real format samples in ``shared`` (when present)
    and files that evmotion's own writers produce. Returns the seeds and, per format
    without a seed, the reason."""
    from evmotion.io import aedat3, dsec, evt21, h5, mvsec, npy, rosbag

    workdir.mkdir(parents=True, exist_ok=True)
    seeds: list[Seed] = []
    missing: dict[str, str] = {}
    fmts = shared / "formats" if shared is not None else None

    def real(name: str, fmt: str, make) -> None:
        src_hint = f"{shared}" if shared is not None else "(shared data not given)"
        try:
            hdr, path = make()
        except FileNotFoundError as exc:
            missing[name] = f"sample not found ({exc.filename or src_hint})"
            return
        seeds.append(Seed(name, fmt, path, hdr))

    def cut(src_name, marker, out, payload, word, extra=0):
        def make():
            if fmts is None:
                raise FileNotFoundError(None, None, "shared data")
            src = fmts / src_name
            if not src.is_file():
                raise FileNotFoundError(None, None, str(src))
            dst = workdir / out
            return _cut_text_header(src, marker, dst, payload, word, extra), dst
        return make

    real("evt3", "evt3", cut("evt3.raw", b"%", "evt3.raw", 48_000, 2))
    real("evt2", "evt2", cut("evt2.raw", b"%", "evt2.raw", 48_000, 4))
    real("dat", "dat", cut("gen4.dat", b"%", "gen4.dat", 48_000, 8, extra=2))
    real("aedat2", "aedat2", cut("davis240_translboxes_aedat2.aedat", b"#", "jaer.aedat",
                                 48_000, 8))

    def aedat4():
        src = fmts / "davis346_short.aedat4" if fmts is not None else Path("-")
        if not src.is_file():
            raise FileNotFoundError(None, None, str(src))
        dst = workdir / "dv.aedat4"
        return _cut_aedat4(src, dst, 60_000), dst

    real("aedat4", "aedat4", aedat4)

    def ecd_text():
        src = shared / "ecd_rotation_windows" / "boxes_rotation" / "events.txt" \
            if shared is not None else Path("-")
        if not src.is_file():
            raise FileNotFoundError(None, None, str(src))
        folder = workdir / "ecd"
        folder.mkdir(exist_ok=True)
        lines = src.read_bytes().split(b"\n")[:1500]
        dst = folder / "events.txt"
        dst.write_bytes(b"\n".join(lines) + b"\n")
        return 64, dst

    real("ecd", "ecd", ecd_text)

    def mat_real():
        src = shared / "ecd_dynamic_undistorted_excerpt" / "event.mat" \
            if shared is not None else Path("-")
        if not src.is_file():
            raise FileNotFoundError(None, None, str(src))
        import scipy.io

        m = scipy.io.loadmat(src)
        dst = workdir / "event.mat"
        # the real excerpt's first 2,000 rows, written compressed as MATLAB 5 like the
        # original ECD .mat files (the zlib streams are what corrupt files break)
        scipy.io.savemat(dst, {"seq": m["seq"][:2000]}, do_compression=True)
        return 128, dst

    real("mat", "mat", mat_real)

    ev = _sim_events()
    # writer-made files: no shared data needed
    h5.write(workdir / "ev.h5", ev, provenance={"tool": "fuzz seed"})
    seeds.append(Seed("h5", "h5", workdir / "ev.h5", 4096))
    _vlen_copy(workdir / "ev.h5", workdir / "ev_vlen.h5")
    # header_len covers the global heap at 2048 that holds the text attributes
    seeds.append(Seed("h5_vlen", "h5", workdir / "ev_vlen.h5", 6144))
    (workdir / "dsec").mkdir(exist_ok=True)
    try:
        dsec.write(workdir / "dsec" / "events.h5", ev)
    except EvmotionError:  # no hdf5plugin: DSEC's Blosc/zstd cannot be written
        dsec.write(workdir / "dsec" / "events.h5", ev, compression="none")
    seeds.append(Seed("dsec", "dsec", workdir / "dsec" / "events.h5", 4096))
    mvsec.write(workdir / "mvsec_data.hdf5", ev)
    seeds.append(Seed("mvsec", "mvsec", workdir / "mvsec_data.hdf5", 4096))
    npy.write(workdir / "ev.npy", ev)
    seeds.append(Seed("npy", "npy", workdir / "ev.npy", 128))
    evt21.write(workdir / "evt21.raw", ev[:4000])
    seeds.append(Seed("evt21", "evt21", workdir / "evt21.raw", 160))
    aedat3.write(workdir / "cAER.aedat", ev[:2500])
    # the text header and the first packet's header
    seeds.append(Seed("aedat3", "aedat3", workdir / "cAER.aedat", 256))
    npy.write(workdir / "ev.npz", ev)
    seeds.append(Seed("npz", "npy", workdir / "ev.npz", 128))
    try:
        rosbag.write(workdir / "ev.bag", ev, message_us=20_000)
        seeds.append(Seed("rosbag", "rosbag", workdir / "ev.bag", 4096))
    except EvmotionError as exc:  # rosbags not installed
        missing["rosbag"] = str(exc)
    if "mat" in missing:
        import scipy.io

        scipy.io.savemat(workdir / "sim.mat", {"events": {"e_data": np.stack(
            [ev.t * 1e-6 - 1700, ev.x, ev.y, ev.p]).astype(np.float64)}},
            do_compression=True)
        seeds.append(Seed("mat", "mat", workdir / "sim.mat", 128))
        missing.pop("mat")
    return seeds, missing


def _vlen_copy(src: Path, dst: Path) -> None:
    """``src`` (an evmotion .h5) with its text attributes variable-length, as evmotion
    wrote them before 2026-11: their bytes sit in a global heap, which libhdf5 can loop on
    when it is corrupt. The attributes are written first, so the heap comes early."""
    import h5py

    with h5py.File(dst, "w") as out, h5py.File(src, "r") as f:
        for k, v in f.attrs.items():
            out.attrs[k] = v.decode() if isinstance(v, bytes) else v
        f.copy("events", out)


# ------------------------------------------------------------------------- mutations
# What a numeric header field is set to: huge, negative, zero, NaN, inf, non-numeric,
# past int64.
FIELD_VALUES = (b"99999999", b"-1", b"0", b"nan", b"inf", b"1e400", b"x",
                b"18446744073709551617", b"-9223372036854775809", b"2147483648", b"")
# Extreme binary integers written over 2, 4 or 8 bytes.
INT_VALUES = (0, 1, 0x7F, 0xFF, 0x7FFF, 0xFFFF, 0x7FFFFFFF, 0xFFFFFFFF, 0x80000000,
              0x7FFFFFFFFFFFFFFF, 0xFFFFFFFFFFFFFFFF, 1 << 40)
_NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")
OPS = ("flip", "insert", "delete", "truncate", "field", "int")


def mutate(data: bytes, header_len: int, ops: list[tuple]) -> bytes:
    """Apply ``ops``, each ``(op, a, b, c)`` of small non-negative ints that pick where
    and what (so hypothesis and numpy draws describe cases alike), to ``data``."""
    buf = bytearray(data)
    for op, a, b, c in ops:
        n = len(buf)
        if n == 0:
            break
        # half of the positions fall in the header, where the sizes and offsets are
        span = min(n, header_len) if a % 2 == 0 else n
        pos = (a // 2) % span
        if op == "flip":
            buf[pos] ^= (b % 255) + 1
        elif op == "insert":
            k = b % 16 + 1
            buf[pos:pos] = bytes((c + 37 * i) % 256 for i in range(k))
        elif op == "delete":
            del buf[pos:pos + b % 64 + 1]
        elif op == "truncate":
            del buf[(a * 7919 + b) % n:]
        elif op == "field":
            nums = list(_NUMBER.finditer(bytes(buf[:min(n, max(header_len, 4096))])))
            if nums:
                m = nums[b % len(nums)]
                buf[m.start():m.end()] = FIELD_VALUES[c % len(FIELD_VALUES)]
            else:
                buf[pos] ^= 0xFF
        elif op == "int":
            width = (2, 4, 8)[b % 3]
            val = INT_VALUES[c % len(INT_VALUES)] & ((1 << (8 * width)) - 1)
            pos = min(pos - pos % width, max(n - width, 0))
            buf[pos:pos + width] = val.to_bytes(width, "little")[:n - pos]
    return bytes(buf)


def random_ops(rng: np.random.Generator, max_ops: int = 3) -> list[tuple]:
    k = int(rng.integers(1, max_ops + 1))
    return [(OPS[int(rng.integers(len(OPS)))], int(rng.integers(1 << 24)),
             int(rng.integers(1 << 16)), int(rng.integers(1 << 16))) for _ in range(k)]


_CASE_NUMBER = itertools.count()


def write_case(seed: Seed, ops: list[tuple], dst_dir: Path) -> Path:
    """The mutated copy of ``seed``, a new file in ``dst_dir`` (named after the seed's,
    so suffixes stay) that replaces the previous case's: HDF5 recognises a file it still
    holds open by its inode, so cases must not rewrite one file in place."""
    dst_dir.mkdir(parents=True, exist_ok=True)
    for old in dst_dir.glob(f"case*_{seed.path.name}"):
        old.unlink()
    dst = dst_dir / f"case{next(_CASE_NUMBER)}_{seed.path.name}"
    dst.write_bytes(mutate(seed.path.read_bytes(), seed.header_len, ops))
    return dst


# ------------------------------------------------------------------------ one case
class _Timeout(BaseException):
    """Raised by the alarm: a BaseException so that no reader's handler swallows it."""


def _alarm(signum, frame):
    raise _Timeout


def type_name(exc: BaseException) -> str:
    """``KeyError``, ``zlib.error``, ``zipfile.BadZipFile``: builtins bare, others with
    their top-level module."""
    cls = type(exc)
    mod = cls.__module__.split(".")[0]
    return cls.__name__ if mod in ("builtins", "evmotion") else f"{mod}.{cls.__name__}"


def _classify(exc: BaseException, path: Path, step: str) -> Outcome:
    cause = exc.__cause__ if exc.__cause__ is not None else exc
    name = type_name(cause)
    msg = str(exc)
    if isinstance(exc, EvmotionError):
        if str(path) not in msg or "\n" in msg or "\r" in msg:
            return Outcome("unnamed", name, msg[:500], step)
        return Outcome("error", name, msg[:500], step)
    return Outcome("leak", name, f"{type_name(exc)}: {msg}"[:500], step)


def _check_events(ev: EventArray) -> str | None:
    h, w = ev.sensor_size
    if not (0 < h <= MAX_SENSOR_SIDE and 0 < w <= MAX_SENSOR_SIDE):
        return f"sensor_size {ev.sensor_size} outside 1..{MAX_SENSOR_SIDE}"
    if len(ev):
        if ev.p.dtype != np.uint8 or ev.p.max() > 1:
            return f"polarity outside 0/1 (max {int(ev.p.max())})"
        if ev.x.max() >= w or ev.y.max() >= h or np.any(np.diff(ev.t) < 0):
            return "events off the sensor or unsorted"
    return None


def run_case(path: Path, fmt: str, *, chunk_events: int = 997, timeout_s: float = 20.0
             ) -> Outcome:
    """What ``evmotion info`` and the API do with ``path`` (of intended format ``fmt``),
    classified; ``hang`` past ``timeout_s`` seconds (SIGALRM, main thread only)."""
    import evmotion.io as eio

    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout_s)
    step = "detect"
    notes = []
    try:
        for step, call in (("detect", lambda: eio.detect_format(path)),
                           ("describe", lambda: eio.describe(path, format=fmt, stream=False))):
            try:
                call()
            except Exception as exc:
                out = _classify(exc, path, step)
                if out.kind != "error":
                    return out
        step = "read"
        try:
            whole = eio.read_events(path, format=fmt)
        except Exception as exc:
            whole = None
            read_out = _classify(exc, path, step)
            if read_out.kind != "error":
                return read_out
        step = "iter"
        try:
            chunks = list(eio.iter_events(path, chunk_events, format=fmt))
        except Exception as exc:
            out = _classify(exc, path, step)
            if out.kind != "error" or whole is not None:
                if out.kind == "error":
                    return Outcome("mismatch", out.exc_type,
                                   f"reads whole but streaming fails: {out.message}", step)
                return out
            return read_out
        if whole is None:
            # streaming checks chunk by chunk (e.g. order across chunk ends is not seen)
            notes.append("streams although reading whole fails")
            read_out.notes = notes
            return read_out
        bad = _check_events(whole)
        if bad:
            return Outcome("invalid", "", bad, "read")
        got = {k: np.concatenate([getattr(c, k) for c in chunks]) if chunks else
               np.empty(0, getattr(whole, k).dtype) for k in "xytp"}
        for k in "xytp":
            if not np.array_equal(got[k], getattr(whole, k)):
                return Outcome("mismatch", "", f"streamed field {k} differs from read", "iter")
        return Outcome("ok", notes=notes)
    except _Timeout:
        return Outcome("hang", "", f"over {timeout_s} s", step)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)

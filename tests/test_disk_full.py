"""A device that fills up during a run: the streamed HDF5 writers stop before the write that
would not fit (libhdf5 failing half-way through a write printed tracebacks, left damaged
files and crashed the process at exit), the command says so in one line, and a flow run
resumes to the output an uninterrupted run writes once there is room."""

from __future__ import annotations

import shutil
from collections import namedtuple

import numpy as np
import pytest

from evmotion.cli import main, no_room
from evmotion.errors import EvmotionError
from evmotion.io.flowfiles import read_flow_h5
from evmotion.utils import NoRoomError, ensure_room

Usage = namedtuple("Usage", "total used free")


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    from evmotion.io import write_events
    from evmotion.sim import simulate

    path = tmp_path_factory.mktemp("full") / "sim.h5"
    write_events(path, simulate("translation", duration_s=0.06, sensor_size=(60, 80),
                                show_progress=False).events)
    return path


def _room_for(monkeypatch, n_writes: int) -> None:
    """A device with room for ``n_writes`` more streamed writes."""
    real, calls = shutil.disk_usage, [0]

    def usage(path):
        calls[0] += 1
        u = real(path)
        return Usage(u.total, u.used, u.free if calls[0] <= n_writes else 1024)

    monkeypatch.setattr(shutil, "disk_usage", usage)


def test_ensure_room(monkeypatch):
    ensure_room(".", 0)
    with pytest.raises(NoRoomError, match="no space left on the device"):
        ensure_room(".", 1 << 62)
    # a need just over the free space reads as more than it (it read "needs up to 1.0
    # MiB, 1.0 MiB are free", probe BB)
    import collections
    import shutil

    usage = collections.namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(1 << 30, 0, (1 << 20) + 1000))
    with pytest.raises(NoRoomError, match=r"needs up to 1\.005 MiB, 1\.001 MiB are free"):
        ensure_room(".", 5000)
    assert no_room(NoRoomError(28, "x")) == 28
    assert no_room(RuntimeError("file write failed: ... errno = 28, error message = ...")) == 28
    # a file-size limit (ulimit -f, FAT32's 4 GiB) and a quota are no room either
    assert no_room(RuntimeError("file write failed: ... errno = 27, error message = ...")) == 27
    assert no_room(OSError(122, "Disk quota exceeded")) == 122
    assert no_room(RuntimeError("something else")) is None
    assert no_room(RuntimeError("... errno = 2, ...")) is None


def test_flow_stops_between_windows_and_resumes(rec, tmp_path, capsys, monkeypatch):
    argv = ["flow", str(rec), "--window-events", "3000", "--max-windows", "5", "--scales", "2"]
    ref = tmp_path / "ref.h5"
    assert main([*argv, "--out", str(ref)]) == 0
    capsys.readouterr()
    out = tmp_path / "f.h5"
    _room_for(monkeypatch, 2)
    assert main([*argv, "--out", str(out)]) == 1
    err = capsys.readouterr().err
    part = tmp_path / "f.h5.part"
    assert err.count("\n") == 1 and "no space left on the device" in err
    assert f"kept in {part}" in err and "--resume" in err and "Traceback" not in err
    assert part.exists() and not out.exists()
    monkeypatch.undo()
    assert main([*argv, "--out", str(out), "--resume"]) == 0
    np.testing.assert_array_equal(read_flow_h5(out).flow, read_flow_h5(ref).flow)


@pytest.mark.parametrize("command", ["convert", "simulate"])
def test_event_writers_leave_nothing(rec, tmp_path, capsys, monkeypatch, command):
    out = tmp_path / "o.h5"
    argv = {"convert": ["convert", str(rec), str(out), "--chunk-events", "2000"],
            "simulate": ["simulate", "rotation", "--size", "60x80", "--duration", "0.05",
                         "--out", str(out)]}[command]
    _room_for(monkeypatch, 1 if command == "convert" else 0)
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no space left on the device" in err
    assert not list(tmp_path.iterdir())


def test_the_library_raises_an_oserror(rec, tmp_path, monkeypatch):
    from evmotion.io import read_events, write_events

    ev = read_events(rec)
    _room_for(monkeypatch, 0)
    with pytest.raises(OSError) as info:
        write_events(tmp_path / "x.h5", ev)
    assert isinstance(info.value, NoRoomError) and not isinstance(info.value, EvmotionError)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("fmt", ["h5", "ecd", "evt3"])
def test_a_device_or_pipe_as_output_is_refused_not_replaced(rec, tmp_path, capsys, fmt):
    # the writers' rename onto the target turned /dev/null and /dev/full into regular files
    import os
    import stat

    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    assert main(["convert", str(rec), str(fifo), "--format-out", fmt]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a regular file (a device or pipe)" in err
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe"]


@pytest.mark.parametrize("resume", [False, True])
def test_a_part_killed_before_its_first_window_does_not_block(rec, tmp_path, capsys, resume):
    # kill -9 right after OUT.part appeared left 96 bytes HDF5 cannot open: --resume blamed
    # a file lock, a plain run told to add --resume
    out = tmp_path / "f.h5"
    (tmp_path / "f.h5.part").write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(88))
    argv = ["flow", str(rec), "--window-events", "3000", "--max-windows", "2", "--scales", "2",
            "--out", str(out)]
    assert main(argv + (["--resume"] if resume else [])) == 0
    capsys.readouterr()
    assert len(read_flow_h5(out).t0) == 2 and not (tmp_path / "f.h5.part").exists()


def test_a_write_error_without_a_file_name_names_the_output(rec, tmp_path, capsys,
                                                           monkeypatch):
    # convert to text on a full device said only '[Errno 28] No space left on device'
    import errno

    from evmotion.io import ecd

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(ecd, "format_text", full)
    out = tmp_path / "c.txt"
    assert main(["convert", str(rec), str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{out}: [Errno 28]" in err


@pytest.mark.parametrize("command", ["flow", "convert"])
def test_a_file_size_limit_stops_before_the_write(rec, tmp_path, command):
    """Past ``ulimit -f`` (EFBIG) h5py's failed flush printed tracebacks and the process
    crashed at exit (rc 139, probe AJ). The writers now check the limit before each write:
    one line, rc 1, and flow keeps its windows for --resume."""
    import subprocess
    import sys

    out = tmp_path / "f.h5"
    argv = {"flow": ["flow", str(rec), "--window-events", "1000", "--scales", "2"],
            "convert": ["convert", str(rec), "--chunk-events", "1000"]}[command]
    code = ("import resource, sys; resource.setrlimit(resource.RLIMIT_FSIZE, "
            "(1 << 19, 1 << 19)); from evmotion.cli import main; sys.exit(main())")
    if command == "convert":
        argv = [*argv[:2], str(out), *argv[2:]]
    else:
        argv = [*argv, "--out", str(out)]
    run = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True,
                         timeout=600)
    assert run.returncode == 1, run.stderr
    # (the windows' own warnings aside: 1,000-event windows move little)
    err = "".join(line for line in run.stderr.splitlines(True)
                  if not line.startswith("evmotion: warning:"))
    assert err.count("\n") == 1 and "file-size limit (ulimit -f)" in err, run.stderr
    assert not out.exists()


def test_resume_names_a_truncated_part(rec, tmp_path, capsys):
    out = tmp_path / "f.h5"
    argv = ["flow", str(rec), "--window-events", "2000", "--scales", "2", "--out", str(out)]
    assert main(argv) == 0
    capsys.readouterr()
    data = out.read_bytes()
    (tmp_path / "f.h5.part").write_bytes(data[: len(data) // 2])
    out.unlink()
    assert main(argv + ["--resume"]) == 2
    err = capsys.readouterr().err
    assert "truncated" in err and "delete it and run again without --resume" in err, err
    assert "file lock" not in err


def test_a_killed_runs_temporaries_are_removed_by_the_next(rec, tmp_path, capsys):
    """SIGKILL leaves the hidden temporaries of a run (probe AJ: 124 MB and 408 MB), which
    no later run removed. A run writing the same output removes those of this host whose
    process is gone, and leaves a running process's and another host's."""
    import os
    import socket
    import subprocess
    import sys

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True).stdout.strip()
    host = socket.gethostname()
    out = tmp_path / "c.txt"
    stale = tmp_path / f".c.txt.{host}-{dead}.abc123.part.txt"
    running = tmp_path / f".c.txt.{host}-{os.getpid()}.def456.part.txt"
    other = tmp_path / f".c.txt.otherhost-{dead}.ghi789.part.txt"
    for p in (stale, running, other):
        p.write_text("x")
    assert main(["convert", str(rec), str(out)]) == 0
    capsys.readouterr()
    assert out.exists() and not stale.exists() and running.exists() and other.exists()


def test_a_final_rename_that_fails_names_the_part_it_keeps(tmp_path, monkeypatch):
    """A folder made read-only (chattr +i) under a finishing run: its last step, renaming
    the finished .part onto the output, failed with a bare "[Errno 1] Operation not
    permitted: 'f.h5.part' -> 'f.h5'" (probe BB). The error names the .part, which holds
    every window, and what to do."""
    import os

    import evmotion.io.flowfiles as flowfiles
    from evmotion.errors import FormatError
    from evmotion.io.flowout import open_flow_output

    real = os.replace

    def refused(src, dst):
        if str(src).endswith(".part"):
            raise PermissionError(1, "Operation not permitted")
        return real(src, dst)

    monkeypatch.setattr(flowfiles.os, "replace", refused)
    out = tmp_path / "f.h5"
    with pytest.raises(FormatError, match=r"f\.h5\.part.*every window.*--resume"):
        with open_flow_output(out, (4, 5), {"method": "x"}) as w:
            w.append(np.zeros((4, 5, 2), np.float32), t0=0, t1=10_000)
    assert (tmp_path / "f.h5.part").is_file() and not out.exists()

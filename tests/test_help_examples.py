"""Every example line of every ``--help`` (the top-level parser, each command and each
subcommand) and of README.md's code blocks runs and exits 0.

The lines of one ``--help`` run in order in one fresh folder (a later line may use what an
earlier one wrote); the folder starts with small versions of the inputs the examples name
(``sim.h5``, ``rec.raw``, an ECD folder ``boxes_rotation/``, a schlieren ``scene/``...),
made once per session by the CLI itself. A line naming a file this set does not hold fails,
so a new example must use these names or add its input here. README.md is read at test
time, so that its examples are checked as they are now.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import os
import re
import shlex
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from evmotion.cli import build_parser, main

REPO = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow

HAS_TORCH = importlib.util.find_spec("torch") is not None


def _parsers():
    """``(label, parser)`` of the top-level parser, every command and every subcommand."""
    out = []

    def walk(parser, label):
        out.append((label, parser))
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, f"{label} {name}")

    walk(build_parser(), "evmotion")
    return out


def example_lines(text: str) -> list[str]:
    """The lines of ``text`` that start with ``evmotion `` (after indentation), with their
    ``\\`` continuation lines joined."""
    lines, pending = [], None
    for raw in text.splitlines():
        line = raw.strip()
        if pending is not None:
            pending += " " + line.rstrip("\\").strip()
            if not line.endswith("\\"):
                lines.append(pending)
                pending = None
            continue
        if line.startswith("evmotion "):
            if line.endswith("\\"):
                pending = line.rstrip("\\").strip()
            else:
                lines.append(line)
    if pending is not None:
        lines.append(pending)
    return lines


def readme_lines() -> list[str]:
    """The ``evmotion`` lines inside README.md's fenced code blocks."""
    readme = REPO / "README.md"
    if not readme.exists():
        return []
    blocks = re.findall(r"^```[^\n]*\n(.*?)^```", readme.read_text(encoding="utf-8"),
                        flags=re.S | re.M)
    return [line for block in blocks for line in example_lines(block)]


def test_every_command_has_examples():
    missing = [label for label, p in _parsers() if not example_lines(p.epilog or "")]
    assert not missing, f"--help without an example line: {missing}"


def test_example_extraction_joins_continuations_and_strips_nothing_else():
    text = "examples:\n  evmotion a b \\\n      --c d   # note\n  evmotion e\n(not evmotion f)\n"
    assert example_lines(text) == ["evmotion a b --c d   # note", "evmotion e"]


# ------------------------------------------------------------------- the inputs
@contextlib.contextmanager
def _cwd(path: Path):
    old = os.getcwd()
    os.chdir(path)
    try:
        yield
    finally:
        os.chdir(old)


def _ok(argv: list[str]) -> None:
    rc = main(argv)
    assert rc == 0, f"making the example inputs: evmotion {' '.join(argv)} exited {rc}"


def _mvsec_gt(sim_gt: Path, out: Path) -> None:
    """An MVSEC-style ``*_gt_flow_dist.npz`` (displacement per frame) from the simulator's
    ground truth."""
    from evmotion.io.flowfiles import read_gt_flow

    gt = read_gt_flow(sim_gt)
    dt = (np.asarray(gt.t1) - np.asarray(gt.t0)) * 1e-6
    disp = np.asarray(gt.flow) * dt[:, None, None, None]
    np.savez(out, timestamps=np.asarray(gt.t0) * 1e-6, x_flow_dist=disp[..., 0],
             y_flow_dist=disp[..., 1])


def _dsec_gt_and_predictions(sim_gt: Path, seq: Path, pred: Path) -> None:
    """A DSEC sequence folder (``flow/forward`` PNGs + timestamps) of the simulator's
    ground truth, and another tool's predictions: PNGs of the same names, no times."""
    from evmotion.io.flowfiles import read_gt_flow, write_dsec_flow_png

    gt = read_gt_flow(sim_gt)
    (seq / "flow" / "forward").mkdir(parents=True)
    pred.mkdir()
    lines = ["# from_timestamp_us, to_timestamp_us"]
    for k in range(min(3, len(gt.t0))):
        disp = np.nan_to_num(gt.flow[k] * ((gt.t1[k] - gt.t0[k]) * 1e-6))
        write_dsec_flow_png(seq / "flow" / "forward" / f"{2 * k:06d}.png", disp)
        write_dsec_flow_png(pred / f"{2 * k:06d}.png", disp + 0.25)
        lines.append(f"{gt.t0[k]}, {gt.t1[k]}")
    (seq / "flow" / "forward_timestamps.txt").write_text("\n".join(lines) + "\n")


@pytest.fixture(scope="session")
def world(tmp_path_factory) -> Path:
    """A folder holding every input the examples name, small enough to run them fast."""
    import evmotion.io as eio
    from evmotion.events import EventArray
    from evmotion.viz import save_png

    root = tmp_path_factory.mktemp("examples_world")
    with _cwd(root):
        _ok(["simulate", "rotation", "--duration", "0.05", "--out", "sim.h5"])
        shutil.copy("sim.h5", "rec.h5")
        _ok(["convert", "sim.h5", "rec.raw"])
        shutil.copy("rec.raw", "recording.raw")
        _ok(["convert", "sim.h5", "rec1.raw", "--t1", "0.02"])
        _ok(["convert", "sim.h5", "rec2.aedat4", "--t0", "0.02", "--t1", "0.04"])
        _ok(["convert", "sim.h5", "val.h5", "--t0", "0.03"])
        # an ECD folder: the DAVIS240C's 240 x 180 px, cut from the top-left corner of the
        # simulated sensor (so the simulator's intrinsics still hold)
        Path("boxes_rotation").mkdir()
        ev = eio.read_events("sim.h5", t1=30_000)
        keep = (ev.x < 240) & (ev.y < 180)
        eio.write_events("boxes_rotation/events.txt",
                         EventArray(ev.x[keep], ev.y[keep], ev.t[keep], ev.p[keep], (180, 240)))
        # ECD text files have no header: the reader takes the DAVIS240C's size
        shutil.copy("boxes_rotation/events.txt", "events.txt")
        shutil.copy("boxes_rotation/events.txt", "window.txt")
        cal = eio.read_calibration("sim.h5")
        Path("boxes_rotation/calib.txt").write_text(
            f"{cal['fx']} {cal['fy']} {cal['cx']} {cal['cy']} 0.01 0 0 0 0\n")
        # its IMU ('t ax ay az gx gy gz', s, m/s^2, rad/s) over the recording's time
        Path("boxes_rotation/imu.txt").write_text("".join(
            f"{k * 1e-3:.6f} 0 9.81 0 0.1 0.2 0.3\n" for k in range(1000)))
        _mvsec_gt(Path("sim_gt.h5"), Path("outdoor_day1_gt_flow_dist.npz"))
        _dsec_gt_and_predictions(Path("sim_gt.h5"), Path("dsec_seq"), Path("eraft_pred"))
        rng = np.random.default_rng(0)
        save_png("photo.png", rng.integers(0, 256, (64, 80, 3), dtype=np.uint8))
        _ok(["flow", "sim.h5", "--max-windows", "2", "--scales", "2", "--out", "flow.h5"])
        _ok(["flow", "sim.h5", "--max-windows", "2", "--scales", "2", "--out",
             "flow_{:05d}.flo"])
        _ok(["simulate", "schlieren", "--scene", "plume", "--size", "128x160", "--duration",
             "0.05", "--out", "scene/"])
        _ok(["bos", "scene/", "--max-intervals", "2", "--out", "bos.h5"])
        _ok(["egomotion", "sim.h5", "--warp", "rotation", "--window-events", "30000",
             "--max-windows", "2", "--max-png", "0", "--out", "ego/"])
    return root


def _run_lines(world: Path, folder: Path, lines: list[str], capsys) -> list[str]:
    """Run ``lines`` in order in ``folder`` (a copy of the world); return the failures."""
    shutil.copytree(world, folder)
    failures = []
    with _cwd(folder):
        for line in lines:
            argv = shlex.split(line, comments=True)[1:]
            needs_torch = "dnn" in argv or (argv and argv[0] == "train")
            if needs_torch and not HAS_TORCH:
                continue  # the network's examples need the 'dnn' extra
            t = time.perf_counter()
            rc = main(argv)
            err = capsys.readouterr().err
            if rc != 0:
                last = err.strip().splitlines()[-1:] or ["(nothing on stderr)"]
                failures.append(f"{line}\n    -> exit {rc} after {time.perf_counter() - t:.1f} "
                                f"s: {last[0]}")
    return failures


@pytest.mark.parametrize("label", [label for label, _ in _parsers()])
def test_help_examples_run(label, world, tmp_path, capsys):
    parser = dict(_parsers())[label]
    lines = example_lines(parser.epilog or "")
    if not lines:
        pytest.skip(f"'{label} --help' has no examples (test_every_command_has_examples)")
    failures = _run_lines(world, tmp_path / "run", lines, capsys)
    assert not failures, f"examples of '{label} --help' that fail:\n" + "\n".join(failures)


# README examples run on full-size inputs (its schlieren scene is 720 x 640 px): the test
# keeps their inputs and outputs but caps the work, appending options that argparse lets
# override earlier ones (measured: 448 s as written, bos 324 s and train 113 s of it)
_README_LIMITS = {
    "bos": (("--max-intervals", "--max-windows"), ["--max-intervals", "1"]),
    "egomotion": (("--max-windows",), ["--max-windows", "2"]),
    "segment": (("--max-windows",), ["--max-windows", "1"]),
    "flow": (("--max-windows", "--method triplet"), ["--max-windows", "2"]),
    "train": ((), ["--sim-windows", "4", "--epochs", "1"]),
}


def limited(line: str) -> str:
    """``line`` with the work capped (see ``_README_LIMITS``)."""
    argv = shlex.split(line, comments=True)
    given, extra = _README_LIMITS.get(argv[1] if len(argv) > 1 else "", ((), []))
    joined = " ".join(argv)
    if any(flag in joined for flag in given):
        return joined
    return " ".join(shlex.quote(a) for a in argv + extra)


def _on_local_cluster(lines: list[str], stack: contextlib.ExitStack) -> list[str]:
    """``lines`` with each ``--scheduler ADDRESS`` pointed at a local Dask cluster (started
    here, two single-threaded workers), so that the README's cluster example really runs on
    one; the lines are unchanged when none names a scheduler."""
    if not any("--scheduler" in line for line in lines):
        return lines
    distributed = pytest.importorskip("distributed")
    cluster = stack.enter_context(distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, protocol="tcp",
        dashboard_address=":0"))
    return [re.sub(r"--scheduler\s+\S+", f"--scheduler {cluster.scheduler_address}", line)
            for line in lines]


def test_readme_examples_run(world, tmp_path, capsys):
    lines = readme_lines()
    if not lines:
        pytest.skip("README.md has no evmotion example in a code block")
    with contextlib.ExitStack() as stack:
        lines = _on_local_cluster([limited(line) for line in lines], stack)
        failures = _run_lines(world, tmp_path / "run", lines, capsys)
    assert not failures, "README.md examples that fail:\n" + "\n".join(failures)

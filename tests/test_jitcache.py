"""The numba cache fallback of a read-only installation, and compile time reported apart."""

from __future__ import annotations

import functools
import os
import shutil
import stat
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from numba import njit

import evmotion
from evmotion.events import EventArray
from evmotion.jitcache import compile_seconds, ensure_cache_dir

PACKAGE = Path(evmotion.__file__).resolve().parent
NOBODY = 65534


def _read_only_copy(base: Path) -> Path:
    """The package copied under ``base`` without caches, every folder read-only."""
    dst = base / "site" / "evmotion"
    shutil.copytree(PACKAGE, dst, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    for d, _, files in os.walk(base / "site"):
        for f in files:
            os.chmod(Path(d, f), 0o444)
        os.chmod(d, 0o555)
    return base / "site"


def _run_as_user(args, env):
    """Run ``args`` as an ordinary user: root writes anywhere whatever the permissions, so
    root drops to ``nobody`` (setpriv) for the test to mean anything."""
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("running as root without setpriv: cannot make a folder unwritable")
        args = ["setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups", *args]
    return subprocess.run(args, env=env, capture_output=True, text=True, timeout=300)


@pytest.fixture
def read_only_install():
    base = Path(tempfile.mkdtemp(prefix="evm-ro-"))
    os.chmod(base, 0o755)
    tmp = base / "tmp"
    tmp.mkdir()
    os.chmod(tmp, 0o1777)
    site = _read_only_copy(base)
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(base / "no-home"),
           "PYTHONPATH": str(site), "TMPDIR": str(tmp), "PYTHONDONTWRITEBYTECODE": "1"}
    yield site, tmp, env
    for d, _, _ in os.walk(base):
        os.chmod(d, stat.S_IRWXU)
    shutil.rmtree(base, ignore_errors=True)


def test_read_only_install_without_home_runs(read_only_install):
    site, tmp, env = read_only_install
    probe = _run_as_user([sys.executable, "-c", "import os, sys; sys.exit(os.access("
                          f"{str(site / 'evmotion')!r}, os.W_OK))"], env)
    if probe.returncode != 0:
        pytest.skip(f"cannot run the interpreter as an unprivileged user: {probe.stderr}")
    res = _run_as_user([sys.executable, "-m", "evmotion", "--version"], env)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == f"evmotion {evmotion.__version__}"
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "NUMBA_CACHE_DIR" in lines[0], res.stderr
    # a kernel compiles and is cached in the folder the line names
    code = ("import numpy as np; from evmotion.core.iwe import accumulate; "
            "print(accumulate(np.array([1.5]), np.array([1.0]), (3, 3)).sum())")
    folder = lines[0].split(" in ")[-1].split(" (")[0]
    res = _run_as_user([sys.executable, "-c", code], env)
    assert res.returncode == 0, res.stderr
    assert float(res.stdout) == 1.0
    assert res.stderr == ""  # said when the folder was made, not at every command
    assert Path(folder).parent == tmp and any(Path(folder).rglob("*.nbi"))
    assert stat.S_IMODE(os.stat(folder).st_mode) == 0o700


def test_a_cache_folder_of_another_user_is_not_used(read_only_install):
    # numba unpickles the cache's index: a folder another user made at the predictable
    # path was used as it was (or, unwritable, crashed every command with a traceback)
    site, tmp, env = read_only_install
    probe = _run_as_user([sys.executable, "-c", "import os; print(os.getuid())"], env)
    if probe.returncode != 0:
        pytest.skip(f"cannot run the interpreter as an unprivileged user: {probe.stderr}")
    planted = tmp / f"evmotion-numba-cache-{probe.stdout.strip()}"
    planted.mkdir()
    os.chmod(planted, 0o777)
    code = ("import numpy as np; from evmotion.core.iwe import accumulate; "
            "print(accumulate(np.array([1.5]), np.array([1.0]), (3, 3)).sum())")
    res = _run_as_user([sys.executable, "-c", code], env)
    assert res.returncode == 0, res.stderr
    assert float(res.stdout) == 1.0
    folder = Path(res.stderr.split(" in ")[-1].split(" (")[0])
    assert folder != planted and folder.parent == tmp and not any(planted.iterdir())


def test_ensure_cache_dir_leaves_a_working_setup(monkeypatch, tmp_path):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    assert ensure_cache_dir() is None
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "m.py").write_text("")
    assert ensure_cache_dir(pkg) is None  # a writable package: numba caches next to it


def test_compile_seconds_counts_compilation_only():
    @njit
    def fresh(a):
        s = 0.0
        for v in a:
            s += v * v
        return s

    a = np.arange(5.0)
    c0 = compile_seconds()
    assert fresh(a) == 30.0
    c1 = compile_seconds()
    assert c1 > c0
    fresh(a)
    assert compile_seconds() == c1


@pytest.mark.slow
def test_dask_worker_compiles_once(tmp_path, monkeypatch):
    distributed = pytest.importorskip("distributed")
    from evmotion.methods.egomotion import estimate_egomotion
    from evmotion.parallel import map_windows

    rng = np.random.default_rng(0)
    n = 6000
    dots = rng.uniform(10, 60, (200, 2))
    k = rng.integers(0, 200, n)
    t = np.sort(rng.integers(0, 150_000, n))
    ev = EventArray(dots[k, 0] + 400.0 * (t % 50_000) * 1e-6, dots[k, 1], t,
                    np.ones(n, int), sensor_size=(80, 128), validate=False)
    windows = [(0, 50_000), (50_000, 100_000), (100_000, 150_000)]
    # a new worker process with an empty cache: it must compile, once
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    job = functools.partial(estimate_egomotion, warp="translation", maps=False)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        res = map_windows(job, ev, windows, scheduler=client, progress=False)
    assert all(r.ok for r in res), [r.error for r in res]
    assert res[0].compile_s > 0.0
    assert [r.compile_s for r in res[1:]] == [0.0, 0.0]
    timings = [r.value.timings for r in res]
    assert timings[0]["compile"] > 0.0 and [t["compile"] for t in timings[1:]] == [0.0, 0.0]
    for r, tm in zip(res, timings, strict=True):
        assert tm["estimate"] == pytest.approx(tm["total"] - tm["compile"])
        assert abs(r.value.params[0] - 400.0) < 20.0

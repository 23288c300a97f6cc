"""Shared fixtures: the real recordings in ../shared/data (skipped when absent)."""

from __future__ import annotations

from pathlib import Path

import pytest

from _helpers import SHARED_DATA


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Folder of real recordings; tests using it skip with a reason when it is missing."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real recordings not found at {SHARED_DATA} "
                    "(set EVMOTION_SHARED_DATA to the shared/data folder)")
    return SHARED_DATA


def pytest_collection_modifyitems(config, items):
    """Mark every test that reads the real recordings ``realdata``, whatever the route.

    A test reaches ../shared/data only through the ``shared_data`` fixture (directly or via a
    fixture built on it), so ``-m realdata`` / ``-m "not realdata"`` select exactly those.
    """
    for item in items:
        if "shared_data" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.realdata)


@pytest.fixture(autouse=True)
def _no_progress_lines(monkeypatch):
    """No progress on stderr unless a test asks for it: on a loaded machine a slow command
    writes a progress line every 30 s into a log, and the error lines the tests compare
    would then not stand alone."""
    monkeypatch.setenv("EVMOTION_PROGRESS", "0")


@pytest.fixture(params=["numba", "numpy"])
def decoder(request, monkeypatch):
    """Run a binary reader's test through its numba kernels and through the numpy
    decoders it uses for blocks of at most ``binary.PLAIN_WORDS`` words."""
    from evmotion.io import binary

    monkeypatch.setattr(binary, "PLAIN_WORDS", -1 if request.param == "numba" else 1 << 40)
    return request.param

"""pytest set-up for the docstring examples of ``src/evmotion`` (run by ``make test``).

Not part of the installed package (only ``src/evmotion`` is). Modules and examples that need
an optional extra are skipped, with the extra named, when that extra is not installed; an
import error of evmotion itself still fails.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parent

# module under src/ (or one example in it: "path::name") -> the optional third-party module
# it needs; a module that imports it at the top is left out, an example is skipped
NEEDS = {
    "evmotion/methods/dnn/loss.py": "torch",
    "evmotion/methods/dnn/model.py": "torch",
    "evmotion/methods/dnn/network.py": "torch",
    "evmotion/methods/dnn/train.py": "torch",
    "evmotion/methods/farneback.py": "cv2",
    "evmotion/methods/baselines.py::evmotion.methods.baselines.farneback_intervals": "cv2",
    "evmotion/viz/video.py::evmotion.viz.video.write_video": "imageio_ffmpeg",
    "evmotion/viz/video.py::evmotion.viz.video.write_flow_video": "imageio_ffmpeg",
    "evmotion/parallel.py::evmotion.parallel.connect_scheduler": "distributed",
    "evmotion/cli/options.py::evmotion.cli.options.scheduler_address": "distributed",
}


def _have(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def _missing_extra(path: Path, name: str = "") -> str | None:
    try:
        rel = path.resolve().relative_to(SRC).as_posix()
    except ValueError:
        return None
    module = NEEDS.get(f"{rel}::{name}" if name else rel)
    return module if module is not None and not _have(module) else None


_SKIPPED: dict[str, str] = {}


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    """Leave out modules that cannot even be imported without their optional extra."""
    if collection_path.suffix == ".py" and (module := _missing_extra(collection_path)):
        _SKIPPED[collection_path.relative_to(SRC).as_posix()] = module
        return True
    return None


def pytest_terminal_summary(terminalreporter) -> None:
    for rel, module in sorted(_SKIPPED.items()):
        terminalreporter.write_line(f"SKIPPED docstring examples of {rel}: "
                                    f"optional package {module!r} is not installed")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Skip the examples that call into an optional extra that is not installed."""
    for item in items:
        if isinstance(item, pytest.DoctestItem) and (module := _missing_extra(item.path, item.name)):
            item.add_marker(pytest.mark.skip(reason=f"optional package {module!r} is not installed"))


@pytest.fixture(autouse=True)
def _examples_write_into_a_temporary_folder(request, tmp_path, monkeypatch):
    """Docstring examples that write files (``save_png("iwe.png", ...)``) run in a fresh
    temporary folder, so they can show the real call without touching the checkout."""
    if isinstance(request.node, pytest.DoctestItem):
        monkeypatch.chdir(tmp_path)

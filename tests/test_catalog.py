"""The light name catalog matches the registries it mirrors, and building the command-line
parser (what ``evmotion --help`` and ``--version`` do) loads none of the heavy modules."""

from __future__ import annotations

import json
import subprocess
import sys

from evmotion.catalog import FORMAT_NAMES, OBJECTIVE_NAMES, WARP_NAMES, WEIGHT_DATASETS
from evmotion.core.collapse import DEFAULT_WEIGHTS
from evmotion.core.objectives import OBJECTIVES
from evmotion.core.warps import WARPS
from evmotion.io.registry import all_formats


def test_catalog_matches_the_registries():
    assert WARP_NAMES == tuple(WARPS)
    assert OBJECTIVE_NAMES == tuple(OBJECTIVES)
    assert WEIGHT_DATASETS == tuple(DEFAULT_WEIGHTS)
    assert FORMAT_NAMES == tuple(f.name for f in all_formats())


HEAVY = ("numba", "scipy", "matplotlib", "h5py", "evmotion.core", "evmotion.methods")


def test_building_the_parser_loads_no_heavy_module():
    code = ("import sys, json; from evmotion.cli import build_parser; build_parser(); "
            f"print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in {HEAVY!r} "
            f"or m.startswith({HEAVY!r}))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert json.loads(out.stdout) == []

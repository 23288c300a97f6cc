"""Fuzzing the result readers with hypothesis: a corrupt flow, BOS or ground-truth file
read by ``eval``, ``info`` or the API gives one line naming it, never a traceback.

The seeds are evmotion's own outputs of a tiny schlieren scene: the ``bos`` CLI's HDF5
(a flow file with q, p and per-window scalars), the simulator's ``schlieren_gt.h5`` and a
Middlebury ``.flo``. Mutations as in ``test_fuzz_readers`` (``fuzzing.mutate``). Before
these readers were guarded, 300 mutations of each gave 16 tracebacks (h5py KeyError and
RuntimeError, a JSONDecodeError of a units attribute, a UnicodeEncodeError) and 10 exits
with an HDF5 message that named no file.
"""

from __future__ import annotations

import numpy as np
import pytest

import fuzzing
from bos_synth import plume_scene
from evmotion.cli import main
from evmotion.errors import EvmotionError
from evmotion.io.bosfiles import read_bos_h5
from evmotion.io.flowfiles import read_flo, read_gt_flow, write_flo
from evmotion.io.flowread import describe_flow, read_flow
from evmotion.sim.schlieren import read_schlieren_gt, read_schlieren_q
from fuzz_cases import run_mutations

CASES = 60


@pytest.fixture(scope="module")
def seeds(tmp_path_factory):
    root = tmp_path_factory.mktemp("flow_seeds")
    scene = plume_scene(root / "plume")
    bos = root / "bos.h5"
    assert main(["bos", str(scene), "--out", str(bos)]) == 0
    flo = root / "x.flo"
    write_flo(flo, np.random.default_rng(0).normal(size=(12, 10, 2)).astype(np.float32))
    return {"bos": bos, "gt": scene / "schlieren_gt.h5", "flo": flo}


READERS = {
    "bos": (read_bos_h5, read_flow, describe_flow),
    "gt": (read_schlieren_gt, read_schlieren_q, read_gt_flow),
    "flo": (read_flo, describe_flow),
}


@pytest.mark.parametrize("name", sorted(READERS))
def test_corrupt_result_files_give_one_line_naming_the_file(name, seeds, tmp_path_factory):
    seed = fuzzing.Seed(name, name, seeds[name], 4096)
    for fn in READERS[name]:
        fn(seed.path)  # the unmutated seed reads
    out_dir = tmp_path_factory.mktemp(f"fuzz_{name}")
    seen = {"cases": 0, "errors": 0}

    def check(path, ops):
        seen["cases"] += 1
        for fn in READERS[name]:
            try:
                fn(path)
            except EvmotionError as exc:
                msg = str(exc)
                assert str(path) in msg and "\n" not in msg, (fn.__name__, msg, ops)
                seen["errors"] += 1

    run_mutations(seed, CASES, out_dir, check)
    assert seen["errors"] > 0

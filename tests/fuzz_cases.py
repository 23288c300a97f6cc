"""The hypothesis side of the fuzz tests: the mutation strategy over ``fuzzing.OPS`` and a
deterministic runner (``derandomize``: the same cases on every run, so CI is repeatable)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import fuzzing

OPS = st.lists(st.tuples(st.sampled_from(fuzzing.OPS), st.integers(0, 1 << 24),
                         st.integers(0, 1 << 16), st.integers(0, 1 << 16)),
               min_size=1, max_size=3)


def run_mutations(seed: fuzzing.Seed, cases: int, out_dir: Path,
                  check: Callable[[Path, list], None]) -> None:
    """``check(path, ops)`` on ``cases`` mutated copies of ``seed`` written to ``out_dir``;
    hypothesis shrinks a failing case to its smallest mutation list."""

    @settings(max_examples=cases, derandomize=True, deadline=None, database=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    @given(ops=OPS)
    def case(ops):
        check(fuzzing.write_case(seed, ops, out_dir), ops)

    case()

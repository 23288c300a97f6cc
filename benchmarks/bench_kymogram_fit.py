"""Speed of the kymogram correlation fit (``fit_correlation``, ``evmotion kymogram``'s
default) against the length of the kymogram.

Its per-block lag sums (``_lag_spectra``) were a loop over the lags, each a cumulative sum
over every time bin: quadratic in the duration (the DAVIS346 recording's 2831 bins x 346
px took 14.6 s of a 16.9 s command). They are FFT cross-correlations along time now. Both
are timed here on the same synthetic streak kymograms (parallel streaks at -900 px/s with
shot noise), interleaved, one pinned core: the lag sums alone (the old loop is the test
suite's reference, ``tests/test_kymogram.py``) and the whole fit, with their largest
relative difference. Run: ``python benchmarks/run.py kymogram_fit``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import harness

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

SIZES = ((120, 96), (600, 346), (2831, 346))


def _kymogram(n_t: int, n_s: int, rate_hz: float = 1200.0):
    from evmotion.methods.kymogram import Kymogram, KymoLine

    rng = np.random.default_rng(0)
    t = np.arange(n_t) / rate_hz
    s = np.arange(float(n_s))
    starts = rng.uniform(-900 * t[-1], n_s, 80)
    c = starts[None, :] - 900.0 * t[:, None]
    data = np.zeros((n_t, n_s))
    for k in range(starts.size):  # streaks one at a time: a (T, S, 80) array is too big
        data += np.exp(-0.5 * ((s[None, :] - c[:, k:k + 1]) / 1.5) ** 2)
    data = rng.poisson(2 * data).astype(float)
    return Kymogram(data, t, s, KymoLine.column(0, (n_s, 1)), rate_hz, "events")


def main(quick: bool = False) -> list[dict]:
    from evmotion.methods.kymogram import _lag_spectra, fit_correlation
    from test_kymogram import _lag_spectra_reference

    harness.pin_idlest_core()
    rows = []
    for n_t, n_s in SIZES[:2] if quick else SIZES:
        k = _kymogram(n_t, n_s)
        d = k.data - k.data.mean(axis=0) - k.data.mean(axis=1, keepdims=True)
        n_lags = max(3, round(0.25 * n_t)) + 1
        edges = np.linspace(0, n_t, 9).round().astype(int)
        reps = 1 if n_t * n_lags > 5e6 else 3
        args = (d, n_lags, edges)
        t = harness.timeit_rounds(
            {"fft": lambda a=args: _lag_spectra(*a),
             "per-lag loop": lambda a=args: _lag_spectra_reference(*a)},
            repeat=reps, rounds=1 if quick else 2, ref="per-lag loop")
        new, old = _lag_spectra(*args), _lag_spectra_reference(*args)
        fit = harness.timeit(lambda k=k: fit_correlation(k), repeat=reps, warmup=1)
        rows.append({"bins x px": f"{n_t}x{n_s}", "lags": n_lags,
                     "lag sums fft s": t["fft"]["median_s"],
                     "lag sums per-lag loop s": t["per-lag loop"]["median_s"],
                     "ratio fft / loop": t["fft"]["ratio"],
                     "max rel diff": float(np.abs(new - old).max() / np.abs(old).max()),
                     "whole fit s": fit["median_s"],
                     "velocity px/s (true -900)": fit_correlation(k).velocity_px_s})
    harness.record("kymogram_fit", rows, notes=(
        "fit_correlation's per-block lag sums by FFT cross-correlation against the per-lag "
        "cumulative-sum loop they replaced (tests' reference), same data, interleaved, one "
        "pinned core; 8 blocks, lags up to a quarter of the duration (the defaults); "
        "medians. Synthetic kymograms: 80 streaks at -900 px/s, Poisson noise, 1200 Hz."))
    return rows


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)

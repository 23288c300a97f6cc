"""Options objects of the estimators: the same result as the keywords, the same defaults
as the keywords, and an ambiguous call (both) refused."""

from __future__ import annotations

import dataclasses
import inspect

import numpy as np
import pytest

from evmotion.errors import ParameterError
from evmotion.events import EventArray
from evmotion.methods.egomotion import EgomotionOptions, estimate_egomotion
from evmotion.methods.multicm import MultiCMOptions, estimate_flow
from evmotion.methods.options import merge_options


@pytest.mark.parametrize("func, cls", [(estimate_egomotion, EgomotionOptions),
                                       (estimate_flow, MultiCMOptions)])
def test_every_field_is_a_keyword_with_the_same_default(func, cls):
    sig = inspect.signature(func).parameters
    for f in dataclasses.fields(cls):
        assert f.name in sig, f.name
        assert sig[f.name].default == f.default, f.name


def _translating_dots(n=6000, seed=0):
    rng = np.random.default_rng(seed)
    dots = rng.uniform(10, 60, (200, 2))
    k = rng.integers(0, 200, n)
    t = np.sort(rng.integers(0, 50_000, n))
    return EventArray(dots[k, 0] + 400.0 * t * 1e-6, dots[k, 1], t, np.ones(n, int),
                      sensor_size=(80, 128), validate=False)


def test_egomotion_options_object_equals_keywords():
    ev = _translating_dots()
    kw = dict(objective="gradient_magnitude", optimizer="newton-cg", t_ref="mid",
              maps=False, diagnose=False)
    a = estimate_egomotion(ev, warp="translation", **kw)
    b = estimate_egomotion(ev, warp="translation", options=EgomotionOptions(**kw))
    np.testing.assert_array_equal(a.params, b.params)
    assert (b.objective, b.optimizer, b.maps, b.t_ref_us) == (
        "gradient_magnitude", "newton-cg", {}, a.t_ref_us)
    assert abs(b.params[0] - 400.0) < 20.0


def test_multicm_options_object_equals_keywords():
    ev = _translating_dots(4000)
    kw = dict(n_scales=2, finest_level=2, max_iter=5, objective="variance")
    a = estimate_flow(ev, **kw)
    b = estimate_flow(ev, options=MultiCMOptions(**kw))
    np.testing.assert_array_equal(a.flow, b.flow)
    assert b.meta["objective"] == "variance" and b.meta["n_scales"] == 2


def test_options_with_keywords_is_refused():
    ev = _translating_dots(500)
    with pytest.raises(ParameterError, match="either options= or the keyword"):
        estimate_egomotion(ev, warp="translation", optimizer="tpe",
                           options=EgomotionOptions())
    with pytest.raises(ParameterError, match="either options= or the keyword.*max_iter"):
        estimate_flow(ev, max_iter=3, options=MultiCMOptions())
    with pytest.raises(ParameterError, match="options must be a MultiCMOptions"):
        estimate_flow(ev, options=EgomotionOptions())


def test_merge_options_keeps_the_object_when_keywords_are_defaults():
    opts = MultiCMOptions(lam=0.01)
    assert merge_options(MultiCMOptions, opts, lam=0.0025, n_bins=None) is opts
    assert merge_options(MultiCMOptions, None, lam=0.01) == opts


def test_progress_in_a_log_is_a_line_now_and_then(monkeypatch, capsys):
    """stderr not a TTY (a log file): no progress at all before; now a plain line every
    LOG_PROGRESS_S seconds with rate and time left, none for a short run."""
    import time

    import evmotion.utils as utils

    monkeypatch.delenv("EVMOTION_PROGRESS", raising=False)
    for _ in utils.progress(range(3), desc="flow", unit="win"):
        pass
    assert capsys.readouterr().err == ""
    monkeypatch.setattr(utils, "LOG_PROGRESS_S", 0.05)
    for _ in utils.progress(range(4), desc="flow", unit="win"):
        time.sleep(0.03)
    lines = capsys.readouterr().err.splitlines()
    assert lines and all(ln.startswith("flow: ") and "left" in ln and "win/s" in ln
                         for ln in lines)
    assert lines[-1].startswith("flow: 4/4 win") and "\r" not in "".join(lines)
    # each line moves the count: no repeat of the last (tqdm's monitor between slow
    # items, the closing refresh)
    counts = [ln.split(" [")[0] for ln in lines]
    assert len(counts) == len(set(counts))
    monkeypatch.setenv("EVMOTION_PROGRESS", "0")
    for _ in utils.progress(range(4), desc="flow", unit="win"):
        time.sleep(0.03)
    assert capsys.readouterr().err == ""


def test_a_fraction_of_a_microsecond_goes_up_whatever_its_unit():
    # probe BL: '--t0 0.0010185' (float: 1018.4999... µs) and '1018.5us' selected
    # different events, and '1018.4us' kept the event at t = 1018
    from evmotion.cli.options import time_us

    assert {time_us(t) for t in ("0.0010185", "1018.5us", "1.0185ms", "1018.4us",
                                 "+1018.0001us")} == {1019}
    assert time_us("1.5") == 1_500_000 and time_us("1590000000.1234567") == 1590000000123457


def test_times_and_durations_take_nanoseconds():
    # probe BM: a recording's ns clock could not be typed as is ('1590000000123456789ns'
    # was 'must be a time'); a fraction of a µs goes up to the next one as for other units
    import argparse

    from evmotion.cli.options import duration_us, time_us

    assert time_us("1590000000123456789ns") == 1590000000123457
    assert time_us("1590000000123456000ns") == 1590000000123456
    assert time_us("+2500ns") == 3 and duration_us("10000000ns") == 10_000
    with pytest.raises(argparse.ArgumentTypeError, match="whole number of microseconds"):
        duration_us("1500ns")


def test_progress_on_a_terminal_of_no_columns_is_drawn_80_wide(monkeypatch, capsys):
    # probe BP: a terminal reporting 0 columns (script without stty cols) got a bar 0
    # wide: no count, rate or ETA
    import os
    import sys

    import evmotion.utils as utils

    monkeypatch.setenv("EVMOTION_PROGRESS", "1")
    monkeypatch.setattr(os, "get_terminal_size", lambda *a: os.terminal_size((0, 0)))
    for _ in utils.progress(range(5), total=5, desc="flow", unit="win"):
        pass
    last = capsys.readouterr().err.replace("\r", "\n").strip().splitlines()[-1]
    assert "flow" in last and "5/5" in last and len(last) <= 80
    assert utils._bar_width() == {"ncols": 80}
    monkeypatch.setattr(os, "get_terminal_size", lambda *a: os.terminal_size((120, 40)))
    monkeypatch.setattr(sys.stderr, "fileno", lambda: 2, raising=False)
    assert utils._bar_width() == {"dynamic_ncols": True}

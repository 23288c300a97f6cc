"""Options objects of the estimators: one dataclass per estimator gathers its tuning
keywords, so that a configuration can be built once, stored, compared and passed around
(``estimate_egomotion(events, options=opts)``), while the keywords keep working.

Examples
--------
>>> from dataclasses import dataclass
>>> @dataclass(frozen=True)
... class Opts:
...     n_iter: int = 100
>>> merge_options(Opts, None, n_iter=5)
Opts(n_iter=5)
>>> merge_options(Opts, Opts(n_iter=7), n_iter=100)   # keywords at their defaults
Opts(n_iter=7)
"""

from __future__ import annotations

import dataclasses

from evmotion.utils import check_switches, resolve_options

__all__ = ["merge_options"]


def _is_default(value, default) -> bool:
    if value is default:
        return True
    scalar = (str, int, float, bool)
    return (isinstance(value, scalar) and type(value) is type(default) and value == default)


def merge_options(cls: type, options, **keywords):
    """The options of one call: ``cls(**keywords)``, or ``options`` when it is given.

    Parameters
    ----------
    cls : dataclass type
        The estimator's options class; its field defaults are the keywords' defaults.
    options : cls or None
        Options passed as an object.
    **keywords
        The estimator's keyword arguments, one per field of ``cls``.

    Returns
    -------
    cls instance

    Raises
    ------
    ParameterError
        ``options`` is not a ``cls``, or it is given together with a keyword that is not at
        its default (the call would be ambiguous).
    """
    defaults = {f.name: f.default for f in dataclasses.fields(cls)}
    given = {k: v for k, v in keywords.items() if not _is_default(v, defaults[k])}
    merged = resolve_options(cls, options, given, cls.__name__)
    # a switch given as a string: "no" is true (use_polarity="no" turned it on: probe)
    check_switches(**{f.name: getattr(merged, f.name) for f in dataclasses.fields(cls)
                      if f.type == "bool"})
    return merged

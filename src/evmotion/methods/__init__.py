"""The estimation methods, one module each (``evmotion.methods.bos.estimate_bos``...);
imported on first use, so that reaching one does not load the others' kernels."""

import importlib as _importlib
import pkgutil as _pkgutil

_MODULES = tuple(m.name for m in _pkgutil.iter_modules(__path__))


def __getattr__(name: str):
    if name in _MODULES:
        return _importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_MODULES})

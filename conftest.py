"""pytest set-up shared by the tests and the docstring examples."""

from __future__ import annotations

import signal

import pytest


@pytest.fixture(autouse=True)
def _ctrl_c_raises():
    """Ctrl-C raises KeyboardInterrupt during each test, as in an interactive session. A
    suite started in the background (``make test &``, a CI step run so) inherits SIGINT
    ignored from its shell, and the tests of what an interrupt leaves behind then failed
    with 'DID NOT RAISE KeyboardInterrupt'."""
    old = signal.getsignal(signal.SIGINT)
    if old is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, old)

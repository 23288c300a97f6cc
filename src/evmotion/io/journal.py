"""A run's journal: the results of its windows as they come in, kept when the run is
interrupted so that ``--resume`` computes only the others.

The file is a stream of pickles: a header (what the run was asked: options, the source's
fingerprint), then one record per finished window ``(position, t0_us, t1_us, digest,
payload)``, ``digest`` the window's events' (:func:`~evmotion.events.events_digest`), which
a resumed run checks each kept window against.
Each record is flushed as it is written; a record cut short by a kill is dropped on
reading. The file is the command's own (written and read back by the same code), so
unpickling it trusts nothing foreign.

Examples
--------
>>> import tempfile, pathlib
>>> path = pathlib.Path(tempfile.mkdtemp()) / "params.part"
>>> with Journal(path, {"warp": "rotation"}) as j:
...     j.add(0, 0, 100, 1234, "first window's result")
>>> Journal.read(path, {"warp": "rotation"})
{0: (0, 100, "first window's result")}
"""

from __future__ import annotations

import os
import pickle
from pathlib import Path
from typing import Any

from evmotion.errors import ParameterError
from evmotion.events import EventArray, events_digest
from evmotion.utils import HELD_NO_WINDOW, ensure_room, keep_for_resume, warn_nothing_to_resume

__all__ = ["Journal"]

# 2: each record holds its window's events' digest (1 checked only the first window's
# events, in the header: a recording changed after it resumed, probe BH)
VERSION = 2


class Journal:
    """Append the results of a run's windows to ``path`` (a context manager). ``header``:
    what the run was asked (compared by :meth:`read` on ``--resume``)."""

    def __init__(self, path: str | os.PathLike, header: dict, *, append: bool = False):
        self.path = Path(path)
        self.count = 0  # the windows this process added
        # the digests of the resumed windows :meth:`open_run` left to :meth:`check_events`
        self.unchecked: dict[int, int] = {}
        self.fh = open(self.path, "ab" if append else "wb")
        if not append:
            self._dump(("evmotion-journal", VERSION, header))

    def _dump(self, obj) -> None:
        data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
        ensure_room(self.path, len(data))
        self.fh.write(data)
        self.fh.flush()

    def add(self, position: int, t0_us: int, t1_us: int, digest: int, payload: Any) -> None:
        """Record window ``position`` (its place in the run's list) of ``[t0_us, t1_us)``
        whose events' digest is ``digest``."""
        self._dump((int(position), int(t0_us), int(t1_us), int(digest), payload))
        self.count += 1

    def close(self) -> None:
        self.fh.close()

    def settle(self, resumed: bool) -> bool:
        """After an interruption: keep the journal for ``--resume`` (the command line names
        it) when it holds a window, this process's or an earlier run's (``resumed``), and
        return True; else delete it (nothing to resume) and return False."""
        if self.count or resumed:
            keep_for_resume(self.path)
            return True
        self.path.unlink(missing_ok=True)
        return False

    def __enter__(self) -> Journal:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @classmethod
    def resume(cls, path: str | os.PathLike, header: dict
               ) -> tuple[Journal, dict[int, tuple[int, int, int, Any]]]:
        """The journal of an interrupted run, reopened to append (a record cut short at its
        end dropped), and the windows it holds, ``{position: (t0_us, t1_us, digest,
        payload)}``."""
        done, end = cls._records(Path(path), header)
        with open(path, "r+b") as fh:
            fh.truncate(end)
        return cls(path, header, append=True), done

    @classmethod
    def open_run(cls, path: str | os.PathLike, header: dict, events: EventArray | None,
                 windows, resume: bool) -> tuple[Journal, dict[int, tuple[int, int, Any]]]:
        """A command's journal at ``path``: a fresh one, or with ``resume`` the
        interrupted run's, reopened, and the windows it holds (:meth:`read`). A journal
        that records no window is replaced; one left without ``resume``, or whose windows
        are not among ``windows`` (:class:`~evmotion.events.Window` of ``events``) with the
        same events, is a ParameterError. ``events`` None (a recording read as a stream):
        the caller checks each resumed window's events with :meth:`check_events`."""
        path = Path(path)
        emptied = path.exists() and cls.holds_nothing(path)
        if emptied:
            path.unlink()  # a run stopped before its first window left it: no work to keep
        if not resume:
            if path.exists():
                raise ParameterError(f"{path} holds the windows of an interrupted run: run "
                                     "the same command with --resume to continue it, or "
                                     "delete it to start again")
            return cls(path, header), {}
        if not path.exists():
            # as flow and bos say it (egomotion and segment started afresh without a word:
            # a mistyped --out resumes nothing, probe BB)
            # (it said "does not exist" of a journal it had just found empty, probe BH)
            warn_nothing_to_resume(path, HELD_NO_WINDOW if emptied else "does not exist")
            return cls(path, header), {}
        journal, done = cls.resume(path, header)
        for k, (t0, t1, kept, _) in done.items():
            if k >= len(windows) or (windows[k].t0, windows[k].t1) != (t0, t1):
                journal.close()
                raise ParameterError(f"cannot resume (--resume): window {k} of {path} is "
                                     f"[{t0}, {t1}) us, not one of this run's (other --t1 "
                                     "or --max-windows, or another recording)")
            if events is None:
                journal.unchecked[k] = kept
            elif events_digest(events.window(windows[k])) != kept:
                journal.close()
                raise journal._changed(k, t0, t1)
        return journal, {k: (t0, t1, payload) for k, (t0, t1, _, payload) in done.items()}

    def check_events(self, position: int, t0_us: int, t1_us: int, events: EventArray) -> None:
        """Refuse (ParameterError) a resumed window ``[t0_us, t1_us)`` whose ``events``
        are not those it was made from, where :meth:`open_run` was given no events."""
        kept = self.unchecked.pop(position, None)
        if kept is not None and events_digest(events) != kept:
            raise self._changed(position, t0_us, t1_us)

    def _changed(self, k: int, t0: int, t1: int) -> ParameterError:
        return ParameterError(f"cannot resume (--resume): the events of window {k} "
                              f"[{t0}, {t1}) us are not those {self.path} was made from "
                              "(the recording changed); delete it to start again")

    @staticmethod
    def holds_nothing(path: str | os.PathLike) -> bool:
        """Whether the journal at ``path`` records no finished window: empty (a full disk
        at its first write), cut within its header, or a header alone."""
        try:
            with open(path, "rb") as fh:
                pickle.load(fh)
                pickle.load(fh)
        except Exception:  # pickle raises many types for a cut file
            return True
        return False

    @classmethod
    def read(cls, path: str | os.PathLike, header: dict) -> dict[int, tuple[int, int, Any]]:
        """The windows a journal holds, ``{position: (t0_us, t1_us, payload)}``; a
        ParameterError when its header differs from ``header`` (another run's journal:
        the options that differ are named)."""
        done = cls._records(Path(path), header)[0]
        return {k: (t0, t1, payload) for k, (t0, t1, _, payload) in done.items()}

    @staticmethod
    def _records(path: Path, header: dict
                 ) -> tuple[dict[int, tuple[int, int, int, Any]], int]:
        done: dict[int, tuple[int, int, int, Any]] = {}
        with open(path, "rb") as fh:
            try:
                head = pickle.load(fh)
            except Exception:  # pickle raises many types for a cut or foreign file
                raise ParameterError(f"cannot resume (--resume): {path} is not a run's "
                                     "journal (cut short or another file); delete it to "
                                     "start again") from None
            if not (isinstance(head, tuple) and len(head) == 3
                    and head[0] == "evmotion-journal"):
                raise ParameterError(f"cannot resume (--resume): {path} is not a run's "
                                     "journal; delete it to start again")
            if head[1] != VERSION:
                raise ParameterError(f"cannot resume (--resume): {path} is the journal of "
                                     f"another version of evmotion (layout {head[1]!r}, "
                                     f"not {VERSION}); delete it to start again")
            differ = sorted(k for k in set(head[2]) | set(header)
                            if head[2].get(k) != header.get(k))
            if differ:
                raise ParameterError(
                    f"cannot resume (--resume): {path} was made with other "
                    f"{', '.join(differ)} ("
                    + "; ".join(f"{k}: {head[2].get(k)!r} there, {header.get(k)!r} now"
                                for k in differ[:3])
                    + "); run with those, or delete it to start again")
            end = fh.tell()
            while True:
                try:
                    pos, t0, t1, digest, payload = pickle.load(fh)
                except Exception:  # the end, or a record cut short by a kill: stop there
                    break
                done[pos] = (t0, t1, digest, payload)
                end = fh.tell()
        return done, end

"""How a long run is asked to stop: Ctrl-C raises ``KeyboardInterrupt``; SIGTERM, while the
CLI's handler is installed, raises :class:`Terminated` where the process is, so that it
unwinds like Ctrl-C; a step that runs too far past the pipeline's ``--time`` is cut by
:func:`time_cap`, which raises :class:`OverTime` where the process is, again every
:data:`REPEAT_SECONDS` until the cut block ends, and from :func:`check_time`, which code between
an environment's steps calls, so an environment that swallows exceptions (a bare ``except:``
around its work) cannot outlast the cap. Anytime work (the pipeline's ladder) catches these
between and inside its steps and returns what it has."""

from __future__ import annotations

import contextlib
import math
import signal
import threading
from collections.abc import Iterator
from typing import Any


class Terminated(BaseException):
    """SIGTERM, raised where the process is, so that it unwinds like Ctrl-C (exit 143)."""


class OverTime(BaseException):
    """Raised by :func:`time_cap` where the process is when its seconds have passed; a
    ``BaseException``, like Ctrl-C, so that no ``except Exception`` inside a step swallows it
    (joblib then stops its workers)."""


STOP_SIGNALS: tuple[type[BaseException], ...] = (KeyboardInterrupt, Terminated)


def stop_reason(err: BaseException) -> str:
    """``interrupted`` (Ctrl-C) or ``terminated`` (SIGTERM)."""
    return "terminated" if isinstance(err, Terminated) else "interrupted"


#: after a cap fires, :class:`OverTime` is raised again this often until its block ends
REPEAT_SECONDS = 1.0
_EXPIRED: list[bool] = []  # one flag per active cap, innermost last: whether it has fired


def _over_time(signum: int, frame: Any) -> None:
    if _EXPIRED:
        _EXPIRED[-1] = True
    raise OverTime


def check_time() -> None:
    """:class:`OverTime` where the innermost active :func:`time_cap` has fired: called between
    an environment's steps, where no code of the environment's can swallow it."""
    if _EXPIRED and _EXPIRED[-1]:
        raise OverTime


@contextlib.contextmanager
def time_cap(seconds: float) -> Iterator[bool]:
    """While active, :class:`OverTime` is raised where the process is once ``seconds`` (wall
    clock) have passed; yields whether the cap is armed. It needs SIGALRM and the main thread
    (the command line's case); elsewhere (a notebook's worker thread, Windows) or with infinite
    ``seconds`` nothing is armed and the code runs to its end."""
    if (not math.isfinite(seconds) or not hasattr(signal, "setitimer")
            or threading.current_thread() is not threading.main_thread()):
        yield False
        return
    previous = signal.signal(signal.SIGALRM, _over_time)
    signal.setitimer(signal.ITIMER_REAL, max(seconds, 1e-3), REPEAT_SECONDS)
    _EXPIRED.append(False)
    try:
        yield True
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        _EXPIRED.pop()
        signal.signal(signal.SIGALRM, previous)

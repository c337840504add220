"""How a long run is asked to stop: Ctrl-C raises ``KeyboardInterrupt``; SIGTERM, while the
CLI's handler is installed, raises :class:`Terminated` where the process is, so that it
unwinds like Ctrl-C. Anytime work (the pipeline's ladder) catches :data:`STOP_SIGNALS` between
its steps and returns what it has."""

from __future__ import annotations


class Terminated(BaseException):
    """SIGTERM, raised where the process is, so that it unwinds like Ctrl-C (exit 143)."""


STOP_SIGNALS: tuple[type[BaseException], ...] = (KeyboardInterrupt, Terminated)


def stop_reason(err: BaseException) -> str:
    """``interrupted`` (Ctrl-C) or ``terminated`` (SIGTERM)."""
    return "terminated" if isinstance(err, Terminated) else "interrupted"

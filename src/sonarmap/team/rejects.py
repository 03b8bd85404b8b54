"""Warnings about frames a robot rejected, bounded in length and in rate (issue 38).

A peer, or a stranger on the network, chooses what a rejected frame holds and how many
it sends: a warning per frame, quoting the frame, would let it fill the disk or the
console. :class:`RejectLog` cuts each line to ``width`` characters, replaces control
characters, and lets through a burst of ``burst`` lines, then ``per_second`` lines a
second; the lines it held back are counted and the next line it lets through says how
many.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

__all__ = ["LINE_WIDTH", "RejectLog", "clip"]

#: Characters a rejection's line keeps at most (the message, not the logger's prefix).
LINE_WIDTH = 200


def clip(text: str, width: int = LINE_WIDTH) -> str:
    """``text`` on one printable line of at most ``width`` characters (an ellipsis marks
    a cut).

    Examples
    --------
    >>> clip("a\\nb" + "x" * 300, 10)
    'a?bxxxx...'
    """
    flat = "".join(c if c.isprintable() else "?" for c in text[: width + 1])
    return flat if len(flat) <= width else flat[: width - 3] + "..."


class RejectLog:
    """Rate-limited, length-bounded warnings on ``logger``.

    Parameters
    ----------
    logger : logging.Logger
        Where the lines go (level WARNING).
    burst : int
        Lines let through at once before the rate applies: 50.
    per_second : float
        Lines a second let through after the burst: 1.
    width : int
        Characters a line keeps at most: :data:`LINE_WIDTH`.
    clock : callable
        Seconds, monotonic (a test's own clock).
    """

    def __init__(
        self,
        logger: logging.Logger,
        *,
        burst: int = 50,
        per_second: float = 1.0,
        width: int = LINE_WIDTH,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.logger = logger
        self.burst = burst
        self.per_second = per_second
        self.width = width
        self.clock = clock
        self._tokens = float(burst)
        self._last = clock()
        #: Lines held back since the last one let through.
        self.suppressed = 0

    def warn(self, message: str) -> bool:
        """Log ``message`` (clipped) unless over the rate; True if it was logged."""
        now = self.clock()
        self._tokens = min(self.burst, self._tokens + (now - self._last) * self.per_second)
        self._last = now
        if self._tokens < 1.0:
            self.suppressed += 1
            return False
        self._tokens -= 1.0
        line = clip(message, self.width)
        if self.suppressed:
            line += f" ({self.suppressed} more rejections not logged)"
            self.suppressed = 0
        self.logger.warning("%s", line)
        return True

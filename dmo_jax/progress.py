"""Progress output for long work."""
from __future__ import annotations

import sys
import time


class Progress:
    """A one-line progress bar on stderr (a line per update when not a terminal)."""

    def __init__(self, label: str, total: int, initial: int = 0):
        self.label, self.total, self.initial, self.start = label, total, initial, time.perf_counter()
        self.tty = sys.stderr.isatty()

    def update(self, done: int, extra: str = "") -> None:
        elapsed = time.perf_counter() - self.start
        rate = (done - self.initial) / elapsed if elapsed > 0 else 0.0
        eta = (self.total - done) / rate if rate > 0 else float("nan")
        width = 24
        bar = "#" * int(width * done / max(self.total, 1))
        line = (f"{self.label} [{bar:<{width}}] {done}/{self.total} {rate:.1f}/s "
                f"ETA {eta:.0f}s {extra}")
        print(("\r" + line) if self.tty else line, end="" if self.tty else "\n", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.tty:
            print(file=sys.stderr)

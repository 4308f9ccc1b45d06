"""Progress output for long work: a tqdm bar (rate, ETA, the current loss) on a terminal; when
stderr is not a terminal (CI logs, ``nohup``), one plain line at each quarter of the work."""
from __future__ import annotations

import sys
import time


class Progress:
    """``Progress(label, total, initial)``; ``update(done, extra)`` with the count done so far
    and a short status (e.g. the loss); ``close()`` at the end."""

    def __init__(self, label: str, total: int, initial: int = 0):
        self.label, self.total, self.initial = label, max(total, 1), initial
        self.start, self.quarter = time.perf_counter(), 4 * initial // self.total
        self.bar = None
        if sys.stderr.isatty():
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=initial, desc=label, file=sys.stderr, dynamic_ncols=True,
                            mininterval=0.5)

    def update(self, done: int, extra: str = "") -> None:
        if self.bar is not None:
            self.bar.update(done - self.bar.n)
            if extra:
                self.bar.set_postfix_str(extra)
            return
        quarter = 4 * done // self.total
        if quarter > self.quarter:
            self.quarter = quarter
            elapsed = time.perf_counter() - self.start
            rate = (done - self.initial) / elapsed if elapsed > 0 else 0.0
            print(f"{self.label}: {done}/{self.total} ({rate:.1f}/s, {elapsed:.0f} s) {extra}".rstrip(),
                  file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()

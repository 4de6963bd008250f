"""Progress on a text stream: trials done, elapsed time and ETA, one line rewritten in place on a terminal
(drawn by tqdm), else a line now and then (logs, pipes). Used by Monte Carlo, reproductions and campaigns."""

from __future__ import annotations

import sys
from typing import TextIO


def format_seconds(s: float) -> str:
    """``12.3 s``, ``4 min 05 s``, ``2 h 07 min``."""
    if s < 60:
        return f"{s:.1f} s"
    if s < 3600:
        return f"{int(s // 60)} min {int(s % 60):02d} s"
    return f"{int(s // 3600)} h {int(s % 3600 // 60):02d} min"


def format_progress(label: str, done: int, total: int, elapsed: float, eta: float | None) -> str:
    """``"<label>: 40/100 trials (40%), 12.3 s elapsed, ETA 18.0 s"``."""
    pct = 100.0 * done / total if total else 100.0
    eta_text = "--" if eta is None else format_seconds(eta)
    return f"{label}: {done}/{total} trials ({pct:.0f}%), {format_seconds(elapsed)} elapsed, ETA {eta_text}"


class ProgressLine:
    """A progress display on a text stream (default stderr): on a terminal one line rewritten in place (drawn
    by tqdm), else (logs, pipes) one line at the first report, then at most every ``interval`` seconds, and at
    the end. The command line passes ``progress=True`` only when stderr is a terminal."""

    def __init__(self, label: str, stream: TextIO | None = None, interval: float = 5.0):
        self.label = label
        self.stream = sys.stderr if stream is None else stream
        self.interval = interval
        isatty = getattr(self.stream, "isatty", None)
        self.tty = bool(isatty()) if callable(isatty) else False
        self._last: float | None = None
        self._bar = None

    def __call__(self, done: int, total: int, elapsed: float, eta: float | None) -> None:
        self.show(format_progress(self.label, done, total, elapsed, eta), elapsed, done >= total)

    def show(self, line: str, elapsed: float, final: bool = False) -> None:
        """Display ``line`` (rewritten in place on a terminal; elsewhere at most every ``interval`` s, and
        always when ``final``)."""
        if self.tty:
            from tqdm import tqdm

            if self._bar is None:
                self._bar = tqdm(file=self.stream, bar_format="{desc}", desc=line, leave=True, mininterval=0)
            else:
                self._bar.set_description_str(line, refresh=True)
            if final:
                self._bar.close()
                self._bar = None
        elif final or self._last is None or elapsed - self._last >= self.interval:
            self.stream.write(line + "\n")
            self._last = elapsed
        self.stream.flush()

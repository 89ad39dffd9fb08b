"""Progress of a long benchmark on stderr, so a run of minutes does not look hung.

On a terminal: one line redrawn in place (carriage return), at most every ``redraw_s``. Anywhere else (a log
file, CI, a pipe): a plain line every ``every_s`` seconds or each time another ``step_percent`` is done, so the
record stays readable. Never on stdout: the report printed there stays the same with or without progress.

    with Progress("loop matrix", total=120.0, unit="s") as progress:
        for k in range(4):
            progress.message(f"... run {k + 1}/4")   # a line on stdout that does not break the bar
            ...
            progress.update(30.0 * (k + 1), note=f"run {k + 1}/4")
"""

from __future__ import annotations

import shutil
import sys
import time
from collections.abc import Callable
from types import TracebackType
from typing import TextIO

BAR_WIDTH = 24
"""Characters of the bar on a terminal."""


def _clock_text(seconds: float) -> str:
    """``m:ss`` (or ``h:mm:ss``) of a non-negative duration [s]."""
    whole = int(max(0.0, seconds) + 0.5)
    hours, rest = divmod(whole, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


def _amount_text(value: float, total: float) -> str:
    """Whole numbers as such; fractions with one decimal while the total is small."""
    return f"{value:.0f}" if value == int(value) or total >= 20 else f"{value:.1f}"


ESTIMATE_AFTER = 0.02
"""No estimate of the time left before this fraction of the work is done (the pace is not known yet)."""


def remaining_s(done: float, total: float, elapsed_s: float) -> float | None:
    """Seconds left at the pace so far [s] (None before :data:`ESTIMATE_AFTER` of the work is done)."""
    if total <= 0.0 or done < ESTIMATE_AFTER * total:
        return None
    return elapsed_s * max(0.0, total - done) / done


def progress_line(
    label: str, done: float, total: float, unit: str, elapsed_s: float, note: str = "", bar: bool = True
) -> str:
    """One line of progress, e.g. ``loop [######------]  50%  60/120 s  1:05 elapsed, ~1:05 left  run 2/4``."""
    fraction = min(1.0, max(0.0, done / total)) if total > 0 else 1.0
    left = remaining_s(done, total, elapsed_s)
    parts = [label]
    if bar:
        filled = round(fraction * BAR_WIDTH)
        parts.append("[" + "#" * filled + "-" * (BAR_WIDTH - filled) + "]")
    parts.append(f"{100 * fraction:3.0f}%")
    parts.append(f"{_amount_text(min(done, total), total)}/{_amount_text(total, total)}{' ' + unit if unit else ''}")
    parts.append(
        f"{_clock_text(elapsed_s)} elapsed, " + (f"~{_clock_text(left)} left" if left is not None else "? left")
    )
    if note:
        parts.append(note)
    return "  ".join(parts)


class Progress:
    """Progress of ``total`` units of work (runs, cycles, measured seconds) on ``stream`` (stderr by default).

    Args:
        label: what is in progress, first on the line.
        total: the amount of work when done (> 0).
        unit: the unit of ``total`` shown after the amounts ("runs", "s"; empty: none).
        stream: where to write (default ``sys.stderr``).
        tty: redraw one line in place; default: whether ``stream`` is a terminal.
        every_s: off a terminal, a line at least this often while work progresses [s].
        step_percent: off a terminal, also a line each time this much more is done [%].
        redraw_s: on a terminal, redraw at most this often [s] (a benchmark should not spend its CPU drawing).
        clock_s: the monotonic clock [s] (tests pass their own).
        columns: on a terminal, the line is cut to this width less one (default: the terminal's width).
    """

    def __init__(
        self,
        label: str,
        total: float,
        unit: str = "",
        *,
        stream: TextIO | None = None,
        tty: bool | None = None,
        every_s: float = 5.0,
        step_percent: float = 25.0,
        redraw_s: float = 0.1,
        clock_s: Callable[[], float] = time.monotonic,
        columns: int | None = None,
    ) -> None:
        if total <= 0:
            raise ValueError(f"progress total must be > 0, got {total}")
        self.label = label
        self.total = float(total)
        self.unit = unit
        self.stream = sys.stderr if stream is None else stream
        self.tty = _is_terminal(self.stream) if tty is None else tty
        self.every_s = every_s
        self.step_percent = step_percent
        self.redraw_s = redraw_s
        self._clock_s = clock_s
        self.columns = columns
        self._started_s = clock_s()
        self._done = 0.0
        self._note = ""
        self._last_written_s = self._started_s
        self._last_step = 0
        self._written_done: float | None = None
        self._drawn_done = -1.0
        self._shown_width = 0
        self._closed = False

    def update(self, done: float, note: str | None = None) -> None:
        """``done`` units of ``total`` are done (absolute); ``note`` (if given) replaces the text after the times."""
        self._done = min(max(done, 0.0), self.total)
        if note is not None:
            self._note = note
        now_s = self._clock_s()
        if self.tty:
            finished = self._done >= self.total and self._drawn_done < self.total  # the end, drawn once
            if now_s - self._last_written_s >= self.redraw_s or finished:
                self._draw(now_s)
            return
        step = int(100 * self._done / self.total // self.step_percent) if self.step_percent > 0 else 0
        if now_s - self._last_written_s >= self.every_s or step > self._last_step:
            self._last_step = step
            self._write_line(now_s)

    @property
    def done(self) -> float:
        """The units done so far."""
        return self._done

    def advance(self, amount: float = 1.0, note: str | None = None) -> None:
        """``amount`` more units are done."""
        self.update(self._done + amount, note)

    def message(self, text: str) -> None:
        """Print ``text`` on stdout as its own line; on a terminal the bar is cleared first and redrawn after."""
        if self.tty and self._shown_width:
            self.stream.write("\r" + " " * self._shown_width + "\r")
            self.stream.flush()
            self._shown_width = 0
        print(text, flush=True)
        if self.tty and not self._closed:
            self._draw(self._clock_s())

    def close(self) -> None:
        """The last state of the progress, ended by a newline (once)."""
        if self._closed:
            return
        now_s = self._clock_s()
        if self.tty:
            self._draw(now_s)
            self.stream.write("\n")
            self.stream.flush()
        elif self._written_done != self._done:  # not the same line twice
            self._write_line(now_s)
        self._closed = True

    def _draw(self, now_s: float) -> None:
        line = progress_line(self.label, self._done, self.total, self.unit, now_s - self._started_s, self._note)
        columns = shutil.get_terminal_size().columns if self.columns is None else self.columns
        line = line[: columns - 1]  # a wrapped line could not be redrawn in place
        padding = " " * max(0, self._shown_width - len(line))  # the rest of a longer previous line
        self.stream.write("\r" + line + padding)
        self.stream.flush()
        self._shown_width = len(line)
        self._last_written_s = now_s
        self._drawn_done = self._done

    def _write_line(self, now_s: float) -> None:
        line = progress_line(
            self.label, self._done, self.total, self.unit, now_s - self._started_s, self._note, bar=False
        )
        self.stream.write(line + "\n")
        self.stream.flush()
        self._last_written_s = now_s
        self._written_done = self._done

    def __enter__(self) -> Progress:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def _is_terminal(stream: TextIO) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        return False

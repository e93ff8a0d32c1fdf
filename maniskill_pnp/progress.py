"""Progress bars for the package's long loops: tqdm on a terminal, whole lines in a log.

On a terminal :func:`progress_bar` is plain ``tqdm``. When its stream is not a terminal (``... > log 2>&1``, a
pipe, a CI job), it follows the usual convention for logs: no ``\\r`` redraws, but whole lines, each ending in
``\\n`` and without the bar's blocks: one when the loop starts, at most one per interval while it runs (60 s; set
``MANISKILL_PNP_PROGRESS_INTERVAL`` to a number of seconds) and one at the end, e.g.
``eval run: 45% 450/1000 [00:10<00:12, 43.2ep/s, grasp=0.81]``.
"""

from __future__ import annotations

import os
import sys
import warnings

from tqdm import tqdm

#: Environment variable: seconds between two progress lines in a log.
INTERVAL_ENV = "MANISKILL_PNP_PROGRESS_INTERVAL"
#: Seconds between two progress lines in a log unless :data:`INTERVAL_ENV` says otherwise.
DEFAULT_INTERVAL_S = 60.0


def log_interval() -> float:
    """Seconds between two progress lines in a log: :data:`INTERVAL_ENV`, else :data:`DEFAULT_INTERVAL_S` (with a
    warning when the variable is not a number >= 0)."""
    value = os.environ.get(INTERVAL_ENV, "").strip()
    if not value:
        return DEFAULT_INTERVAL_S
    try:
        seconds = float(value)
    except ValueError:
        seconds = -1.0
    if not seconds >= 0 or seconds == float("inf"):
        warnings.warn(f"{INTERVAL_ENV}={value!r} is not a number of seconds >= 0; using {DEFAULT_INTERVAL_S:g}",
                      stacklevel=3)
        return DEFAULT_INTERVAL_S
    return seconds


def _is_terminal(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError, OSError):  # no isatty, or a closed stream
        return False


class LogProgress(tqdm):
    """tqdm writing whole lines: the first display, then at most one per ``interval`` s, then the last one at
    :meth:`close` (whatever ``leave`` says). Nested bars' cursor moves and clears are left out."""

    def __init__(self, *args, interval: float = DEFAULT_INTERVAL_S, **kwargs):
        # Set before tqdm's __init__, whose first refresh displays the opening line.
        self._interval = interval
        self._last_line_t = None
        self._last_line = None  # (n, desc, postfix) of the last line after the opening one
        self._final = False
        kwargs.setdefault("ncols", 0)  # tqdm's bar-less meter: "desc: 45% 450/1000 [...]"
        kwargs["mininterval"] = kwargs["maxinterval"] = interval
        super().__init__(*args, **kwargs)

    def display(self, msg=None, pos=None):
        if msg is not None:  # tqdm clears a bar by displaying "": a log keeps its lines
            return False
        now = self._time()
        if not self._final and self._last_line_t is not None and now - self._last_line_t < self._interval:
            return False
        self._last_line = None if self._last_line_t is None else (self.n, self.desc, self.postfix)
        self._last_line_t = now
        self.fp.write(self.__str__() + "\n")
        getattr(self.fp, "flush", lambda: None)()
        return True

    def close(self):
        if getattr(self, "disable", True) or self._final:
            return super().close()
        self._final = True
        with self._lock:
            if self._last_line != (self.n, self.desc, self.postfix):  # else the last line already says it all
                self._ema_dt = lambda: None  # the last line shows the overall rate, as tqdm's own does
                self.display()
        self.leave = False  # the last line is written: tqdm's close only clears, which display() skips
        return super().close()

    def clear(self, nolock=False):
        pass

    def moveto(self, n):
        pass


def progress_bar(iterable=None, *, total=None, desc=None, unit="it", initial=0, **kwargs) -> tqdm:
    """A tqdm progress bar over ``iterable`` (or updated by hand up to ``total``) that writes whole lines when its
    stream (``file``, default ``sys.stderr``) is not a terminal (see the module docstring). Other keyword arguments
    go to tqdm."""
    args = dict(total=total, desc=desc, unit=unit, initial=initial, **kwargs)
    stream = kwargs.get("file") or sys.stderr
    if _is_terminal(stream):
        return tqdm(iterable, **args)
    return LogProgress(iterable, interval=log_interval(), **args)


__all__ = ["DEFAULT_INTERVAL_S", "INTERVAL_ENV", "LogProgress", "log_interval", "progress_bar"]

"""Progress that reads well on a terminal and in a log file.

On a TTY: a tqdm bar, with ``logging`` records and :meth:`write` lines printed above it (never
through it). Anywhere else (piped to a file, ``make demo > log``): no carriage returns, one plain
line every ``interval_s`` seconds and one at the end.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO


def _is_tty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


class LineProgress:
    """tqdm's ``update / set_postfix / write / close / n`` as plain periodic lines."""

    def __init__(self, total: int | None, desc: str = '', unit: str = 'it', initial: int = 0,
                 file: TextIO | None = None, interval_s: float = 5.0):
        self.total, self.desc, self.unit, self.n = total, desc, unit, initial
        self.file = file if file is not None else sys.stderr
        self.interval_s = interval_s
        self.postfix = ''
        self._start = self._last = time.monotonic()
        self._closed = False
        self._shown: int | None = None  # n at the last line

    def __enter__(self) -> 'LineProgress':
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def update(self, n: int = 1) -> None:
        self.n += n
        if time.monotonic() - self._last >= self.interval_s:
            self._line()

    def set_postfix(self, ordered_dict=None, **kwargs) -> None:
        items = dict(ordered_dict or {}, **kwargs)
        self.postfix = ', '.join(f'{k}={v}' for k, v in items.items())

    def write(self, text: str, file: TextIO | None = None) -> None:
        print(text, file=file or self.file, flush=True)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            if self._shown != self.n:
                self._line()

    def _line(self) -> None:
        self._last, self._shown = time.monotonic(), self.n
        elapsed = self._last - self._start
        of = f'/{self.total}' if self.total is not None else ''
        pct = f' ({100 * self.n / self.total:.0f} %)' if self.total else ''
        post = f' [{self.postfix}]' if self.postfix else ''
        self.write(f'{self.desc}: {self.n}{of} {self.unit}{pct} in {elapsed:.0f} s{post}')


def progress_bar(total: int | None, desc: str = '', unit: str = 'it', initial: int = 0,
                 file: TextIO | None = None, interval_s: float = 5.0, **tqdm_kwargs):
    """A tqdm bar on a TTY (logging redirected above it until ``close``), else a
    :class:`LineProgress`."""
    stream = file if file is not None else sys.stderr
    if not _is_tty(stream):
        return LineProgress(total, desc, unit, initial, stream, interval_s)
    from tqdm import tqdm
    from tqdm.contrib.logging import logging_redirect_tqdm

    class _Bar(tqdm):
        def close(self):
            try:
                super().close()
            finally:
                redirect = getattr(self, '_redirect', None)
                if redirect is not None:
                    self._redirect = None
                    redirect.__exit__(None, None, None)

    bar = _Bar(total=total, desc=desc, unit=unit, initial=initial, file=stream,
               dynamic_ncols=True, **tqdm_kwargs)
    bar._redirect = logging_redirect_tqdm()
    bar._redirect.__enter__()
    return bar

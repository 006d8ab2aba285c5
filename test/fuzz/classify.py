"""What one input's outcome counts as: ok, a clear error, an unclear one, a crash or a hang.

- ``ok``: accepted (and what came back passed the family's sanity check);
- ``clear_error``: the family's documented exception type, whose message names the file (or
  field) and says more than that;
- ``unclear_error``: a data-error exception type we do not document (``ValueError``,
  ``KeyError``, ...), or the documented type with an empty or uninformative message;
- ``accepted_bad``: accepted although the input must be refused (a pickled array) or the
  result breaks an invariant (NaN in what was returned);
- ``crash``: the process died, or an exception that signals a bug escaped (``AttributeError``,
  ``AssertionError``, ``RecursionError``, ``MemoryError``, ...);
- ``hang``: no outcome within the per-input timeout.
"""

from __future__ import annotations

import zipfile

CATEGORIES = ('ok', 'clear_error', 'unclear_error', 'accepted_bad', 'crash', 'hang')
FAILING = ('crash', 'hang', 'accepted_bad')

DATA_ERRORS = (ValueError, TypeError, LookupError, OSError, ArithmeticError, EOFError,
               UnicodeError, zipfile.BadZipFile)
"""Exceptions a parser may raise on bad data without a bug: unclear, not a crash."""

MIN_MESSAGE = 12
"""Characters a message must add to the name of the file or field it blames."""


def classify_exception(exc: BaseException, documented: tuple[type, ...], names: tuple[str, ...]
                       ) -> str:
    """The category of an exception raised on an input; ``names``: what the message must
    mention (the file's path or name), any one of them."""
    if isinstance(exc, (RecursionError, MemoryError)):
        return 'crash'
    if isinstance(exc, documented):
        message = str(exc)
        named = [n for n in names if n and n in message]
        if not names:
            return 'clear_error' if len(message) >= MIN_MESSAGE else 'unclear_error'
        if named and len(message) - max(len(n) for n in named) >= MIN_MESSAGE:
            return 'clear_error'
        return 'unclear_error'
    if isinstance(exc, DATA_ERRORS):
        return 'unclear_error'
    return 'crash'


def describe(exc: BaseException, limit: int = 300) -> str:
    """``Type: message`` cut to ``limit`` characters (for the report's examples)."""
    text = f'{type(exc).__name__}: {exc}'
    return text if len(text) <= limit else text[:limit] + '...'

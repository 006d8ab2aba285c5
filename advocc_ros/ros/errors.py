"""The services' status codes (``advocc_msgs/ErrorCodes``, MoveIt's values where one fits)."""

from __future__ import annotations

from advocc_msgs.msg import ErrorCodes

#: Codes of an Attack answer that carry usable boxes.
ATTACK_OK = (ErrorCodes.SUCCESS, ErrorCodes.PARTIAL)


def code_name(val: int) -> str:
    """``'SUCCESS'`` for ``ErrorCodes.SUCCESS``; the number as text for an unknown code."""
    for name in dir(ErrorCodes):
        if name.isupper() and getattr(ErrorCodes, name) == val:
            return name
    return str(val)


__all__ = ['ATTACK_OK', 'ErrorCodes', 'code_name']

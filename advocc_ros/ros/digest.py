"""A content digest of a ROS message, for recognising a request seen before.

Not the serialized bytes: Fast DDS's CDR leaves the terminator byte of an empty string
unwritten, so one message serialized twice may differ in that byte (measured on an
``Attack.Request`` whose ``goal_policy`` is ``''``).
"""

from __future__ import annotations

import array
import hashlib


def message_digest(msg) -> str:
    """SHA-256 over every field of ``msg``, nested messages and arrays included, in field
    order; numbers by their exact ``repr``, arrays by their raw bytes."""
    digest = hashlib.sha256()
    _feed(msg, digest)
    return digest.hexdigest()


def _feed(value, digest) -> None:
    if hasattr(value, 'get_fields_and_field_types'):
        digest.update(f'{type(value).__name__}{{'.encode())
        for name in value.get_fields_and_field_types():
            digest.update(f'{name}='.encode())
            _feed(getattr(value, name), digest)
        digest.update(b'}')
    elif isinstance(value, (bytes, bytearray)):
        digest.update(b'bytes%d:' % len(value) + bytes(value))
    elif isinstance(value, array.array) or hasattr(value, 'dtype'):  # numeric sequences
        data = value.tobytes()
        kind = value.typecode if isinstance(value, array.array) else str(value.dtype)
        digest.update(f'{kind}{len(data)}:'.encode() + data)
    elif isinstance(value, (list, tuple)):
        digest.update(b'list%d[' % len(value))
        for item in value:
            _feed(item, digest)
        digest.update(b']')
    else:  # str, int, float, bool: repr is exact and says the type
        digest.update(f'{value!r};'.encode())


__all__ = ['message_digest']

"""Values kept beside an object rather than on it: a filter's compiled kernel, a state's packed vector.

An equinox Module's pytree structure includes its ``__dict__`` (a key added to it changes the treedef, so that
``jit`` would trace again and ``tree_map`` over two states would fail): caches live here instead, keyed by the
object's identity and dropped with it.
"""

from __future__ import annotations

import weakref

_SIDE: dict[tuple[int, str], tuple[weakref.ref, object]] = {}


def get(obj, name: str):
    """The value kept beside ``obj`` under ``name``, or None."""
    entry = _SIDE.get((id(obj), name))
    return entry[1] if entry is not None and entry[0]() is obj else None


def put(obj, name: str, value) -> None:
    """Keep ``value`` beside ``obj`` under ``name`` until ``obj`` is collected."""
    key = (id(obj), name)
    _SIDE[key] = (weakref.ref(obj, lambda _, key=key: _SIDE.pop(key, None)), value)

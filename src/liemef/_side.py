"""Values kept beside an object rather than on it: a filter's compiled kernel, a state's packed vector.

An equinox Module's pytree structure includes its ``__dict__`` (a key added to it changes the treedef, so that
``jit`` would trace again and ``tree_map`` over two states would fail): caches live here instead, keyed by the
object's identity and checked against a weak reference to it (an identity can be reused once the object is
gone). Entries of collected objects are dropped in sweeps, whenever the table has doubled since the last one:
a weak reference with a callback would cost more than the online step's whole budget to create.
"""

from __future__ import annotations

import weakref

_SIDE: dict[tuple[int, str], tuple[weakref.ref, object]] = {}
_SWEEP_AT = [1024]


def get(obj, name: str):
    """The value kept beside ``obj`` under ``name``, or None."""
    entry = _SIDE.get((id(obj), name))
    return entry[1] if entry is not None and entry[0]() is obj else None


def put(obj, name: str, value) -> None:
    """Keep ``value`` beside ``obj`` under ``name`` while ``obj`` lives (dropped in a later sweep after)."""
    _SIDE[(id(obj), name)] = (weakref.ref(obj), value)
    if len(_SIDE) > _SWEEP_AT[0]:
        sweep()


def sweep() -> None:
    """Drop the entries of collected objects."""
    for key, entry in [(key, entry) for key, entry in list(_SIDE.items()) if entry[0]() is None]:
        if _SIDE.get(key) is entry:  # not replaced meanwhile by another thread's put at a reused identity
            _SIDE.pop(key, None)
    _SWEEP_AT[0] = max(1024, 2 * len(_SIDE))

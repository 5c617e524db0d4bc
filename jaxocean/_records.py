"""Settings records (NamedTuples of numbers, strings and tuples) to and from JSON.

* ``record_to_json(record) -> dict``: fields as JSON values, tuples as lists (nested).
* ``record_from_json(cls, data, what) -> cls``: lists back to tuples (nested); an unknown
  key is a ``ValueError`` naming it, the known fields and ``what`` the record describes.
* ``register_static(cls) -> cls``: the record class as a pytree node without leaves (the
  record is its static aux data), so that ``jax.jit(f)(..., record)`` takes it as static.

Used by :class:`jaxocean.io.dataset.SceneRanges` and :class:`jaxocean.nn.geometry.GeometryConfig`.
"""

from __future__ import annotations

import jax

__all__ = ["record_to_json", "record_from_json", "register_static"]


def _to_json(value):
    return [_to_json(v) for v in value] if isinstance(value, tuple) else value


def _from_json(value):
    return tuple(_from_json(v) for v in value) if isinstance(value, list) else value


def record_to_json(record) -> dict:
    return {k: _to_json(v) for k, v in record._asdict().items()}


def record_from_json(cls, data: dict, what: str):
    unknown = set(data) - set(cls._fields)
    if unknown:
        raise ValueError(f"unknown {what} field(s) {sorted(unknown)}; known: {list(cls._fields)}")
    return cls(**{k: _from_json(v) for k, v in data.items()})


def register_static(cls):
    jax.tree_util.register_pytree_node(cls, lambda record: ((), record), lambda record, _: record)
    return cls

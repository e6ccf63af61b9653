"""Parameter records built from the registry's field declarations, so that no record lists an effect's
parameters by hand.

Every registry entry declares the fields it sets (:class:`~.effect_spec.ChainField`); :mod:`.effects`
collects them over all entries and builds, with the functions here,

* the kernels' record (a named tuple of floats: numba reads its fields by name),
* the fit's record (a frozen dataclass; ``None`` marks an absent part of the car, e.g. no tires),
* the grid's structured dtype (one float column per field), and
* make-recording's record of concealed physics.
"""

from __future__ import annotations

import collections
import dataclasses
from collections.abc import Iterable

import numpy as np

from plm_highway.sim2real.physics.effect_spec import ChainField


def merged_fields(declared: Iterable[ChainField]) -> tuple[ChainField, ...]:
    """The declared fields in first-declared order, each once; a field declared twice must agree."""
    out: dict[str, ChainField] = {}
    for f in declared:
        known = out.setdefault(f.name, f)
        if known != f:
            raise ValueError(f"chain field {f.name!r} is declared twice, differently: {known} and {f}")
    return tuple(out.values())


def _home(cls: type, module: str) -> type:
    """Give a built class its importable name (pickling and numba's cache find it there)."""
    cls.__module__ = module
    return cls


def kernel_record(name: str, fields: tuple[ChainField, ...], module: str) -> type:
    """A named tuple of floats, one per field, defaulting to the kernels' neutral values (0.0 for absent)."""
    neutral = tuple(0.0 if f.neutral is None else float(f.neutral) for f in fields)
    return collections.namedtuple(name, [f.name for f in fields], defaults=neutral, module=module)


def structured_dtype(fields: tuple[ChainField, ...]) -> np.dtype:
    """One float64 column per field (a grid of parameter sets is an array of this dtype)."""
    return np.dtype([(f.name, np.float64) for f in fields])


def _as_kernel(value: float | None) -> float:
    return 0.0 if value is None else float(value)


def fit_record(name: str, fields: tuple[ChainField, ...], kernel: type, module: str, doc: str) -> type:
    """A frozen dataclass of the fields with ``chain()`` (its kernel record) and ``from_chain``.

    A field with ``absent_unless`` is None here while that kernel field is not positive, 0.0 there.
    """

    def chain(self):
        """The same parameters as the kernels take them."""
        return kernel(*(_as_kernel(getattr(self, f.name)) for f in fields))

    def from_chain(cls, p):
        values = {}
        for f in fields:
            value = float(getattr(p, f.name))
            absent = f.absent_unless is not None and not getattr(p, f.absent_unless) > 0
            values[f.name] = None if absent else value
        return cls(**values)

    spec = [(f.name, float | None if f.absent_unless else float,
             dataclasses.field(default=None if f.absent_unless else f.neutral)) for f in fields]
    cls = dataclasses.make_dataclass(name, spec, frozen=True,
                                     namespace={"chain": chain, "from_chain": classmethod(from_chain), "__doc__": doc})
    return _home(cls, module)


def plain_record(name: str, fields: tuple[ChainField, ...], module: str, doc: str) -> type:
    """A frozen dataclass of the fields at their neutral values."""
    spec = [(f.name, float | None, dataclasses.field(default=f.neutral)) for f in fields]
    return _home(dataclasses.make_dataclass(name, spec, frozen=True, namespace={"__doc__": doc}), module)

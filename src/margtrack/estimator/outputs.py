"""The per-sample outputs of an ``Estimate`` (``Estimate.outputs``), some computed on first read.

An :class:`Outputs` is a mutable mapping name -> array like a dict; a value may be given
as a *deferred* one, a function of no arguments that computes it. It is called the first
time the value is read (``outputs[name]``, ``get``, ``items``, ``values``, a copy or a
pickle), its result kept and returned from then on. Names, ``in`` and ``len`` never
compute anything. So a method can leave series that are pure functions of its output
orientations (Euler angles, gravity and linear acceleration of the gradient filter) out of
its hot loop: ``run`` pays for them only when they are read, and then gets the values the
loop would have written (the same compiled formulas on the same numbers).

A deferred value is computed from the arrays its function holds (for the compiled methods:
the estimate's ``quat`` as returned, and what the kernel kept per sample): change
``Estimate.quat`` in place only after reading the outputs that depend on it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator, Mapping, MutableMapping
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from margtrack.estimator.estimate import Estimate

__all__ = ["Deferred", "Outputs", "with_output_types"]

Value = NDArray[Any]


class Deferred:
    """A value to compute when first read: ``compute()`` returns the array."""

    __slots__ = ("compute",)

    def __init__(self, compute: Callable[[], Value]) -> None:
        self.compute = compute


class Outputs(MutableMapping[str, Value]):
    """Named per-sample series, each an array or a :class:`Deferred` computed on first read.

    ``Outputs({"a": x, "b": Deferred(f)})``: ``outputs["b"]`` calls ``f()`` once and keeps
    the result. Iteration follows the given order. Pickling and copying compute every
    deferred value (the result holds plain arrays).
    """

    def __init__(self, values: Mapping[str, Value | Deferred] | None = None) -> None:
        # another Outputs: its deferred values stay deferred
        source = values._values if isinstance(values, Outputs) else values
        self._values: dict[str, Value | Deferred] = dict(source or {})

    def __getitem__(self, name: str) -> Value:
        value = self._values[name]
        if isinstance(value, Deferred):
            value = self._values[name] = value.compute()
        return value

    def __setitem__(self, name: str, value: Value | Deferred) -> None:
        self._values[name] = value

    def __delitem__(self, name: str) -> None:
        del self._values[name]

    def __contains__(self, name: object) -> bool:
        return name in self._values

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def pending(self) -> list[str]:
        """Names whose values have not been computed yet."""
        return [k for k, v in self._values.items() if isinstance(v, Deferred)]

    def mapped(self, func: Callable[[str, Value], Value]) -> Outputs:
        """A new mapping with ``func(name, value)`` for every value, deferred where the value
        is (``func`` runs when that value is first read from the new mapping)."""
        out: dict[str, Value | Deferred] = {}
        for name, value in self._values.items():
            if isinstance(value, Deferred):
                out[name] = Deferred(_compose(func, name, value))
            else:
                out[name] = func(name, value)
        return Outputs(out)

    def __reduce__(self) -> tuple[Any, ...]:
        return (Outputs, ({k: self[k] for k in self._values},))

    def __repr__(self) -> str:
        parts = [
            f"{k}: (deferred)" if isinstance(v, Deferred) else f"{k}: {_describe(v)}"
            for k, v in self._values.items()
        ]
        return "Outputs({" + ", ".join(parts) + "})"


def _compose(
    func: Callable[[str, Value], Value], name: str, value: Deferred
) -> Callable[[], Value]:
    return lambda: func(name, value.compute())


def _describe(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return f"array{value.shape} {value.dtype}"
    return type(value).__name__


def with_output_types(est: Estimate, types: Mapping[str, Any]) -> Estimate:
    """The estimate with the named outputs as before the compiled path: width-1 series
    squeezed to (…, N) and converted to the given type (None: kept float).

    A conversion is made when its output is first read (``Outputs``' deferred values): it
    reads a strided column of all the kernel's outputs, 5 ms per output of 1000 sensors x
    1000 samples (a sixth of Bachmann's ``run``), which most callers never read.
    """
    outputs = Outputs(est.outputs)
    for name, dtype in types.items():
        outputs[name] = Deferred(partial(_typed, est.outputs, name, dtype))
    return dataclasses.replace(est, outputs=outputs)


def _typed(outputs: Mapping[str, Any], name: str, dtype: Any) -> NDArray[Any]:
    value = outputs[name][..., 0]
    return value if dtype is None else value.astype(dtype)

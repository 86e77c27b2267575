"""Input checks shared by the API: dtype, rank, finiteness, and keyword options → settings."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

# float32 represents every integer up to 2**24 exactly: larger integer samples would lose digits.
_FLOAT32_EXACT = 2**24


def _named(name: str, axes: Sequence[str]) -> str:
    return f"{name} ({', '.join(axes)})"


def real32(name: str, values: Any, axes: Sequence[str]) -> np.ndarray:
    """`values` as a C-contiguous float32 array with len(axes) dimensions, or ValueError.

    Integers (int16 scanners) and float64 are cast; complex input is refused (dropping the
    imaginary part would be silent truncation)."""
    array = np.asarray(values)
    if array.dtype.kind == "c":
        raise ValueError(
            f"{_named(name, axes)}: complex samples (dtype {array.dtype}) where real RF is expected"
        )
    if array.dtype.kind not in "iuf":
        raise ValueError(f"{_named(name, axes)}: dtype {array.dtype} is not numeric")
    _check_rank(name, array, axes)
    if array.dtype.kind in "iu" and array.size and np.abs(array).max() > _FLOAT32_EXACT:
        raise ValueError(
            f"{name}: integer samples beyond ±2**24 would lose digits as float32; scale them first"
        )
    if array.dtype.kind == "f" and not np.isfinite(array).all():
        raise ValueError(f"{name}: the samples hold NaN or Inf")
    return np.ascontiguousarray(array, dtype=np.float32)


def complex64(name: str, values: Any, axes: Sequence[str]) -> np.ndarray:
    """`values` as a C-contiguous complex64 array with len(axes) dimensions, or ValueError.

    Real input is taken as complex with zero imaginary part."""
    array = np.asarray(values)
    if array.dtype.kind not in "iufc":
        raise ValueError(f"{_named(name, axes)}: dtype {array.dtype} is not numeric")
    _check_rank(name, array, axes)
    if not np.isfinite(array).all():
        raise ValueError(f"{name}: the samples hold NaN or Inf")
    return np.ascontiguousarray(array, dtype=np.complex64)


def float64(name: str, values: Any, axes: Sequence[str]) -> np.ndarray:
    """`values` as a C-contiguous float64 array with len(axes) dimensions (NaN allowed)."""
    array = np.asarray(values)
    if array.dtype.kind not in "iuf":
        raise ValueError(f"{_named(name, axes)}: dtype {array.dtype} is not real numeric")
    _check_rank(name, array, axes)
    return np.ascontiguousarray(array, dtype=np.float64)


def _check_rank(name: str, array: np.ndarray, axes: Sequence[str]) -> None:
    if array.ndim != len(axes):
        raise ValueError(
            f"{_named(name, axes)}: expected {len(axes)} dimensions, got shape {array.shape}"
        )
    if array.size == 0:
        raise ValueError(f"{_named(name, axes)}: the array is empty (shape {array.shape})")


def reorder(
    name: str, array: np.ndarray, axes: Sequence[str], canonical: Sequence[str]
) -> np.ndarray:
    """`array`, whose axes are named `axes`, transposed to the `canonical` order."""
    if sorted(axes) != sorted(canonical) or len(set(axes)) != len(axes):
        raise ValueError(
            f"{name}: axes {tuple(axes)} must name each of {tuple(canonical)} once"
        )
    if array.ndim != len(axes):
        raise ValueError(
            f"{name} ({', '.join(axes)}): expected {len(axes)} dimensions, got shape {array.shape}"
        )
    return np.transpose(array, [list(axes).index(a) for a in canonical])


def whole_number(name: str, value: Any, minimum: int = 1) -> int:
    """`value` as a whole number ≥ `minimum` that the native half holds (below 2⁶³), or
    ValueError naming it (not OverflowError, nor a bare int() message)."""
    need = f"{name}: expected a whole number ≥ {minimum}, got {value!r}"
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)):
        raise ValueError(need)
    if isinstance(value, (float, np.floating)) and not (np.isfinite(value) and value == int(value)):
        raise ValueError(need)
    if not minimum <= int(value) < 2**63:
        raise ValueError(need)
    return int(value)


def finite_number(name: str, value: Any, positive: bool = True) -> float:
    """`value` as a finite float (positive when asked), or ValueError naming it."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number, got {value!r}") from None
    if not np.isfinite(number) or (positive and number <= 0):
        need = "a finite number > 0" if positive else "a finite number"
        raise ValueError(f"{name}: expected {need}, got {value!r}")
    return number


def to_options(function: str, options: Mapping[str, Any], known: Iterable[str]) -> str:
    """Keyword options as the JSON object the native half reads into its settings (`None`
    values dropped: the default); an unknown keyword is a TypeError that lists the known ones."""
    known = set(known)
    given = {}
    for key, value in options.items():
        if key not in known:
            valid = ", ".join(sorted(known))
            raise TypeError(f"{function}() got an unexpected keyword {key!r}; valid: {valid}")
        if value is None:
            continue
        if isinstance(value, bool):
            raise TypeError(f"{function}(): {key} takes a value, not {value!r}")
        given[key] = _plain(value)
    return finite_json(given)


def finite_json(values: Mapping[str, Any]) -> str:
    """Plain keyword values as a JSON object; a number that is not finite (JSON has none) is a
    ValueError naming its keyword, where the native half could only say where its parse failed."""

    def numbers(value: Any) -> Iterable[Any]:
        if isinstance(value, list):
            for v in value:
                yield from numbers(v)
        else:
            yield value

    for key, value in values.items():
        if any(isinstance(v, float) and not math.isfinite(v) for v in numbers(value)):
            raise ValueError(f"{key}: expected finite numbers, got {value!r}")
    return json.dumps(values)


def _plain(value: Any) -> Any:
    """`value` as JSON holds it: numpy scalars and arrays as numbers and lists, paths as text."""
    if isinstance(value, (str, int, float)):
        return value
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Iterable):
        return [_plain(v) for v in value]
    return value

"""A user's arguments as the compiled core takes them: real numbers as
``float``, array-likes as float64 arrays. Each refusal names the argument
first (``"Q: expected real numbers (int or float), got an array of
complex128"``); shapes and values are the core's to check (it names them
too). Nothing is cast silently: bools, complex numbers, strings and other
objects are a ``TypeError``.
"""

from __future__ import annotations

from typing import Any, cast

import numpy as np
import numpy.typing as npt


def real(value: object, name: str) -> float:
    """``value`` as a float: an int, a float or a numpy real scalar."""
    kind = type(value)
    numeric = hasattr(kind, "__float__") or hasattr(kind, "__index__")
    if numeric and not issubclass(kind, (bool, np.bool_, complex, np.complexfloating)):
        try:
            return float(value)  # type: ignore[arg-type]
        except (TypeError, ValueError, OverflowError):
            pass
    raise TypeError(f"{name}: expected a real number, got {kind.__name__}")


def real_array(value: object, name: str) -> npt.NDArray[np.float64]:
    """``value`` as a float64 array: as it is, or what ``numpy.asarray``
    reads as integers or floats (nested lists, float32, Fortran order)."""
    if isinstance(value, np.ndarray) and cast("np.ndarray[Any, Any]", value).dtype == np.float64:
        return cast("npt.NDArray[np.float64]", value)
    got = type(value).__name__
    try:
        array = np.asarray(value)
    except (TypeError, ValueError) as e:  # ragged nested lists
        raise ValueError(f"{name}: expected an array of real numbers, cannot read this {got} as one ({e})") from None
    if array.dtype.kind not in "fiu":
        what = got if array.dtype.kind == "O" else f"an array of {array.dtype}"
        raise TypeError(f"{name}: expected real numbers (int or float), got {what}")
    return array.astype(np.float64)

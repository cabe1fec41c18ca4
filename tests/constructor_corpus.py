"""A corpus of bad arguments for every constructor the binding exposes.

For each constructor (the three estimators, ``Plant``, the Riccati helpers
``lqr`` / ``care`` / ``dare`` / ``agent_gains``), every argument gets every
bad value of its kind
(wrong shapes, NaN and infinities, negative variances, indefinite and
asymmetric matrices, values that make a step overflow, wrong types), alone
and in pairs with another argument's bad values. Each case must raise a
``TypeError`` or ``ValueError`` whose message starts with the name of a bad
argument (``"Q: ..."``, or ``"(A, B): ..."`` for a property of two), never
be accepted silently, and never raise anything else.

The package's classes and functions take any array-like and real number
(``sensaug._args`` converts them); ``sensaug._core``'s take typed arguments
only (float, float64 arrays; anything else is pyo3's own ``TypeError``) and
every keyword is required. So the ``_core.*`` constructors get the typed bad
values only (wrong shapes, NaN and infinities, values out of range), each
named as the package names it, with the schema's defaults for the keywords
the package fills in (``_core``'s estimators name the step ``dt_s``).

``tests/test_constructor_errors.py`` asserts it; run this file to count
(``python tests/constructor_corpus.py``): how many cases raise an error, how
many of those errors name the argument, and how many bad inputs were
accepted.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

import sensaug
from sensaug import _core
from sensaug.config_types import ChannelConfig, PlantConfig, SigmaConfig, WorldConfig

NAN, INF = math.nan, math.inf


@dataclass(frozen=True)
class Case:
    """One call: ``ctor(**kwargs)`` with the named arguments bad."""

    ctor: str
    kwargs: dict[str, Any]
    bad: tuple[str, ...]
    what: str


# --- bad values by kind ------------------------------------------------------

_WRONG_TYPES: list[tuple[str, Any]] = [
    ("a str", "1.0"),
    ("a dict", {}),
    ("an object", object()),
    ("a complex", 1 + 1j),
    ("a bool", True),
]


def scalar_bad(kind: str, *, required: bool, extremes: tuple[float, ...] = ()) -> list[tuple[str, Any]]:
    """``kind``: "pos" (> 0), "nonneg" (>= 0) or "finite"."""
    out = [("NaN", NAN), ("inf", INF), ("-inf", -INF), ("a list", [1.0]), *_WRONG_TYPES]
    if kind in ("pos", "nonneg"):
        out.append(("negative", -1.0))
    if kind == "pos":
        out.append(("zero", 0.0))
    if required:
        out.append(("None", None))
    out += [(f"extreme {v:g}", v) for v in extremes]
    return out


def vector_bad(n: int) -> list[tuple[str, Any]]:
    def with_entry(v: float) -> np.ndarray:
        a = np.zeros(n)
        a[-1] = v
        return a

    return [
        ("too short", np.zeros(n - 1)),
        ("too long", np.zeros(n + 1)),
        ("2-D", np.zeros((1, n))),
        ("a scalar", 0.0),
        ("a NaN entry", with_entry(NAN)),
        ("an inf entry", with_entry(INF)),
        ("a -inf entry", with_entry(-INF)),
        ("strings", ["a"] * n),
        ("None", None),
        ("complex", np.zeros(n, dtype=complex)),
        ("bools", np.zeros(n, dtype=bool)),
        ("ragged", [[0.0], [0.0, 1.0]]),
        ("a dict", {}),
        ("objects", np.array([object()] * n)),
    ]


def matrix_bad(rows: int, cols: int) -> list[tuple[str, Any]]:
    """Shapes and types for any ``rows x cols`` matrix argument."""

    def with_entry(v: float) -> np.ndarray:
        a = np.eye(rows, cols)
        a[-1, -1] = v
        return a

    return [
        ("1-D", np.ones(rows * cols)),
        ("one row short", np.eye(rows + 1, cols)[: rows - 1] if rows > 1 else np.ones((2, cols))),
        ("too many columns", np.eye(rows, max(rows, cols) + 1)),
        ("one size larger", np.eye(rows + 1, cols + 1)),
        ("3-D", np.eye(rows, cols)[None]),
        ("a scalar", 1.0),
        ("a NaN entry", with_entry(NAN)),
        ("an inf entry", with_entry(INF)),
        ("a -inf entry", with_entry(-INF)),
        ("strings", [["a"] * cols] * rows),
        ("None", None),
        ("complex", np.eye(rows, cols, dtype=complex)),
        ("bools", np.eye(rows, cols, dtype=bool)),
        ("ragged", [[1.0], [0.0, 1.0]]),
        ("a dict", {}),
        ("objects", np.array([object()] * (rows * cols)).reshape(rows, cols)),
    ]


def covariance_bad(n: int, *, definite: bool) -> list[tuple[str, Any]]:
    """``matrix_bad`` plus the values a covariance must not have: a negative
    variance, an indefinite or asymmetric matrix, and (``definite``) a
    singular one."""
    neg = np.eye(n)
    neg[0, 0] = -1.0
    out = matrix_bad(n, n) + [("a negative variance", neg), ("negated", -np.eye(n))]
    if n >= 2:
        indefinite = np.eye(n)
        indefinite[0, 1] = indefinite[1, 0] = 2.0  # eigenvalues 3 and -1
        asymmetric = np.eye(n)
        asymmetric[0, 1] = 0.5
        out += [("indefinite", indefinite), ("asymmetric", asymmetric)]
    if definite:
        out.append(("singular", np.zeros((n, n))))
    return out


# --- the constructors ----------------------------------------------------------


@dataclass(frozen=True)
class Ctor:
    name: str
    call: Callable[..., Any]
    good: dict[str, Any]
    bad: dict[str, list[tuple[str, Any]]]


M = 0.0035
_SIGMA = {
    "alpha": scalar_bad("pos", required=False, extremes=(1e-200, 1e200)),
    "beta": scalar_bad("finite", required=False),
    "kappa": scalar_bad("finite", required=False, extremes=(-6.0, -100.0)),
}
_MODEL = {
    "mass": scalar_bad("pos", required=True, extremes=(1e-320,)),
    "damping": scalar_bad("nonneg", required=False),
    "dt": scalar_bad("pos", required=False, extremes=(1e200,)),
}


def _extended(cls: type, m: int) -> Ctor:
    return Ctor(
        cls.__name__,
        cls,
        dict(mass=M, Q=1e-2 * np.eye(6), R=1e-7 * np.eye(m), x0=np.zeros(6), P0=np.eye(6)),
        {
            **_MODEL,
            "Q": covariance_bad(6, definite=False),
            "R": covariance_bad(m, definite=False),
            "x0": vector_bad(6),
            "P0": covariance_bad(6, definite=True),
            **_SIGMA,
        },
    )


_GOOD_LQR = dict(
    A=np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]),
    B=np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]),
    Q=np.eye(3),
    R=np.eye(2),
)
_BAD_LQR = {
    "A": matrix_bad(3, 3),
    "B": matrix_bad(3, 2),
    "Q": covariance_bad(3, definite=False),
    "R": covariance_bad(2, definite=True),
}
_AGENT = dict(mass=1.0, damping=0.0, q_pos=1.0, q_vel=0.0)
_BAD_AGENT = {
    "mass": scalar_bad("pos", required=True, extremes=(1e-320,)),
    "damping": scalar_bad("nonneg", required=True),
    "q_pos": scalar_bad("pos", required=True),
    "q_vel": scalar_bad("nonneg", required=True),
}

_PACKAGE: list[Ctor] = [
    _extended(sensaug.GainEstimator, 3),
    _extended(sensaug.TrajectoryEstimator, 5),
    Ctor(
        "GoalIntegrator",
        sensaug.GoalIntegrator,
        dict(mass=M, Q=1e-2 * np.eye(2), R=np.diag([1e-4, 1e-7]), x0=np.zeros(2), P0=np.eye(2)),
        {
            **_MODEL,
            "Q": covariance_bad(2, definite=False),
            "R": covariance_bad(2, definite=False),
            "x0": vector_bad(2),
            "P0": covariance_bad(2, definite=True),
            "gate": scalar_bad("pos", required=False),
            "window_n0": scalar_bad("pos", required=False),
            "hold_max_s": scalar_bad("pos", required=False),
        },
    ),
    Ctor(
        "Plant",
        sensaug.Plant,
        dict(mass=M),
        {
            "mass": scalar_bad("pos", required=True, extremes=(1e-320, 1e-310)),
            "damping": scalar_bad("nonneg", required=False),
            "coulomb": scalar_bad("nonneg", required=False, extremes=(1e308,)),
            "dt_s": scalar_bad("pos", required=False, extremes=(1e200,)),
            "x0": scalar_bad("finite", required=False),
            "v0": scalar_bad("finite", required=False),
        },
    ),
    Ctor("lqr", sensaug.lqr, _GOOD_LQR, _BAD_LQR),
    Ctor("care", sensaug.care, _GOOD_LQR, _BAD_LQR),
    Ctor("dare", sensaug.dare, {**_GOOD_LQR, "A": 0.5 * np.eye(3)}, _BAD_LQR),
    Ctor("agent_gains", sensaug.agent_gains, _AGENT, _BAD_AGENT),
]


def _typed(v: Any, good: Any, matrices: bool) -> bool:
    """What ``_core`` takes where ``good`` goes: a float, or a float64 array
    (not a bool, list, str, ...); with ``matrices`` (``_core.lqr``), a 2-D one."""
    if isinstance(good, np.ndarray):
        return isinstance(v, np.ndarray) and v.dtype == np.float64 and (v.ndim == 2 or not matrices)
    return type(v) is float


def _core_ctor(ctor: Ctor, call: Callable[..., Any], defaults: dict[str, float], matrices: bool = False) -> Ctor:
    """``ctor``'s compiled counterpart: every keyword given (``defaults``),
    ``dt`` spelled ``dt_s``, only typed bad values."""
    spelled = {"dt": "dt_s"}
    good = {spelled.get(k, k): v for k, v in {**defaults, **ctor.good}.items()}
    typed = {k: [(w, v) for w, v in vs if _typed(v, good[spelled.get(k, k)], matrices)] for k, vs in ctor.bad.items()}
    bad = {spelled.get(k, k): vs for k, vs in typed.items()}
    return Ctor(f"_core.{ctor.name}", call, good, bad)


_P, _S, _C, _W = PlantConfig(), SigmaConfig(), ChannelConfig(), WorldConfig()
_ESTIMATOR = dict(damping=_P.damping, dt=_P.dt_s)
_EXTENDED = dict(_ESTIMATOR, alpha=_S.alpha, beta=_S.beta, kappa=_S.kappa)
_by_name = {c.name: c for c in _PACKAGE}
CONSTRUCTORS: list[Ctor] = _PACKAGE + [
    _core_ctor(_by_name["GainEstimator"], _core.GainEstimator, _EXTENDED),
    _core_ctor(_by_name["TrajectoryEstimator"], _core.TrajectoryEstimator, _EXTENDED),
    _core_ctor(
        _by_name["GoalIntegrator"], _core.GoalIntegrator, dict(_ESTIMATOR, gate=_C.gate, window_n0=_C.window_n0, hold_max_s=_C.hold_max_s)
    ),
    _core_ctor(_by_name["Plant"], _core.Plant, dict(damping=_P.damping, coulomb=_P.coulomb, dt_s=_P.dt_s, x0=_W.x0, v0=_W.v0)),
    _core_ctor(_by_name["lqr"], lambda A, B, Q, R: _core.lqr(A, B, Q, R, discrete=False), {}, matrices=True),
    _core_ctor(_by_name["agent_gains"], _core.agent_gains, {}),
]

#: Bad values of each argument also tried together with another argument's.
PAIRED = 4


def cases(ctor: Ctor) -> Iterator[Case]:
    """Every argument's every bad value alone, then every pair of arguments
    with the first :data:`PAIRED` bad values of each."""
    for arg, values in ctor.bad.items():
        for what, v in values:
            yield Case(ctor.name, {**ctor.good, arg: v}, (arg,), f"{arg} {what}")
    for (a, va), (b, vb) in itertools.combinations(ctor.bad.items(), 2):
        for (wa, x), (wb, y) in itertools.product(va[:PAIRED], vb[:PAIRED]):
            yield Case(ctor.name, {**ctor.good, a: x, b: y}, (a, b), f"{a} {wa}, {b} {wb}")


def named(message: str) -> set[str]:
    """The arguments a message names first: ``"Q: ..."`` -> {Q},
    ``"(A, B): ..."`` -> {A, B}."""
    head = message.split(":", 1)[0] if ":" in message else ""
    return {part.strip() for part in head.strip("()").split(",")}


def outcome(ctor: Ctor, case: Case) -> tuple[str, str]:
    """``("names", msg)``, ``("unnamed", msg)``, ``("accepted", "")`` or
    ``("wrong type", msg)`` for an exception other than TypeError/ValueError."""
    try:
        ctor.call(**case.kwargs)
    except (TypeError, ValueError) as e:
        msg = str(e)
        return ("names" if named(msg) & set(case.bad) else "unnamed"), f"{type(e).__name__}: {msg}"
    except Exception as e:  # noqa: BLE001 - counted, and the test fails on it
        return "wrong type", f"{type(e).__name__}: {e}"
    return "accepted", ""


def main() -> None:
    import warnings

    warnings.simplefilter("ignore")
    totals: dict[str, int] = {}
    for ctor in CONSTRUCTORS:
        counts: dict[str, int] = {}
        examples: dict[str, str] = {}
        for case in cases(ctor):
            kind, msg = outcome(ctor, case)
            counts[kind] = counts.get(kind, 0) + 1
            examples.setdefault(kind, f"{case.what} -> {msg[:110]}")
            totals[kind] = totals.get(kind, 0) + 1
        print(f"{ctor.name}: {counts}")
        for kind in ("unnamed", "accepted", "wrong type"):
            if kind in examples:
                print(f"    e.g. {kind}: {examples[kind]}")
    errors = totals.get("names", 0) + totals.get("unnamed", 0) + totals.get("wrong type", 0)
    print(
        f"\n{sum(totals.values())} cases: {errors} raised, {totals.get('names', 0)} of them name the argument, "
        f"{totals.get('unnamed', 0)} do not, {totals.get('wrong type', 0)} are neither TypeError nor ValueError; "
        f"{totals.get('accepted', 0)} bad inputs accepted"
    )


if __name__ == "__main__":
    main()

"""Every constructor error names the argument (tests/constructor_corpus.py).

The corpus gives each argument of the estimators, ``Plant`` and the Riccati
helpers every bad value of its kind, alone and in pairs; each call must
raise a ``TypeError`` or ``ValueError`` whose message starts with a bad
argument's name. Array arguments take any array-like of real numbers, and
the conversion gives the very filter a float64 array gives.
"""

from __future__ import annotations

import inspect
import warnings

import numpy as np
import pytest

import sensaug
from constructor_corpus import CONSTRUCTORS, Ctor, cases, named, outcome


@pytest.mark.parametrize("ctor", CONSTRUCTORS, ids=lambda c: c.name)
def test_every_bad_argument_is_refused_naming_it(ctor: Ctor) -> None:
    failures = []
    n = 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # e.g. numpy's ComplexWarning: nothing is silently cast
        for case in cases(ctor):
            n += 1
            kind, msg = outcome(ctor, case)
            if kind != "names":
                failures.append(f"{case.what}: {kind} {msg}")
    assert n > 100
    assert not failures, f"{len(failures)} of {n} cases:\n" + "\n".join(failures[:20])


@pytest.mark.parametrize("ctor", CONSTRUCTORS, ids=lambda c: c.name)
def test_wrong_types_are_type_errors(ctor: Ctor) -> None:
    """A str, dict, object, complex or bool where a number goes is a TypeError."""
    for arg, values in ctor.bad.items():
        for what, v in values:
            if what not in ("a str", "a dict", "an object", "a complex", "a bool", "strings", "complex", "bools", "objects"):
                continue
            with pytest.raises(TypeError, match=f"^{arg}: expected (a )?real number"):
                ctor.call(**{**ctor.good, arg: v})


def test_names_reads_the_leading_arguments() -> None:
    assert named("Q: must be symmetric") == {"Q"}
    assert named("(A, B): not stabilisable") == {"A", "B"}
    assert named("must be real number, not str") == {""}


KW6 = dict(mass=0.0035, Q=1e-2 * np.eye(6), R=1e-7 * np.eye(3), x0=np.zeros(6), P0=np.eye(6))


@pytest.mark.parametrize(
    "convert",
    [
        lambda a: a.tolist(),  # nested lists
        lambda a: a.astype(np.float32) if a.dtype == np.float64 and np.all(a == a.astype(np.float32)) else a,
        lambda a: np.asfortranarray(a),
    ],
    ids=["lists", "float32 where exact", "fortran order"],
)
def test_array_likes_give_the_same_filter(convert) -> None:
    ref = sensaug.GainEstimator(**KW6)
    est = sensaug.GainEstimator(**{k: convert(v) if isinstance(v, np.ndarray) else v for k, v in KW6.items()})
    y = np.array([0.01, -0.02, 0.005])
    for e in (ref, est):
        e.update(y)
        e.predict(0.1, 0.0, 0.0)
    np.testing.assert_array_equal(est.x, ref.x)
    np.testing.assert_array_equal(est.P, ref.P)


def test_integer_and_zero_variance_covariances_are_accepted() -> None:
    """Ints convert; a zero variance is a valid (positive semidefinite) noise."""
    sensaug.GoalIntegrator(mass=1, Q=[[1, 0], [0, 0]], R=[[1, 0], [0, 0]], x0=[0, 0], P0=[[1, 0], [0, 1]])
    sensaug.Plant(mass=2, dt_s=1)


def test_defaults_are_the_documented_ones() -> None:
    """The optional keywords default to the signature's values."""
    shown = {n: p.default for n, p in inspect.signature(sensaug.GainEstimator).parameters.items()}
    assert shown == {**dict.fromkeys(["mass", "Q", "R", "x0", "P0"], inspect.Parameter.empty),
                     "damping": 0.0, "dt": 1e-3, "alpha": 1.0, "beta": 2.0, "kappa": 0.0}  # fmt: skip
    a = sensaug.GainEstimator(**KW6)
    b = sensaug.GainEstimator(**KW6, damping=0.0, dt=1e-3, alpha=1.0, beta=2.0, kappa=0.0)
    for e in (a, b):
        e.update(np.array([0.01, -0.02, 0.005]))
        e.predict(0.1, 0.0, 0.0)
    np.testing.assert_array_equal(a.P, b.P)
    p = sensaug.Plant(mass=1.0)
    assert p.step(1.0) == sensaug.Plant(mass=1.0, damping=0.0, coulomb=0.0, dt_s=1e-3, x0=0.0, v0=0.0).step(1.0)


@pytest.mark.parametrize("cls", [sensaug.GainEstimator, sensaug.TrajectoryEstimator, sensaug.GoalIntegrator, sensaug.Plant])
def test_the_compiled_classes_take_typed_required_arguments_only(cls) -> None:
    """``sensaug._core``'s constructors have no defaults of their own (every
    keyword required) and take floats and float64 arrays only: a list is
    pyo3's ``TypeError`` (the package's classes convert it)."""
    core = cls.__mro__[[c.__module__ for c in cls.__mro__].index("sensaug._core")]
    with pytest.raises(TypeError, match="missing"):
        core(mass=0.0035)
    if cls is not sensaug.Plant:
        kw = dict(KW6, damping=0.0, dt_s=1e-3, alpha=1.0, beta=2.0, kappa=0.0)
        if cls is sensaug.GoalIntegrator:
            kw = dict(mass=0.0035, Q=np.eye(2), R=np.eye(2), x0=np.zeros(2), P0=np.eye(2), damping=0.0, dt_s=1e-3,
                      gate=4.0, window_n0=80.0, hold_max_s=0.25)  # fmt: skip
        if cls is sensaug.TrajectoryEstimator:
            kw["R"] = np.eye(5)
        core(**kw)
        with pytest.raises(TypeError, match="'Q'"):
            core(**{**kw, "Q": kw["Q"].tolist()})

"""Riccati / LQR: sensaug against scipy and python-control.

Random systems (``_random_system``) are drawn reproducibly from
``numpy.random.default_rng(seed)``, 1000 per state count n = 1..6, for both
the CARE and the DARE:

* ``A = N(0, 1)^{n x n} / sqrt(n)`` (spectral radius about 1: in continuous
  time roughly half the modes are unstable, in discrete time a few are),
* ``m`` uniform in ``1..min(n, 3)``, ``B = N(0, 1)^{n x m}``,
* ``Q = C'C`` with ``C = N(0, 1)^{p x n}``, ``p`` uniform in ``1..n``, so ``Q``
  is often singular; half the draws add ``1e-2 I``,
* ``R = L L' + 0.1 I`` with ``L = N(0, 1)^{m x m}``.

Well-posedness is enforced, not hoped for: a draw is rejected and redrawn
when some unstable or near-marginal eigenvalue of ``A`` (continuous
``Re >= -0.05``, discrete ``|lambda| >= 0.95``) has a PBH margin
``sigma_min([A - lambda I, B])`` or ``sigma_min([A - lambda I; C])`` below
``0.05`` relative to the matrix scale, i.e. when the problem is close to not
stabilisable / not detectable (where the stabilising solution is
ill-conditioned and neither solver is accurate). The redraw count is
reported. Nothing is filtered on the solvers' answers: every accepted draw
must agree with scipy to 1e-8 relative (Frobenius) and have our relative
residual (``docs/riccati.md``) at most 1e-10. scipy's own residual is
measured too and printed, so a disagreement could be attributed.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
import scipy.linalg as sla

import sensaug


N_SAMPLES = 1000
REL_TOL = 1e-8
RES_TOL = 1e-10
PBH_MARGIN = 0.05


def _sigma_min(m: np.ndarray) -> float:
    return float(np.linalg.svd(m, compute_uv=False)[-1])


def _well_posed(A, B, C, discrete: bool) -> bool:
    n = A.shape[0]
    eye = np.eye(n)
    sb = np.sqrt(np.linalg.norm(A) ** 2 + np.linalg.norm(B) ** 2)
    sc = np.sqrt(np.linalg.norm(A) ** 2 + np.linalg.norm(C) ** 2)
    for lam in np.linalg.eigvals(A):
        marginal = abs(lam) >= 0.95 if discrete else lam.real >= -0.05
        if not marginal:
            continue
        if _sigma_min(np.hstack([A - lam * eye, B])) < PBH_MARGIN * sb:
            return False
        if _sigma_min(np.vstack([A - lam * eye, C])) < PBH_MARGIN * sc:
            return False
    return True


def _random_system(rng: np.random.Generator, n: int, discrete: bool, inputs: int | None = None):
    """One well-posed (A, B, Q, R) and the number of rejected draws before it;
    ``m`` is drawn in ``1..min(n, 3)`` unless ``inputs`` fixes it."""
    rejected = 0
    while True:
        A = rng.standard_normal((n, n)) / np.sqrt(n)
        m = int(rng.integers(1, min(n, 3) + 1)) if inputs is None else inputs
        B = rng.standard_normal((n, m))
        p = int(rng.integers(1, n + 1))
        C = rng.standard_normal((p, n))
        Q = C.T @ C
        if rng.random() < 0.5:
            Q = Q + 1e-2 * np.eye(n)
            C = np.linalg.cholesky(Q).T
        Lr = rng.standard_normal((m, m))
        R = Lr @ Lr.T + 0.1 * np.eye(m)
        if _well_posed(A, B, C, discrete):
            return A, B, Q, R, rejected
        rejected += 1


def care_residual(A, B, Q, R, X) -> float:
    """||A'X + XA - XGX + Q||_F / (||Q||_F + 2||A'X||_F + ||XGX||_F), G = B R^-1 B'."""
    G = B @ np.linalg.solve(R, B.T)
    AtX = A.T @ X
    XGX = X @ G @ X
    res = AtX + AtX.T - XGX + Q
    return float(np.linalg.norm(res) / (np.linalg.norm(Q) + 2 * np.linalg.norm(AtX) + np.linalg.norm(XGX)))


def dare_residual(A, B, Q, R, X) -> float:
    """||A'XA - X - A'XB S^-1 B'XA + Q||_F / (||Q|| + ||X|| + ||A'XA|| + ||A'XB S^-1 B'XA||), S = R + B'XB."""
    AtXA = A.T @ X @ A
    BtXA = B.T @ X @ A
    corr = BtXA.T @ np.linalg.solve(R + B.T @ X @ B, BtXA)
    res = AtXA - X - corr + Q
    den = np.linalg.norm(Q) + np.linalg.norm(X) + np.linalg.norm(AtXA) + np.linalg.norm(corr)
    return float(np.linalg.norm(res) / den)


@pytest.mark.parametrize("n", range(1, 7))
@pytest.mark.parametrize("discrete", [False, True], ids=["care", "dare"])
def test_random_systems_match_scipy(n: int, discrete: bool) -> None:
    rng = np.random.default_rng(1000 * n + int(discrete))
    ours_solve = sensaug.dare if discrete else sensaug.care
    scipy_solve = sla.solve_discrete_are if discrete else sla.solve_continuous_are
    residual = dare_residual if discrete else care_residual
    worst_diff = worst_res = worst_scipy_res = 0.0
    rejected_total = 0
    for i in range(N_SAMPLES):
        A, B, Q, R, rejected = _random_system(rng, n, discrete)
        rejected_total += rejected
        X = ours_solve(A, B, Q, R)
        Xs = scipy_solve(A, B, Q, R)
        diff = np.linalg.norm(X - Xs) / np.linalg.norm(Xs)
        res = residual(A, B, Q, R, X)
        res_s = residual(A, B, Q, R, Xs)
        worst_diff, worst_res = max(worst_diff, diff), max(worst_res, res)
        worst_scipy_res = max(worst_scipy_res, res_s)
        assert np.array_equal(X, X.T), f"sample {i}: X not symmetric"
        assert res <= RES_TOL, f"sample {i}: residual {res:.2e} (scipy {res_s:.2e})"
        assert diff <= REL_TOL, (
            f"sample {i}: rel diff {diff:.2e}; residual ours {res:.2e} scipy {res_s:.2e}\n"
            f"A={A!r}\nB={B!r}\nQ={Q!r}\nR={R!r}"
        )
        assert np.linalg.eigvalsh(X)[0] >= -1e-10 * np.linalg.norm(X)
    kind = "dare" if discrete else "care"
    print(
        f"\n{kind} n={n}: max rel diff vs scipy {worst_diff:.2e}, max residual ours "
        f"{worst_res:.2e}, scipy {worst_scipy_res:.2e}, redrawn {rejected_total}"
    )


@pytest.mark.parametrize("n,m", [(n, m) for n in range(4, 7) for m in range(4, n + 1)])
@pytest.mark.parametrize("discrete", [False, True], ids=["care", "dare"])
def test_more_than_three_inputs_match_scipy(n: int, m: int, discrete: bool) -> None:
    """Every 1 <= m <= n <= 6 is instantiated; m > 3 against scipy, 100 draws each."""
    rng = np.random.default_rng(7000 + 100 * n + 10 * m + int(discrete))
    ours_solve = sensaug.dare if discrete else sensaug.care
    scipy_solve = sla.solve_discrete_are if discrete else sla.solve_continuous_are
    residual = dare_residual if discrete else care_residual
    for i in range(100):
        A, B, Q, R, _ = _random_system(rng, n, discrete, inputs=m)
        assert B.shape == (n, m)
        X = ours_solve(A, B, Q, R)
        Xs = scipy_solve(A, B, Q, R)
        diff = np.linalg.norm(X - Xs) / np.linalg.norm(Xs)
        assert residual(A, B, Q, R, X) <= RES_TOL, f"sample {i}"
        assert diff <= REL_TOL, f"sample {i}: rel diff {diff:.2e}"
    K, _ = sensaug.lqr(A, B, Q, R, discrete=discrete)
    assert K.shape == (m, n)


@pytest.mark.parametrize("seed", range(5))
def test_lqr_matches_python_control(seed: int) -> None:
    import control

    rng = np.random.default_rng(seed)
    for discrete in (False, True):
        A, B, Q, R, _ = _random_system(rng, 4, discrete)
        K, X = sensaug.lqr(A, B, Q, R, discrete=discrete)
        if discrete:
            Kc, Xc, _ = control.dlqr(A, B, Q, R)
            cl = np.abs(np.linalg.eigvals(A - B @ K)).max()
            assert cl < 1
        else:
            Kc, Xc, _ = control.lqr(A, B, Q, R)
            cl = np.linalg.eigvals(A - B @ K).real.max()
            assert cl < 0
        assert np.linalg.norm(K - Kc) <= REL_TOL * np.linalg.norm(Kc)
        assert np.linalg.norm(X - Xc) <= REL_TOL * np.linalg.norm(Xc)


def _paper_pair(mass: float, damping: float):
    A = np.array([[0.0, 1.0, 0.0], [0.0, -damping / mass, 0.0], [0.0, 1.0, 0.0]])
    B = np.array([[0.0], [1.0 / mass], [0.0]])
    return A, B


@pytest.mark.parametrize("mass,damping", [(6.0, 0.0), (6.0, 2.0), (0.0035, 0.0)])
def test_paper_three_state_pair_raises(mass: float, damping: float) -> None:
    A, B = _paper_pair(mass, damping)
    Q = np.diag([20000.0, 2.0, 0.0])
    R = np.eye(1)
    with pytest.raises(ValueError, match="not stabilisable"):
        sensaug.care(A, B, Q, R)
    with pytest.raises(ValueError, match="not stabilisable"):
        sensaug.lqr(A, B, Q, R)
    # The quirk we refuse to mirror: scipy returns a P whose closed loop keeps
    # the uncontrollable eigenvalue at 0.
    P = sla.solve_continuous_are(A, B, Q, R)
    eig = np.linalg.eigvals(A - B @ B.T @ P)
    assert np.abs(eig).min() < 1e-6


@pytest.mark.parametrize("mass,q_pos,q_vel", [(6.0, 20000.0, 2.0), (0.0035, 1.0, 0.0), (1.0, 3.0, 0.5)])
def test_agent_gains_closed_form(mass: float, q_pos: float, q_vel: float) -> None:
    k_pos, k_vel = sensaug.agent_gains(mass, 0.0, q_pos, q_vel)
    assert k_pos == pytest.approx(np.sqrt(q_pos), rel=1e-10)
    assert k_vel == pytest.approx(np.sqrt(q_vel + 2 * mass * np.sqrt(q_pos)), rel=1e-10)
    np.testing.assert_array_equal(sensaug.robot_gain_vector(mass, 0.0, q_pos, q_vel), [k_pos, k_vel, 0.0])
    np.testing.assert_array_equal(sensaug.partner_gain_vector(mass, 0.0, q_pos, q_vel), [0.0, k_vel, k_pos])


def test_agent_gains_with_damping_match_scipy() -> None:
    mass, damping, q_pos, q_vel = 2.0, 3.0, 50.0, 1.0
    A = np.array([[0.0, 1.0], [0.0, -damping / mass]])
    B = np.array([[0.0], [1.0 / mass]])
    P = sla.solve_continuous_are(A, B, np.diag([q_pos, q_vel]), np.eye(1))
    np.testing.assert_allclose(sensaug.agent_gains(mass, damping, q_pos, q_vel), (B.T @ P)[0], rtol=1e-10)


@pytest.mark.parametrize(
    "kwargs,name",
    [
        (dict(mass=0.0), "mass"),
        (dict(mass=np.nan), "mass"),
        (dict(damping=-1.0), "damping"),
        (dict(q_pos=0.0), "q_pos"),
        (dict(q_vel=-1.0), "q_vel"),
        (dict(q_vel=np.inf), "q_vel"),
    ],
)
def test_agent_gains_bad_parameter_named(kwargs: dict, name: str) -> None:
    args = dict(mass=1.0, damping=0.0, q_pos=1.0, q_vel=0.0) | kwargs
    with pytest.raises(ValueError, match=f"^{name}:"):
        sensaug.agent_gains(**args)
    # The core refuses it too (the Python pre-check is not the only guard).
    with pytest.raises(ValueError, match=f"^{name}:"):
        sensaug._core.agent_gains(**args)


def _good3():
    A = np.array([[0.2, 1.0, -0.3], [0.5, -1.0, 0.7], [-0.4, 0.3, 0.9]])
    B = np.array([[1.0, 0.0], [0.3, 1.0], [-0.5, 0.8]])
    return A, B, np.eye(3), np.eye(2)


def _bad(arg: str, value):
    A, B, Q, R = _good3()
    d = dict(A=A, B=B, Q=Q, R=R)
    d[arg] = value
    return d


@pytest.mark.parametrize(
    "case,arg,fragment",
    [
        (_bad("A", np.ones((3, 2))), "A", "square"),
        (_bad("A", np.ones(3)), "A", "2-D"),
        (_bad("A", np.eye(7)), "A", "1 <= n <= 6"),
        (_bad("B", np.ones((2, 1))), "(A, B)", r"\(n, m\) = \(3, m\) with 1 <= m <= 3, got \(2, 1\)"),
        (_bad("B", np.ones((3, 4))), "(A, B)", "1 <= m <= 3"),
        (_bad("Q", np.eye(2)), "(A, Q)", r"\(3, 3\)"),
        (_bad("R", np.eye(3)), "(B, R)", r"\(2, 2\)"),
        (_bad("A", np.diag([1.0, np.nan, 1.0])), "A", "NaN or infinite"),
        (_bad("B", np.full((3, 2), np.inf)), "B", "NaN or infinite"),
        (_bad("Q", np.array([[1.0, 0.1, 0], [0, 1, 0], [0, 0, 1]])), "Q", "symmetric"),
        (_bad("Q", np.diag([1.0, -1.0, 1.0])), "Q", "positive semidefinite"),
        (_bad("R", np.array([[1.0, 0.5], [0.0, 1.0]])), "R", "symmetric"),
        (_bad("R", np.array([[1.0, 2.0], [2.0, 1.0]])), "R", "positive definite"),
        (_bad("R", np.diag([1.0, 0.0])), "R", "positive definite"),
    ],
)
@pytest.mark.parametrize("fn", ["care", "dare", "lqr"])
def test_value_error_names_argument(case: dict, arg: str, fragment: str, fn: str) -> None:
    with pytest.raises(ValueError, match=f"^{re.escape(arg)}:.*{fragment}"):
        getattr(sensaug, fn)(case["A"], case["B"], case["Q"], case["R"])


def test_not_detectable_raises() -> None:
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    B = np.array([[0.0], [1.0]])
    with pytest.raises(ValueError, match="not detectable"):
        sensaug.care(A, B, np.diag([0.0, 1.0]), np.eye(1))


def test_core_rejects_what_python_layer_checks() -> None:
    """The binding's own checks, bypassing lqr.py: errors still name the argument."""
    A, B, Q, R = _good3()
    with pytest.raises(ValueError, match=r"^\(A, B\): B must have as many rows as A"):
        sensaug._core.lqr(A, np.ones((2, 1)), Q, R, discrete=False)
    with pytest.raises(ValueError, match="^Q: must be symmetric"):
        sensaug._core.lqr(A, B, Q + np.triu(np.ones((3, 3)), 1), R, discrete=True)
    with pytest.raises(ValueError, match="^R: must be positive definite"):
        sensaug._core.lqr(A, B, Q, -R, discrete=False)
    with pytest.raises(ValueError, match="^A: contains NaN"):
        sensaug._core.lqr(A * np.nan, B, Q, R, discrete=False)
    # Fortran order is contiguous too; read row-major it would be A's transpose.
    with pytest.raises(ValueError, match="^A: must be C-contiguous"):
        sensaug._core.lqr(np.asfortranarray(A), B, Q, R, discrete=False)


def test_any_memory_order_gives_the_same_gains() -> None:
    """``sensaug.lqr`` takes Fortran-ordered and strided arrays as the
    matrices they are (its copy is C-ordered): the same K and X as C order."""
    A, B, Q, R = _good3()
    assert not np.allclose(A, A.T), "the check needs an asymmetric A"
    want = sensaug.lqr(A, B, Q, R)
    for layout in (np.asfortranarray, lambda m: np.repeat(m, 2, axis=1)[:, ::2]):
        got = sensaug.lqr(layout(A), layout(B), layout(Q), layout(R))
        for w, g in zip(want, got):
            np.testing.assert_array_equal(g, w)


def test_convergence_error_is_runtime_error() -> None:
    assert issubclass(sensaug.RiccatiConvergenceError, RuntimeError)

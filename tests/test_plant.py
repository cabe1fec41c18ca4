"""The 1-DoF plant against scipy's zero-order-hold discretisation.

Oracle: scipy.signal.cont2discrete(method="zoh") computes expm of the augmented
matrix [[A, B], [0, 0]] by Pade approximation; our closed form uses exp/expm1.
Both are accurate to a few ulp of the state's scale, so after 2000 steps the
states agree to 1e-10 relative (error grows at most linearly with the step
count, ~1e-13 per step). Extreme parameters (below) against an exact decimal
closed form.
"""
import decimal
import itertools

import numpy as np
import pytest
import scipy.linalg
import scipy.signal

import sensaug


def zoh_oracle(mass, damping, dt, torques, x0=0.0, v0=0.0):
    A = np.array([[0.0, 1.0], [0.0, -damping / mass]])
    B = np.array([[0.0], [1.0 / mass]])
    Ad, Bd, *_ = scipy.signal.cont2discrete((A, B, np.eye(2), np.zeros((2, 1))), dt, method="zoh")
    s = np.array([x0, v0])
    out = np.empty((len(torques), 2))
    for k, u in enumerate(torques):
        s = Ad @ s + Bd[:, 0] * u
        out[k] = s
    return out


@pytest.mark.parametrize(
    "mass,damping,dt",
    [
        (0.0035, 0.0, 1e-3),  # Hi5, friction compensated
        (0.0035, 0.02, 1e-3),  # Hi5 with viscous friction
        (6.0, 0.0, 1e-3),  # the paper's simulation
        (6.0, 1e-5, 1e-3),  # s = C dt / M tiny: the series branch of phi2
        (1.0, 50.0, 0.01),  # s = 0.5: the direct branch
    ],
)
def test_plant_matches_scipy_zoh(mass, damping, dt):
    rng = np.random.default_rng(1)
    torques = rng.normal(0.0, 0.05, size=2000)
    plant = sensaug.Plant(mass=mass, damping=damping, dt_s=dt, x0=0.1, v0=-0.2)
    xs, vs = plant.run(torques)
    ref = zoh_oracle(mass, damping, dt, torques, 0.1, -0.2)
    scale = np.abs(ref).max(axis=0)
    np.testing.assert_allclose(xs, ref[:, 0], rtol=0, atol=1e-10 * scale[0])
    np.testing.assert_allclose(vs, ref[:, 1], rtol=0, atol=1e-10 * scale[1])


def test_double_integrator_closed_form():
    """C = 0: x' = x + dt v + dt^2 u / (2M), v' = v + dt u / M, exactly."""
    m, dt, u = 0.0035, 1e-3, 0.01
    p = sensaug.Plant(mass=m, dt_s=dt, x0=1.0, v0=2.0)
    x, v = p.step(u)
    assert x == pytest.approx(1.0 + dt * 2.0 + dt**2 * u / (2 * m), rel=1e-15)
    assert v == pytest.approx(2.0 + dt * u / m, rel=1e-15)


def test_stiction_holds_below_coulomb_and_sliding_stops():
    p = sensaug.Plant(mass=0.0035, coulomb=0.02, dt_s=1e-3)
    for _ in range(100):
        x, v = p.step(0.019)  # below the Coulomb level: no motion at all
    assert (x, v) == (0.0, 0.0)
    p = sensaug.Plant(mass=0.0035, coulomb=0.02, dt_s=1e-3, v0=1.0)
    xs, vs = p.run(np.zeros(1000))
    # deceleration is fc/M = 5.7 rad/s^2: from 1 rad/s it stops after 0.175 s and stays
    assert vs[-1] == 0.0
    assert np.all(vs >= 0.0)
    stop = np.argmax(vs == 0.0)
    assert abs(stop * 1e-3 - 0.0035 / 0.02) < 2e-3


def test_bad_parameters_name_the_field():
    with pytest.raises(ValueError, match="mass"):
        sensaug.Plant(mass=-1.0)
    with pytest.raises(ValueError, match="damping"):
        sensaug.Plant(mass=1.0, damping=float("nan"))
    with pytest.raises(ValueError, match="dt_s"):
        sensaug.Plant(mass=1.0, dt_s=0.0)


def test_non_finite_torque_is_rejected_and_state_kept():
    p = sensaug.Plant(mass=1.0, x0=0.5)
    with pytest.raises(ValueError, match="torque"):
        p.step(float("nan"))
    assert p.x == 0.5 and p.v == 0.0
    with pytest.raises(ValueError, match=r"torques\[2\]"):
        p.run(np.array([0.0, 0.0, np.inf]))
    assert p.x == 0.5


# --- extreme parameters: rejected by name, or stepped exactly ----------------
#
# Oracle: the exact zero-order-hold step of M xdd + C xd = u in decimal
# arithmetic (60 digits, an exponent range far beyond float64's), so that
# neither overflow nor cancellation touches it: with s = C dt / M,
# v' = e^{-s} v + dt phi1(s) u / M, x' = x + dt phi1(s) v + dt^2 phi2(s) u / M,
# phi1 = (1 - e^{-s}) / s, phi2 = (s - 1 + e^{-s}) / s^2 (their Taylor series
# below s = 1e-12, truncation error < s^3 relative). scipy's expm of the
# augmented matrix [[0, dt, 0], [0, -s, dt/M], [0, 0, 0]] checks the oracle
# itself wherever that matrix is moderate.

FMAX = decimal.Decimal(np.finfo(float).max)
CTX = decimal.Context(prec=60, Emax=10**9, Emin=-(10**9))
EXTREME_MASS = [1e-320, 1e-310, 1e-300, 1e-200, 1e-30, 1e-6, 1.0, 1e12, 1e200, 1e300, 1.7e308]
EXTREME_DT = [1e-320, 1e-300, 1e-30, 1e-6, 1e-3, 1.0, 1e3, 1e100, 1e150, 1e160, 1e300]
EXTREME_DAMPING = [0.0, 1e-300, 1e-6, 1.0, 1e100, 1e300, 1.7e308]


def zoh_coefficients(mass, damping, dt):
    """Exact (decay, dt phi1, dt^2 phi2) as Decimals."""
    with decimal.localcontext(CTX):
        m, c, h = decimal.Decimal(mass), decimal.Decimal(damping), decimal.Decimal(dt)
        s = c * h / m
        if s < decimal.Decimal("1e-12"):
            phi1 = 1 - s / 2 + s * s / 6
            phi2 = decimal.Decimal("0.5") - s / 6 + s * s / 24
        else:
            e = (-s).exp()
            phi1 = (1 - e) / s
            phi2 = (s - 1 + e) / (s * s)
        return (-s).exp(), h * phi1, h * h * phi2


def exact_step(mass, damping, dt, x, v, u):
    """``(x', v', tol_x, tol_v)``: the exact step and what float64 may miss
    it by: 1e-12 of its terms' magnitudes, plus the subnormal spacing of
    ``u / M`` (and of each product) amplified by the coefficient it meets."""
    decay, g1, g2 = zoh_coefficients(mass, damping, dt)
    with decimal.localcontext(CTX):
        m, x, v, u = (decimal.Decimal(a) for a in (mass, x, v, u))
        terms_x = (x, g1 * v, g2 * u / m)
        terms_v = (decay * v, g1 * u / m)
        rel = decimal.Decimal("1e-12")
        tol_x = rel * sum(abs(t) for t in terms_x) + (3 + g1 + g2) * SUBNORMAL_ULP
        tol_v = rel * sum(abs(t) for t in terms_v) + (3 + g1) * SUBNORMAL_ULP
        return sum(terms_x), sum(terms_v), tol_x, tol_v


FMIN = decimal.Decimal(np.finfo(float).tiny)  # smallest normal float64
#: Absolute rounding of a subnormal float64 (its spacing, 2^-1074).
SUBNORMAL_ULP = decimal.Decimal(2) ** -1074


def step_representable(mass, damping, coulomb, dt):
    """Every quantity one float64 step forms fits in float64: its
    coefficients (dt^2, dt phi1 and dt^2 phi2 as normal numbers), 1 / M,
    s = C dt / M, and the response to a unit torque and to the friction."""
    decay, g1, g2 = zoh_coefficients(mass, damping, dt)
    with decimal.localcontext(CTX):
        m, c, fc, h = (decimal.Decimal(a) for a in (mass, damping, coulomb, dt))
        big = [1 / m, c * h / m, g1 / m, g2 / m, fc / m, fc * g1 / m, fc * g2 / m]
        normal = [h * h, g1, g2]
        return all(abs(q) <= FMAX for q in big + normal) and all(q >= FMIN for q in normal)


@pytest.mark.parametrize("mass,dt", list(itertools.product(EXTREME_MASS, EXTREME_DT)))
def test_extreme_parameters_are_refused_by_name_or_step_exactly(mass, dt):
    """Over every damping: a plant whose step cannot be formed in float64 is
    refused naming mass, damping or dt_s (and only such a plant); any other
    steps within 1e-12 of the exact ZOH step (relative to the sum of its
    terms' magnitudes, plus the spacing of subnormal numbers), or refuses the
    step naming the torque when the exact new state does not fit in float64,
    its state unchanged. Never an inf."""
    for damping in EXTREME_DAMPING:
        representable = step_representable(mass, damping, 0.0, dt)
        try:
            p = sensaug.Plant(mass=mass, damping=damping, dt_s=dt, x0=0.1, v0=-0.2)
        except ValueError as e:
            assert str(e).split(":")[0] in ("mass", "damping", "dt_s"), str(e)
            assert not representable, f"refused needlessly: damping {damping:g}: {e}"
            continue
        assert representable, f"damping {damping:g}: accepted, but its step overflows"
        for u in (1.0, -0.5, 1e-3):
            x, v = p.x, p.v
            ex, ev, sx, sv = exact_step(mass, damping, dt, x, v, u)
            if abs(ex) > FMAX or abs(ev) > FMAX:
                with pytest.raises(ValueError, match="^torque: this step's new state would overflow"):
                    p.step(u)
                assert (p.x, p.v) == (x, v)
                break
            x1, v1 = p.step(u)
            assert np.isfinite(x1) and np.isfinite(v1)
            assert abs(decimal.Decimal(x1) - ex) <= sx, (damping, u)
            assert abs(decimal.Decimal(v1) - ev) <= sv, (damping, u)


@pytest.mark.parametrize("mass,damping,dt", [(m, c, h) for m in (1e-6, 1.0, 1e6) for c in (0.0, 1e-3, 10.0, 1e4) for h in (1e-9, 1e-3, 1.0)])
def test_decimal_oracle_agrees_with_scipy_expm(mass, damping, dt):
    """The oracle itself against scipy's expm where the augmented matrix is
    moderate (entries within 1e9): the same step to 1e-12."""
    aug = np.array([[0.0, dt, 0.0], [0.0, -damping * dt / mass, dt / mass], [0.0, 0.0, 0.0]])
    E = scipy.linalg.expm(aug)
    x, v, u = 0.1, -0.2, 0.7
    ref = E @ np.array([x, v, u])
    ex, ev, tol_x, tol_v = exact_step(mass, damping, dt, x, v, u)
    assert abs(float(ex) - ref[0]) <= float(tol_x)
    assert abs(float(ev) - ref[1]) <= float(tol_v)


@pytest.mark.parametrize("coulomb", [1e300, 1.7e308])
@pytest.mark.parametrize("mass", [1e-300, 1e-6, 1.0, 1e300])
def test_extreme_friction_is_refused_by_name_or_finite(coulomb, mass):
    rep = step_representable(mass, 0.0, coulomb, 1e-3)
    try:
        p = sensaug.Plant(mass=mass, coulomb=coulomb, v0=1.0)
    except ValueError as e:
        assert str(e).startswith(("coulomb:", "mass:")), str(e)
        assert not rep
        return
    assert rep
    for u in (0.0, 1.0):
        try:
            x, v = p.step(u)
        except ValueError as e:
            assert str(e).startswith("torque: this step's new state would overflow")
            continue
        assert np.isfinite(x) and np.isfinite(v)


def test_run_names_the_step_that_would_overflow():
    """A finite torque sequence whose state overflows stops at that step by
    name; the steps before it ran."""
    p = sensaug.Plant(mass=1e-300, dt_s=1.0)
    with pytest.raises(ValueError, match=r"^torques\[\d+\]: the state would overflow at this step"):
        p.run(np.full(10, 1e8))
    assert np.isfinite(p.x) and np.isfinite(p.v) and p.v > 0

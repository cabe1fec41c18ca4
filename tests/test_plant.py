"""The 1-DoF plant against scipy's zero-order-hold discretisation.

Oracle: scipy.signal.cont2discrete(method="zoh") computes expm of the augmented
matrix [[A, B], [0, 0]] by Pade approximation; our closed form uses exp/expm1.
Both are accurate to a few ulp of the state's scale, so after 2000 steps the
states agree to 1e-10 relative (error grows at most linearly with the step
count, ~1e-13 per step).
"""
import numpy as np
import pytest
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

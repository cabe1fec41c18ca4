"""Is the partner's closed loop stable with its sensorimotor delays?

Two independent computations (noise-free, targets at rest, the robot's LQR
law on the current measurement, the partner's on the delayed one):

* discrete, exact: the 1 kHz closed loop with the delays as shift registers,
  ``x[k+1] = x + dt v + dt^2 f / (2M)``, ``v[k+1] = v + dt f / M`` (ZOH of
  ``M xdd = f``, C = 0), ``f = -kp x[k] - kv v[k] - (Lhx + Lhh) x[k - dv]
  - Lhv v[k - dp]``; stable iff the spectral radius of the companion matrix
  is < 1.
* continuous: the characteristic quasi-polynomial
  ``M s^2 + kv s + kp + (Lhx + Lhh) e^{-s dv} + Lhv s e^{-s dp} = 0``;
  for ``Lhv = 0`` the first crossing delay has a closed form
  (``critical_visual_delay``).

``python stability.py`` prints the table's cells with their verdicts.
"""

from __future__ import annotations

import math

import numpy as np

from settings import Hi5, hi5

from sensaug.partner_delay import spectral_radius


def discrete_spectral_radius(h: Hi5, gains, dv: int, dp: int) -> float:
    """Spectral radius of the discrete closed loop; delays in ticks (the
    product's computation, sensaug.partner_delay.spectral_radius, on the
    same preset as ``h``)."""
    return spectral_radius(gains, dv, dp)


def critical_visual_delay(h: Hi5, stiffness: float) -> float:
    """First delay (s) at which ``M s^2 + kv s + kp + k e^{-s d}`` has a root
    on the imaginary axis (Lhv = 0); ``inf`` when the loop is stable for every
    delay (``|kp - M w^2 + j kv w| > k`` for all w > 0)."""
    M, kv, kp, k = h.M, h.kv, h.kp, stiffness
    # |kp - M w^2 + j kv w|^2 = k^2  ->  M^2 W^2 + (kv^2 - 2 M kp) W + kp^2 - k^2 = 0, W = w^2
    roots = np.roots([M * M, kv * kv - 2 * M * kp, kp * kp - k * k])
    best = math.inf
    for W in roots:
        if abs(W.imag) > 1e-9 or W.real <= 0:
            continue
        w = math.sqrt(W.real)
        # k e^{-j w d} = -(kp - M w^2 + j kv w)
        target = -complex(kp - M * w * w, kv * w)
        phase = -math.atan2(target.imag, target.real)  # w d = phase (mod 2 pi)
        d = (phase % (2 * math.pi)) / w
        best = min(best, d)
    return best


def verdict(h: Hi5, gains, dv_ms: float, dp_ms: float) -> tuple[bool, float]:
    dv, dp = int(round(dv_ms * 1e-3 / h.dt)), int(round(dp_ms * 1e-3 / h.dt))
    r = discrete_spectral_radius(h, gains, dv, dp)
    return r < 1.0, r


def main() -> None:
    h = hi5()
    print(f"robot kp = {h.kp:.4f} N m/deg, kv = {h.kv:.5f} N m s/deg, M = {h.M}")
    for lhh in (0.5, 1.0, 2.0):
        print(f"Lhh = {lhh}: critical visual delay (Lhv = 0, continuous) = "
              f"{critical_visual_delay(h, lhh) * 1e3:.1f} ms")
    for lhv_name, lhv_of in (("Lhv=0", lambda l: 0.0), ("Lhv=sqrt(2 M Lhh)", lambda l: math.sqrt(2 * h.M * l))):
        print(f"\n{lhv_name}: spectral radius of the discrete closed loop (>= 1: unstable)")
        print("Lhh  Lhv      dp\\dv " + " ".join(f"{d:>7}" for d in (0, 50, 100, 150, 200)))
        for lhh in (0.5, 1.0, 2.0):
            for dp in (0, 40):
                g = (0.0, lhv_of(lhh), lhh)
                cells = []
                for dv in (0, 50, 100, 150, 200):
                    ok, r = verdict(h, g, dv, dp)
                    cells.append(f"{r:.5f}" + ("" if ok else "!"))
                print(f"{lhh:<4} {g[1]:.4f} {dp:>6}    " + " ".join(f"{c:>7}" for c in cells))
    # Where exactly does each become unstable (discrete scan, 1 ms)?
    print("\nfirst unstable visual delay (discrete, 1 ms scan up to 300 ms):")
    for lhv_name, lhv_of in (("Lhv=0", lambda l: 0.0), ("Lhv=sqrt(2 M Lhh)", lambda l: math.sqrt(2 * h.M * l))):
        for lhh in (0.5, 1.0, 2.0):
            for dp in (0, 40):
                g = (0.0, lhv_of(lhh), lhh)
                first = next((dv for dv in range(0, 301) if not verdict(h, g, dv, dp)[0]), None)
                print(f"  {lhv_name:18} Lhh={lhh} dp={dp} ms: "
                      + ("stable up to 300 ms" if first is None else f"unstable from {first} ms"))


if __name__ == "__main__":
    main()

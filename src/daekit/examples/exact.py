"""Exact solutions and published reference values of the example DAEs.

Every function takes ``t`` (a number or a NumPy array) and returns a dict from the model's
names (``"x"``, ``"der(x)"``, ``"der(x,2)"``, ``"y[0]"`` ...) to NumPy arrays shaped like ``t``:
the unknowns and the derivatives that appear in the model, so that the model's residual can be
evaluated on them. See ``reference-problems.md``.

>>> import numpy as np
>>> s = pendulum_planar(5.0, np.pi / 6, g=9.8)
>>> round(float(s["x"]), 12), round(float(s["T"]), 10)
(-0.476578725582, -8.8723769482)
"""

from __future__ import annotations

import numpy as np
from scipy.special import ellipj, ellipk

__all__ = [
    "pendulum_planar",
    "pendulum_planar_period",
    "pendulum_wall_impacts",
    "gear_petzold",
    "oki_linear",
    "iwata_nonlinear",
    "brenan",
    "jay",
    "arevalo",
    "planar_chain_rotating",
    "planar_chain_hanging",
    "chained_pendula_rest",
    "CHEMAKZO_Y0",
    "CHEMAKZO_TEND",
    "CHEMAKZO_YEND",
    "TRANSISTOR_Y0",
    "TRANSISTOR_TEND",
    "TRANSISTOR_YEND",
]


def pendulum_planar(t, theta0: float, g: float = 9.81, L: float = 1.0) -> dict[str, np.ndarray]:
    """Exact motion of :func:`daekit.examples.pendulum_planar` released at rest from ``theta0``.

    ``sin(theta/2) = k cd(w t | k^2)``, ``k = sin(theta0/2)``, ``w = sqrt(g/L)``, ``cd = cn/dn``
    (Jacobi elliptic functions, :func:`scipy.special.ellipj`); ``x = L sin theta``,
    ``y = -L cos theta``. The velocity uses ``d cd/du = -(1 - k^2) sn / dn^2``, the rod force
    ``T = (g y - |v|^2) / L^2 = g (3 y - 2 y0) / L^2``, the accelerations follow from the model
    (``x'' = x T``, ``y'' = y T - g``). ``theta0`` is measured from the downward vertical,
    positive towards ``+x``; ``|theta0| < pi``.

    Returns a dict with ``x``, ``y``, ``der(x)``, ``der(y)``, ``der(x,2)``, ``der(y,2)``, ``T``
    and ``theta``.
    """
    t = np.asarray(t, dtype=float)
    k = np.sin(theta0 / 2.0)
    m = k * k
    w = np.sqrt(g / L)
    sn, cn, dn, _ = ellipj(w * t, m)
    s = k * cn / dn  # sin(theta/2)
    c = np.sqrt(1.0 - s * s)  # cos(theta/2) > 0
    theta = 2.0 * np.arcsin(s)
    ds = -k * w * (1.0 - m) * sn / (dn * dn)  # d/dt sin(theta/2)
    dtheta = 2.0 * ds / c
    sin_th = 2.0 * s * c
    cos_th = 1.0 - 2.0 * s * s
    x = L * sin_th
    y = -L * cos_th
    dx = L * cos_th * dtheta
    dy = L * sin_th * dtheta
    T = (g * y - (dx * dx + dy * dy)) / L**2
    return {
        "x": x,
        "y": y,
        "der(x)": dx,
        "der(y)": dy,
        "der(x,2)": x * T,
        "der(y,2)": y * T - g,
        "T": T,
        "theta": theta,
    }


def pendulum_planar_period(theta0: float, g: float = 9.81, L: float = 1.0) -> float:
    """Period ``4 K(k^2) / w`` of the planar pendulum released at rest from ``theta0``."""
    return float(4.0 * ellipk(np.sin(theta0 / 2.0) ** 2) / np.sqrt(g / L))


def pendulum_wall_impacts(n: int, e: float, g: float = 9.81, L: float = 1.0) -> np.ndarray:
    """The first ``n`` impact times of the planar pendulum released at rest from horizontal
    (``x = L``, ``y = 0``) with a wall at ``x = 0`` (the bottom) and restitution ``e``.

    The first impact is at a quarter period of the amplitude ``pi/2``,
    ``K(1/2) / w`` (``w = sqrt(g/L)``, ``K`` the complete elliptic integral of the first kind,
    parameter ``m = sin^2(theta/2)``). The impact scales the velocity by ``e``, hence the
    kinetic energy at the bottom by ``e^2``: the next amplitude has
    ``1 - cos(theta_k) = e^2 (1 - cos(theta_{k-1}))``, and the next impact comes half a period
    of the new amplitude, ``2 K(sin^2(theta_k / 2)) / w``, later.

    >>> t = pendulum_wall_impacts(3, 1.0)
    >>> bool(abs(t[0] - 0.5919604868940593) < 1e-15), bool(abs(t[1] - 3 * t[0]) < 1e-14)
    (True, True)
    """
    w = np.sqrt(g / L)
    theta = np.pi / 2.0
    out = [float(ellipk(np.sin(theta / 2.0) ** 2) / w)]
    for _ in range(int(n) - 1):
        theta = float(np.arccos(1.0 - e * e * (1.0 - np.cos(theta))))
        out.append(out[-1] + float(2.0 * ellipk(np.sin(theta / 2.0) ** 2) / w))
    return np.array(out[: int(n)])


def gear_petzold(t, eta: float = -2.0) -> dict[str, np.ndarray]:
    """F1 (:func:`daekit.examples.gear_petzold`) with ``f = sin t``, ``g = cos t``:
    ``z = g - f' = 0``, ``y = f - eta t z = sin t`` (for every ``eta``)."""
    t = np.asarray(t, dtype=float)
    zero = np.zeros_like(t)
    return {"y": np.sin(t), "der(y)": np.cos(t), "z": zero, "der(z)": zero.copy()}


def oki_linear(t) -> dict[str, np.ndarray]:
    """F2 (:func:`daekit.examples.oki_linear`): ``x = t + sin t``, ``y = 0``."""
    t = np.asarray(t, dtype=float)
    return {
        "x": t + np.sin(t),
        "der(x)": 1.0 + np.cos(t),
        "der(x,2)": -np.sin(t),
        "y": np.zeros_like(t),
    }


def iwata_nonlinear(t, sign: float = 1.0) -> dict[str, np.ndarray]:
    """F3 (:func:`daekit.examples.iwata_nonlinear`): ``x1 = cos t - t``,
    ``x2 = sign sqrt(1 + 2 sin t)``, ``x3 = t + 1 + sin t`` (real where ``sin t >= -1/2``)."""
    t = np.asarray(t, dtype=float)
    return {
        "x1": np.cos(t) - t,
        "der(x1)": -np.sin(t) - 1.0,
        "x2": sign * np.sqrt(1.0 + 2.0 * np.sin(t)),
        "x3": t + 1.0 + np.sin(t),
    }


def brenan(t) -> dict[str, np.ndarray]:
    """E1 (:func:`daekit.examples.brenan`) with ``y(0) = (1, 0)``:
    ``y1 = e^-t + t sin t``, ``y2 = sin t``."""
    t = np.asarray(t, dtype=float)
    return {
        "y1": np.exp(-t) + t * np.sin(t),
        "der(y1)": -np.exp(-t) + np.sin(t) + t * np.cos(t),
        "y2": np.sin(t),
        "der(y2)": np.cos(t),
    }


def jay(t) -> dict[str, np.ndarray]:
    """E2 (:func:`daekit.examples.jay`) with ``y(0) = (1, 1)``:
    ``y1 = e^t``, ``y2 = e^-2t``, ``w = e^2t``."""
    t = np.asarray(t, dtype=float)
    return {
        "y1": np.exp(t),
        "der(y1)": np.exp(t),
        "y2": np.exp(-2.0 * t),
        "der(y2)": -2.0 * np.exp(-2.0 * t),
        "w": np.exp(2.0 * t),
    }


def arevalo(t) -> dict[str, np.ndarray]:
    """E3 (:func:`daekit.examples.arevalo`), ``t in [1, 5]``: ``(x, y) = (sin t^2, cos t^2)``,
    ``(u, v) = (2t cos t^2, -2t sin t^2)``, ``l = -4 t^2``."""
    t = np.asarray(t, dtype=float)
    s, c = np.sin(t * t), np.cos(t * t)
    return {
        "x": s,
        "y": c,
        "u": 2 * t * c,
        "v": -2 * t * s,
        "der(x)": 2 * t * c,
        "der(y)": -2 * t * s,
        "der(u)": 2 * c - 4 * t * t * s,
        "der(v)": -2 * s - 4 * t * t * c,
        "l": -4 * t * t,
    }


def planar_chain_rotating(t, N: int, omega: float = 1.0) -> dict[str, np.ndarray]:
    """:func:`daekit.examples.planar_chain` with ``g = 0`` turning rigidly and uniformly.

    Mass ``k`` at ``q_k = k (cos w t, sin w t)``; the rods carry the centripetal forces,
    ``lam_k = w^2 (k + (k+1) + ... + N)``. Values are for one scalar ``t``: ``q``, ``v``,
    ``der(q)``, ``der(v)`` (2N each), ``lam`` (N).
    """
    t = float(t)
    k = np.arange(1, N + 1, dtype=float)
    er = np.array([np.cos(omega * t), np.sin(omega * t)])
    et = np.array([-np.sin(omega * t), np.cos(omega * t)])
    q = np.outer(k, er).ravel()
    v = omega * np.outer(k, et).ravel()
    a = -(omega**2) * np.outer(k, er).ravel()
    lam = omega**2 * np.cumsum(k[::-1])[::-1]
    return {"q": q, "v": v, "der(q)": v.copy(), "der(v)": a, "lam": lam}


def planar_chain_hanging(N: int, g: float = 9.81) -> dict[str, np.ndarray]:
    """:func:`daekit.examples.planar_chain` hanging at rest: ``q_k = (0, -k)``, and rod ``k``
    carries the weight of the masses ``k..N``: ``lam_k = g (N - k + 1)``."""
    k = np.arange(1, N + 1, dtype=float)
    q = np.column_stack([np.zeros(N), -k]).ravel()
    zero = np.zeros(2 * N)
    return {"q": q, "v": zero, "der(q)": zero.copy(), "der(v)": zero.copy(), "lam": g * k[::-1]}


def chained_pendula_rest(
    p: int, G: float = 9.8, L: float = 1.0, c: float = 0.1
) -> dict[str, np.ndarray]:
    """:func:`daekit.examples.chained_pendula` at rest (gravity along ``+y``): ``x_i = 0``,
    ``y_i = L + c l_{i-1}``, ``l_i = G / y_i``; all derivatives zero."""
    out: dict[str, np.ndarray] = {}
    prev = 0.0
    for i in range(1, p + 1):
        y = L + c * prev
        lam = G / y
        out.update(
            {f"x{i}": 0.0, f"y{i}": y, f"l{i}": lam, f"der(x{i},2)": 0.0, f"der(y{i},2)": 0.0}
        )
        prev = lam
    return {k: np.asarray(v, dtype=float) for k, v in out.items()}


# Test Set for IVP Solvers (Mazzia, Magherini, Iavernaro; University of Bari): chemakzo.
CHEMAKZO_Y0 = np.array([0.444, 0.00123, 0.0, 0.007, 0.0, 115.83 * 0.444 * 0.007])
CHEMAKZO_TEND = 180.0
CHEMAKZO_YEND = np.array(
    [
        0.1150794920661702,
        0.1203831471567715e-2,
        0.1611562887407974,
        0.3656156421249283e-3,
        0.1708010885264404e-1,
        0.4873531310307455e-2,
    ]
)

# Test Set for IVP Solvers: transistor amplifier.
TRANSISTOR_Y0 = np.array([0.0, 3.0, 3.0, 6.0, 3.0, 3.0, 6.0, 0.0])
TRANSISTOR_TEND = 0.2
TRANSISTOR_YEND = np.array(
    [
        -0.5562145012262709e-2,
        0.3006522471903042e1,
        0.2849958788608128e1,
        0.2926422536206241e1,
        0.2704617865010554e1,
        0.2761837778393145e1,
        0.4770927631616772e1,
        0.1236995868091548e1,
    ]
)

"""DAEs on which structural analysis fails: the system Jacobian is identically singular.

Pantelides and Pryce's Sigma-method report too low an index and too many degrees of freedom on
these; the true index must come from a numeric test (the derivative array). See
``reference-problems.md``, section 4.
"""

from __future__ import annotations

import casadi as ca

from ..model import Model

__all__ = ["gear_petzold", "f1", "f2", "f3", "oki_linear", "iwata_nonlinear"]


def gear_petzold(eta: float = -2.0) -> Model:
    """Gear and Petzold's linear time-varying DAE (F1), with ``f = sin t``, ``g = cos t``.

    ``y' + eta t z' + (1 + eta) z = g(t)`` (``dynamic``), ``y + eta t z = f(t)``
    (``constraint``); both ``y`` and ``z`` appear differentiated (states), parameter ``eta``.

    Source: Ascher & Petzold, *Computer Methods for ODEs and DAEs* (SIAM 1998).
    Structural analysis claims index 1, DOF 1 (``structurally_ok`` is False: the system
    Jacobian ``[[1, eta t], [1, eta t]]`` is singular). The truth is differential index 2, DOF 0:
    differentiating the constraint and subtracting gives ``z = g - f'``, and ``z'`` needs a second
    differentiation. Exact solution ``z = g - f' = 0``, ``y = f - eta t z = sin t``.

    >>> gear_petzold().unknown_names
    ['y', 'z']
    """
    m = Model("gear_petzold")
    y = m.state("y")
    z = m.state("z")
    et = m.parameter("eta", eta)
    t = m.t
    m.equation(m.der(y) + et * t * m.der(z) + (1 + et) * z - ca.cos(t), name="dynamic")
    m.equation(y + et * t * z - ca.sin(t), name="constraint")
    return m


f1 = gear_petzold


def oki_linear() -> Model:
    """F2: ``-x'' - y = sin t`` (``forced``), ``x'' + x + y = t`` (``spring``).

    State ``x`` (second order), algebraic ``y``.

    Source: T. Oki's DAE preprocessing toolbox demo. Structural analysis claims index 1, DOF 2
    (``structurally_ok`` False: ``[[-1, -1], [1, 1]]`` is singular). Adding the equations gives
    ``x = t + sin t``: DOF 0. The reference quotes "index 2 in first-order form"; counting
    differentiations of the derivative array until ``x'`` (or ``x''``) and ``y'`` are determined,
    ``x'' = -sin t`` needs two and ``y' = -x''' - cos t`` three, so the differential index is 3
    (like the pendulum: position fixed, ``y`` plays the constraint force). Exact solution
    ``x = t + sin t``, ``y = 0``.

    >>> oki_linear().equation_names
    ['forced', 'spring']
    """
    m = Model("f2_oki")
    x = m.state("x")
    y = m.algebraic("y")
    t = m.t
    m.equation(-m.der(x, 2) - y - ca.sin(t), name="forced")
    m.equation(m.der(x, 2) + x + y - t, name="spring")
    return m


f2 = oki_linear


def iwata_nonlinear() -> Model:
    """F3: ``x1' + x2^2 = sin t``, ``x1' + x1 + x3 = cos t``, ``x1' + x3 = t``.

    State ``x1``, algebraic ``x2``, ``x3``; equations ``quadratic``, ``linear1``, ``linear2``.
    Source: Iwata, Oki, Takamatsu, J. ACM 66(5), 2019. Structural analysis claims index 1,
    DOF 1 (``structurally_ok`` False: the rows of ``linear1`` and ``linear2`` in the system
    Jacobian are equal). Truth: differential index 2, DOF 0: ``linear1 - linear2`` gives
    ``x1 = cos t - t``; then ``x3 = t + 1 + sin t`` and ``x2^2 = 1 + 2 sin t``; ``x3'`` needs a
    second differentiation.
    Exact solution ``x1 = cos t - t``, ``x3 = t + 1 + sin t``, ``x2 = +-sqrt(1 + 2 sin t)``
    (real for ``sin t > -1/2``).

    >>> iwata_nonlinear().unknown_names
    ['x1', 'x2', 'x3']
    """
    m = Model("f3_iwata")
    x1 = m.state("x1")
    x2 = m.algebraic("x2")
    x3 = m.algebraic("x3")
    t = m.t
    m.equation(m.der(x1) + x2**2 - ca.sin(t), name="quadratic")
    m.equation(m.der(x1) + x1 + x3 - ca.cos(t), name="linear1")
    m.equation(m.der(x1) + x3 - t, name="linear2")
    return m


f3 = iwata_nonlinear

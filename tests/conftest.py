"""Shared test systems."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest


@pytest.fixture
def circle_system():
    """x' = (-x1, x0) on the unit circle |x| = 1 (the invariant "circle"), z = x0 from
    alg = z - x0: a ReducedDAE whose nearest point on the constraint is x / |x| exactly."""
    from daekit.reduced import ReducedDAE

    t = ca.SX.sym("t")
    x = ca.SX.sym("x", 2)
    z = ca.SX.sym("z")
    return ReducedDAE(t, x, z, ca.SX(0, 1), ca.SX(0, 1), ca.vertcat(-x[1], x[0]), z - x[0],
                      ca.dot(x, x) - 1, ["circle"], ["x[0]", "x[1]"], ["z"], [], [],
                      np.zeros(0))


@pytest.fixture
def forbid(monkeypatch):
    """``forbid("daekit.initialize", "initialize")``: calling that function fails the test
    (for what must be checked before any work starts)."""
    import sys

    def _forbid(module: str, name: str) -> None:
        def never(*args, **kwargs):
            raise AssertionError(f"{module}.{name} ran")

        monkeypatch.setattr(sys.modules[module], name, never)

    return _forbid

"""Consistent initialization from rough guesses on big mechanisms (issue 14, item 0).

The planar chain of N unit rods (:func:`daekit.examples.planar_chain`), only a guess of the
positions, nothing fixed. The checks do not trust daekit's own equations:

- the rods hold: ``|q_k - q_{k-1}| = 1`` computed here with NumPy;
- the result is the least-squares pull of the guess: ``q - guess`` is normal to the set of
  consistent positions (orthogonal to every tangent direction, which for a chain is a change
  of the link angles: ``dq_k = sum_{i<=k} dtheta_i (cos theta_i, sin theta_i)``), and it is no
  farther from the guess than the consistent chain the guess was made from;
- the multipliers and accelerations satisfy Newton's law and the twice differentiated rods
  (written out here in NumPy).
"""

from __future__ import annotations

import numpy as np
import pytest

import daekit as dk
from daekit.reduction import reduce_index

G = 9.81


def tilted_guess(N: int, eps: float, angle: float = 0.3) -> np.ndarray:
    """The issue's guess: a straight chain at ``angle`` from the downward vertical, each
    position moved by ``eps (sin i, cos i)``."""
    i = np.arange(N)
    x = (i + 1) * np.sin(angle) + eps * np.sin(i)
    y = -(i + 1) * np.cos(angle) + eps * np.cos(i)
    return np.column_stack([x, y]).ravel()


def links(q: np.ndarray) -> np.ndarray:
    Q = q.reshape(-1, 2)
    return np.diff(np.vstack([[0.0, 0.0], Q]), axis=0)


def check_consistent(init, guess_q: np.ndarray, N: int) -> None:
    q, v = init["q"], init["v"]
    d = links(q)
    assert np.abs(np.linalg.norm(d, axis=1) - 1.0).max() < 1e-10  # the rods
    dv = links(v)
    assert np.abs(np.sum(d * dv, axis=1)).max() < 1e-10  # their time derivative
    # least squares: q - guess is orthogonal to every angle change (tangent directions)
    theta_dirs = d  # (cos theta_i, sin theta_i) rotated: tangent of link i is perp(d_i)
    perp = np.column_stack([-theta_dirs[:, 1], theta_dirs[:, 0]])
    r = (q - guess_q).reshape(-1, 2)
    # dq_k / dtheta_i = perp_i for k >= i: the gradient is sum_{k >= i} r_k . perp_i
    tail = np.cumsum(r[::-1], axis=0)[::-1]
    grad = np.sum(tail * perp, axis=1)
    assert np.abs(grad).max() < 1e-9 * max(1.0, np.abs(q).max())
    # Newton's law and the twice differentiated rods, written out here
    lam, a = init["lam"], init["der(v)"].reshape(-1, 2)
    force = np.zeros((N, 2))
    force[:, 1] -= G
    force -= lam[:, None] * d
    force[:-1] += lam[1:, None] * d[1:]
    assert np.abs(a - force).max() < 1e-8 * (1 + np.abs(lam).max())
    da = np.diff(np.vstack([[0.0, 0.0], a]), axis=0)
    assert np.abs(np.sum(d * da, axis=1) + np.sum(dv * dv, axis=1)).max() < 1e-8 * (
        1 + np.abs(lam).max())


@pytest.mark.parametrize("N", [50, 200, 1000])
def test_chain_from_a_rough_guess(N):
    eps = 1e-2
    r = reduce_index(dk.examples.planar_chain(N))
    guess = tilted_guess(N, eps)
    init = dk.initialize(r, guess={"q": guess})
    check_consistent(init, guess, N)
    # no farther from the guess than the straight chain it was made from (a consistent point)
    straight = tilted_guess(N, 0.0)
    assert np.linalg.norm(init["q"] - guess) <= np.linalg.norm(straight - guess) + 1e-12
    assert np.abs(init["q"] - guess).max() < 3 * eps
    assert init.iterations <= 12  # Newton from 1 cm off: a handful of steps, at any N


def test_chain_consistent_guess_is_kept_exactly():
    """The unperturbed straight chain at 0.3 rad at rest is consistent: it comes back as it
    is (the exact answer), with multipliers that satisfy Newton's law."""
    N, phi = 100, 0.3
    r = reduce_index(dk.examples.planar_chain(N))
    q = tilted_guess(N, 0.0, phi)
    init = dk.initialize(r, guess={"q": q, "v": np.zeros(2 * N)})
    assert np.abs(init["q"] - q).max() < 1e-12 and np.abs(init["v"]).max() < 1e-12
    check_consistent(init, q, N)


@pytest.mark.parametrize("seed", range(4))
def test_chain_random_states_random_perturbations(seed):
    """Random consistent chains (angles, rates), guesses of q and v 1 cm off in random
    directions: a consistent point no farther from the guess than the state it came from."""
    rng = np.random.default_rng(100 + seed)
    N = int(rng.integers(20, 300))
    th = rng.uniform(-1.2, 1.2, N)
    om = rng.uniform(-1.0, 1.0, N)
    e = np.column_stack([np.sin(th), -np.cos(th)])
    q = np.cumsum(e, axis=0).ravel()
    v = np.cumsum(om[:, None] * np.column_stack([np.cos(th), np.sin(th)]), axis=0).ravel()
    gq = q + 1e-2 * rng.standard_normal(2 * N)
    gv = v + 1e-2 * rng.standard_normal(2 * N)
    r = reduce_index(dk.examples.planar_chain(N))
    init = dk.initialize(r, guess={"q": gq, "v": gv})
    d = links(init["q"])
    assert np.abs(np.linalg.norm(d, axis=1) - 1.0).max() < 1e-10
    assert np.abs(np.sum(d * links(init["v"]), axis=1)).max() < 1e-10
    dist = np.sqrt(np.sum((init["q"] - gq) ** 2) + np.sum((init["v"] - gv) ** 2))
    dist0 = np.sqrt(np.sum((q - gq) ** 2) + np.sum((v - gv) ** 2))
    assert dist <= dist0 + 1e-12
    assert init.iterations <= 12

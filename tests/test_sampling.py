"""dk.sample: bad distributions and seeds are refused with the entry named, never NaN."""

import numpy as np
import pytest

import daekit as dk


@pytest.mark.parametrize("dist, message", [
    (("triangular", 0, 2, 1), r"'L': triangular \(lo, mode, hi\) needs the mode in \[lo, hi\], "
                              r"got \('triangular', 0, 2, 1\)"),
    (("triangular", 1, 1, 1), r"'L': triangular \(lo, mode, hi\) needs lo < hi"),
    (("truncnormal", 1, 0.1, 2, 0), r"'L': truncnormal \(mean, std, lo, hi\) needs lo < hi, "
                                    r"got \('truncnormal', 1, 0.1, 2, 0\)"),
    (("choice", 3), r"'L': \('choice', 3\): choice takes a list of values"),
    (("choice", "abc"), r"'L': \('choice', 'abc'\): choice takes a list of values"),
    (("choice", [1.0, "x"]), r"'L': .*'x' is not a finite number"),
    (("choice", []), r"'L': choice needs at least one value"),
    (("uniform", "a", 1), r"'L': \('uniform', 'a', 1\): 'a' is not a finite number"),
    (("uniform", 0, np.inf), r"'L': .*inf is not a finite number"),
    (("normal", 0, 0), r"'L': the standard deviation must be > 0"),
    (("constant",), r"'L': 'constant' takes 1 number"),
    (("constant", "x"), r"'L': \('constant', 'x'\): 'x' is not a finite number"),
    (float("nan"), r"'L': nan: nan is not a finite number"),
    (("gamma", 1, 2), r"'L': \('gamma', 1, 2\) is not a distribution"),
])
def test_bad_distributions_are_named(dist, message):
    with pytest.raises(dk.ModelError, match="^sample: " + message):
        dk.sample({"L": dist}, 4, seed=1)


@pytest.mark.parametrize("seed", [-1, 1.5, None, True, "1"])
def test_bad_seeds_are_refused(seed):
    with pytest.raises(dk.ModelError, match=rf"seed must be a non-negative integer .*got "
                                            rf"{seed!r}"):
        dk.sample({"L": ("uniform", 0, 1)}, 4, seed=seed)
    if seed is None:  # says how to get fresh draws that can be reproduced
        with pytest.raises(dk.ModelError, match="secrets.randbits"):
            dk.sample({"L": ("uniform", 0, 1)}, 4, seed=None)


def test_good_edges_and_seeds():
    # the mode at an end of the range is a (right-angled) triangle: all draws inside
    s = dk.sample({"a": ("triangular", 0.0, 0.0, 1.0), "b": ("truncnormal", 0.0, 1.0, 0.5, 0.6),
                   "c": ("choice", np.array([2, 3])), "d": ("constant", 4)}, 200, seed=np.int64(7))
    a, b = np.array([x["a"] for x in s]), np.array([x["b"] for x in s])
    assert np.all((a >= 0) & (a <= 1)) and np.all((b >= 0.5) & (b <= 0.6))
    # a right triangle on [0, 1] with its mode at 0 has mean 1/3 (std 0.236: 200 draws
    # give the mean to about 0.017)
    assert abs(a.mean() - 1 / 3) < 0.06
    assert {x["c"] for x in s} == {2.0, 3.0} and {x["d"] for x in s} == {4.0}
    assert dk.sample({"L": ("uniform", 0, 1)}, 3) == dk.sample({"L": ("uniform", 0, 1)}, 3, seed=0)

"""Error messages name the user's own things (issue: the first hour of a new user)."""

from __future__ import annotations

import pytest

import daekit as dk


def test_unknown_in_no_equation_is_named_without_an_empty_list():
    m = dk.Model("stray")
    x = m.state("x")
    m.algebraic("z")
    m.equation(m.der(x) + x, name="decay")
    with pytest.raises(dk.StructuralError) as err:
        dk.analyze(m)
    text = str(err.value)
    assert "'z' appear in no equation" in text
    assert "equations ," not in text and "1 equation," in text
    assert err.value.underdetermined_variables == ["z"]

"""Words in daekit's messages: a count with its noun in the right number.

``count(1, "initial value")`` is ``"1 initial value"``, ``count(4, "initial value")`` is
``"4 initial values"``. Every message that states how many of something there are goes through
:func:`count`, so that none says "1 initial values".

>>> count(1, "equation"), count(3, "equation"), count(2, "velocity"), count(0, "match")
('1 equation', '3 equations', '2 velocities', '0 matches')
"""

from __future__ import annotations

__all__ = ["count", "plural", "derivative_name", "listing"]


def plural(noun: str) -> str:
    """The plural of an English ``noun`` (the last word of a phrase): ``"state"`` -> ``"states"``,
    ``"velocity"`` -> ``"velocities"``, ``"box"`` -> ``"boxes"``, ``"initial value"`` ->
    ``"initial values"``.

    >>> plural("boundary condition"), plural("degree of freedom")
    ('boundary conditions', 'degrees of freedom')
    """
    head, sep, tail = noun.partition(" of ")
    if sep:  # "degree of freedom" -> "degrees of freedom"
        return plural(head) + sep + tail
    if noun.endswith("y") and len(noun) > 1 and noun[-2] not in "aeiou":
        return noun[:-1] + "ies"
    if noun.endswith(("s", "x", "z", "ch", "sh")):
        return noun + "es"
    return noun + "s"


def count(n: int, noun: str, plural_form: str | None = None) -> str:
    """``n`` and ``noun``, singular for exactly one and plural otherwise (``plural_form`` for an
    irregular plural).

    >>> count(1, "initial value"), count(6, "initial value"), count(2, "matrix", "matrices")
    ('1 initial value', '6 initial values', '2 matrices')
    """
    if n == 1:
        return f"{n} {noun}"
    return f"{n} {plural_form or plural(noun)}"


def derivative_name(equation: str, k: int) -> str:
    """The name of the ``k``-th time derivative of an equation, as every message and every
    reduced system writes it.

    >>> derivative_name("rod", 0), derivative_name("rod", 1), derivative_name("rod", 2)
    ('rod', 'd/dt rod', 'd2/dt2 rod')
    """
    if k == 0:
        return equation
    return f"d/dt {equation}" if k == 1 else f"d{k}/dt{k} {equation}"


def listing(names: list[str], limit: int = 10) -> str:
    """Names quoted and joined for a message, at most ``limit`` of them and then how many in
    all.

    >>> listing(["rod", "newton"]), listing([f"e{i}" for i in range(5)], 2)
    ("'rod', 'newton'", "'e0', 'e1', ... (5 in all)")
    """
    shown = ", ".join(repr(n) for n in names[:limit])
    return shown + (f", ... ({len(names)} in all)" if len(names) > limit else "")

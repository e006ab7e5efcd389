"""The one progress bar of daekit's integrators (IDAS driver and RATTLE).

It draws on stderr only when stderr is a terminal (``isatty()``): in a pipe, a file or a log it
writes nothing, so no carriage returns end up in files.

>>> import io
>>> out = io.StringIO()                  # not a terminal
>>> bar = Progress(True, 0.0, 1.0, "simulate", stream=out)
>>> bar.update(0.5); bar.close()
>>> out.getvalue()
''
"""

from __future__ import annotations

import sys

__all__ = ["Progress"]


class Progress:
    """A one-line progress bar ``label [#####....]  40%  t = 0.4`` on stderr (terminals only).

    Parameters
    ----------
    enabled : bool
        The caller's ``progress=`` argument; the bar draws only if it is true *and* the stream
        is a terminal.
    t0, tf : float
        The time span.
    label : str
        What runs (``"simulate"``, ``"projection"``, ``"RATTLE"``).
    stream : file, optional
        Default ``sys.stderr`` (looked up when the bar is made).
    """

    def __init__(self, enabled: bool, t0: float, tf: float, label: str, stream=None) -> None:
        self.out = sys.stderr if stream is None else stream
        try:
            tty = bool(self.out.isatty())
        except Exception:  # noqa: BLE001 - closed or odd streams
            tty = False
        self.enabled = bool(enabled) and tty and tf > t0
        self.t0, self.tf, self.label = float(t0), float(tf), label
        self.last = -1
        self.drawn = False

    def update(self, t: float, detail: str | None = None) -> None:
        """Show the fraction of the span reached at ``t`` (a time, or a count such as the
        samples done of an ensemble); ``detail`` replaces the ``t = ...`` text."""
        if not self.enabled:
            return
        frac = min(max((t - self.t0) / (self.tf - self.t0), 0.0), 1.0)
        pct = int(frac * 100)
        if pct == self.last and detail is None:
            return
        self.last = pct
        bar = "#" * (pct // 4) + "." * (25 - pct // 4)
        text = f"t = {t:.4g}" if detail is None else detail
        self.out.write(f"\r{self.label} [{bar}] {pct:3d}%  {text}")
        self.out.flush()
        self.drawn = True

    def close(self) -> None:
        """End the line (only if something was drawn)."""
        if self.enabled and self.drawn:
            self.out.write("\n")
            self.out.flush()

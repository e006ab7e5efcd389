"""Output written by C code (SUNDIALS, IPOPT, CasADi) to file descriptors 1 and 2.

SUNDIALS reports the time of a failure only on stderr ("At t = 0.99 and h = 1e-17, ..."),
and CasADi's integrator statistics are reset when a call fails. :func:`c_output` redirects
both descriptors to a temporary file while a block runs and hands the text back, so that a
caller can stay silent and still read what was said.
"""

from __future__ import annotations

import atexit
import contextlib
import io
import os
import re
import sys
import tempfile

__all__ = ["c_output", "failure_time"]

_AT_T = re.compile(r"At t\s*=\s*([-+0-9.eE]+)")


class _Captured:
    text = ""


#: temporary files not in use (one is taken per block and truncated after it: creating a
#: file per call cost a tenth of a millisecond, comparable to a short integration)
_FREE: list = []


@atexit.register
def _close_free() -> None:
    while _FREE:
        _FREE.pop().close()


@contextlib.contextmanager
def c_output(enabled: bool = True):
    """Capture what C code writes to stdout and stderr inside the block (``.text`` after it).

    ``enabled=False`` lets everything through (``.text`` stays empty).
    """
    out = _Captured()
    if not enabled:
        yield out
        return
    try:
        saved = (os.dup(1), os.dup(2))
    except OSError:  # pragma: no cover - no file descriptors (embedded interpreters)
        yield out
        return
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    try:
        tmp = _FREE.pop()
    except IndexError:
        tmp = tempfile.TemporaryFile()
    # CasADi's Python module routes its own messages through sys.stdout/sys.stderr, plain C
    # code writes to the descriptors: catch both
    py_out, py_err = sys.stdout, sys.stderr
    buf = io.StringIO()
    try:
        os.dup2(tmp.fileno(), 1)
        os.dup2(tmp.fileno(), 2)
        sys.stdout = sys.stderr = buf
        yield out
    finally:
        sys.stdout, sys.stderr = py_out, py_err
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved:
            os.close(fd)
        if os.fstat(tmp.fileno()).st_size:  # (nothing written, the common case: no I/O)
            tmp.seek(0)
            out.text = tmp.read().decode(errors="replace")
            tmp.seek(0)
            tmp.truncate()
        out.text += buf.getvalue()
        _FREE.append(tmp)


def failure_time(text: str) -> float | None:
    """The last time SUNDIALS reported (``At t = ...``) in captured output, or None.

    >>> failure_time("[IDAS ERROR]  IDASolve\\n  At t = 0.999 and h = 1e-17, the corrector failed")
    0.999
    """
    hits = _AT_T.findall(text or "")
    if not hits:
        return None
    try:
        return float(hits[-1].rstrip("."))
    except ValueError:
        return None

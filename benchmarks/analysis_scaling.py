"""How the analysis scales: ``dk.analyze`` on a planar chain of N links (5N equations).

Run ``python benchmarks/analysis_scaling.py`` (add ``--profile`` to see where the time of the
largest case goes, ``--sizes 10 100`` to choose the sizes). Prints one row per N: the number
of equations, the seconds to build the model with :func:`daekit.examples.planar_chain`, the
seconds for :func:`daekit.analyze`, and the index and DOF found (3 and 2N expected). Target:
``analyze`` on N = 2000 (10,000 equations) in under 2 s.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import time

import daekit as dk
from daekit.examples import planar_chain

SIZES = (10, 20, 50, 100, 200, 500, 1000, 2000)


def run(sizes=SIZES, profile: bool = False, budget: float = 60.0) -> list[dict]:
    """Time building and analyzing ``planar_chain(N)`` for each N; return the rows.

    Once one ``analyze`` takes longer than ``budget`` seconds the larger sizes are skipped
    (and reported as skipped), so that the script always finishes.
    """
    rows = []
    print(f"{'N':>6} {'equations':>10} {'build [s]':>10} {'analyze [s]':>12} {'index':>6} {'dof':>6}")
    for n in sizes:
        if rows and rows[-1]["analyze"] > budget:
            print(f"{n:>6} {5 * n:>10}   skipped: the previous analyze took more than {budget:g} s")
            rows.append(dict(N=n, equations=5 * n, build=None, analyze=float("inf"), ok=False))
            continue
        t0 = time.perf_counter()
        m = planar_chain(n)
        t1 = time.perf_counter()
        a = dk.analyze(m)
        t2 = time.perf_counter()
        ok = a.index == 3 and a.dof == 2 * n
        row = dict(N=n, equations=m.n_equations, build=t1 - t0, analyze=t2 - t1,
                   index=a.index, dof=a.dof, ok=ok)  # fmt: skip
        rows.append(row)
        flag = "" if ok else "   <-- expected index 3, dof 2N"
        print(f"{n:>6} {m.n_equations:>10} {t1 - t0:>10.3f} {t2 - t1:>12.3f} {a.index:>6} "
              f"{a.dof:>6}{flag}", flush=True)  # fmt: skip
    done = [r["N"] for r in rows if r["build"] is not None]
    if profile and done:
        m = planar_chain(done[-1])
        prof = cProfile.Profile()
        prof.enable()
        dk.analyze(m)
        prof.disable()
        print(f"\nprofile of analyze(planar_chain({done[-1]})), by cumulative time:")
        pstats.Stats(prof, stream=sys.stdout).sort_stats("cumulative").print_stats(20)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="*", default=list(SIZES))
    ap.add_argument("--profile", action="store_true", help="profile analyze on the largest N")
    ap.add_argument("--budget", type=float, default=60.0,
                    help="skip larger sizes once one analyze takes longer (seconds)")  # fmt: skip
    args = ap.parse_args(argv)
    rows = run(args.sizes, args.profile, args.budget)
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())

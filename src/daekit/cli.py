"""Command line: ``daekit tour | analyze | reduce | simulate``.

``FILE.py[:FUNCTION]`` names a Python file whose function (default ``model``) returns a
:class:`daekit.Model` (or a :class:`daekit.mechanics.LagrangianSystem`, or for ``simulate`` a
:class:`daekit.ReducedDAE`). Instead of a file, the name of a built-in example works too
(``daekit analyze pendulum3d``; ``daekit analyze --list`` lists them).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np

from .errors import DaekitError, ModelError

__all__ = ["main", "load_target"]


def load_target(spec: str):
    """Load ``FILE.py[:FUNCTION]`` (default function ``model``) or a built-in example name and
    return what the function returns."""
    from . import examples

    path_part, _, func = spec.partition(":")
    if not path_part.endswith(".py"):
        cat = examples.catalog()
        if spec in cat:
            return cat[spec].factory()
        if hasattr(examples, spec) and callable(getattr(examples, spec)):
            return getattr(examples, spec)()
        raise ModelError(
            f"{spec!r} is neither a Python file (FILE.py[:FUNCTION]) nor a built-in example; "
            f"examples: {', '.join(sorted(cat))}"
        )
    path = Path(path_part)
    if not path.is_file():
        raise ModelError(f"no such file: {path}")
    func = func or "model"
    mod_spec = importlib.util.spec_from_file_location(f"daekit_user_{path.stem}", path)
    module = importlib.util.module_from_spec(mod_spec)
    sys.path.insert(0, str(path.parent.resolve()))
    try:
        mod_spec.loader.exec_module(module)
    finally:
        sys.path.pop(0)
    if not hasattr(module, func):
        funcs = [n for n in dir(module) if callable(getattr(module, n)) and not n.startswith("_")]
        raise ModelError(f"{path} has no function {func!r} (it has: {', '.join(funcs) or 'none'})")
    return getattr(module, func)()


def _as_model(obj):
    from .mechanics import LagrangianSystem
    from .model import Model

    if isinstance(obj, LagrangianSystem):
        return obj.model()
    if isinstance(obj, Model):
        return obj
    raise ModelError(f"expected a daekit.Model (or LagrangianSystem), got {type(obj).__name__}")


def _as_reduced(obj, method: str, stabilization: str | None):
    from .mechanics import LagrangianSystem
    from .reduced import ReducedDAE
    from .reduction import reduce_index

    if isinstance(obj, ReducedDAE):
        return obj
    if isinstance(obj, LagrangianSystem) and method != "rattle" and stabilization != "dummy_derivatives":
        return obj.index1()
    if isinstance(obj, LagrangianSystem):
        return obj.index1() if method == "rattle" else reduce_index(obj.model(), method="dummy_derivatives")
    red_method = "dummy_derivatives" if stabilization == "dummy_derivatives" else "differentiate"
    return reduce_index(_as_model(obj), method=red_method)


def _cmd_analyze(args) -> int:
    from .analysis import analyze

    m = _as_model(load_target(args.target))
    a = analyze(m)
    if args.json:
        print(json.dumps(a.to_dict(), indent=2))
    else:
        print(a.explain())
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        a.plot_structure().savefig(args.plot, dpi=110)
        print(f"wrote {args.plot}", file=sys.stderr if args.json else sys.stdout)
    return 0


def _parse_inputs(specs: list[str] | None, r) -> dict | None:
    """``["u=[0, 0, sin(t)]"]`` -> ``{"u": SX expression of r.t}`` (CasADi's math names)."""
    import casadi as ca

    if not specs:
        return None
    names = {k: getattr(ca, k) for k in ("sin", "cos", "tan", "exp", "log", "sqrt", "tanh",
                                         "fabs", "fmin", "fmax", "pi", "atan2")}
    names.update(t=r.t, abs=ca.fabs)
    out = {}
    for spec in specs:
        key, eq, text = spec.partition("=")
        if not eq or not key.strip():
            raise ModelError(f"--input {spec!r}: write NAME=EXPRESSION, e.g. u='[0, 0, sin(t)]'")
        try:
            val = eval(text, {"__builtins__": {}}, names)  # noqa: S307 - the user's own command
        except Exception as exc:  # noqa: BLE001 - reported as a daekit error
            raise ModelError(f"--input {spec!r}: cannot evaluate {text!r} ({exc})") from None
        out[key.strip()] = ca.vertcat(*val) if isinstance(val, (list, tuple)) else val
    return out


def _cmd_reduce(args) -> int:
    from .reduction import format_reduced

    obj = load_target(args.target)
    r = _as_reduced(obj, "idas", "dummy_derivatives" if args.method == "dummy_derivatives" else None)
    print(format_reduced(r))
    return 0


def _cmd_simulate(args) -> int:
    from .initialize import initialize
    from .simulate import simulate

    obj = load_target(args.target)
    r = _as_reduced(obj, args.method, args.stabilization)
    fixed = json.loads(args.fixed) if args.fixed else None
    guess = json.loads(args.guess) if args.guess else None
    inputs = _parse_inputs(args.input, r)
    init = initialize(r, fixed=fixed, guess=guess, inputs=inputs)
    t = np.linspace(0.0, args.t_end, args.points)
    traj = simulate(r, t, init, inputs=inputs, stabilization=args.stabilization, rtol=args.rtol,
                    atol=args.atol, method=args.method, progress=not args.quiet)
    final = traj.at(float(t[-1]))
    maxinv = traj.max_invariant()
    print(f"simulated {r.model.name if r.model is not None else 'system'} to t = {t[-1]:g}: "
          f"{traj.stats.get('steps', '?')} steps, {traj.stats.get('wall_time', float('nan')):.3f} s")
    if traj.events:
        shown = ", ".join(f"{n} at t = {te:.10g}" for te, n in traj.events[:10])
        more = f", ... ({len(traj.events)} in all)" if len(traj.events) > 10 else ""
        print(f"events: {shown}{more}")
    for k, v in final.items():
        print(f"  {k:>16} = {v: .10g}")
    if maxinv:
        print("max |invariant|: " + ", ".join(f"{k}: {v:.2e}" for k, v in maxinv.items()))
    if args.json:
        data = {"t": traj.t.tolist(), "values": {k: traj[k].tolist() for k in traj.names},
                "invariant_names": traj.invariant_names, "invariants": traj.invariants.tolist(),
                "stats": {k: v for k, v in traj.stats.items() if isinstance(v, (int, float, str))},
                "events": [[te, n] for te, n in traj.events]}
        Path(args.json).write_text(json.dumps(data))
        print(f"wrote {args.json}")
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        fig = traj.plot()
        fig.savefig(args.plot, dpi=110)
        print(f"wrote {args.plot}")
    return 0


def _cmd_tour(args) -> int:
    from .tour import run_tour

    run_tour(out=args.out, t_end=args.t_end, quiet=args.quiet,
             gifs=args.gifs and not args.no_animations, ocp=not args.no_ocp)
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="daekit", description="DAEs of any index: analyze, reduce, "
                                "simulate with drift control, optimal control.")
    sub = p.add_subparsers(dest="command", required=True)

    t = sub.add_parser("tour", help="the lecture's story on the 3D pendulum and the delta robot")
    t.add_argument("--out", default="daekit-tour", help="folder for the figures (default: %(default)s)")
    t.add_argument("--t-end", type=float, default=100.0, help="simulated seconds (default: 100)")
    t.add_argument("--quiet", action="store_true", help="no progress on stderr")
    t.add_argument("--gifs", action="store_true",
                   help="also write the GIF animations (real time, 480 pixels; a few seconds more)")
    t.add_argument("--no-animations", action="store_true",
                   help="no GIF animations (the default; overrides --gifs)")
    t.add_argument("--no-ocp", action="store_true", help="skip the optimal control section")
    t.set_defaults(func=_cmd_tour)

    a = sub.add_parser("analyze", help="index, offsets, DOF and a plain-language explanation")
    a.add_argument("target", help="FILE.py[:FUNCTION] or a built-in example name")
    a.add_argument("--json", action="store_true", help="print a JSON summary")
    a.add_argument("--plot", metavar="OUT.png", help="save the Sigma matrix with offsets")
    a.set_defaults(func=_cmd_analyze)

    r = sub.add_parser("reduce", help="print the index-1 form, invariants, state selection")
    r.add_argument("target")
    r.add_argument("--method", default="differentiate", choices=["differentiate", "dummy_derivatives"])
    r.set_defaults(func=_cmd_reduce)

    s = sub.add_parser("simulate", help="reduce, initialize and simulate")
    s.add_argument("target")
    s.add_argument("--t-end", type=float, required=True)
    s.add_argument("--points", type=int, default=501, help="output points (default: %(default)s)")
    s.add_argument("--stabilization", default=None,
                   choices=["baumgarte", "projection", "dummy_derivatives"])
    s.add_argument("--method", default="idas", choices=["idas", "rattle"])
    s.add_argument("--fixed", help='JSON of fixed initial values, e.g. \'{"p[0]": 1.0}\'')
    s.add_argument("--guess", help="JSON of initial guesses")
    s.add_argument("--input", action="append", metavar="NAME=EXPR",
                   help="an input as an expression of t, e.g. u='[0, 0, sin(t)]' (repeatable; "
                        "inputs not given are zero)")
    s.add_argument("--rtol", type=float, default=1e-8)
    s.add_argument("--atol", type=float, default=1e-8)
    s.add_argument("--json", metavar="OUT", help="write the trajectory as JSON")
    s.add_argument("--plot", metavar="OUT.png", help="save a plot of the trajectory")
    s.add_argument("--quiet", action="store_true")
    s.set_defaults(func=_cmd_simulate)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except DaekitError as exc:
        print(f"daekit: error: {exc}", file=sys.stderr)
        return 2
    except json.JSONDecodeError as exc:
        print(f"daekit: error: --fixed/--guess is not valid JSON ({exc})", file=sys.stderr)
        return 2
    except OSError as exc:  # a figure or JSON file that cannot be written
        print(f"daekit: error: {exc.strerror or exc}: {exc.filename or ''}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())

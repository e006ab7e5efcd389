"""Command line: ``daekit tour | analyze | reduce | simulate | sweep``.

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
    """Load ``FILE.py[:NAME]`` or a built-in example name: what the function ``NAME``
    (default ``model``) returns, or ``NAME`` itself where it is a Model (or ReducedDAE,
    Lagrangian system); without ``:NAME`` and without a ``model``, the one model the file
    builds at top level."""
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
    explicit = bool(func)
    func = func or "model"
    mod_spec = importlib.util.spec_from_file_location(f"daekit_user_{path.stem}", path)
    module = importlib.util.module_from_spec(mod_spec)
    sys.path.insert(0, str(path.parent.resolve()))
    try:
        mod_spec.loader.exec_module(module)
    except SyntaxError as exc:
        where = f"{path}, line {exc.lineno}" if exc.lineno else str(path)
        text = f":\n    {exc.text.rstrip()}" if exc.text else ""
        raise ModelError(f"{where}: syntax error: {exc.msg}{text}") from None
    except DaekitError:
        raise
    except Exception as exc:  # noqa: BLE001 - the user's code: say where, no traceback
        raise ModelError(f"{path}{_user_line(exc, path)}: running the file raised "
                         f"{type(exc).__name__}: {exc}") from None
    finally:
        sys.path.pop(0)
    from .mechanics import LagrangianSystem
    from .model import Model
    from .reduced import ReducedDAE

    def is_model(v) -> bool:  # what _as_model and the commands accept
        return isinstance(v, (Model, ReducedDAE, LagrangianSystem))
    if not hasattr(module, func):
        found = [n for n, v in vars(module).items() if not n.startswith("_") and is_model(v)]
        if not explicit and len(found) == 1:  # a script that builds one model at top level
            return getattr(module, found[0])
        funcs = [n for n in dir(module) if callable(getattr(module, n)) and not n.startswith("_")]
        models = f"; models: {', '.join(found)} (name one: {path}:NAME)" if found else ""
        raise ModelError(f"{path} has no function {func!r} (it has: {', '.join(funcs) or 'none'}"
                         f"{models})")
    if not callable(getattr(module, func)):
        if is_model(getattr(module, func)):  # model = m: the object itself
            return getattr(module, func)
        raise ModelError(f"{path}: {func!r} is a {type(getattr(module, func)).__name__}, not a "
                         "function returning a model or a daekit Model")
    try:
        return getattr(module, func)()
    except DaekitError as exc:
        raise type(exc)(f"{path}{_user_line(exc, path)}: {func}() raised: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - the user's code: say where, no traceback
        raise ModelError(f"{path}{_user_line(exc, path)}: {func}() raised "
                         f"{type(exc).__name__}: {exc}") from None


def _user_line(exc: BaseException, path: Path) -> str:
    """``", line N"`` of the innermost frame of ``exc`` in the user's file ``path``."""
    import traceback

    try:
        target = path.resolve()
        frames = [f for f in traceback.extract_tb(exc.__traceback__)
                  if Path(f.filename).resolve() == target]
    except OSError:  # pragma: no cover
        return ""
    return f", line {frames[-1].lineno}" if frames else ""


def _as_model(obj):
    from .mechanics import LagrangianSystem
    from .model import Model

    if isinstance(obj, LagrangianSystem):
        return obj.model()
    if isinstance(obj, Model):
        return obj
    raise ModelError(f"expected a daekit.Model (or LagrangianSystem), got {type(obj).__name__}")


def _as_reduced(obj, method: str, stabilization: str | None):
    """The file's object as a ReducedDAE, by the entry points' one rule
    (:func:`daekit.reduction.as_reduced`)."""
    from .reduced import ReducedDAE
    from .reduction import as_reduced

    if not isinstance(obj, ReducedDAE) and not hasattr(obj, "index1"):
        obj = _as_model(obj)  # names what the file returned when it is not a model
    return as_reduced(obj, "simulate", stabilization=stabilization, method=method)


def _cmd_analyze(args) -> int:
    from .analysis import analyze

    m = _as_model(load_target(args.target))
    a = analyze(m)
    if args.json:
        print(json.dumps(_analysis_json(a, m), indent=2))
    else:
        print(a.explain())
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        a.plot_structure().savefig(args.plot, dpi=110)
        print(f"wrote {args.plot}", file=sys.stderr if args.json else sys.stdout)
    return 0


def _analysis_json(a, m) -> dict:
    """``analyze --json``: the analysis, the consistency conditions (from the reduction, when it
    succeeds), the input derivatives and the plain-language explanation."""
    d = a.to_dict()
    d["input_derivatives"] = dict(a.input_derivatives)
    d["definitions"] = list(a.definitions)
    try:
        from .reduction import reduce_index

        d["consistency_conditions"] = list(reduce_index(m).invariant_names)
    except DaekitError as exc:
        d["consistency_conditions"] = None
        d["consistency_conditions_error"] = str(exc)
    d["explanation"] = a.explain()
    return d


def _reduced_json(r) -> dict:
    """``reduce --json``: the index-1 form by names, its invariants and state selection."""
    def text(e):
        return [str(e[i]) for i in range(e.numel())]

    d = {
        "model": getattr(r.model, "name", None), "method": r.method,
        "stabilization": r.stabilization,
        "states": list(r.x_names), "algebraic": list(r.z_names), "inputs": list(r.u_names),
        "parameters": dict(zip(r.p_names, np.asarray(r.p_values, float).ravel().tolist(),
                               strict=False)),
        "input_derivatives": list(r.input_derivatives),
        "invariant_names": list(r.invariant_names),
        "ode": dict(zip(r.x_names, text(r.ode), strict=False)),
        "alg": dict(zip(r.alg_labels, text(r.alg), strict=False)),
        "invariants": dict(zip(r.invariant_names, text(r.invariants), strict=False)),
        "eliminated": [{k: str(v) for k, v in e.items()} for e in r.eliminated],
    }
    if r.state_selection:
        d["state_selection"] = json.loads(json.dumps(r.state_selection, default=str))
    return d


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
    if args.json:
        print(json.dumps(_reduced_json(r), indent=2))
    else:
        print(format_reduced(r))
    return 0


def _cmd_simulate(args) -> int:
    import math

    from .initialize import initialize
    from .simulate import simulate

    # the checks of the numbers first: nothing runs (nor prints) on a bad --t-end or --rtol
    for flag, value in (("--t-end", args.t_end), ("--rtol", args.rtol), ("--atol", args.atol)):
        if not (math.isfinite(value) and value > 0):
            raise SystemExit(f"daekit simulate: {flag} must be a positive number, got {value}")
    if args.points < 2:
        raise SystemExit(f"daekit simulate: --points must be at least 2, got {args.points}")
    # "--json -" writes the JSON to stdout; the human-readable lines then go to stderr
    out = sys.stderr if args.json == "-" else sys.stdout

    def say(text: str = "") -> None:
        print(text, file=out)

    obj = load_target(args.target)
    r = _as_reduced(obj, args.method, args.stabilization)
    fixed = json.loads(args.fixed) if args.fixed else None
    guess = json.loads(args.guess) if args.guess else None
    inputs = _parse_inputs(args.input, r)
    init = initialize(r, fixed=fixed, guess=guess, inputs=inputs)
    say(_describe_initial(r, init, fixed, guess))
    t = np.linspace(0.0, args.t_end, args.points)
    tols = {} if args.method == "rattle" else {"rtol": args.rtol, "atol": args.atol}
    traj = simulate(r, t, init, inputs=inputs, stabilization=args.stabilization,
                    method=args.method, progress=not args.quiet, **tols)
    final = traj.at(float(t[-1]))
    maxinv = traj.max_invariant()
    say(f"simulated {r.model.name if r.model is not None else 'system'} to t = {t[-1]:g}: "
          f"{traj.stats.get('steps', '?')} steps, {traj.stats.get('wall_time', float('nan')):.3f} s")
    if traj.events:
        shown = ", ".join(f"{n} at t = {te:.10g}" for te, n in traj.events[:10])
        more = f", ... ({len(traj.events)} in all)" if len(traj.events) > 10 else ""
        say(f"events: {shown}{more}")
    pnames = set(r.p_names)
    for k, v in final.items():
        if k not in pnames:
            say(f"  {k:>16} = {v: .10g}")
    if r.p_names:
        pv = _trajectory_json_parameters(r, traj)
        say("parameters: " + ", ".join(f"{k} = {v:g}" for k, v in pv.items()))
    if maxinv:
        say("max |invariant|: " + ", ".join(f"{k}: {v:.2e}" for k, v in maxinv.items()))
    if args.json == "-":
        print(json.dumps(_trajectory_json(r, traj)))
    elif args.json:
        Path(args.json).write_text(json.dumps(_trajectory_json(r, traj)))
        say(f"wrote {args.json}")
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        from .plot import plot_overview

        fig = plot_overview(traj, exclude=r.p_names)
        fig.savefig(args.plot, dpi=110)
        print(f"wrote {args.plot}")
    return 0


def _describe_initial(r, init, fixed, guess) -> str:
    """The initial values used, each marked fixed (given), free (could have been given) or
    determined (by the constraints and the others)."""
    fixed_names = set(getattr(init, "fixed", None) or [])
    if not fixed_names and fixed:
        from .model import expand_name

        for k in fixed:
            try:
                fixed_names.update(expand_name(k, r.variables))
            except DaekitError:
                pass
    free = set(init.free)
    how = "from your --fixed/--guess" if (fixed or guess) else \
        ("no --fixed/--guess given: dk.initialize's default start (zeros, and a generic "
         "point where zeros are singular) made consistent by Gauss-Newton; give --fixed to "
         "choose")
    lines = [f"initial values at t = {init.t0:g} ({how}; consistent to {init.residual:.1e}):"]
    for nm, v in zip(r.x_names, init.x0, strict=False):
        mark = "fixed" if nm in fixed_names else ("free" if nm in free else "determined")
        lines.append(f"  {nm:>16} = {v: .10g}   {mark}")
    others = sorted(fixed_names - set(r.x_names))
    for nm in others:
        lines.append(f"  {nm:>16} = {init.values.get(nm, float('nan')): .10g}   fixed")
    if free - fixed_names:
        lines.append("  free: could be set with --fixed instead ("
                     + ", ".join(n for n in r.x_names if n in free and n not in fixed_names) + ")")
    return "\n".join(lines)


def _trajectory_json_parameters(r, traj) -> dict[str, float]:
    """The parameter values used (a constant column of the trajectory), else the defaults."""
    pvals = dict(zip(r.p_names, np.asarray(r.p_values, float).ravel().tolist(), strict=False))
    for k in r.p_names:
        if k in traj.values and traj.values[k].size:
            pvals[k] = float(traj.values[k][0])
    return pvals


def _trajectory_json(r, traj) -> dict:
    """``simulate --json``: time series of the variables, the parameters once."""
    pnames = set(r.p_names)
    pvals = _trajectory_json_parameters(r, traj)
    return {
        "t": traj.t.tolist(),
        "values": {k: traj[k].tolist() for k in traj.names if k not in pnames},
        "parameters": pvals,
        "invariant_names": traj.invariant_names, "invariants": traj.invariants.tolist(),
        "stats": {k: v for k, v in traj.stats.items() if isinstance(v, (int, float, str))},
        "events": [[te, n] for te, n in traj.events],
    }


def _parse_param(spec: str) -> tuple[str, list[float]]:
    """``"L=0.5:2.0:16"`` (16 values from 0.5 to 2.0) or ``"L=0.5,1,2"`` -> (name, values)."""
    name, eq, text = spec.partition("=")
    name = name.strip()
    if not eq or not name or not text.strip():
        raise ModelError(f"--param {spec!r}: write NAME=LO:HI:N (N values from LO to HI) or "
                         "NAME=V1,V2,...")
    try:
        if ":" in text:
            parts = text.split(":")
            if len(parts) != 3:
                raise ValueError
            lo, hi, n = float(parts[0]), float(parts[1]), int(parts[2])
            if n < 1:
                raise ValueError
            return name, np.linspace(lo, hi, n).tolist()
        return name, [float(v) for v in text.split(",")]
    except ValueError:
        raise ModelError(f"--param {spec!r}: write NAME=LO:HI:N (N an integer >= 1) or "
                         "NAME=V1,V2,... with numbers") from None


def _parse_draw(spec: str) -> tuple[str, tuple]:
    """``"L=uniform:0.8:1.2"`` -> ``("L", ("uniform", 0.8, 1.2))`` (see :func:`daekit.sample`)."""
    name, eq, text = spec.partition("=")
    parts = text.split(":")
    try:
        if not eq or not name.strip() or len(parts) < 2:
            raise ValueError
        return name.strip(), (parts[0].strip(), *[float(v) for v in parts[1:]])
    except ValueError:
        raise ModelError(f"--draw {spec!r}: write NAME=DISTRIBUTION:A:B, e.g. L=uniform:0.8:1.2 "
                         "or m=normal:1.0:0.05") from None


def _cmd_sweep(args) -> int:
    import itertools

    from .ensemble import Ensemble, ensemble

    if not args.param and not args.draw:
        raise ModelError("sweep: give --param NAME=LO:HI:N (a grid) or --draw NAME=DIST:A:B "
                         "--n N (Monte Carlo)")
    # the summary file is checked first: a bad --out must not cost the whole sweep
    Ensemble.summary_format(args.out, where=f"--out {args.out}")
    obj = load_target(args.target)
    r = _as_reduced(obj, "idas", args.stabilization)
    grids = [_parse_param(p) for p in args.param or []]
    spec = dict(_parse_draw(d) for d in args.draw or [])
    names = [g[0] for g in grids] + list(spec)
    if len(set(names)) != len(names):
        raise ModelError(f"--param/--draw: a name is given twice ({', '.join(names)})")
    samples = [dict(zip(names, combo, strict=False))
               for combo in itertools.product(*[g[1] for g in grids])]
    if spec:
        from .sampling import sample

        draws = sample(spec, args.n, seed=args.seed)
        samples = [{**g, **d} for g in samples for d in draws]
    fixed = json.loads(args.fixed) if args.fixed else None
    guess = json.loads(args.guess) if args.guess else None
    inputs = _parse_inputs(args.input, r)
    t = np.linspace(0.0, args.t_end, args.points)
    client = None
    executor = "serial" if args.serial else None
    if args.scheduler:
        try:
            from distributed import Client
        except ImportError:
            raise ModelError('--scheduler needs Dask: pip install "daekit[dask]"') from None
        try:
            client = Client(args.scheduler, timeout=args.timeout)
        except Exception as exc:  # noqa: BLE001 - a bad address (ValueError), no scheduler
            # there (OSError, TimeoutError), ...: the user's address, reported without traceback
            raise ModelError(f"--scheduler {args.scheduler}: cannot connect "
                             f"({type(exc).__name__}: {exc})") from None
        executor = client
    try:
        ens = ensemble(r, t, samples, executor=executor, fixed=fixed, guess=guess, inputs=inputs,
                       progress=not args.quiet, keep="summary",
                       stabilization=args.stabilization, rtol=args.rtol, atol=args.atol)
    finally:
        if client is not None:
            client.close()
    out = args.out
    ens.save_summary(out)
    ok = len(ens) - len(ens.failures)
    print(f"swept {len(ens)} samples of {', '.join(names)} on {ens.stats['executor']} in "
          f"{ens.stats['wall_time']:.2f} s: {ok} succeeded, {len(ens.failures)} failed")
    for msg in list(ens.failures.values())[:5]:
        print(f"  failed: {msg[:300]}")
    if len(ens.failures) > 5:
        print(f"  ... ({len(ens.failures) - 5} more failures in {out})")
    print(f"wrote {out}")
    return 0 if ok else 1


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
                   help="also write the GIF animations (real time, 480 pixels; 10-20 s more)")
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
    r.add_argument("--json", action="store_true",
                   help="print the index-1 form, invariants and state selection as JSON")
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
    s.add_argument("--json", metavar="OUT",
                   help="write the trajectory as JSON to OUT ('-': to stdout, the rest to stderr)")
    s.add_argument("--plot", metavar="OUT.png", help="save a plot of the trajectory")
    s.add_argument("--quiet", action="store_true",
                   help="no progress bar on stderr (the results are still printed)")
    s.set_defaults(func=_cmd_simulate)

    w = sub.add_parser("sweep", help="a parameter sweep: one simulation per sample, a summary "
                       "table (CSV or Parquet); local processes or a Dask scheduler")
    w.add_argument("target")
    w.add_argument("--param", action="append", metavar="NAME=LO:HI:N",
                   help="values of a parameter (or of a fixed initial value): LO:HI:N or "
                        "V1,V2,...; several --param give the full grid")
    w.add_argument("--draw", action="append", metavar="NAME=DIST:A:B",
                   help="Monte Carlo: draw NAME from uniform:LO:HI, normal:MEAN:STD, "
                        "lognormal:MU:SIGMA, loguniform:LO:HI, triangular:LO:MODE:HI (--n draws, "
                        "--seed; with --param, at every grid point)")
    w.add_argument("--n", type=int, default=100, help="number of draws (default: %(default)s)")
    w.add_argument("--seed", type=int, default=0, help="seed of the draws (default: 0)")
    w.add_argument("--t-end", type=float, required=True)
    w.add_argument("--points", type=int, default=501, help="output points (default: %(default)s)")
    w.add_argument("--stabilization", default=None,
                   choices=["baumgarte", "projection", "dummy_derivatives"])
    w.add_argument("--fixed", help="JSON of fixed initial values shared by all samples")
    w.add_argument("--guess", help="JSON of initial guesses")
    w.add_argument("--input", action="append", metavar="NAME=EXPR")
    w.add_argument("--rtol", type=float, default=1e-8)
    w.add_argument("--atol", type=float, default=1e-8)
    w.add_argument("--out", default="sweep.csv",
                   help="summary file, .csv or .parquet (default: %(default)s)")
    w.add_argument("--scheduler", metavar="ADDRESS",
                   help="a Dask scheduler, e.g. tcp://10.0.0.5:8786 (default: local processes)")
    w.add_argument("--timeout", type=float, default=10.0, help="seconds to reach the scheduler")
    w.add_argument("--serial", action="store_true", help="run in this process")
    w.add_argument("--quiet", action="store_true")
    w.set_defaults(func=_cmd_sweep)
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

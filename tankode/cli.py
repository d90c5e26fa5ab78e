"""Command line: ``tankode simulate | assimilate | predict | diagnose | bench | sensitivity``."""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from contextlib import contextmanager
from pathlib import Path

from .errors import ConfigurationError
from .files import check_output_dir

# Choices spelled out so that argument parsing imports neither torch nor CoolProp (a test
# checks each against the library's own table).
_GRADIENTS = ("adjoint", "backprop", "checkpointed")  # tankode assimilate --gradient
_INPUT_SETS = ("operations", "paper", "extended")  # tankode.closures.INPUT_SETS, the default first
_EXIT_ERROR = 2  # every error: a bad input, a failed simulation, a refused output


def _input_set(name: str) -> tuple[str, ...]:
    from .closures import INPUT_SETS

    return INPUT_SETS[name]


def _gradient(name: str):
    from .solver import Adjoint, Backprop, Checkpointed

    return {"adjoint": Adjoint, "backprop": Backprop, "checkpointed": Checkpointed}[name]()


def _load_case_or_run(spec: str):
    from .cases import CASES, get_case
    from .run_io import read_run

    if spec in CASES:
        return get_case(spec), False
    path = Path(spec)
    if not path.exists():
        raise FileNotFoundError(f"{spec!r} is neither a case ({', '.join(CASES)}) nor an existing run JSON file")
    run = read_run(path)
    return run, len(run.observations) > 0


def _input_files(run) -> list[Path]:
    """The files a run was read from (its JSON and CSV), for the output guard; none for a built-in case."""
    if run.path is None:
        return []
    from .run_io import timeseries_path

    return [Path(run.path), timeseries_path(Path(run.path))]


def _parse_mechanism(spec: str):
    """``ID:NAME=VALUE[,NAME=VALUE]`` (e.g. ``vapor_leak:mdot_kg_s=1e-4``) -> a mechanism."""
    from .mechanisms import make_mechanism

    mid, _, rest = spec.partition(":")
    values = {}
    for item in filter(None, rest.split(",")):
        name, eq, value = item.partition("=")
        try:
            values[name.strip()] = float(value)
        except ValueError:
            eq = ""
        if not eq:
            raise ConfigurationError(f"--mechanism {spec!r}: expected ID:NAME=VALUE[,NAME=VALUE], e.g. vapor_leak:mdot_kg_s=1e-4")
    with _options_checked():
        return make_mechanism(mid.strip(), **values)


def _parse_mechanisms(specs) -> tuple:
    """Every ``--mechanism`` spec parsed (``_parse_mechanism``); a mechanism named twice is refused
    with the form that sets several of its parameters."""
    out = tuple(_parse_mechanism(spec) for spec in specs)
    ids = [m.id for m in out]
    twice = sorted({i for i in ids if ids.count(i) > 1})
    if twice:
        raise ConfigurationError(f"--mechanism names {', '.join(twice)} more than once; give a mechanism's parameters "
                                 f"once, comma-separated, e.g. {twice[0]}:NAME=VALUE,NAME=VALUE")
    return out


@contextmanager
def _options_checked():
    """A configuration's refusal of the options as a ``ConfigurationError`` (not led by the runs)."""
    try:
        yield
    except ConfigurationError:
        raise
    except ValueError as err:
        raise ConfigurationError(str(err)) from err


def _whole_number(text: str, option: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise ConfigurationError(f"{option}: expected a whole number, got {text!r}") from None


def _audited_wall(run):
    """``run`` with a wall heat capacity it does not state read by the inventory audit where it can be
    (``with_audited_wall``), saying so. Not for ``diagnose``, which audits the run itself and keeps
    such a capacity an estimate (not a stated value a fault could make wrong)."""
    if not len(run.observations):
        return run
    from .diagnosis.audit import with_audited_wall

    run, note = with_audited_wall(run)
    if note:
        print(f"note: {note}")
    return run


def _initial(run, how: str):
    """The run started as asked (``metadata`` or ``measured``), saying where its metadata and first samples
    disagree."""
    for note in run.notes():
        print(f"note: {note}")
    for note in run.initial_disagreements():
        print(f"note: {note}; starting from the " + ("samples at the start (--initial measured)" if how == "measured"
                                                   else "metadata (--initial measured starts from the samples)"))
    return run.with_measured_initial() if how == "measured" else run


def cmd_simulate(args) -> int:
    from .plotting import plot_run
    from .run_io import write_run
    from .simulation import simulate
    from .synthetic import solution_to_runs

    run, measured = _load_case_or_run(args.run)
    inputs = _input_files(run)
    closure, mechanisms = None, ()
    if args.model is not None:
        from .saved import load_model

        inputs.append(Path(args.model))
    out = check_output_dir(args.out, inputs)
    run = _initial(_audited_wall(run), args.initial)
    if args.model is not None:
        closure, mechanisms, _ = load_model(args.model)
    hidden = _parse_mechanisms(args.mechanism)
    model_name = f"the model in {args.model}" if args.model else "the reference closure"
    if hidden:
        model_name += " and the mechanism(s) " + ", ".join(f"{m.id} {m.values_dict()}" for m in hidden)
    sol = simulate(run, closure, output_dt_s=args.dt, mechanisms=tuple(mechanisms) + hidden)
    (sim,) = solution_to_runs(run, sol, noise=args.noise, seed=args.seed, model_name=model_name)
    json_path, csv_path = write_run(sim, out)
    png = out / f"{sim.name}.png"
    clean = solution_to_runs(run, sol, noise="clean")[0]
    plot_run(png, clean if args.noise != "clean" else sim, measured=run if measured else (sim if args.noise != "clean" else None),
             title=f"{run.name}: tankode simulation" + (" vs measured data" if measured else f" ({args.noise} noise)"))
    for note in sol.notes:
        print(f"note: {note}")
    print(f"simulated {sol.t_s[-1] - sol.t_s[0]:.0f} s of {run.name} in {sol.wall_time_s:.2f} s "
          f"(real-time factor {sol.real_time_factor:.0f}, {sol.stats.n_rhs_evals} RHS evaluations, "
          f"{sol.stats.n_segments} segments)")
    print(f"wrote {json_path}, {csv_path}, {png}")
    return 0


def cmd_assimilate(args) -> int:
    from trainers.assimilate import WINDOW_MIN_SAMPLES, AssimilationConfig, Assimilator, window_for
    from trainers.memory import MEMORIES

    from trainers.distributed import launch_from_environment

    from .run_io import read_run
    from .saved import load_model, save_model

    # Under torchrun (RANK, WORLD_SIZE > 1): one rank of a data-parallel job; rank 0 alone writes.
    launch = launch_from_environment(args.collective_timeout)
    writes = launch is None or launch.writes
    read = [read_run(p) for p in args.runs]
    for p, r in zip(args.runs, read):
        if not (r.observations.t_s > r.t0_s).any():
            raise ValueError(f"{p}: no measurement after the run's start (t = {r.t0_s:g} s): nothing for the agent "
                             f"to learn from")
    out = check_output_dir(args.out, [f for r in read for f in _input_files(r)]
                           + ([Path(args.init)] if args.init is not None else []))
    checkpoint = out / "checkpoint.pt"
    if writes and args.resume and not checkpoint.exists():
        raise FileNotFoundError(f"--resume: there is no checkpoint to resume from ({checkpoint} does not exist)")
    if writes and checkpoint.exists() and not args.resume:
        raise ValueError(f"{checkpoint} exists: pass --resume to continue that training, or choose another --out")
    runs = [_initial(_audited_wall(r), args.initial) for r in read]
    # Options left out take the configuration's defaults; the gradient follows the integrator
    # (Rosenbrock has no continuous adjoint).
    integrator = args.integrator or AssimilationConfig.integrator
    gradient = _gradient(args.gradient) if args.gradient else (
        AssimilationConfig.gradient if integrator == AssimilationConfig.integrator
        else _gradient("backprop" if integrator == "rosenbrock" else "adjoint"))
    window_s = args.window
    if window_s is None:  # from the data: a window must hold samples to learn from
        window_s = window_for(runs)
        if window_s != AssimilationConfig.window_s:
            print(f"note: windows of {window_s:.0f} s, {WINDOW_MIN_SAMPLES} samples of the most sparsely logged run "
                  f"(--window sets another length)")
    with _options_checked():
        config = AssimilationConfig(window_s=window_s, mode=args.mode or AssimilationConfig.mode,
                                    batch_fraction=args.batch, iters=args.iters, seed=args.seed,
                                    memory=MEMORIES[args.memory](),
                                    window_start=args.window_start or AssimilationConfig.window_start,
                                    start_prior_sigmas=args.start_prior_sigmas, gradient=gradient, integrator=integrator,
                                    train_mechanisms=tuple(args.train_mechanisms),
                                    replay_segments=args.replay_segments or AssimilationConfig.replay_segments,
                                    replay_s=args.replay_s or AssimilationConfig.replay_s,
                                    update_budget_s=args.update_budget,
                                    wall=args.wall or AssimilationConfig.wall,
                                    boiling=args.boiling or AssimilationConfig.boiling,
                                    unknown_wall=args.unknown_wall or AssimilationConfig.unknown_wall,
                                    carry_over=args.carry_over or AssimilationConfig.carry_over,
                                    agent_features=(_input_set(args.inputs) if args.inputs is not None
                                                    else AssimilationConfig.agent_features))
    if writes:
        out.mkdir(parents=True, exist_ok=True)
    closure, mechanisms = None, ()
    if args.inputs is not None and args.init is not None:
        raise ConfigurationError("--inputs chooses the features of a fresh agent; --init's closure already fixes them")
    if args.init is not None:
        closure, mechanisms, _ = load_model(args.init)
        if not any(p.requires_grad for p in closure.parameters()):
            # e.g. a diagnosed model on the reference correlations: train a fresh agent with its mechanisms
            print(f"note: the closure of {args.init} has no trainable weights; training a fresh MLP agent with "
                  f"its mechanisms {[m.id for m in mechanisms]}")
            closure = None
    mechanisms = tuple(mechanisms) + _parse_mechanisms(args.mechanism)
    local, parallel = runs, None
    if launch is not None:  # this rank's shard of the runs, cut by probed cost
        local, parallel = launch.shard(runs, config, closure, mechanisms)
        print(launch.describe([r.name for r in runs]), flush=True)
    assim = Assimilator(local, config, closure=closure, mechanisms=mechanisms, parallel=parallel)
    for note in assim.fleet.wall_notes():  # what the model took for a wall the run does not state
        print(f"note: {note}", flush=True)

    def report(r):
        tag = f" ({r.note})" if r.note else ""
        print(f"window {r.index + 1}/{len(assim.windows)} [{r.t0_s:.0f}, {r.t1_s:.0f}] s: J {r.cost_before:.4g} -> "
              f"{r.cost_after:.4g}, {r.n_iters} iterations, {r.n_evals} evaluations, {r.wall_s:.1f} s{tag}", flush=True)
        for mid, values in r.mechanisms.items():
            print(f"  {mid}: " + ", ".join(f"{k} = {v:.4g}" for k, v in values.items()), flush=True)
        warning = r.saturation_warning([run.name for run in runs])
        if warning:
            print(f"  warning: {warning}", flush=True)

    result = assim.run(checkpoint=checkpoint, resume=args.resume, logdir=args.logdir,
                       progress=not args.quiet and writes, on_window=report)
    info = {"runs": [r.name for r in runs], "assimilation": config.to_json(),
            "final_cost": result.reports[-1].cost_after if result.reports else None,
            **(launch.info() if launch is not None else {})}
    unknown = next((m for m in assim.model.mechanisms if m.id == "unknown_wall_capacity"), None)
    if unknown is not None and unknown in assim.trained.mechanisms:
        for run, cw in zip(assim.fleet.runs, assim.model.effective_wall_heat_capacity_J_per_K.tolist()):
            print(f"note: {run.name}: wall heat capacity learned from the data: {cw:.4g} J/K "
                  f"({float(unknown.value[0].exp()):.3g} times the assumed shell)", flush=True)
    if writes:
        save_model(out, result.closure, runs[0].fluid, info, mechanisms=tuple(assim.model.mechanisms))
        print(f"wrote {out / 'model.json'}, {out / 'weights.pt'}")
    if launch is not None:
        launch.close()
    return 0


def cmd_predict(args) -> int:
    from .plotting import plot_run
    from .run_io import read_run, write_run
    from .saved import load_model
    from .simulation import simulate
    from .synthetic import solution_to_runs

    run = read_run(args.run)
    out = check_output_dir(args.out, _input_files(run) + [Path(args.model)])
    closure, mechanisms, meta = load_model(args.model)
    run = _initial(_audited_wall(run), args.initial)
    if run.fluid != meta["fluid"]:
        raise ValueError(f"model {args.model} is for {meta['fluid']}, run {args.run} is {run.fluid}")
    sol = simulate(run, closure, output_dt_s=args.dt, mechanisms=mechanisms)
    (pred,) = solution_to_runs(run, sol, noise="clean", model_name=f"the model in {args.model}")
    json_path, csv_path = write_run(pred, out)
    png = out / f"{pred.name}.png"
    plot_run(png, pred, measured=run if len(run.observations) else None, title=f"{run.name}: prediction of {args.model}")
    for note in sol.notes:
        print(f"note: {note}")
    print(f"wrote {json_path}, {csv_path}, {png}")
    return 0


def cmd_diagnose(args) -> int:
    from .diagnosis import (DEFAULT_CANDIDATES, DiagnosisConfig, HoldOutTail, LeaveOneRunOut, ModelError, SensorNoise,
                            diagnose, write_report)
    from .run_io import read_run
    from .saved import load_model

    read = [read_run(p) for p in args.runs]
    check_output_dir(args.out, [f for r in read for f in _input_files(r)]
                     + ([Path(args.model)] if args.model is not None else []))
    runs = [_initial(r, args.initial) for r in read]
    closure, mechanisms = None, ()
    if args.model is not None:
        closure, mechanisms, meta = load_model(args.model)
        if meta["fluid"] != runs[0].fluid:
            raise ValueError(f"model {args.model} is for {meta['fluid']}, the runs are {runs[0].fluid}")
    split = None
    if args.holdout is not None and (args.split == "run" or (args.split == "auto" and len(runs) > 1)):
        raise ConfigurationError("--holdout sets the held-out tail of each run, and these runs are held out one at a "
                                 "time (--split run, or auto with several runs): add --split tail or drop --holdout")
    with _options_checked():
        if args.split == "tail" or args.holdout is not None:
            split = HoldOutTail() if args.holdout is None else HoldOutTail(args.holdout)
        elif args.split == "run":
            split = LeaveOneRunOut()
    candidates = tuple(args.candidates) if args.candidates else DEFAULT_CANDIDATES
    weighting = ModelError() if args.weighting == "model-error" else SensorNoise()
    refit_top = None if args.refit_top == "all" else _whole_number(args.refit_top, "--refit-top N|all")
    with _options_checked():
        config = DiagnosisConfig(candidates=candidates, split=split, weighting=weighting, block_s=args.block,
                                 hold=tuple(args.hold), refit_top=refit_top,
                                 refit_budget_s=(DiagnosisConfig.refit_budget_s if args.refit_budget is None
                                                 else args.refit_budget))
    d = diagnose(runs, closure, mechanisms, config, progress=None if args.quiet else print)
    paths = write_report(d, args.out, runs[0].fluid)
    v = d.verdict
    if v.kind == "cause":
        print(f"cause: {d.cause} ({v.source}): {v.sentence}")
        if d.alternatives:
            print(f"not ruled out (also clear every threshold, dBIC within {d.thresholds.alternative_bic:g}): "
                  + ", ".join(d.alternatives))
    elif v.kind == "unresolved":
        print(f"measured, not located: {v.sentence}; candidates: {', '.join(v.candidates)}")
    elif v.kind == "model_form":
        print(f"cause: none; the model's form: {d.named} ({v.source}): {v.sentence.removeprefix('no cause: ')}")
    else:
        print(f"cause: none ({v.sentence.removeprefix('no cause: ')})")
    for note in v.notes:
        print(f"note: {note}")
    if d.withheld:
        print("withheld by the inventory audit (see the report): " + "; ".join(d.withheld))
    print(f"diagnosis took {d.wall_time_s:.1f} s ({d.n_simulations} simulations); wrote {paths['json']}, "
          f"{paths['md']}, {paths['model']}/")
    return 0


def cmd_bench(args) -> int:
    from .bench import run_benchmarks, summary_lines, verdict

    result = run_benchmarks(n_points=args.points, repeats=args.repeats)
    lines = summary_lines(result)
    if args.training:
        from trainers.bench import run_training_benchmarks

        result["training"] = tr = run_training_benchmarks()
        w, m = tr["window_update"], tr["adjoint_memory"]
        for label, u in w["modes"].items():
            lines.append(f"window update, {label}: {w['n_tanks']} tanks, {w['window_s']:.0f} s window, {u['iters']} "
                         f"iterations ({u['function_evals']} evaluations) in {u['update_wall_s']:.1f} s: real-time "
                         f"factor {u['real_time_factor']:.1f} ({verdict(u['real_time_factor'], 10)})")
        lines.append(f"autograd memory vs horizon {m['lengths_s']} s: adjoint {m['adjoint_bytes']} B, "
                     f"backprop {m['backprop_bytes']} B, checkpointed {m['checkpointed_bytes']} B")
    print("\n".join(lines))
    print(json.dumps(result))
    return 0


def cmd_sensitivity(args) -> int:
    """``tankode sensitivity CASE_OR_RUN --out DIR``: writes DIR/sobol.json, DIR/sensitivity.png."""
    from .sensitivity import one_at_a_time, plot_sensitivity, slosh_intervals, sobol_indices

    run, _ = _load_case_or_run(args.run)
    out = check_output_dir(args.out, _input_files(run))
    res = sobol_indices(run, spread=args.spread, n_base=args.n_base, seed=args.seed, output_dt_s=args.dt)
    oat = one_at_a_time(run, spread=args.spread, output_dt_s=args.dt)
    out.mkdir(parents=True, exist_ok=True)
    (out / "sobol.json").write_text(json.dumps(res.to_json()))
    png = plot_sensitivity(res, oat, out / "sensitivity.png", slosh=slosh_intervals(run, res.t_s))
    print(f"{res.n_samples} samples of {run.name} simulated in {res.wall_s:.1f} s")
    print(f"wrote {out / 'sobol.json'}, {png}")
    return 0


_INITIAL_HELP = ("start from the run's metadata 'initial' (the format's rule, default) or from the samples measured at "
                 "the start where there are any (p_v, T_v, T_l, T_w; the fill stays the metadata's); a run whose first "
                 "samples contradict its metadata by more than 5 sigma is reported either way")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="tankode", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    s = sub.add_parser("simulate", help="simulate a case or a run's initial state and inputs")
    s.add_argument("run", help="case1..case5 or a run JSON in the interchange format")
    s.add_argument("--out", required=True, help="output directory for NAME.json, NAME.csv, NAME.png")
    s.add_argument("--noise", choices=("clean", "low", "high", "sensors"), default="clean",
                   help="synthetic sensor noise: clean (default), the paper's low or high level, or sensors (the "
                        "run's own noise_std)")
    s.add_argument("--seed", type=int, default=0, help="noise seed")
    s.add_argument("--dt", type=float, default=10.0, help="output spacing in s (observation times are added)")
    s.add_argument("--model", default=None, help="a saved model directory (closure and mechanisms); default: the "
                   "reference correlations")
    s.add_argument("--mechanism", action="append", default=[], metavar="ID:NAME=VALUE",
                   help="add a mechanism to the simulation, e.g. vapor_leak:mdot_kg_s=1e-4 (a hidden effect for "
                        "testing the diagnosis); repeatable, once per mechanism, several parameters comma-separated "
                        "(ID:A=1,B=2; a parameter left out is 0)")
    s.add_argument("--initial", choices=("metadata", "measured"), default="metadata", help=_INITIAL_HELP)
    s.set_defaults(func=cmd_simulate)
    a = sub.add_parser("assimilate", help="train the MLP closure (the agent) on measured runs, window by window")
    a.add_argument("runs", nargs="+", help="run JSON files (several = one closure for a fleet)")
    a.add_argument("--out", required=True, help="model directory (model.json, weights.pt, checkpoint.pt)")
    a.add_argument("--window", type=float, default=None,
                   help="window length in s (default 600, lengthened to 10 sampling intervals of a sparsely logged run)")
    a.add_argument("--mode", choices=("fixed", "growing", "replay"), default=None,
                   help="window mode: the newest window only (fixed), all data so far (growing), or the newest "
                        "window plus a bounded replay sample of the earlier data (replay); default: "
                        "AssimilationConfig's (trainers/assimilate.py)")
    a.add_argument("--wall", choices=("two_node", "lumped"), default=None,
                   help="the wall: dry and wetted parts at their own temperatures, the shell's sheet resistance "
                        "trained (two_node), or one lumped temperature (lumped, the paper's); default: "
                        "AssimilationConfig's")
    a.add_argument("--boiling", choices=("learned", "bulk"), default=None,
                   help="the liquid's flashing: a share of the liquid boiling at saturation, trained (learned), or "
                        "only the bulk's flash 0.2 K past saturation (bulk); default: AssimilationConfig's")
    a.add_argument("--unknown-wall", choices=("trained", "assumed"), default=None,
                   help="a wall heat capacity that no run states and no wall sensor reads: a factor on the "
                        "aluminium-shell estimate trained with the agent (trained), or the estimate as it is "
                        "(assumed); default: AssimilationConfig's")
    a.add_argument("--carry-over", choices=("validated", "integrable"), default=None,
                   help="how an update starts from the previous windows' agent: checked on the new window against "
                        "the initial agent and shrunk towards it where it predicts worse (validated), or as it is "
                        "unless it cannot integrate the window (integrable, the paper's); default: AssimilationConfig's")
    a.add_argument("--replay-segments", type=int, default=None, help="--mode replay: earlier segments per update")
    a.add_argument("--replay-s", type=float, default=None, help="--mode replay: length of each segment in s")
    a.add_argument("--update-budget", type=float, default=None, metavar="SECONDS",
                   help="wall-clock budget of one window's update; once spent it keeps the best weights it "
                        "evaluated; default: half the window's length (real time); inf: no budget (results that "
                        "do not depend on the machine's speed)")
    a.add_argument("--batch", type=float, default=1.0, help="fraction of observation times per gradient, (0, 1]")
    a.add_argument("--iters", type=int, default=20, help="L-BFGS iterations per window (default 20)")
    a.add_argument("--seed", type=int, default=0, help="weight initialisation and batch seed")
    # The names of trainers.memory.MEMORIES, spelled out: the parser does not import the trainers.
    a.add_argument("--memory", choices=("forget", "laplace"), default="forget",
                   help="what a fixed window keeps of the earlier ones: forget (the paper, default) or laplace "
                        "(a prior on the coefficients they determined; trainers/memory.py)")
    a.add_argument("--gradient", choices=_GRADIENTS, default=None,
                   help="adjoint (with dopri5: memory independent of the solver's steps), backprop (with rosenbrock; "
                        "through the solver's steps: memory grows with them) or checkpointed (backprop's gradient, one "
                        "output interval's steps in memory at a time); default: the integrator's")
    a.add_argument("--integrator", choices=("dopri5", "rosenbrock"), default=None,
                   help="the ODE solver inside training: rosenbrock (linearly implicit: steps follow accuracy, not a "
                        "light wall's stability) or dopri5 (explicit, with the adjoint); default: AssimilationConfig's")
    a.add_argument("--window-start", choices=("model", "data", "joint"), default=None,
                   help="a fixed or replay window's initial state: the model's carried state, a line fit of the "
                        "data, or (fixed windows) the carried state plus an offset fitted with the agent (joint; "
                        "trainers/window_start.py); default: AssimilationConfig's")
    a.add_argument("--start-prior-sigmas", type=float, default=1.0,
                   help="with --window-start joint: the carried state's background std in noise sigmas (default 1)")
    a.add_argument("--init", "--model", dest="init", default=None,
                   help="start from this model directory (its closure, and its mechanisms: fixed unless named by "
                        "--train-mechanisms)")
    a.add_argument("--mechanism", action="append", default=[], metavar="ID:NAME=VALUE",
                   help="add a mechanism to the model trained, e.g. dry_wall_node:R_sheet_K_per_W=10; repeatable, "
                        "once per mechanism, several parameters comma-separated (ID:A=1,B=2; a parameter left out is 0)")
    a.add_argument("--train-mechanisms", nargs="+", default=[], metavar="ID",
                   help="train these mechanisms' parameters with the agent, inside their physical bounds, starting "
                        "from their given values (trainers/mechanism_params.py)")
    a.add_argument("--inputs", choices=_INPUT_SETS, default=None,
                   help="input features of a fresh agent (tankode/closures/mlp.py): operations (the default) = the "
                        "paper's eight and the four operations' turnovers, paper = its eight, extended = nine "
                        "(not with --init, whose closure fixes them)")
    a.add_argument("--logdir", default=None, help="TensorBoard log directory")
    a.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt after an interruption")
    a.add_argument("--collective-timeout", type=float, default=None, metavar="SECONDS",
                   help="under torchrun: how long a rank waits for the others at a collective before the job stops "
                        "with an error (default 600; trainers/distributed.py)")
    a.add_argument("--quiet", action="store_true", help="no progress bar")
    a.add_argument("--initial", choices=("metadata", "measured"), default="metadata", help=_INITIAL_HELP)
    a.set_defaults(func=cmd_assimilate)
    pr = sub.add_parser("predict", help="predict a run from its initial state and inputs with a saved model")
    pr.add_argument("model", help="model directory written by assimilate or diagnose")
    pr.add_argument("run", help="run JSON (its observations, if any, are drawn for comparison)")
    pr.add_argument("--out", required=True, help="output directory for the predicted run")
    pr.add_argument("--dt", type=float, default=10.0, help="output spacing in s (observation times are added)")
    pr.add_argument("--initial", choices=("metadata", "measured"), default="metadata", help=_INITIAL_HELP)
    pr.set_defaults(func=cmd_predict)
    dg = sub.add_parser("diagnose", help="what entered or left the tank unmetered (inventory audit), what the model gets "
                                         "wrong, which missing mechanism explains it")
    dg.add_argument("runs", nargs="+", help="measured run JSON files of one tank")
    dg.add_argument("--out", required=True, help="output directory (report.json, report.md, figures, model/)")
    dg.add_argument("--model", default=None, help="start from this saved model (default: the reference correlations)")
    dg.add_argument("--split", choices=("auto", "tail", "run"), default="auto",
                    help="held-out data: the tail of each run, or leave one run out (auto: runs if several)")
    dg.add_argument("--holdout", type=float, default=None,
                    help="held-out fraction of each run, with --split tail (or auto on one run); default 0.3 "
                         "(HoldOutTail)")
    dg.add_argument("--candidates", nargs="*", default=None, help="mechanism ids to test (default: every mechanism but the opt-in surface_layer, boundary_layer_stratification, growing_layer and diffusive_layer)")
    dg.add_argument("--weighting", choices=("sensor", "model-error"), default="sensor",
                    help="weigh residuals by the sensor noise, or by the calibrated baseline's RMS residual where it "
                         "misses a channel beyond chance (real tanks: a channel the model cannot follow stops "
                         "dominating the evidence)")
    # DiagnosisConfig.block_s, spelled out: the parser does not import the diagnosis.
    dg.add_argument("--block", type=float, default=120.0, metavar="SECONDS",
                    help="bootstrap block length of the held-out gain's interval in s (default 120; longer than the "
                         "residuals' correlation time: an hour for sparse real data such as MHTB's)")
    dg.add_argument("--hold", nargs="+", default=[], metavar="COEFFICIENT",
                    help="closure coefficients (h_vi h_li h_wv h_wl) whose multiplier stays 1: their correlation is "
                         "trusted, not calibrated (when the report says an estimate trades off with a factor)")
    # DiagnosisConfig.refit_top, spelled out like --block.
    dg.add_argument("--refit-top", default="5", metavar="N|all",
                    help="refit the N candidates the score test ranks first, or all (default 5; the score test is a "
                         "slope at 0 and under-ranks strongly nonlinear mechanisms on real data such as MHTB's)")
    dg.add_argument("--refit-budget", type=float, default=None, metavar="SECONDS",
                    help="no candidate is refitted once this much wall-clock time has passed since the start "
                         "(default: DiagnosisConfig's, ten minutes; inf: every refit, a result independent of the "
                         "machine's speed)")
    dg.add_argument("--quiet", action="store_true", help="no progress lines")
    dg.add_argument("--initial", choices=("metadata", "measured"), default="metadata", help=_INITIAL_HELP)
    dg.set_defaults(func=cmd_diagnose)
    b = sub.add_parser("bench", help="surrogate accuracy and speed vs CoolProp; forward real-time factor")
    b.add_argument("--points", type=int, default=10_000, help="held-out points for the surrogate benchmark")
    b.add_argument("--repeats", type=int, default=3, help="timing repeats (best is kept)")
    b.add_argument("--training", action="store_true", help="also time a window update and measure adjoint memory (~1 min)")
    b.set_defaults(func=cmd_bench)
    sv = sub.add_parser("sensitivity", help="Sobol (S1, ST) and one-at-a-time sensitivity of p_v to the four h")
    sv.add_argument("run", help="case1..case5 or a run JSON in the interchange format")
    sv.add_argument("--out", required=True, help="output directory for sobol.json and sensitivity.png")
    sv.add_argument("--spread", type=float, default=0.10, help="multipliers 1 +- spread, spread in (0, 1) (default 0.1)")
    sv.add_argument("--n-base", type=int, default=64, help="Saltelli base sample N, a power of 2; 6N runs (default 64)")
    sv.add_argument("--seed", type=int, default=0, help="Sobol' scrambling and bootstrap seed")
    sv.add_argument("--dt", type=float, default=10.0, help="output spacing in s (default 10)")
    sv.set_defaults(func=cmd_sensitivity)
    return p


def _one_line(text: str) -> str:
    """A message on one line: its lines joined (a failed simulation's state rows included)."""
    return " ".join(line.strip() for line in str(text).splitlines() if line.strip())


def describe_error(err: BaseException) -> str:
    """What went wrong, in one line, for any exception that reaches the command line."""
    if isinstance(err, IsADirectoryError):
        return f"{err.filename} is a directory; a file was expected"
    if isinstance(err, FileExistsError):
        return f"{err.filename} exists and is not a directory"
    if isinstance(err, PermissionError):
        return f"{err.filename}: permission denied"
    if isinstance(err, (FileNotFoundError, NotADirectoryError)) and err.filename is not None:
        return f"{err.filename}: {err.strerror or 'not found'}"
    if isinstance(err, (ValueError, RuntimeError, OSError, ArithmeticError)):
        text = str(err.args[0]) if isinstance(err, (FileNotFoundError, OSError)) and len(err.args) == 1 else str(err)
        return _one_line(text) or type(err).__name__
    # Anything else is a defect of tankode, still said in one line, never as a traceback.
    return f"internal error ({type(err).__name__}: {_one_line(str(err))}); please report it with the command line"


def _warning_line(message, category, filename, lineno, line=None) -> str:
    return f"tankode: warning: {_one_line(str(message))}\n"


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    warnings.formatwarning = _warning_line
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print(f"tankode {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as err:  # noqa: BLE001 - every failure becomes one line and exit code 2 (describe_error)
        print(f"tankode {args.command}: error: {_naming_the_runs(err, args)}", file=sys.stderr)
        return _EXIT_ERROR


def _naming_the_runs(err: BaseException, args) -> str:
    """``describe_error(err)`` led by the run files the command was given, unless it names a path
    the command was given already (a format error names its own file, a missing model its
    directory; a failure deep in the properties or the solver knows the state, not the file)."""
    from .run import RunFormatError

    message = describe_error(err)
    given = list(getattr(args, "runs", None) or []) or ([args.run] if getattr(args, "run", None) else [])
    # a model directory by its path as given: its name alone ("model") is a common word
    models = [str(p) for p in (getattr(args, "model", None), getattr(args, "init", None)) if p]
    if (not given or isinstance(err, (RunFormatError, ConfigurationError)) or any(Path(p).name in message for p in given)
            or any(p in message for p in models)):
        return message
    return f"{', '.join(given)}: {message}"


if __name__ == "__main__":
    sys.exit(main())

"""Real-time assimilation: update the agent every window as data stream in (paper, section 5.3).

The data of a fleet arrive as a stream. Every ``window_s`` seconds the agent (the MLP closure)
is updated with ``iters`` bounded L-BFGS iterations on the cost J over

* ``mode="fixed"``: only the newest window ``[t_k, t_k + window_s]``;
* ``mode="growing"``: all data so far ``[t_0, t_k + window_s]`` (the cost grows with time);
* ``mode="replay"``: the newest window plus a bounded replay sample of the earlier data
  (experience replay, as in the reinforcement-learning setting the paper borrows from), at a
  fixed cost per update: ``replay_segments`` segments of ``replay_s`` seconds, their start
  times drawn uniformly (seeded by ``seed`` and the window index) from the times the earlier
  windows were simulated at, each integrated from the state the model reached there after that
  window's update. The cost weighs the newest window by its share of the data so far,
  ``window_s / (t_k + window_s - t_0)``, and the replay segments share the rest equally, so
  every second of the stream carries the same weight in expectation, as in a growing window.
  The segments are integrated together, as one batched ODE on a time axis relative to each
  one's start (``Assimilator._replay_states``): the cost of a right-hand side barely grows
  with the batch (8 tanks cost 1.02 times one), so three segments cost about one.

Initial state of each window. Growing windows always start from the run's initial state (the
metadata's p, T and fill). A fixed window k > 0, and a replay update's newest window (its
replayed segments start from the states the earlier windows' simulations reached), starts
from the state at ``t_k`` of the simulation of window k-1 with the agent as updated on window
k-1 (``window_start="model"``, the default): the model carries its own state, so an agent is
only rewarded for being right over the whole stream (on case 1 this gives the final agent a
whole-hour pressure error several times smaller than data starts do; on another simulator's
stratified tanks data starts fit the windows more closely and forecast no better;
``experiments/README.md``). With
``window_start="data"`` every measured channel (p_v, T_v, T_l, T_w, H_l) is replaced by the
value at ``t_k`` of a straight line fitted to its last samples (at most ``FIT_SPAN_S``, none
before the last input change, which would bend the line) and the state is rebuilt from them
with CoolProp; unmeasured channels keep the model's value. That stops an early agent's errors
from drifting the state of every later window (the level moves ~7 mm per 0.3 K of liquid
temperature, ten times the level noise), at the price of no longer penalising drift.
With ``window_start="joint"`` the window starts from the model's carried state plus an offset
in the five observed quantities that is fitted with the weights, held to the carried state by
a Gaussian background term of ``start_prior_sigmas`` noise sigmas (``trainers/window_start.py``,
4D-Var's background): the data correct the start where they resolve it, the carried state
decides where they do not, and the next window starts from the end of the corrected trajectory.

One L-BFGS per window: when a window's data arrive the objective changes, so the curvature
pairs of the previous window are no secant pairs of the new objective; the optimiser (history,
latent variables, batch generator seeded by ``seed`` and the window index) is created afresh
for each window from the current weights. A checkpoint after each window (weights, optimiser
state, the next window's initial state, configuration, reports) therefore resumes exactly.
"""

from __future__ import annotations

import copy
import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from tankode.closures import FEATURE_NAMES, OPERATION_FEATURES, STATE_FEATURES, THETA_NAMES, MLPClosure, MLPConfig
from tankode.errors import SimulationError
from tankode.fleet import Fleet, sampling_interval_s
from tankode.forcing import Forcing
from tankode.integrate import integrate, state_scale
from tankode.mechanisms import Mechanism, applied_to_walls, make_mechanism
from tankode.model import TankModel
from tankode.solver import AdaptiveRK, Adjoint, Backprop, Checkpointed, NoGradient, Rosenbrock
from tankode.state import N_STATE
from tankode.threads import single_threaded

from .checkpoint import save_checkpoint
from .cost import Window, cost, cost_terms
from .distributed import SingleProcess, group_sum
from .evaluate import closure_inputs_along
from .lbfgs import BoundedLBFGS, Box, MiniBatch, ResetHistory, StopStep, uniform_box
from .mechanism_params import PREFIX, TrainedMechanisms
from .memory import Forget, LaplaceMemory, Prior, WindowMemory, remember
from .window_start import StartEstimate

_INTEGRATORS = {"dopri5": AdaptiveRK, "rosenbrock": Rosenbrock}
MODES = ("fixed", "growing", "replay")
CARRY_OVERS = ("validated", "integrable")  # AssimilationConfig.carry_over
_GRADIENTS = {"Adjoint": Adjoint, "Backprop": Backprop, "Checkpointed": Checkpointed}
_MEMORIES = {"Forget": Forget, "LaplaceMemory": LaplaceMemory}
# Share of a window's length that its update's search may take by default: the other half is
# for the closure call under way when the budget runs out and the solves after the search
# (one or two forward solves of the window), so that the update ends before the next window.
REAL_TIME_SHARE = 0.5


@dataclass(frozen=True)
class AssimilationConfig:
    """How the agent is trained from a stream.

    Attributes:
        window_s: window length (s); the paper's 10 minutes.
        mode: "replay" (default: the newest window and a bounded replay sample of the earlier
            data, every second of the stream weighted alike at a fixed cost per update; module
            docstring), "fixed" (the paper: the newest window only) or "growing" (all data so far).
        iters: L-BFGS iterations per window update (paper: k).
        batch_fraction: share of the window's observation times per gradient, in (0, 1].
        iters_per_batch: iterations on one mini-batch before drawing the next (ignored when
            ``batch_fraction`` is 1: then one step of ``iters`` iterations).
        history_size: L-BFGS curvature pairs kept.
        weight_bound: every MLP weight is boxed in [-bound, bound]; wide enough not to bind for
            the scaled features, narrow enough to keep tanh units out of saturation-driven blow-ups.
        seed: seed of the weight initialisation and the batch draws.
        prior_weight: strength of a Gaussian prior centred on the weights the window starts
            from, ``J + prior_weight/2 * mean((w - w_start)^2)``: the previous windows' knowledge
            as a prior (as a sequential Bayesian update would carry it), which limits how far
            one window's data drag the agent (forgetting, over-fitting 60 noisy samples).
            0 = the paper's plain cost.
        base_prior_weight: strength of a Gaussian prior centred on the weights the agent started
            the run with, ``J + base_prior_weight/2 * mean((w - w_0)^2)``: for an agent on a
            physical base (``MLPConfig.base``), whose start is that closure, the learned correction
            stays near 1 where the data do not ask for one (an operating regime not seen yet).
        window_start: "model", "data" or "joint": where a fixed or replay window's newest
            window starts (module docstring); "data" needs ``mode="fixed"`` or ``"replay"``,
            "joint" ``mode="fixed"``.
        start_prior_sigmas: with ``window_start="joint"``, the background std of the carried
            state in units of each channel's noise std (1: the carried state is worth one
            sample per channel, so a window's ~60 samples decide the offset).
        gradient: ``Backprop()`` (default, with the Rosenbrock integrator: through its few
            steps), ``Adjoint()`` (with dopri5: memory independent of the step count; its backward
            re-integration diverges on stiff tanks) or ``Checkpointed()`` (Backprop's gradient,
            memory bounded by one output interval's steps).
        memory: what a fixed window's update keeps of the earlier windows: ``Forget()`` (the
            paper: nothing) or ``LaplaceMemory()`` (a Laplace prior on the coefficients the
            earlier windows determined; ``trainers/memory.py``). Fixed mode only: growing
            windows refit all the data anyway.
        integrator: the ODE solver inside training: "rosenbrock" (``Rosenbrock``, linearly
            implicit, the default: its steps follow accuracy, not the stability of a fast mode, a
            light wall's or a strongly convecting ullage's; on another simulator's 13.6 m3 tank one
            20-minute window trained in 22 s against dopri5's 363 s, on the MHTB tests it takes
            about a hundred times fewer right-hand sides) or "dopri5" (``AdaptiveRK``, explicit,
            with any gradient). Rosenbrock has no adjoint: use it with Backprop() or Checkpointed().
        rtol, atol: solver tolerances inside training, looser than for reference simulations
            because the noise, not the solver, limits the fit: at 1e-5 / 1e-7 the Rosenbrock
            solution of cases 1-4 (an hour) and of MHTB P263981D (5.4 h) stays within 0.08 of the
            lowest sensor noise in the format's examples (300 Pa, 0.05 K, 1 mm) of a solution at
            1e-9, and an update of 4 tanks takes half the right-hand sides of 1e-6 (7,151 against
            14,079; 2.4 times faster, the same cost reached); at 1e-4 the pressure error reaches
            0.7 of that noise. The paper's setup keeps 1e-6 / 1e-8.
        max_rhs_evals: solver budget per segment inside training; a trial agent that makes the
            ODE too stiff to integrate within it is rejected (the update keeps the last good
            weights) instead of stalling the real-time loop.
        update_budget_s: wall-clock budget of one window's update (s), its checks and solves
            included. Once spent, the L-BFGS search ends at the best weights it evaluated
            (``StopStep``; the report's note says so), so that a window the agent finds hard
            cannot hold the stream up (measured: one MHTB window's update ran past 40 minutes
            without it). Checked between the optimiser's closure calls, each bounded by
            ``max_rhs_evals``; with data parallelism every rank stops at the same call. None (the
            default): ``REAL_TIME_SHARE`` (half) of ``window_s``, so that an update, with its last
            call and the solves after the search, ends before the next window has arrived.
            ``math.inf``: no budget, for results that do not depend on the machine's speed
            (bit-exact resumes and comparisons).
        replay_segments: with ``mode="replay"``, the earlier segments replayed per update.
        replay_s: with ``mode="replay"``, the length of each replayed segment (s); with the
            defaults an update integrates the window plus 3 x 200 s, twice a 10-minute window.
            Lengthened to ``REPLAY_MIN_SAMPLES`` (3) sampling intervals of the most sparsely
            sampled run (``Assimilator.replay_s``), so that every segment holds data.
        wall: ``"two_node"``: the dry and the wetted wall at their own temperatures
            (``tankode.mechanisms.TwoNodeWall``), the shell's sheet resistance trained with the
            agent and the split of the measured mean between them at the start taken from the
            first window (``Assimilator._place_wall_start``); ``"lumped"``: the paper's one wall
            temperature.
        wall_R_sheet_K_per_W: the sheet resistance the two-node wall starts from (K/W;
            aluminium of 10 mm at 20 K; the training moves it).
        boiling: ``"learned"``: a share of the liquid boils as soon as it passes saturation
            (``tankode.mechanisms.SaturatedBoiling``), the share trained with the agent, beside
            the bulk's flash 0.2 K past it (``tankode.bulk``); ``"bulk"``: the bulk's flash
            only. How close to saturation a tank's liquid stays through a vent or a drain
            differs from tank to tank (a thin boiling surface layer over a subcooled bulk, or a
            stirred liquid that follows ``T_sat(p)``), so the data set it; measured in
            ``experiments/README.md``, section 5.
        boiling_share: the boiling share the training starts from: a tenth, the surface layer of
            a few centimetres over a liquid a metre or more deep (dimensionless, in (0, 1)).
        unknown_wall: where no run of the fleet states its wall heat capacity (nor does the
            caller read it, e.g. the CLI's inventory audit where a wall sensor reads the wall:
            ``tankode.diagnosis.audit.with_audited_wall``): ``"trained"``, a factor on
            tankode's aluminium-shell estimate trained with the agent on a log scale, a tenth to
            a thousand times (``tankode.mechanisms.UnknownWallCapacity``; one factor for the
            fleet's tanks); ``"assumed"``: the estimate as it is. Other simulators' walls, and
            the paper's, are 20 to 500 times the shell at the fluid's temperature, and a wall no
            sensor reads sets how fast a warm ullage cools (``experiments/README.md``, section 5).
        carry_over: how an update starts from the agent the previous windows left:
            ``"validated"`` (default: the agent is first checked on the new window, which it has
            not seen, against the initial agent; one that predicts it worse or cannot integrate
            it starts from the best of its shrinkages towards the initial agent,
            ``Assimilator._cost_before``) or ``"integrable"`` (the paper: the agent as it is,
            shrunk only where it cannot integrate the window).
        agent_base: the base closure of a fresh agent (``MLPConfig.base``): ``"natural"``
            (textbook convection on each surface, which the agent corrects), ``"reference"`` or
            ``"constant"`` (the paper's agent, from fixed mid-range coefficients).
        agent_domain_margin: a fresh agent's ``MLPConfig.domain_margin`` (feature units): its
            learned correction fades to the base outside the inputs it was trained on, so that a
            forecast into an operation the stream has not shown (a fill after a hold, sloshing
            after a vent) uses the physical base, not the network's extrapolation. The box grows
            with each window's trajectory, before its update (so the update may learn there)
            and after it. 0.1 is a factor of about 20 in a Grashof number
            (``ln(Gr + 1) / 30``), a tenth of the fill, or a flow moving 1 % of its phase per
            hour. None: no fade (the paper's agent).
        agent_clamped_features: features a fresh agent projects onto its seen box instead of
            fading over (``MLPConfig.clamped_features``; those of them among ``agent_features``).
            The default, ``STATE_FEATURES``, clamps the tank's state and fades its operations, so a
            repeated operation at a state a little beyond the seen ones keeps what the stream
            taught; measured in ``experiments/README.md``, section 5. Empty: every feature fades.
        agent_features: a fresh agent's input features (``MLPConfig.features``). The default,
            ``OPERATION_FEATURES``, adds the four operations' turnovers to the paper's eight, so
            that a fill, a drain, a vent or an injection the stream has not shown lies outside
            the seen box; the paper's setup uses its eight (``FEATURE_NAMES``).
        train_mechanisms: ids of the model's mechanisms whose parameters each window's update
            trains with the weights, inside their physical bounds (``trainers/mechanism_params.py``):
            e.g. ``("dry_wall_node",)`` learns the shell's sheet resistance from the stream. Empty
            (the default): mechanisms keep the values they were given. Not with ``LaplaceMemory()``,
            whose prior covers the closure only.
    """

    window_s: float = 600.0
    mode: str = "replay"
    iters: int = 20
    batch_fraction: float = 1.0
    iters_per_batch: int = 5
    history_size: int = 10
    weight_bound: float = 10.0
    seed: int = 0
    prior_weight: float = 0.0
    base_prior_weight: float = 0.0
    window_start: str = "model"
    start_prior_sigmas: float = 1.0
    gradient: Adjoint | Backprop | Checkpointed = Backprop()
    memory: Forget | LaplaceMemory = Forget()
    integrator: str = "rosenbrock"
    rtol: float = 1e-5
    atol: float = 1e-7
    max_rhs_evals: int = 20_000
    update_budget_s: float | None = None
    train_mechanisms: tuple[str, ...] = ()
    replay_segments: int = 3
    replay_s: float = 200.0
    wall: str = "two_node"
    wall_R_sheet_K_per_W: float = 10.0
    boiling: str = "learned"
    boiling_share: float = 0.1
    unknown_wall: str = "trained"
    carry_over: str = "validated"
    agent_base: str = "natural"
    agent_domain_margin: float | None = 0.1
    agent_clamped_features: tuple[str, ...] = STATE_FEATURES
    agent_features: tuple[str, ...] = OPERATION_FEATURES

    def __post_init__(self):
        if not (self.window_s > 0 and math.isfinite(self.window_s)):
            raise ValueError(f"window_s must be a positive number of seconds, got {self.window_s}")
        if self.window_start not in ("data", "model", "joint"):
            raise ValueError(f"window_start must be 'model', 'data' or 'joint', got {self.window_start!r}")
        if not (self.start_prior_sigmas > 0 and math.isfinite(self.start_prior_sigmas)):
            raise ValueError(f"start_prior_sigmas must be a positive number of noise sigmas, got {self.start_prior_sigmas}")
        object.__setattr__(self, "agent_features", tuple(self.agent_features))  # lists from JSON or a CLI
        object.__setattr__(self, "agent_clamped_features", tuple(self.agent_clamped_features))
        if self.agent_clamped_features:  # names the agent may not use now, but none it cannot
            try:
                MLPConfig(features=self.agent_clamped_features)
            except ValueError as e:
                raise ValueError(f"agent_clamped_features: {e}") from None
        self._agent_config(seed=self.seed)  # the agent's settings, validated where they are defined
        if self.carry_over not in CARRY_OVERS:
            raise ValueError(f"carry_over must be one of {CARRY_OVERS}, got {self.carry_over!r}")
        if self.wall not in ("two_node", "lumped"):
            raise ValueError(f"wall must be 'two_node' or 'lumped', got {self.wall!r}")
        if not (0 < self.wall_R_sheet_K_per_W < 1e4):
            raise ValueError(f"wall_R_sheet_K_per_W must be in (0, 1e4) K/W, got {self.wall_R_sheet_K_per_W}")
        if self.boiling not in ("learned", "bulk"):
            raise ValueError(f"boiling must be 'learned' or 'bulk', got {self.boiling!r}")
        if self.unknown_wall not in ("trained", "assumed"):
            raise ValueError(f"unknown_wall must be 'trained' or 'assumed', got {self.unknown_wall!r}")
        if not (0 < self.boiling_share < 1):
            raise ValueError(f"boiling_share must be in (0, 1), got {self.boiling_share}")
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        if self.update_budget_s is not None and not self.update_budget_s > 0:
            raise ValueError(f"update_budget_s must be None, a positive number of seconds or inf, got {self.update_budget_s}")
        if self.replay_segments < 1 or not (self.replay_s > 0 and math.isfinite(self.replay_s)):
            raise ValueError(f"replay_segments must be >= 1 and replay_s a positive number of seconds, got "
                             f"{self.replay_segments} and {self.replay_s}")
        if self.iters < 1 or self.iters_per_batch < 1 or self.history_size < 1:
            raise ValueError("iters, iters_per_batch and history_size must be >= 1")
        if not (0 < self.batch_fraction <= 1):
            raise ValueError(f"batch_fraction must be in (0, 1], got {self.batch_fraction}")
        for name in ("prior_weight", "base_prior_weight"):
            if not (getattr(self, name) >= 0 and math.isfinite(getattr(self, name))):
                raise ValueError(f"{name} must be finite and >= 0, got {getattr(self, name)}")
        if not (self.weight_bound > 0):
            raise ValueError(f"weight_bound must be > 0, got {self.weight_bound}")
        if not isinstance(self.gradient, (Adjoint, Backprop, Checkpointed)):
            raise ValueError(f"gradient must be Adjoint(), Backprop() or Checkpointed(), got {self.gradient!r}")
        if not isinstance(self.memory, (Forget, LaplaceMemory)):
            raise ValueError(f"memory must be Forget() or LaplaceMemory(), got {self.memory!r}")
        if self.integrator not in _INTEGRATORS:
            raise ValueError(f"integrator must be one of {tuple(_INTEGRATORS)}, got {self.integrator!r}")
        if self.integrator == "rosenbrock" and isinstance(self.gradient, Adjoint):
            raise ValueError("integrator='rosenbrock' has no continuous adjoint: use gradient=Backprop() or Checkpointed()")
        if self.window_start != "model" and self.mode == "growing":
            # a growing window starts from the run's initial state: it has no start to take from the data
            raise ValueError(f"window_start={self.window_start!r} needs mode='fixed' or 'replay' (a growing window "
                             "starts from the run's initial state: use window_start='model' or another mode)")
        if self.window_start == "joint" and self.mode != "fixed":
            # the offset is fitted on the newest window alone; the replayed segments start from states
            # that were carried, and an offset trained on both would be judged by data it never moves
            raise ValueError("window_start='joint' needs mode='fixed' (use window_start='data' or 'model' with "
                             f"mode={self.mode!r})")
        if (not isinstance(self.train_mechanisms, tuple) or not all(isinstance(m, str) for m in self.train_mechanisms)
                or len(set(self.train_mechanisms)) != len(self.train_mechanisms)):
            raise ValueError(f"train_mechanisms must be a tuple of distinct mechanism ids, got {self.train_mechanisms!r}")
        if self.train_mechanisms and isinstance(self.memory, LaplaceMemory):
            raise ValueError("train_mechanisms needs memory=Forget(): LaplaceMemory's prior covers the closure only")
        if isinstance(self.memory, LaplaceMemory) and self.mode != "fixed":
            raise ValueError("memory=LaplaceMemory() needs mode='fixed' (growing windows already refit all the data)")

    def _agent_config(self, seed: int) -> MLPConfig:
        try:
            return MLPConfig(features=self.agent_features, seed=seed, base=self.agent_base,
                             domain_margin=self.agent_domain_margin,
                             clamped_features=tuple(f for f in self.agent_features if f in self.agent_clamped_features))
        except ValueError as e:
            raise ValueError(f"the agent's settings (agent_features, agent_base, agent_domain_margin): {e}") from None

    def agent(self, seed: int | None = None) -> MLPClosure:
        """A fresh agent of this configuration (its features, base and domain margin), seeded
        ``seed`` (default: ``self.seed``)."""
        return MLPClosure(self._agent_config(self.seed if seed is None else seed))

    @property
    def budget_s(self) -> float:
        """One update's wall-clock budget (s): ``update_budget_s``, or its default share of the window."""
        return REAL_TIME_SHARE * self.window_s if self.update_budget_s is None else self.update_budget_s

    def solver(self):
        """The ODE solver of the training's forward pass (``integrator`` at ``rtol``/``atol``)."""
        return _INTEGRATORS[self.integrator](rtol=self.rtol, atol=self.atol, max_rhs_evals=self.max_rhs_evals)

    @staticmethod
    def paper(**changes) -> "AssimilationConfig":
        """The paper's setup: fixed windows, dopri5 with the adjoint, one lumped wall, the agent
        from constant coefficients, carried from window to window unchecked, every update given
        its iterations whatever they take (no time budget); ``changes`` override
        fields (e.g. ``window_s``, ``iters``). The studies that reproduce the paper's figures on its own cases use it."""
        return replace(AssimilationConfig(mode="fixed", integrator="dopri5", gradient=Adjoint(), wall="lumped", boiling="bulk",
                                          unknown_wall="assumed",
                                          agent_base="constant", carry_over="integrable", agent_domain_margin=None,
                                          agent_clamped_features=(),
                                          agent_features=FEATURE_NAMES, update_budget_s=math.inf,
                                          rtol=1e-6, atol=1e-8),
                       **changes)

    def to_json(self) -> str:
        d = asdict(self)
        d["gradient"] = type(self.gradient).__name__
        d["memory"] = type(self.memory).__name__
        if d["update_budget_s"] == math.inf:  # strict JSON has no infinity
            d["update_budget_s"] = "inf"
        return json.dumps(d, sort_keys=True, allow_nan=False)

    @staticmethod
    def from_json(text: str) -> "AssimilationConfig":
        d = json.loads(text)
        # Configurations written before the memory option existed trained with Forget().
        d.setdefault("memory", "Forget")
        d.setdefault("start_prior_sigmas", 1.0)  # unused before window_start="joint" existed
        d.setdefault("integrator", "dopri5")  # the only one before Rosenbrock existed
        d.setdefault("replay_segments", 3)  # unused before the replay mode existed
        d.setdefault("replay_s", 200.0)
        d.setdefault("wall", "lumped")  # the only wall before the two-node one existed
        d.setdefault("base_prior_weight", 0.0)
        d.setdefault("agent_base", "constant")  # the only agent before the residual one existed
        d.setdefault("wall_R_sheet_K_per_W", 10.0)
        d.setdefault("boiling", "bulk")  # the bulk's flash alone before the boiling share existed
        d.setdefault("carry_over", "integrable")  # before the check existed
        d.setdefault("unknown_wall", "assumed")  # the aluminium shell's estimate before it was trained
        d.setdefault("agent_domain_margin", None)  # agents extrapolated freely before the fade existed
        d["agent_clamped_features"] = tuple(d.get("agent_clamped_features", ()))  # all faded before the clamp
        budget = d.get("update_budget_s", "inf")  # "inf" as to_json writes it; unbounded before the budget existed
        d["update_budget_s"] = None if budget is None else float(budget)
        d.setdefault("agent_features", FEATURE_NAMES)  # the paper's eight before the operations existed
        d["train_mechanisms"] = tuple(d.get("train_mechanisms", ()))  # JSON has lists; none trained before
        for key, known in (("gradient", _GRADIENTS), ("memory", _MEMORIES)):
            if d[key] not in known:
                raise ValueError(f"assimilation configuration: {key} {d[key]!r} is not one of {sorted(known)}")
            d[key] = known[d[key]]()
        return AssimilationConfig(**d)


@dataclass(frozen=True)
class WindowReport:
    """What one window update did (the numbers TensorBoard shows)."""

    index: int
    t0_s: float
    t1_s: float
    cost_before: float
    cost_after: float
    cost_terms: list  # (env, 5) after the update, per channel
    theta_mean: list  # (env, 4) mean h over the window after the update, W/(m^2 K)
    grad_norm: float
    n_evals: int
    n_iters: int
    wall_s: float
    note: str = ""
    start_offset_sigmas: list = field(default_factory=list)  # (env, 5) window_start="joint"'s fitted offset
    saturated: list = field(default_factory=list)  # (env, 4) share of the window at an output bound (MLP agents)
    mechanisms: dict = field(default_factory=dict)  # {id: {param: value}} after the update (train_mechanisms)

    def saturation_warning(self, env_names) -> str:
        """A line naming the coefficients the agent held at an output bound over most of the window, or ""."""
        held = [f"{h} ({share:.0%} of the window, {name})" for name, row in zip(env_names, self.saturated)
                for h, share in zip(THETA_NAMES, row) if share >= SATURATED_SHARE]
        if not held:
            return ""
        return ("at the bound of the agent's output range: " + ", ".join(held) + ". There the agent has no "
                "gradient, and a closure pushed to the end of its range usually compensates for physics the "
                "model lacks (tankode diagnose)")


@dataclass
class AssimilationResult:
    """The trained closure, the per-window reports and the state the stream was carried to.

    ``state_end``: ``(env, n_state)`` the model's state at the last window's end (this process's
    runs), integrated window by window from the carried state with each window's updated agent:
    where a real-time twin stands when the data stop, and where a forecast starts.
    """

    closure: MLPClosure
    config: AssimilationConfig
    reports: list[WindowReport] = field(default_factory=list)
    state_end: Tensor | None = None


# window_start="joint": the offset's name among the trained parameters, and its box (noise
# sigmas): far beyond the offsets measured on case 1 (all below 0.7 sigma), narrow enough to
# keep the linear state map near the state where it was taken.
_OFFSET = "window_start_offset"
START_OFFSET_BOUND_SIGMAS = 30.0
# A replayed segment spans at least this many sampling intervals of the most sparsely sampled run:
# a segment between two samples teaches nothing (real tanks, such as MHTB's, log every 5-30 min).
REPLAY_MIN_SAMPLES = 3
# K; a two-node wall split by less than this at the start is not split: a wall at the liquid's
# temperature (as a run without T_w starts) differs from it by the surrogate's rounding of T_l.
WALL_START_SAME_K = 1e-3

# The forward pass integrated, the gradient's did not: torchdiffeq's adjoint re-integrates the
# state backwards in time, which diverges where the tank has a fast decaying mode (MHTB's light
# aluminium wall at 20 K: the state of P263981D turns NaN within 70 s of backward integration,
# measured). Backprop (and Checkpointed) differentiate the forward steps themselves and are stable
# there; the Rosenbrock integrator takes steps that follow accuracy instead of the wall's stability.
ADJOINT_DIVERGED = (" (in the adjoint's backward pass, which re-integrates the state backwards in time and "
                    "diverges where the tank is stiff, e.g. a light wall with a sub-second time constant: train "
                    "with integrator='rosenbrock' and gradient=Backprop(), "
                    "`tankode assimilate --integrator rosenbrock --gradient backprop`)")

# An output is at its bound where |tanh(o)| >= 0.99 (its slope is 2 % of the centre's); a warning
# when that holds over half a window or more. On the MHTB tests every trained agent sat there.
SATURATED_TANH = 0.99
SATURATED_SHARE = 0.5

# Samples used for a data-informed window start: the last two minutes (12 samples at 10 s) average
# the noise while a straight line still follows the tank's curvature.
FIT_SPAN_S = 120.0


def _mean_square_change(params, anchor) -> torch.Tensor:
    """mean over all weights of (w - w_anchor)^2."""
    total = sum(((p - a) ** 2).sum() for p, a in zip(params, anchor))
    return total / sum(a.numel() for a in anchor)


# A window's update needs samples to learn from: a window holds at least this many sampling
# intervals of the most sparsely logged run when its length is left to the data
# (``window_for``). The paper's 10-minute windows of 10-s samples hold 60; the MHTB tests log
# every 3-13 minutes, so a 10-minute window holds one sample or none.
WINDOW_MIN_SAMPLES = 10


def uniform_wall(config: AssimilationConfig) -> tuple[Mechanism, ...]:
    """The configured wall given to an ``Assimilator``, starting uniform: its first update then
    does not choose the start (``Assimilator._place_wall_start``); for benchmarks that time
    updates alone. ``()`` for the lumped wall."""
    if config.wall != "two_node":
        return ()
    return (make_mechanism("two_node_wall", R_sheet_K_per_W=config.wall_R_sheet_K_per_W),)


def window_for(runs, window_s: float = AssimilationConfig.window_s) -> float:
    """The window length (s) for ``runs``: ``window_s``, lengthened where needed to
    ``WINDOW_MIN_SAMPLES`` sampling intervals of the most sparsely logged run
    (``tankode.fleet.sampling_interval_s``), rounded up to whole minutes."""
    sparsest = max(sampling_interval_s(r) for r in runs)
    return max(window_s, 60.0 * math.ceil(WINDOW_MIN_SAMPLES * sparsest / 60.0 - 1e-9))


def window_edges(t0: float, t_end: float, window_s: float) -> list[tuple[float, float]]:
    """Consecutive windows of ``window_s`` covering [t0, t_end]; a last partial window is kept."""
    n = max(1, int(math.ceil((t_end - t0) / window_s - 1e-9)))
    return [(t0 + k * window_s, min(t0 + (k + 1) * window_s, t_end)) for k in range(n)]


class Assimilator:
    """Train an MLP closure on a fleet's stream of observations, window by window.

    Args:
        runs: one or several measured runs (one closure for all: multi-environment).
        config: an ``AssimilationConfig``.
        closure: the agent to train; a fresh ``MLPClosure`` (seeded) if None (e.g. pass the
            agent trained on other environments to continue from it).
        surrogate: property surrogate (cached default for the runs' fluid if None).
        mechanisms: extra physical effects (``tankode.mechanisms``, e.g. from a model the
            diagnosis extended), part of the model; their values stay fixed while the closure
            trains, except those of ``config.train_mechanisms``, which are trained in place
            (the objects passed here hold the trained values afterwards, as the closure does).
        parallel: where the fleet's other environments are (``trainers/distributed.py``):
            ``SingleProcess()`` (None, the default: all of them are ``runs``) or ``DataParallel``
            (``runs`` are this rank's shard: the data cost and its gradient are all-reduced
            inside every loss evaluation, report rows and checkpoints cover the whole fleet).
    """

    def __init__(self, runs, config: AssimilationConfig = AssimilationConfig(), closure=None, surrogate=None,
                 mechanisms=(), parallel=None):
        self.fleet = Fleet.from_runs(runs, surrogate)
        self.config = config
        self.closure = closure if closure is not None else config.agent()
        self.parallel = SingleProcess() if parallel is None else parallel
        # a factor learned on an unknown wall does not multiply a stated one (e.g. a model given by --init)
        (mechanisms, _), trained = applied_to_walls(mechanisms, [r.name for r in self.fleet.runs], self.fleet.walls), \
            config.train_mechanisms
        ids = {m.id for m in mechanisms}
        wall_added = False
        if config.wall == "two_node":
            if "dry_wall_node" in ids or "dry_wall_heating" in ids:
                raise ValueError("wall='two_node' models the dry wall already; with dry_wall_node or dry_wall_heating "
                                 "use wall='lumped'")
            wall_added = "two_node_wall" not in ids  # a given one (a saved model's) keeps its values
            if wall_added:
                mechanisms += (make_mechanism("two_node_wall", R_sheet_K_per_W=config.wall_R_sheet_K_per_W),)
            trained = tuple(dict.fromkeys(trained + ("two_node_wall",)))
        if config.boiling == "learned":
            if "saturated_boiling" not in ids:  # a given one (a saved model's) keeps its value
                mechanisms += (make_mechanism("saturated_boiling", share=config.boiling_share),)
            trained = tuple(dict.fromkeys(trained + ("saturated_boiling",)))
        # every rank's shard decides alike (one shared factor, one set of trained parameters)
        if config.unknown_wall == "trained" and not self.parallel.any(not all(w.assumed for w in self.fleet.walls)):
            if "unknown_wall_capacity" not in ids:  # a given one (a saved model's) keeps its value
                mechanisms += (make_mechanism("unknown_wall_capacity"),)
            trained = tuple(dict.fromkeys(trained + ("unknown_wall_capacity",)))
        self.model = TankModel(self.fleet.fluid, self.fleet.geometry, self.closure,
                               self.fleet.wall_heat_capacity_J_per_K, mechanisms)
        self.s0 = Assimilator.start_state(self)  # (env, n_state); a subclass's groups are not built yet
        self.scale = state_scale(self.s0, self.fleet.geometry.volume_m3, self.model.extra_state_scales)
        self.solver = config.solver()
        self.windows = window_edges(self.fleet.t0_s, self.fleet.t_end_s, config.window_s)
        self.memories: list[WindowMemory] = []  # one per window trained on, with LaplaceMemory()
        # mode="replay": every trained window's output times and states after its update.
        self.history: list[tuple[Tensor, Tensor]] = []
        self._replay_fleets: dict[tuple[int, int], Fleet] = {}  # (cost group, segments): the batched copies
        self.trained = TrainedMechanisms(self.model.mechanisms, trained)
        self.w0 = [p.detach().clone() for p in self.closure.parameters()]  # base_prior_weight's centre
        self.parallel.check(self)
        # The replayed segments' length (s), alike on every rank: see AssimilationConfig.replay_s.
        sparsest = float(self.parallel.rows(torch.as_tensor(self.fleet.sampling_intervals_s())).max())
        self.replay_s = max(config.replay_s, REPLAY_MIN_SAMPLES * sparsest)
        # The two-node wall's start is chosen by the first window's update (_place_wall_start).
        self._wall_start_pending = wall_added

    def start_state(self) -> Tensor:
        """The fleet's initial state ``(env, n_state)`` with the mechanisms' values as they stand
        (differentiable in trained ones that offset a reading it is built from:
        ``tankode.fleet.Fleet.initial_state``)."""
        return self.model.initial_state(self.fleet.initial_state(self.model.mechanisms))

    def _trained_start(self, s0: Tensor) -> Tensor:
        """The run's first state for an evaluation: ``s0``, or, where a trained mechanism offsets a
        reading it is built from (``TrainedMechanisms.sets_start``), rebuilt from the trained values
        as they stand, differentiably, since it moves with them."""
        if not self.trained.sets_start:
            return s0
        self.trained.apply()
        return self.start_state()

    def _wall(self) -> Mechanism | None:
        """The model's two-node wall, or None without one."""
        return next((m for m in self.model.mechanisms if m.id == "two_node_wall"), None)

    def _start_wall_at(self, share: float) -> Tensor:
        """Set the two-node wall's ``start_share``; return the fleet's initial state from it."""
        wall = self._wall()
        wall.set_values([share if p.name == "start_share" else v for p, v in zip(wall.params, wall.value.tolist())])
        return self.start_state()

    def _place_wall_start(self) -> str:
        """Set the two-node wall's ``start_share`` (``tankode.mechanisms.TwoNodeWall``) and ``s0``;
        called by the first window's update, of a wall the configuration added.

        A wall sensor reads the wall's mean; how it divides between the dry and the wetted wall
        at the first time stamp is unmeasured, and it decides the first windows: a dry wall
        several kelvin above the wetted one keeps the ullage warm, a uniform wall at the same
        mean cools it within minutes. The two physical ends are compared, a uniform wall (0, the
        lumped wall of the paper's cases) and the wetted wall at the liquid's temperature (1, a
        tank at rest under a heat load), each by the first window's J after the agent is fitted
        to it as its update would (``config.iters`` L-BFGS iterations from the agent as it
        starts, each within a quarter of the update budget, which counts this choice), so that
        the agent's own error does not decide the wall's. The share 1 is taken only where it
        fits better by more than the Bayesian information criterion's price of one parameter,
        ``2 N (J_0 - J_1) > ln(5 N)`` (``N`` sample times; ``N J`` is the window's negative
        log-likelihood): where the first window cannot tell them apart the wall starts uniform.
        With data parallelism every rank compares the fleet's J and takes the same share. The
        agent and the trained mechanisms are put back afterwards; the window's update trains
        from them. Nothing is compared when the
        wall reads the liquid's temperature (then both are the same start) or the first window
        holds no data, and where a candidate cannot be integrated the wall starts uniform.
        Returns a note for the log ("" where nothing was compared).

        Why fitted rather than as it starts: on tankode's case 1, whose paper wall is one lump
        9 K above the liquid, the agent as it starts predicts the first window better from the
        split start (J 590 against 2,116), yet both starts fit it to the floor, and the split
        one leaves the next windows at J 29 and 37 where the uniform one gives 2.5 and 6.8
        (``experiments/README.md``, section 5).
        """
        split = self._start_wall_at(1.0)
        x_col = self.model.state_names.index("two_node_wall.dT_dry_wet_K")
        t0, t1 = self.windows[0]
        window = Window.from_runs(self.fleet.runs, t0, t1)
        differ = bool((split[:, x_col].abs() > WALL_START_SAME_K).any())
        if not self.parallel.any(differ and len(window) > 0):  # nothing to choose, or no data to choose by
            self.s0 = self._start_wall_at(0.0)
            return ""
        cfg = self.config
        t_eval = self.parallel.times(torch.cat([window.t_s, torch.tensor([t1], dtype=torch.float64)]).unique())
        obs_index = torch.searchsorted(t_eval, window.t_s)
        named = [(n, p) for n, p in self.closure.named_parameters() if p.requires_grad] + self.trained.named()
        bounds = uniform_box(self.closure, -cfg.weight_bound, cfg.weight_bound)
        bounds.update(self.trained.bounds())
        tensors = [p for _, p in named]
        agent, mechanisms = copy.deepcopy(self.closure.state_dict()), self.trained.state_dict()

        def fitted(share: float) -> float | None:
            s0, start, calls = self._start_wall_at(share), time.perf_counter(), [0]

            def loss():
                over = time.perf_counter() - start > cfg.budget_s / 4  # both fits within half the update's
                if calls[0] > 0 and self.parallel.any(over):
                    raise StopStep("a quarter of the update budget spent")
                calls[0] += 1
                return self.parallel.data_cost(lambda: cost(self.model.observe(
                    self.predict(self._trained_start(s0), t0, t_eval, cfg.gradient)[:, obs_index]), window), tensors)

            failed, J = False, float("nan")
            try:
                opt = BoundedLBFGS(named, bounds, max_iter=cfg.iters, history_size=cfg.history_size,
                                   reject=(SimulationError, AssertionError))
                opt.step(loss)
                self.trained.settle()
                with torch.no_grad():
                    J = float(cost(self.model.observe(
                        self.predict(self._trained_start(s0), t0, t_eval, NoGradient())[:, obs_index]), window))
            except (SimulationError, StopStep, FloatingPointError):
                failed = True
            self.closure.load_state_dict(agent)
            self.trained.load_state_dict(mechanisms)
            return None if self.parallel.any(failed or not math.isfinite(J)) else self.parallel.mean(J)

        began, timings = time.perf_counter(), replace(self.parallel.timings)
        J0, J1 = fitted(0.0), fitted(1.0)
        self.parallel.timings = timings  # they count the updates' evaluations (the note says this one's time)
        n = self.parallel.mean(float(len(window)))
        best = 1.0 if J0 is not None and J1 is not None and 2 * n * (J0 - J1) > math.log(5 * n) else 0.0
        self.s0 = self._start_wall_at(best)
        J0s, J1s = ("-" if j is None else f"{j:.4g}" for j in (J0, J1))
        return (f"two-node wall start_share {best:g} (the first window fitted from a uniform wall to J {J0s}, "
                f"from the wetted wall at the liquid's temperature to J {J1s}; {time.perf_counter() - began:.3g} s)")

    # -- forward pieces ------------------------------------------------------------------------

    def predict(self, s_start: Tensor, t_start: float, t_eval: Tensor, gradient, model: TankModel | None = None) -> Tensor:
        """States ``(env, T, 7)`` at ``t_eval`` integrating from ``s_start`` at ``t_start``.

        ``model``: another right-hand side on the same fleet (e.g. a perturbed closure); the agent's by default.
        """
        self.trained.apply()  # the optimiser moves the trained parameters in place
        states, _ = integrate(self.model if model is None else model, s_start, self.fleet.segments(t_start, float(t_eval[-1])), self.fleet.forcing,
                              t_eval, self.scale, self.solver, gradient)
        return states

    # -- the data cost by groups of environments (GroupedAssimilator) --------------------------

    @property
    def cost_groups(self) -> list[list[int]]:
        """Environment indices whose data cost is computed and differentiated together: the fleet."""
        return [list(range(self.fleet.n_env))]

    def _group_predict(self, g: int, s_start: Tensor, t_start: float, t_eval: Tensor, gradient) -> Tensor:
        """States ``(env_g, T, n)`` of cost group ``g``, from the whole fleet's ``s_start``."""
        return self.predict(s_start, t_start, t_eval, gradient)

    def _group_model(self, g: int) -> tuple[TankModel, Fleet]:
        """Cost group ``g``'s right-hand side and fleet."""
        return self.model, self.fleet

    def _group_observe(self, g: int, states: Tensor) -> Tensor:
        """Observations ``(env_g, T, 5)`` of cost group ``g``'s states."""
        return self._group_model(g)[0].observe(states)

    def _group_windows(self, window: Window) -> list[Window]:
        """The cost groups' parts of the fleet's ``window``, each from its own runs (times included)."""
        return [window]

    def _span(self, k: int, s_next: Tensor) -> tuple[float, Tensor]:
        """(t_start, s_start) of window k's integration for the configured mode."""
        if self.config.mode == "growing" or k == 0:
            return self.fleet.t0_s, self.s0
        t_k = self.windows[k][0]
        if self.config.window_start in ("model", "joint"):
            return t_k, s_next
        return t_k, self._data_corrected(s_next, *self.windows[k - 1])

    def _data_corrected(self, s_model: Tensor, t0: float, t1: float) -> Tensor:
        """The model's state at t1 with every measured channel replaced by a line fit ending at t1.

        Unmeasured mechanism states (a surface layer's excess) keep the model's values.
        """
        with torch.no_grad():
            obs = self.model.observe(s_model).numpy().copy()  # (env, 5): p_v, T_v, T_l, T_w, H_l
        t0 = max([t0, t1 - FIT_SPAN_S, *self.fleet.breakpoints(t0, t1)])
        for e, run in enumerate(self.fleet.runs):
            for c in range(5):
                t, v = run.observations.t_s, run.observations.values[:, c]
                sel = (t >= t0) & (t <= t1) & np.isfinite(v)
                if sel.sum() >= 3:
                    _, intercept = np.polyfit(t[sel] - t1, v[sel], 1)
                    obs[e, c] = intercept
        V_l = self.fleet.geometry.volume_at_level(torch.as_tensor(obs[:, 4])).detach().numpy()
        tank = self.fleet.state_from(obs[:, 0], obs[:, 1], obs[:, 2], obs[:, 3], V_l)  # (env, 7)
        return torch.cat([tank, s_model[:, N_STATE:].detach()], dim=-1)

    def _replay(self, k: int) -> list[tuple[float, Tensor, Window, Tensor, Tensor]]:
        """Window k's replay sample (module docstring): per segment ``(t_start, s_start, parts)``,
        ``parts`` one ``(window, t_eval, obs_index)`` per cost group (each from its own runs' times,
        as a data-parallel rank takes them)."""
        cfg = self.config
        t_k = self.windows[k][0]
        if not self.history:
            return []
        times = torch.cat([t for t, _ in self.history])
        states = torch.cat([s for _, s in self.history], dim=1)
        candidates = (times <= t_k - self.replay_s + 1e-9).nonzero().flatten()
        if len(candidates) == 0:
            return []
        rng = np.random.default_rng([cfg.seed, k, 1])
        out = []
        for i in rng.choice(candidates.numpy(), size=cfg.replay_segments, replace=True):
            a = float(times[i])
            window = Window.from_runs(self.fleet.runs, a, a + self.replay_s)
            if not self.parallel.any(len(window) > 0):  # no data there (with data parallelism: on any rank)
                continue
            parts = []
            for w in self._group_windows(window):
                t_eval = torch.cat([torch.tensor([a], dtype=torch.float64), w.t_s,
                                    torch.tensor([a + self.replay_s], dtype=torch.float64)]).unique()
                parts.append((w, t_eval, torch.searchsorted(t_eval, w.t_s)))
            out.append((a, states[:, i].detach(), parts))
        return out

    def _replay_states(self, g: int, replay, gradient) -> list[Tensor]:
        """Cost group ``g``'s states ``(env_g, T_a, n)`` at each replayed segment's ``t_eval``, one batched ODE.

        Segment i's copy of the group's tanks starts from its own state at its own time ``a_i``;
        all copies share a time axis ``tau = t - a_i`` (the model is autonomous between input
        changes, so only the forcing needs each copy's own clock), restart at every copy's input
        changes, and take the same steps, set by the copy that needs the smallest.
        """
        self.trained.apply()
        model, fleet = self._group_model(g)
        idx = self.cost_groups[g]
        n, R = fleet.n_env, len(replay)
        copies = self._replay_fleets.get((g, R))
        if copies is None:
            copies = self._replay_fleets[(g, R)] = Fleet.from_runs(fleet.runs * R, fleet.fluid)
        starts = [a for a, _, _ in replay]
        rel = [parts[g][1] - a for a, _, parts in replay]  # each segment's output times on its own clock
        tau = torch.cat(rel).unique()
        cuts = [0.0]
        for c in sorted(b - a for a in starts for b in fleet.breakpoints(a, a + float(tau[-1]))):
            if c - cuts[-1] > 1e-6:  # the copies' input changes; ones that coincide (to rounding) merged
                cuts.append(c)
        cuts.append(float(tau[-1]))

        def forcing(t_s: float, s: Tensor) -> Forcing:
            parts = [fleet.forcing(a + t_s, s[i * n:(i + 1) * n]) for i, a in enumerate(starts)]
            return Forcing(*(torch.cat(field) for field in zip(*parts)))

        s0 = torch.cat([s_a[idx] for _, s_a, _ in replay])
        states, _ = integrate(model.on(copies), s0, list(zip(cuts[:-1], cuts[1:])), forcing, tau,
                              self.scale[idx].repeat(R, 1), self.solver, gradient)
        return [states[i * n:(i + 1) * n, torch.searchsorted(tau, r)] for i, r in enumerate(rel)]

    # -- one window ----------------------------------------------------------------------------

    # One torch thread: the tensors are (env, 7) and an (env, 8) MLP, so extra threads only
    # contend. Measured (4 tanks, one window): 55 s against 97 s with two threads alone, and
    # 56 s against 303 s with two such jobs on the two cores.
    @single_threaded()
    def update(self, k: int, s_next: Tensor) -> tuple[WindowReport, Tensor, dict]:
        """Train on window k; return its report, the next fixed window's initial state and the optimiser state."""
        cfg = self.config
        start = time.perf_counter()  # the wall's start is chosen within the first window's update
        wall_note = ""
        if k == 0 and self._wall_start_pending:
            wall_note, self._wall_start_pending = self._place_wall_start(), False
        t_data0 = self.fleet.t0_s if cfg.mode == "growing" else self.windows[k][0]
        t1 = self.windows[k][1]
        t_start, s_start = self._span(k, s_next)
        window = Window.from_runs(self.fleet.runs, t_data0, t1)
        # Output times: the window's sample times (with data parallelism: of every rank's runs, so all
        # ranks replay from the same times).
        t_eval = self.parallel.times(torch.cat([window.t_s, torch.tensor([t1], dtype=torch.float64)]).unique())
        obs_index = torch.searchsorted(t_eval, window.t_s)

        named = [(n, p) for n, p in self.closure.named_parameters() if p.requires_grad]
        bounds = uniform_box(self.closure, -cfg.weight_bound, cfg.weight_bound)
        named += self.trained.named()
        bounds.update(self.trained.bounds())
        estimate = None
        if cfg.window_start == "joint" and k > 0:  # the config allows "joint" in fixed mode only
            estimate = StartEstimate(self.fleet, self.model, s_start, window, cfg.start_prior_sigmas)
            named.append((_OFFSET, estimate.delta))
            bounds[_OFFSET] = Box(-START_OFFSET_BOUND_SIGMAS, START_OFFSET_BOUND_SIGMAS)
        anchor = [p.detach().clone() for p in self.closure.parameters()]
        remembering = isinstance(cfg.memory, LaplaceMemory)
        prior = Prior(self, self.memories) if remembering and self.memories else None
        duration_s = t1 - t_data0

        in_backward = False  # set once the forward pass of an evaluation has succeeded
        replay = self._replay(k) if cfg.mode == "replay" else []
        # Every second of the stream weighs the same in expectation (module docstring).
        w_new = (t1 - self.windows[k][0]) / (t1 - self.fleet.t0_s) if replay else 1.0
        w_replay = (1.0 - w_new) / max(len(replay), 1)

        # Each cost group's data cost is its own graph; groups are summed as data-parallel ranks
        # are (group_sum), so one process reproduces a distributed job's arithmetic.
        windows = self._group_windows(window)
        indices = [torch.searchsorted(t_eval, w.t_s) for w in windows]
        shares = [len(idx) / self.fleet.n_env for idx in self.cost_groups]

        rebuilt_start = self.trained.sets_start and t_start == self.fleet.t0_s

        def group_cost(g, mask):
            if rebuilt_start:
                s0 = self._trained_start(s_start)
            else:
                s0 = s_start if estimate is None else estimate.state()
            states = self._group_predict(g, s0, t_start, t_eval, cfg.gradient)
            J = w_new * cost(self._group_observe(g, states[:, indices[g]]), windows[g], mask)
            if replay:
                replayed = self._replay_states(g, replay, cfg.gradient)
                for (_, _, parts), states_a in zip(replay, replayed):
                    window_a, _, index_a = parts[g]
                    J = J + w_replay * cost(self._group_observe(g, states_a[:, index_a]), window_a)
            return J

        trained_tensors = [p for _, p in named]

        def data_cost(mask=None):
            return group_sum([lambda g=g: group_cost(g, mask) for g in range(len(windows))], shares, trained_tensors)

        n_called = 0

        def loss(mask=None):
            nonlocal in_backward, n_called
            in_backward = False
            # After the first call (the optimiser needs one point); every rank decides alike.
            over = time.perf_counter() - start > cfg.budget_s
            if n_called > 0 and self.parallel.any(over):
                raise StopStep(f"update budget of {cfg.budget_s:g} s spent")
            n_called += 1
            # The environments' share of J, summed over all ranks with its gradient (self.parallel).
            J = self.parallel.data_cost(lambda: data_cost(mask), trained_tensors)
            if estimate is not None:
                J = J + estimate.penalty()
            if cfg.prior_weight > 0:
                J = J + 0.5 * cfg.prior_weight * _mean_square_change(self.closure.parameters(), anchor)
            if cfg.base_prior_weight > 0:
                J = J + 0.5 * cfg.base_prior_weight * _mean_square_change(self.closure.parameters(), self.w0)
            if prior is not None:
                J = J + prior(duration_s)
            in_backward = True
            return J

        # The agent may learn where this window goes: its seen box (MLPClosure.extend_domain)
        # takes the window's trajectory under the agent as it stands. Before the check below,
        # which must judge the agent with that box: a new operation (a warm-gas injection after
        # a hold) lies outside the old box, where the agent is its base and predicts well, and
        # inside the new one, where the network extrapolates (measured: J 1,700 judged in the old
        # box, 3,100 after the update that started in the new one, on another simulator's tank).
        self._extend_seen_along(s_start, t_start, t_eval)
        # Before the optimiser is built: it may move the weights back (an agent that cannot
        # integrate this window), and BoundedLBFGS holds the weights it starts from.
        before, note = self._cost_before(s_start, t_start, t_eval, obs_index, window)
        n_data = len(window) + sum(len(parts[g][0]) for _, _, parts in replay for g in range(len(windows)))
        measured = (window.weights.sum(1) > 0) & (window.inv_var > 0)  # (env, 5): the window's channels
        floor = self.parallel.mean(0.5 * float(measured.double().sum(-1).mean())) if len(window) else 0.0
        scan_note = self._scan_unknown_wall(lambda: float(self.parallel.data_cost(data_cost, trained_tensors)),
                                            self.parallel.mean(float(n_data)), floor)
        if scan_note:
            note = f"{note}; {scan_note}" if note else scan_note
        if wall_note:
            note = f"{wall_note}; {note}" if note else wall_note
        batch = None
        n_outer, per_step = 1, cfg.iters
        if cfg.batch_fraction < 1.0:
            batch = MiniBatch(fraction=cfg.batch_fraction, n_samples=len(window), seed=cfg.seed * 100_003 + k,
                              history=ResetHistory())
            n_outer, per_step = max(1, cfg.iters // cfg.iters_per_batch), cfg.iters_per_batch
        # A trial agent whose ODE (or its adjoint) cannot be integrated is an infeasible point
        # of the line search, not a failure of the update.
        opt = BoundedLBFGS(named, bounds, max_iter=per_step, history_size=cfg.history_size, batch=batch,
                           reject=(SimulationError, AssertionError))
        # (J of the newest window before and after are reported; the replayed segments only train.)
        n_evals = n_iters = 0
        grad_norm = float("nan")

        def noted(line: str) -> str:
            """The window's note with one more sentence."""
            return f"{note}; {line}" if note else line

        def spent() -> str:
            return f"update budget of {cfg.budget_s:g} s spent: the best of {n_evals} evaluated weights kept"

        if self.parallel.any(len(window) > 0):  # with data parallelism: data on any rank
            for _ in range(n_outer):
                try:
                    res = opt.step(loss)
                except StopStep:  # spent before a later mini-batch step's first call: that step never began
                    note = noted(spent())
                    break
                except (SimulationError, FloatingPointError) as err:
                    # BoundedLBFGS restored the weights of the step's start: keep them, say why.
                    note = noted(f"step stopped, weights kept from before it: {str(err).splitlines()[0]}")
                    if in_backward and isinstance(cfg.gradient, Adjoint):
                        note += ADJOINT_DIVERGED
                    break
                n_evals += res.n_evals
                n_iters += res.n_iters
                grad_norm = res.proj_grad_norm
                if res.stopped:
                    note = noted(spent())
                    break
        self.trained.settle()
        if rebuilt_start:
            with torch.no_grad():
                s_start = self.s0 = self.start_state()
        offsets = []
        if estimate is not None:
            with torch.no_grad():
                s_start = estimate.state()
            offsets = estimate.offset.detach().tolist()
        with torch.no_grad():
            states = self.predict(s_start, t_start, t_eval, NoGradient())
            # The box takes the trained trajectory; if that widened it, the agent changed where the
            # trajectory left the old box, and the window must end on the agent as kept.
            if self._extend_seen(t_eval, states):
                states = self.predict(s_start, t_start, t_eval, NoGradient())
            pred = self.model.observe(states[:, obs_index])
            terms = self.parallel.rows(cost_terms(pred, window))  # (N, 5): the whole fleet's
            after = float(terms.sum() / terms.shape[0])
            inputs = closure_inputs_along(self.model, self.fleet, t_eval, states)
            theta = torch.stack([self.model.closure(x) for x in inputs], dim=1)  # (env, T, 4)
            saturated = []
            if isinstance(self.closure, MLPClosure):
                position = torch.stack([self.closure.output_position(x) for x in inputs], dim=1)
                saturated = (position.abs() >= SATURATED_TANH).double().mean(1).tolist()
        if replay and after > before:
            # Not a failed update: it minimises this window and the replayed earlier data together.
            note = noted(f"this window's J rose: the update fits it with {len(replay)} replayed segments of "
                         f"the earlier data, which weigh {1 - w_new:.0%} of its cost")
        if remembering and len(window) > 0:
            self.memories.append(remember(self, s_start, t_start, t_eval, obs_index, window, states, duration_s))
        if cfg.mode == "replay":
            self.history.append((t_eval.clone(), states.detach().clone()))
        theta_mean = self.parallel.rows(theta.mean(1))
        if saturated:
            saturated = self.parallel.rows(torch.tensor(saturated)).tolist()
        report = WindowReport(k, t_data0, t1, before, after, terms.tolist(), theta_mean.tolist(), grad_norm,
                              n_evals, n_iters, time.perf_counter() - start, note, offsets, saturated,
                              self.trained.values())
        return report, states[:, -1].detach().clone(), opt.state_dict()

    def _gated(self) -> bool:
        return isinstance(self.closure, MLPClosure) and self.closure.config.domain_margin is not None

    def _extend_seen(self, t_eval: Tensor, states: Tensor) -> bool:
        """Widen the agent's seen box with its inputs along a trajectory ``states`` ``(env, T,
        n_state)`` at times ``t_eval`` ``(T,)``, every rank's; whether the box changed (never for
        an agent without a domain margin)."""
        if not self._gated():
            return False
        with torch.no_grad():
            rows = []
            for g, idx in enumerate(self.cost_groups):  # each group's features as its rank computes them
                model, fleet = self._group_model(g)
                inputs = closure_inputs_along(model, fleet, t_eval, states[idx])
                f = torch.stack([self.closure.features(x) for x in inputs], dim=1)  # (env_g, T, F)
                finite = torch.isfinite(f)
                rows.append(torch.cat([torch.where(finite, f, math.inf).amin(1),
                                       torch.where(finite, f, -math.inf).amax(1)], dim=-1))
            both = self.parallel.rows(torch.cat(rows, dim=0))  # (N, 2F): the whole fleet's
        n = both.shape[-1] // 2
        return self.closure.extend_domain(torch.cat([both[:, :n], both[:, n:]], dim=0))

    def _extend_seen_along(self, s_start: Tensor, t_start: float, t_eval: Tensor) -> None:
        """``_extend_seen`` along the window's trajectory under the agent as it stands. If that
        agent cannot integrate the window (``_cost_before`` then shrinks it), the box grows
        after the update only."""
        if not self._gated():
            return
        failed = False
        try:
            with torch.no_grad():
                states = self.predict(s_start, t_start, t_eval, NoGradient())
        except SimulationError:
            failed = True
        if not self.parallel.any(failed):  # every rank widens the box alike, or none does
            self._extend_seen(t_eval, states)

    # Shares of its change since the initial agent that the carried-over agent may keep, tried
    # when it predicts the new window worse than the initial agent or cannot integrate it
    # (_cost_before).
    _BACKTRACK = (0.5, 0.25, 0.125)

    def _cost_before(self, s_start, t_start, t_eval, obs_index, window) -> tuple[float, str]:
        """J of the newest window with the agent carried over, and a note ("" if nothing was done).

        Before its update the newest window is data the agent has not seen: a check of how the
        agent extrapolates. An agent trained on earlier windows can extrapolate badly to a new
        operating regime (a warm-gas injection after a quiet window: its learned factors swing
        to their bounds and the window's J rises a thousandfold), or not integrate the window at
        all (out of the property domain, an impossible state). The carried agent ``w`` is
        therefore compared with the initial agent ``w0`` (a physical closure for the residual
        agent) on the window; if ``w`` integrates and predicts no worse, it is kept. Otherwise the
        agent starts the update from the best-predicting of ``w0 + a (w - w0)``, ``a`` in
        ``(0.5, 0.25, 0.125, 0)`` (the window's data choose how much of the earlier learning
        carries into the new regime; replayed segments then teach the earlier data again), and the
        note says which and why. With ``carry_over="integrable"`` (the paper's setup) the agent is
        kept as it is where it integrates the window, else the largest share that does is taken.
        Only if no candidate integrates is the first ``SimulationError`` raised. With data
        parallelism every rank compares the fleet's J and takes the same ``a``.
        """
        params = list(self.closure.parameters())
        trained = [p.detach().clone() for p in params]
        first_err = None

        def apply(share):
            with torch.no_grad():
                for p, w, w0 in zip(params, trained, self.w0):
                    p.copy_(w0 + share * (w - w0))

        def cost_at(share):
            nonlocal first_err
            apply(share)
            local, failed = float("nan"), False
            try:
                with torch.no_grad():
                    local = float(cost(self.model.observe(
                        self.predict(s_start, t_start, t_eval, NoGradient())[:, obs_index]), window))
            except SimulationError as err:
                first_err, failed = first_err or err, True
            return None if self.parallel.any(failed) else self.parallel.mean(local)

        moved = any(bool((w != w0).any()) for w, w0 in zip(trained, self.w0))
        validated = self.config.carry_over == "validated"
        J = {1.0: cost_at(1.0)}
        if moved and validated:
            J[0.0] = cost_at(0.0)
        if J[1.0] is not None and (J.get(0.0) is None or J[1.0] <= J[0.0]):
            apply(1.0)
            return J[1.0], ""
        ok = {}
        if moved:  # else every share is the same agent
            for share in (*self._BACKTRACK, 0.0):
                if share not in J:
                    J[share] = cost_at(share)
                if J[share] is not None and not validated:
                    break  # "integrable": the largest share that integrates
            ok = {a: j for a, j in J.items() if j is not None}
        if not ok:
            if first_err is not None:
                raise first_err
            raise SimulationError("neither the agent nor the initial agent can integrate this window on another rank", t_start)
        # "validated": the lowest J, on a tie the most of the learning; "integrable": the only one
        share = min(ok, key=lambda a: (ok[a], -a))
        apply(share)
        if J[1.0] is None:
            why = str(first_err).splitlines()[0] if first_err is not None else "on another rank"
            why = f"could not integrate this window ({why})"
        else:
            why = f"predicted this window at J {J[1.0]:.4g}, the initial agent at {J[0.0]:.4g}"
        return ok[share], f"the agent carried over {why}; it keeps {share:g} of its change from the initial agent"

    def _scan_unknown_wall(self, data_cost: Callable[[], float], n: float, floor: float) -> str:
        """Move a trained unknown wall's factor by decades where the update's data say so, before
        the update; return a note ("" if it stays).

        The factor (``tankode.mechanisms.UnknownWallCapacity``) spans four decades and its
        gradient is local: a quiet window barely sees the wall, and once a warm-gas injection
        shows it the agent's bounded factors absorb part of the misfit first, so L-BFGS leaves
        the factor near where it stood (measured on another simulator's ullage fed with 300 K
        gas, a wall 170 times the shell: 1.6, 1.2 and 1.2 times the shell after the first three
        windows, at J 5, 1,030 and 6,060). So each update first walks the factor a decade at a
        time (up first, then down), the agent as it stands, while the update's own data cost
        (``data_cost``: the newest window and the replayed segments, with their weights; ``n``
        samples) falls, and keeps the walk where it fits better by more than the Bayesian
        information criterion's price of one parameter, ``2 n (J_start - J) / B > ln(5 n)`` (as
        ``_place_wall_start``), the gain scaled down by the misfit ``B = max(1, J / floor)``
        (``floor``: the noise's J, half the measured channels), for a model that misses the data
        by far is not judged by the sensors' noise alone (measured on the MHTB test P263968K,
        at J 695: a tenfold lighter wall lowers J by 0.4 %, which the unscaled price took); the
        update then refines it with the weights. The newest window
        alone is not the judge: it moves a constant of the tank with the carried state's error
        (measured on the same run: 226, 2.3, then 1,000 times the shell in consecutive windows).
        A forward pass per step; a step that cannot be integrated ends the walk. With data
        parallelism every rank compares the fleet's J."""
        xi = dict(self.trained.named()).get(PREFIX + "unknown_wall_capacity")
        if xi is None or not n > 0:
            return ""
        box = self.trained.bounds()[PREFIX + "unknown_wall_capacity"]
        start = float(xi.detach()[0])

        def J_at(x: float) -> float | None:
            with torch.no_grad():
                xi.fill_(x)
            J, failed = float("nan"), False
            try:
                with torch.no_grad():
                    J = data_cost()
            except SimulationError:
                failed = True
            return None if self.parallel.any(failed or not math.isfinite(J)) else J

        J_start = J_at(start)
        if J_start is None:
            return ""
        # a hair inside the box: the bounded optimiser has no slope on a bound
        lo, hi = float(box.lower) + 1e-6, float(box.upper) - 1e-6
        best, J_best = start, J_start
        for direction in (1.0, -1.0):
            x = start
            while True:
                y = min(max(x + direction * math.log(10.0), lo), hi)
                J = None if y == x else J_at(y)
                if J is None or J >= J_best:
                    break
                best, J_best, x = y, J, y
            if best != start:
                break
        misfit = max(1.0, J_best / floor) if floor > 0 else 1.0
        kept = best != start and 2 * n * (J_start - J_best) / misfit > math.log(5 * n)
        with torch.no_grad():
            xi.fill_(best if kept else start)
        self.trained.settle()
        if not kept:
            return ""
        return (f"the unknown wall's heat capacity moved from {math.exp(start):.3g} to {math.exp(best):.3g} "
                f"times the assumed shell before the update (its data at J {J_start:.4g}, then {J_best:.4g})")

    # -- the loop ------------------------------------------------------------------------------

    @single_threaded()
    def run(self, checkpoint: str | Path | None = None, resume: bool = False, logdir: str | Path | None = None,
            progress: bool = False, on_window=None) -> AssimilationResult:
        """Update the agent on every window in turn; checkpoint after each.

        Args:
            checkpoint: file to write after every window (and to resume from).
            resume: continue from ``checkpoint`` if it exists (same runs and configuration).
            logdir: TensorBoard log directory (None: no logging).
            progress: show a progress bar.
            on_window: optional callback ``on_window(report)`` after each window.
        """
        result = AssimilationResult(self.closure, self.config)
        k0, s_next = 0, self.s0
        restored = self.parallel.read_checkpoint(checkpoint) if resume and checkpoint is not None else None
        if restored is not None:
            k0, s_next = self._restore(restored, result)
            result.state_end = s_next
        writer = None
        if logdir is not None and self.parallel.writes:
            from .logger import TrainingLogger

            writer = TrainingLogger(logdir, self.parallel.run_names([r.name for r in self.fleet.runs]))
        iterator = range(k0, len(self.windows))
        if progress:
            from tqdm import tqdm

            iterator = tqdm(iterator, total=len(self.windows), initial=k0, desc="windows", unit="window")
        for k in iterator:
            report, s_end, opt_state = self.update(k, s_next)
            s_next = s_end
            result.reports.append(report)
            result.state_end = s_next
            if writer is not None:
                writer.log_window(report, self, s_next)
            if checkpoint is not None:
                payload = self._payload(k, self.parallel.rows(s_next), opt_state, result)  # the whole fleet's
                if self.parallel.writes:
                    save_checkpoint(checkpoint, payload)
            if on_window is not None:
                on_window(report)
        if writer is not None:
            writer.close()
        return result

    def _agent_json(self) -> str:
        """The agent's configuration as checkpoints record it (and resume compares it)."""
        if not isinstance(self.closure, MLPClosure):  # e.g. a known closure while mechanisms train
            return json.dumps({"type": type(self.closure).__name__})
        return json.dumps(asdict(self.closure.config))

    def _payload(self, k: int, s_next: Tensor, opt_state: dict, result: AssimilationResult) -> dict:
        return {
            "format": "tankode-assimilation-checkpoint-1",
            "next_window": k + 1,
            "config": self.config.to_json(),
            "mlp_config": self._agent_json(),
            "runs": self.parallel.run_names([r.name for r in self.fleet.runs]),
            "weights": {n: p.detach().clone() for n, p in self.closure.state_dict().items()},
            "optimizer": opt_state,
            "s_next": s_next,
            "reports": [json.dumps(asdict(r)) for r in result.reports],
            "memories": [m.to_payload() for m in self.memories],
            "history": [{"t_s": t, "states": self.parallel.rows(x)} for t, x in self.history],
            "mechanisms": self.trained.state_dict(),
            "wall_start_share": None if self._wall() is None else self._wall().values_dict()["start_share"],
        }

    def _restore(self, ck: dict, result: AssimilationResult) -> tuple[int, Tensor]:
        if ck.get("format") != "tankode-assimilation-checkpoint-1":
            raise ValueError(f"not a tankode assimilation checkpoint (format {ck.get('format')!r})")
        # Compared as configurations, not strings: a checkpoint written before a field existed
        # (e.g. integrator) records its default implicitly.
        if AssimilationConfig.from_json(ck["config"]) != self.config:
            raise ValueError("checkpoint was written with another configuration:\n"
                             f"  checkpoint: {ck['config']}\n  now:        {self.config.to_json()}")
        now = self._agent_json()
        if ck["mlp_config"] != now:
            raise ValueError("checkpoint was written for another agent (MLP configuration):\n"
                             f"  checkpoint: {ck['mlp_config']}\n  now:        {now}")
        names = self.parallel.run_names([r.name for r in self.fleet.runs])
        if list(ck["runs"]) != names:
            raise ValueError(f"checkpoint is for runs {list(ck['runs'])}, not {names}")
        self.closure.load_state_dict(ck["weights"])
        result.reports.extend(WindowReport(**json.loads(r)) for r in ck["reports"])
        self.memories = [WindowMemory.from_payload(m) for m in ck.get("memories", [])]
        self.history = [(h["t_s"], self.parallel.local_rows(h["states"])) for h in ck.get("history", [])]
        self.trained.load_state_dict(ck.get("mechanisms", {}))
        share = ck.get("wall_start_share")
        if share is not None and self._wall() is not None:  # the start the windows so far were trained from
            self.s0 = self._start_wall_at(share)
        return int(ck["next_window"]), self.parallel.local_rows(ck["s_next"])


__all__ = ["Assimilator", "AssimilationConfig", "AssimilationResult", "WindowReport", "uniform_wall", "window_edges"]

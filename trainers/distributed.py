"""Data-parallel assimilation on ``torch.distributed``: one closure, a fleet's runs sharded over ranks.

The cost of a window is a mean over environments, ``J = 1/(2N) sum_env ...`` (``trainers/cost.py``),
so its value and gradient are sums over environments. Each rank holds a shard of the runs and
integrates it as one batched ODE (its own ``Assimilator`` on its own ``Fleet``); inside every
L-BFGS closure call the rank computes its shard's data cost and gradient, and one all-reduce of
one flat buffer ``[failure flags, n_r/N * J_r, n_r/N * dJ_r/dw]`` gives every rank the global
value and gradient. Every rank therefore sees the same loss and gradient at the same point, so
torch's L-BFGS takes the same directions, the same strong-Wolfe line search and the same steps
on every rank, and all ranks hold the same weights after every update without broadcasting them.
Terms of the loss that depend on the weights only (the prior on the weights) are computed
identically on every rank and added after the reduction.

The strategy is handed to ``Assimilator(..., parallel=...)``:

* ``SingleProcess()`` (the default): all environments in this process, no reduction.
* ``DataParallel(shards, names)``: this rank's runs are ``shards[rank]`` of the global ``names``;
  costs and gradients are all-reduced, per-environment report rows and the checkpoint's
  carried states are gathered into the global run order, rank 0 alone writes the checkpoint,
  every rank restores from it (rank 0 reads it and broadcasts it, so the other ranks need no
  shared file system). A checkpoint is the same file a single process writes for the same runs.

A shard is integrated as its own batched ODE with its own step sequence (the stiffest tank of
the shard sets its steps), so the data-parallel objective is the single-process objective of the
fleet integrated in those groups (``trainers/grouped.py``), which it equals to rounding; against
one batched ODE of the whole fleet it differs by the solver's tolerance.

Failures. A trial point that one rank cannot integrate (``SimulationError``) is rejected on every
rank (the flags travel in the same all-reduce): the line search backtracks everywhere alike. Any
other error on a rank stops every rank with its message. A rank that dies makes the others' next
collective fail as soon as the transport notices (gloo: a closed connection, within seconds); a
rank that hangs makes them fail after ``DistributedConfig.timeout_s``. Either way every surviving
rank raises ``RankFailure`` with one line that says what stopped and how to resume.

Every rank outputs its trajectories at the union of all ranks' sample times in a window, so
``mode="replay"`` draws the same replay start times on every rank (and a replayed segment is
kept while any rank has data in it), as one process does for the whole fleet.

Limits: ``window_start="joint"`` (per-environment offsets trained with the weights),
``memory=LaplaceMemory()`` and mini-batches (``batch_fraction < 1``; the masks are over each
rank's own observation times) are refused with data parallelism.
"""

from __future__ import annotations

import math
import os
import re
import sys
import time
from dataclasses import dataclass, field
from datetime import timedelta
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch
from torch import Tensor

from tankode.errors import SimulationError

# Errors of a trial point that the L-BFGS line search treats as an infeasible point (those
# Assimilator.update hands to BoundedLBFGS as ``reject``, and the non-finite loss it adds).
_REJECTED = (SimulationError, AssertionError, FloatingPointError)

BACKENDS = ("gloo", "nccl")


class RankFailure(RuntimeError):
    """Another rank stopped, hung or failed: the data-parallel job cannot continue (one-line message)."""


@dataclass(frozen=True)
class DistributedConfig:
    """How ranks talk to each other.

    Attributes:
        backend: "gloo" (default: tankode integrates on the CPU, so the reduced buffer is a CPU
            tensor of a few kB per loss evaluation) or "nccl" (the buffer is copied to this
            rank's GPU ``cuda:LOCAL_RANK`` for each collective).
        timeout_s: longest wait at a collective (s) before the rank gives up on the others:
            a rank that hangs ends the job after this long. It must exceed the longest
            legitimate wait: the imbalance of one loss evaluation between the slowest and the
            fastest rank, plus rank 0's checkpoint write. Default 600 s: an hour of tank time is
            six 10-minute windows, and one loss evaluation of a 1,024-tank shard takes seconds
            (``trainers/bench.py``), so a wait of ten minutes means a rank is gone.
    """

    backend: str = "gloo"
    timeout_s: float = 600.0

    def __post_init__(self):
        if self.backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {self.backend!r}")
        if not (self.timeout_s > 0 and math.isfinite(self.timeout_s)):
            raise ValueError(f"timeout_s must be a positive number of seconds, got {self.timeout_s}")


@dataclass
class Timings:
    """Where a rank's time goes inside loss evaluations (s), accumulated until ``reset``.

    ``forward_s``: the shard's data cost (integration and observation); ``backward_s``: its
    gradient; ``reduce_s``: the all-reduce, which includes waiting for slower ranks;
    ``n_evals``: loss evaluations.
    """

    forward_s: float = 0.0
    backward_s: float = 0.0
    reduce_s: float = 0.0
    n_evals: int = 0

    def reset(self) -> None:
        self.forward_s = self.backward_s = self.reduce_s = 0.0
        self.n_evals = 0


class SingleProcess:
    """All environments in this process: the data cost is the loss term itself, nothing is reduced.

    The ``Assimilator``'s default. Records the forward time of the data cost (``timings``); the
    gradient is taken later by the optimiser and is not timed here.
    """

    writes = True

    def __init__(self):
        self.timings = Timings()

    def check(self, assimilator) -> None:
        """Nothing to check: every configuration runs in one process."""

    def data_cost(self, local: Callable[[], Tensor], params: list[Tensor]) -> Tensor:
        """``local()``: the fleet's data cost J (a mean over its environments), with its graph."""
        start = time.perf_counter()
        J = local()
        self.timings.forward_s += time.perf_counter() - start
        self.timings.n_evals += 1
        return J

    def mean(self, value: float) -> float:
        """The fleet's mean of a per-environment mean over this process's environments: ``value``."""
        return value

    def any(self, flag: bool) -> bool:
        """Whether ``flag`` holds in any process: ``flag``."""
        return bool(flag)

    def times(self, local: Tensor) -> Tensor:
        """The sorted union of every process's times ``(T,)`` (s): ``local``."""
        return local

    def rows(self, local: Tensor) -> Tensor:
        """Per-environment rows ``(env, ...)`` of the whole fleet, in run order: ``local``."""
        return local

    def local_rows(self, rows: Tensor) -> Tensor:
        """This process's rows of per-environment rows of the whole fleet: ``rows``."""
        return rows

    def run_names(self, local_names: list[str]) -> list[str]:
        """The whole fleet's run names, in order: ``local_names``."""
        return list(local_names)

    def read_checkpoint(self, path) -> dict | None:
        """The checkpoint at ``path``, or None when there is none."""
        from .checkpoint import load_checkpoint

        return load_checkpoint(path) if Path(path).exists() else None


class _Reduced(torch.autograd.Function):
    """A scalar whose value and gradient with respect to ``params`` were computed (and reduced) already."""

    @staticmethod
    def forward(ctx, value: Tensor, flat_grad: Tensor, *params: Tensor) -> Tensor:
        ctx.save_for_backward(flat_grad)
        ctx.shapes = [(p.shape, p.dtype) for p in params]
        return value.clone()

    @staticmethod
    def backward(ctx, g: Tensor):
        (flat,) = ctx.saved_tensors
        out, offset = [], 0
        for shape, dtype in ctx.shapes:
            n = math.prod(shape)
            out.append((g * flat[offset:offset + n]).reshape(shape).to(dtype))
            offset += n
        return (None, None, *out)


def group_sum(parts: Sequence[Callable[[], Tensor]], shares: Sequence[float], params: list[Tensor]) -> Tensor:
    """``sum_g shares[g] * parts[g]()``, summed as a data-parallel job sums its ranks.

    One part: its value with its graph, untouched. Several (a process integrating the fleet in
    groups, ``GroupedAssimilator``): each part's value and gradient with respect to ``params``
    are taken now, each alone (``torch.autograd.grad``), weighted by its share and summed in
    order, exactly as ``DataParallel.data_cost`` weighs a rank's and the all-reduce adds them;
    the scalar returned deposits that gradient on backward. A one-process run in a two-rank
    job's shards therefore takes the job's steps bit for bit (``tests/test_distributed.py``).

    Args:
        parts: ``part() -> J_g``, a scalar with its graph.
        shares: each part's weight (its environments over the fleet's).
        params: the tensors the gradient is taken for.
    """
    if len(parts) == 1:
        return parts[0]()
    total = None
    for part, share in zip(parts, shares):
        J = part()
        found = torch.autograd.grad(J, params, allow_unused=True) if J.requires_grad else [None] * len(params)
        grads = [torch.zeros_like(p) if g is None else g for p, g in zip(params, found)]
        term = _weighted(J.detach(), grads, share)
        total = term if total is None else total + term
    return _Reduced.apply(total[0], total[1:], *params)


def _weighted(value: Tensor, grads: list[Tensor], share: float) -> Tensor:
    """``(1 + n_params,)``: a cost's value and flattened gradient times its share, in float64: what
    a rank contributes to the all-reduce and a group to ``group_sum`` (one expression, so that
    both sum the same numbers)."""
    return torch.cat([(share * value.to(torch.float64)).reshape(1)]
                     + [(share * g.detach().to(torch.float64)).reshape(-1) for g in grads])


def _first_line(err: BaseException) -> str:
    text = str(err).strip()
    return (text.splitlines()[0] if text else "") or type(err).__name__


def _transport_message(err: BaseException) -> str:
    """The transport's own words, without its source location and advice: e.g. "Connection closed by peer [ip]:port"."""
    text = re.sub(r"^\[[^\]]*\]\s*", "", _first_line(err))
    return text.split(". ")[0].rstrip(".")


class DataParallel:
    """This rank's part of a data-parallel assimilation (module docstring).

    Args:
        shards: the global run indices of every rank, ``shards[r]`` for rank ``r`` (e.g.
            ``shard_by_cost``); every index of ``range(len(names))`` exactly once.
        names: the names of all runs, in the global order (checkpoints and reports use it).
        t_end_s: the end of the longest run of the whole fleet (s): every rank updates on the
            same windows, up to it (a rank without data in a window still joins its collectives).
        group: the process group (None: the default group, ``torch.distributed.init_process_group``).
        config: ``DistributedConfig`` (backend, for the buffers' device).

    Attributes:
        rank, world_size: this rank and the number of ranks in ``group``.
        timings: ``Timings`` of this rank's loss evaluations.
    """

    def __init__(self, shards, names, t_end_s: float, group=None, config: DistributedConfig = DistributedConfig()):
        import torch.distributed as dist

        if not dist.is_initialized():
            raise RuntimeError("DataParallel needs an initialised process group (torch.distributed.init_process_group)")
        self.group = group
        self.rank = dist.get_rank(group)
        self.world_size = dist.get_world_size(group)
        self.shards = tuple(tuple(int(i) for i in s) for s in shards)
        self.names = tuple(names)
        if len(self.shards) != self.world_size:
            raise ValueError(f"{len(self.shards)} shards for {self.world_size} ranks")
        flat = sorted(i for s in self.shards for i in s)
        if flat != list(range(len(self.names))):
            raise ValueError(f"shards must hold every run index 0..{len(self.names) - 1} exactly once")
        if any(len(s) == 0 for s in self.shards):
            raise ValueError("every rank needs at least one run")
        self.t_end_s = float(t_end_s)
        self.config = config
        self.device = torch.device(f"cuda:{int(os.environ.get('LOCAL_RANK', 0))}") if config.backend == "nccl" \
            else torch.device("cpu")
        self.timings = Timings()

    # -- the strategy ----------------------------------------------------------------------------

    @property
    def writes(self) -> bool:
        """Whether this rank writes outputs (rank 0)."""
        return self.rank == 0

    @property
    def n_local(self) -> int:
        return len(self.shards[self.rank])

    @property
    def n_total(self) -> int:
        return len(self.names)

    def check(self, assimilator) -> None:
        """Refuse what data parallelism does not support; check the rank's fleet is its shard.

        Raises:
            ValueError: with the option that is refused.
        """
        cfg = assimilator.config
        refused = []
        if cfg.window_start == "joint":
            refused.append("window_start='joint' (per-environment offsets are trained with the weights)")
        if type(cfg.memory).__name__ == "LaplaceMemory":
            refused.append("memory=LaplaceMemory()")
        if cfg.batch_fraction < 1.0:
            refused.append("batch_fraction < 1 (mini-batch masks are over each rank's own observation times)")
        if refused:
            raise ValueError("data-parallel assimilation does not support " + "; ".join(refused))
        mine = [self.names[i] for i in self.shards[self.rank]]
        have = [r.name for r in assimilator.fleet.runs]
        if have != mine:
            raise ValueError(f"rank {self.rank}'s fleet holds runs {have}, its shard is {mine}")
        if assimilator.fleet.t_end_s != self.t_end_s:
            from .assimilate import window_edges

            assimilator.windows = window_edges(assimilator.fleet.t0_s, self.t_end_s, cfg.window_s)

    def data_cost(self, local: Callable[[], Tensor], params: list[Tensor]) -> Tensor:
        """The whole fleet's data cost from this rank's ``local()`` (a mean over its environments).

        Computes the shard's cost and its gradient with respect to ``params`` here, all-reduces
        both (with failure flags) in one collective, and returns a scalar with the global value
        whose backward pass deposits the global gradient into ``params``.

        Raises:
            SimulationError: some rank could not integrate this trial point (all ranks raise it).
            RankFailure: some rank failed otherwise, or a collective failed.
        """
        start = time.perf_counter()
        failure = None
        value = torch.zeros((), dtype=torch.float64)
        grads = [torch.zeros_like(p) for p in params]
        mid = None
        try:
            J = local()
            mid = time.perf_counter()
            if J.requires_grad:
                found = torch.autograd.grad(J, params, allow_unused=True)
                grads = [torch.zeros_like(p) if g is None else g for p, g in zip(params, found)]
            value = J.detach()
        except Exception as err:  # noqa: BLE001 - every rank must learn of it (below), then it is raised
            failure = err
        end = time.perf_counter()
        mid = end if mid is None else mid
        self.timings.forward_s += mid - start
        self.timings.backward_s += end - mid
        self.timings.n_evals += 1
        share = self.n_local / self.n_total
        flags = torch.tensor([float(isinstance(failure, _REJECTED)),
                              float(failure is not None and not isinstance(failure, _REJECTED))], dtype=torch.float64)
        buf = torch.cat([flags, _weighted(value, grads, share)])
        buf = self._all_reduce(buf, "a loss evaluation")
        self.timings.reduce_s += time.perf_counter() - end
        if buf[0] > 0 or buf[1] > 0:
            self._raise_failure(failure, bool(buf[1] > 0))
        return _Reduced.apply(buf[2], buf[3:], *params)

    def times(self, local: Tensor) -> Tensor:
        """The sorted union ``(T,)`` of every rank's times (s), from this rank's sorted ``local`` times."""
        local = torch.as_tensor(local, dtype=torch.float64)
        n = self._all_gather_list(torch.tensor([float(len(local))], dtype=torch.float64), "an exchange of time grids")
        width = int(max(float(x[0]) for x in n))
        padded = torch.full((width,), math.nan, dtype=torch.float64)
        padded[:len(local)] = local
        parts = self._all_gather_list(padded, "an exchange of time grids")
        merged = torch.cat([p[:int(float(k[0]))] for p, k in zip(parts, n)])
        return torch.unique(merged)

    def mean(self, value: float) -> float:
        """The whole fleet's mean of a per-environment quantity whose mean over this rank's shard is ``value``."""
        buf = torch.tensor([value * self.n_local / self.n_total], dtype=torch.float64)
        return float(self._all_reduce(buf, "a fleet mean")[0])

    def any(self, flag: bool) -> bool:
        """Whether ``flag`` holds on any rank (e.g. a window with data on some rank's runs)."""
        buf = torch.tensor([float(bool(flag))], dtype=torch.float64)
        return bool(self._all_reduce(buf, "an exchange of flags")[0] > 0)

    def rows(self, local: Tensor) -> Tensor:
        """The whole fleet's per-environment rows ``(N, ...)`` in run order, from this rank's ``(n_local, ...)``."""
        local = torch.as_tensor(local, dtype=torch.float64)
        if local.shape[0] != self.n_local:
            raise ValueError(f"rank {self.rank}: {local.shape[0]} rows for a shard of {self.n_local} runs")
        width = max(len(s) for s in self.shards)
        padded = torch.zeros((width, *local.shape[1:]), dtype=torch.float64)
        padded[:self.n_local] = local
        parts = self._all_gather_list(padded, "a gather of rows")
        out = torch.empty((self.n_total, *local.shape[1:]), dtype=torch.float64)
        for part, shard in zip(parts, self.shards):
            out[list(shard)] = part[:len(shard)]
        return out

    def local_rows(self, rows: Tensor) -> Tensor:
        """This rank's rows of the whole fleet's per-environment ``rows`` ``(N, ...)``."""
        if rows.shape[0] != self.n_total:
            raise ValueError(f"{rows.shape[0]} rows for a fleet of {self.n_total} runs")
        return rows[list(self.shards[self.rank])].clone()

    def run_names(self, local_names: list[str]) -> list[str]:
        """The whole fleet's run names in the global order."""
        return list(self.names)

    def read_checkpoint(self, path) -> dict | None:
        """Rank 0 reads the checkpoint at ``path`` (None when there is none) and every rank receives it."""
        import torch.distributed as dist

        from .checkpoint import load_checkpoint

        box = [None]
        if self.rank == 0:
            try:
                box[0] = {"checkpoint": load_checkpoint(path) if Path(path).exists() else None}
            except Exception as err:  # noqa: BLE001 - the other ranks raise it too
                box[0] = {"error": f"{type(err).__name__}: {_first_line(err)}"}
        self._collective(lambda: dist.broadcast_object_list(box, src=0, group=self.group), "the checkpoint's broadcast")
        if "error" in box[0]:
            raise ValueError(f"rank 0 could not read the checkpoint {path}: {box[0]['error']}")
        return box[0]["checkpoint"]

    # -- collectives ---------------------------------------------------------------------------

    def _collective(self, op: Callable[[], object], what: str):
        """Run a collective; a failure of the transport (a rank died or hung) becomes one ``RankFailure`` line."""
        try:
            return op()
        except RankFailure:
            raise
        except RuntimeError as err:  # gloo and nccl report closed connections and timeouts as RuntimeError
            raise RankFailure(
                f"rank {self.rank} of {self.world_size}: {what} failed: another rank stopped or stopped answering "
                f"({_transport_message(err)}); the job is stopped; rerun the same command with --resume to continue from "
                "the last checkpoint") from None

    def _all_gather_list(self, buf: Tensor, what: str) -> list[Tensor]:
        import torch.distributed as dist

        on = buf.to(self.device)
        parts = [torch.empty_like(on) for _ in range(self.world_size)]
        self._collective(lambda: dist.all_gather(parts, on, group=self.group), what)
        return [p.cpu() for p in parts]

    def _all_reduce(self, buf: Tensor, what: str) -> Tensor:
        import torch.distributed as dist

        on = buf.to(self.device)
        self._collective(lambda: dist.all_reduce(on, group=self.group), what)
        return on.cpu()

    def _raise_failure(self, failure: BaseException | None, fatal: bool):
        """Every rank raises the same error for a loss evaluation that failed on some rank."""
        import torch.distributed as dist

        mine = None if failure is None else f"rank {self.rank}: {type(failure).__name__}: {_first_line(failure)}"
        messages = [None] * self.world_size
        self._collective(lambda: dist.all_gather_object(messages, mine, group=self.group), "the exchange of an error")
        said = "; ".join(m for m in messages if m is not None)
        if fatal:
            raise RankFailure(f"a loss evaluation failed on {said}") from failure
        raise SimulationError(f"trial point rejected: {said}") from failure


# ---------------------------------------------------------------------------------------------
# Shards by cost
# ---------------------------------------------------------------------------------------------

# Right-hand sides of a batched ODE cost a fixed part and a part per tank. Measured on this
# project's 2-core machine, one thread: 2.2 ms for 1 tank, 6.7 ms for 512, 17 ms for 4,096
# (without autograd); 6.0, 10.7 and 63 ms with its backward pass: the fixed part is worth
# about 500 tanks.
OVERHEAD_TANKS = 500.0
# A batched ODE restarts wherever any of its tanks' inputs change, and each restart costs right-
# hand sides of its own (a first slope, short first steps, a rejection where the change starts a
# transient), more as the agent trains. Measured on the jittered benchmark fleets (10-minute
# window, the Rosenbrock solver's warm start): 7-12 per restart with the untrained agent and no
# gradient (64 and 256 tanks), 13-15 over the first evaluations of a 1,024-tank update, about 40
# over a 20-iteration update of 64 tanks.
RESTART_EVALS = 30.0


@dataclass(frozen=True)
class ShardCost:
    """The cost model of a shard: ``(max(rates) + restart_evals * sum(restarts)) * (n_tanks + overhead_tanks)``.

    A shard shares one step sequence, so its steps per second of tank time are those of its
    stiffest tank (the largest rate) plus a restart at each of its tanks' input changes (their
    union: tanks scheduled independently change at different times), and every right-hand side
    costs a fixed part plus a part per tank. The restarts make a shard's cost grow as the square
    of its size for large fleets (1,024 jittered tanks restart 516 times in 10 minutes), which
    is why they must be balanced, not only the stiffness.

    Attributes:
        overhead_tanks: the fixed cost of a right-hand side in units of the cost per tank
            (dimensionless; 500, ``OVERHEAD_TANKS``).
        restart_evals: right-hand sides per restart (dimensionless; 30, ``RESTART_EVALS``).
    """

    overhead_tanks: float = OVERHEAD_TANKS
    restart_evals: float = RESTART_EVALS

    def __post_init__(self):
        for name in ("overhead_tanks", "restart_evals"):
            v = getattr(self, name)
            if not (v >= 0 and math.isfinite(v)):
                raise ValueError(f"{name} must be finite and >= 0, got {v}")

    def of(self, rates, restarts=None) -> float:
        """The cost of one shard with these per-tank rates (right-hand sides per second of tank
        time) and, optionally, per-tank input changes per second (``restart_rates``)."""
        rates = np.asarray(rates, dtype=float)
        if not len(rates):
            return 0.0
        extra = self.restart_evals * float(np.sum(restarts)) if restarts is not None else 0.0
        return float((rates.max() + extra) * (len(rates) + self.overhead_tanks))


def restart_rates(runs) -> np.ndarray:
    """Input changes per second of each run's own schedule over its span, ``(n,)`` (0 without inputs)."""
    out = np.zeros(len(runs))
    for k, run in enumerate(runs):
        span = run.t_end_s - run.t0_s
        if run.inputs is not None and span > 0:
            out[k] = len(run.inputs.breakpoints(run.t0_s, run.t_end_s)) / span
    return out


def shard_by_cost(rates, n_ranks: int, model: ShardCost = ShardCost(), restarts=None) -> tuple[tuple[int, ...], ...]:
    """Assign runs to ``n_ranks`` shards so that the costliest shard is as cheap as possible.

    Runs are ordered by rate, stiffest first, and cut into ``n_ranks`` contiguous blocks: the
    stiff tanks share shards with each other, not with tanks they would hold to small steps.
    The cuts minimise the largest ``model.of(block)`` (a bisection on that cost, filling each
    shard greedily from the stiffest remaining run); every shard gets at least one run.

    Args:
        rates: per-run cost rates (e.g. ``probe_costs``: right-hand sides per second), positive.
        n_ranks: number of shards, 1 <= n_ranks <= number of runs.
        model: the shard's cost model.
        restarts: per-run input changes per second (``restart_rates``), >= 0; None: not counted.

    Returns:
        ``n_ranks`` tuples of run indices (into ``rates``), each sorted ascending.

    Raises:
        ValueError: no runs, a rate that is not positive and finite, or more ranks than runs.
    """
    rates = np.asarray(rates, dtype=float)
    n = len(rates)
    if n == 0:
        raise ValueError("shard_by_cost needs at least one run")
    if not (np.isfinite(rates).all() and (rates > 0).all()):
        raise ValueError(f"rates must be positive and finite, got {rates.tolist()}")
    if not 1 <= n_ranks <= n:
        raise ValueError(f"cannot give each of {n_ranks} ranks a run out of {n} runs: use at most {n} ranks")
    restarts = np.zeros(n) if restarts is None else np.asarray(restarts, dtype=float)
    if restarts.shape != (n,) or not (np.isfinite(restarts).all() and (restarts >= 0).all()):
        raise ValueError(f"restarts must be {n} finite rates >= 0, got {restarts.tolist()}")
    order = np.argsort(-rates, kind="stable")
    r, q = rates[order], restarts[order] * model.restart_evals  # q: right-hand sides per second

    def cuts(limit: float) -> list[int] | None:
        """Greedy blocks of cost <= limit from the stiffest run on; their starts, or None if > n_ranks."""
        starts, i = [], 0
        while i < n:
            if len(starts) == n_ranks:
                return None
            starts.append(i)
            # a block from i has max rate r[i]; it grows while (r[i] + restarts) (size + overhead) <= limit
            j, extra = i, 0.0
            while j < n and (r[i] + extra + q[j]) * (j - i + 1 + model.overhead_tanks) <= limit * (1 + 1e-12):
                extra += q[j]
                j += 1
            if j == i:
                return None
            i = j
        return starts

    lo, hi = 0.0, model.of(rates, restarts) * (1 + 1e-9)  # one shard of everything is feasible
    for _ in range(200):
        if hi - lo <= 1e-12 * hi:
            break
        mid = 0.5 * (lo + hi)
        if cuts(mid) is None:
            lo = mid
        else:
            hi = mid
    starts = cuts(hi)
    # Split the largest blocks until there is one per rank (splitting never raises a block's cost).
    blocks = [list(range(a, b)) for a, b in zip(starts, starts[1:] + [n])]
    while len(blocks) < n_ranks:
        k = max(range(len(blocks)), key=lambda j: len(blocks[j]))
        b = blocks.pop(k)
        blocks[k:k] = [b[:len(b) // 2], b[len(b) // 2:]]
    return tuple(tuple(sorted(int(order[i]) for i in b)) for b in blocks)


# Probes: each run's first PROBE_S seconds integrated with the training's solver, the agent the
# training starts from and no gradient. Five minutes: a light wall's start transient dominates a
# shorter probe (64 jittered tanks, median rates of light and other walls: 2.23 and 0.57 right-hand
# sides per second over 60 s, 0.83 and 0.30 over 300 s, 0.49 and 0.23 over 600 s), and a shard
# cut on it left the light-walled tanks' rank waiting 145 s of a 272-s update. Runs are probed
# in batches of similar walls (ordered by the wall's heat capacity per wall area, the stiffness
# of a light wall) so that at most MAX_PROBES integrations are made whatever the fleet's size:
# a batch's count is the cost of integrating similar tanks together, which is what a shard does.
PROBE_S = 300.0
MAX_PROBES = 64


def _wall_capacity_per_area(fleet) -> np.ndarray:
    area = fleet.geometry.wall_area_m2.detach().numpy() * np.ones(fleet.n_env)
    return fleet.wall_heat_capacity_J_per_K.numpy() / area


def probe_costs(runs, config, closure=None, mechanisms=(), span_s: float = PROBE_S, max_probes: int = MAX_PROBES,
                surrogate=None, batches: list[list[int]] | None = None) -> np.ndarray:
    """Measured cost rates of ``runs``: right-hand-side evaluations per second of tank time (``(n,)``).

    Each batch of runs (``probe_batches``; or ``batches``, e.g. a rank's share of them) is
    integrated as one batched ODE over its first ``span_s`` seconds with ``config``'s integrator
    and tolerances, the agent ``closure`` (a fresh seeded ``MLPClosure`` when None) and no
    gradient; its evaluations over ``span_s`` are the rate of each of its runs. A batch that
    cannot be integrated gets the solver's whole budget (as costly as a tank can be). Runs not
    in ``batches`` get NaN.
    """
    from tankode.fleet import Fleet
    from tankode.integrate import integrate, state_scale
    from tankode.model import TankModel
    from tankode.solver import NoGradient

    runs = list(runs)
    if not (span_s > 0 and math.isfinite(span_s)):
        raise ValueError(f"span_s must be a positive number of seconds, got {span_s}")
    closure = closure if closure is not None else config.agent()
    if batches is None:
        batches = probe_batches(runs, max_probes, surrogate)
    solver = config.solver()
    rates = np.full(len(runs), np.nan)
    for batch in batches:
        fleet = Fleet.from_runs([runs[i] for i in batch], surrogate)
        surrogate = fleet.fluid
        model = TankModel(fleet.fluid, fleet.geometry, closure, fleet.wall_heat_capacity_J_per_K, mechanisms)
        t0 = fleet.t0_s
        t1 = min(t0 + span_s, fleet.t_end_s)
        try:
            with torch.no_grad():
                s0 = model.initial_state(fleet.initial_state(model.mechanisms))
                scale = state_scale(s0, fleet.geometry.volume_m3, model.extra_state_scales)
                _, stats = integrate(model, s0, fleet.segments(t0, t1), fleet.forcing,
                                     torch.tensor([t0, t1], dtype=torch.float64), scale, solver, NoGradient())
            evals = stats.n_rhs_evals
        except SimulationError:
            evals = config.max_rhs_evals
        rates[list(batch)] = evals / (t1 - t0)
    return rates


def probe_batches(runs, max_probes: int = MAX_PROBES, surrogate=None) -> list[list[int]]:
    """Batches of run indices for ``probe_costs``: at most ``max_probes``, each of walls of similar stiffness."""
    from tankode.fleet import Fleet

    if max_probes < 1:
        raise ValueError(f"max_probes must be >= 1, got {max_probes}")
    runs = list(runs)
    key = _wall_capacity_per_area(Fleet.from_runs(runs, surrogate))
    order = np.argsort(key, kind="stable")
    size = math.ceil(len(runs) / max_probes)
    return [sorted(int(i) for i in order[a:a + size]) for a in range(0, len(runs), size)]


# ---------------------------------------------------------------------------------------------
# Launching under torchrun
# ---------------------------------------------------------------------------------------------


def in_distributed_environment() -> bool:
    """Whether this process was started by torchrun (or another launcher) for several ranks (RANK, WORLD_SIZE)."""
    return "RANK" in os.environ and int(os.environ.get("WORLD_SIZE", "1")) > 1


@dataclass
class Launch:
    """This process's place in a data-parallel job started by torchrun.

    ``Launch.from_environment()`` initialises the default process group from the environment
    torchrun sets (RANK, WORLD_SIZE, MASTER_ADDR, MASTER_PORT, LOCAL_RANK) with the configured
    backend and collective timeout; ``shard`` probes the runs' costs (each rank a share of the
    probes), cuts the shards and returns this rank's runs and its ``DataParallel``.
    """

    rank: int
    world_size: int
    config: DistributedConfig = field(default_factory=DistributedConfig)
    parallel: DataParallel | None = None
    rates: list = field(default_factory=list)
    restarts: list = field(default_factory=list)
    cost_model: ShardCost = field(default_factory=ShardCost)

    @staticmethod
    def from_environment(config: DistributedConfig = DistributedConfig()) -> "Launch":
        import torch.distributed as dist

        missing = [k for k in ("RANK", "WORLD_SIZE", "MASTER_ADDR", "MASTER_PORT") if k not in os.environ]
        if missing:
            raise ValueError(f"data-parallel launch: the environment lacks {', '.join(missing)} (start the command "
                             "with torchrun --nproc-per-node N ...)")
        if config.backend == "nccl":
            torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", 0)))
        dist.init_process_group(config.backend, init_method="env://", timeout=timedelta(seconds=config.timeout_s))
        return Launch(dist.get_rank(), dist.get_world_size(), config)

    @property
    def writes(self) -> bool:
        return self.rank == 0

    def shard(self, runs, assimilation, closure=None, mechanisms=(), model: ShardCost = ShardCost(),
              max_probes: int = MAX_PROBES):
        """This rank's runs and its ``DataParallel``: costs probed (shared out), shards cut by cost.

        Every rank reads all runs (they are the command's arguments) and computes the same
        shards from the same all-gathered probe results.
        """
        import torch.distributed as dist

        runs = list(runs)
        starts = sorted({r.t0_s for r in runs})
        if len(starts) > 1:
            raise ValueError(f"runs of one fleet must start at the same time stamp, got {starts} s")
        if len(runs) < self.world_size:
            raise ValueError(f"{len(runs)} runs for {self.world_size} ranks: every rank needs a run; "
                             f"start at most {len(runs)} processes")
        batches = probe_batches(runs, max_probes)
        mine = batches[self.rank::self.world_size]
        try:
            part = probe_costs(runs, assimilation, closure, mechanisms, batches=mine)
            result = {"rates": [(i, float(part[i])) for b in mine for i in b]}
        except Exception as err:  # noqa: BLE001 - every rank must learn of it
            result = {"error": f"rank {self.rank}: {type(err).__name__}: {_first_line(err)}"}
        gathered = [None] * self.world_size
        try:
            dist.all_gather_object(gathered, result)
        except RuntimeError as err:
            raise RankFailure(f"rank {self.rank} of {self.world_size}: the exchange of the cost probes failed: another "
                              f"rank stopped or stopped answering ({_first_line(err)})") from None
        errors = [g["error"] for g in gathered if "error" in g]
        if errors:
            raise ValueError("cost probe failed: " + "; ".join(errors))
        rates = np.full(len(runs), np.nan)
        for g in gathered:
            for i, v in g["rates"]:
                rates[i] = v
        self.rates = rates.tolist()
        self.restarts = restart_rates(runs).tolist()
        self.cost_model = model
        shards = shard_by_cost(rates, self.world_size, model, self.restarts)
        self.parallel = DataParallel(shards, [r.name for r in runs], max(r.t_end_s for r in runs), config=self.config)
        return [runs[i] for i in shards[self.rank]], self.parallel

    def describe(self, names) -> str:
        """One line per shard: its runs' count and its modelled cost."""
        lines = [f"data-parallel: {self.world_size} ranks ({self.config.backend}, collective timeout "
                 f"{self.config.timeout_s:g} s), shards by probed cost (right-hand sides per second of tank time):"]
        rates, restarts = np.asarray(self.rates), np.asarray(self.restarts)
        for r, shard in enumerate(self.parallel.shards):
            shown = ", ".join(names[i] for i in shard[:4]) + (", ..." if len(shard) > 4 else "")
            mine = list(shard)
            lines.append(f"  rank {r}: {len(shard)} runs, rates {rates[mine].min():.3g}-{rates[mine].max():.3g}, "
                         f"{restarts[mine].sum() * 3600:.3g} input changes per hour, modelled cost "
                         f"{self.cost_model.of(rates[mine], restarts[mine]):.4g} ({shown})")
        return "\n".join(lines)

    def info(self) -> dict:
        """What a saved model records of the launch."""
        if self.parallel is None:
            return {}
        return {"data_parallel": {"world_size": self.world_size, "backend": self.config.backend,
                                  "shards": [[self.parallel.names[i] for i in s] for s in self.parallel.shards]}}

    def close(self) -> None:
        """Leave the process group together: a barrier (rank 0 has written its outputs), then destroy.

        A rank that tore its group down while another still held connections to it was seen to
        abort in gloo's teardown ("terminate called without an active exception") on a loaded
        machine; leaving at one barrier keeps every rank's teardown after the last exchange.
        """
        import torch.distributed as dist

        if dist.is_initialized():
            dist.barrier()
            dist.destroy_process_group()


def launch_from_environment(timeout_s: float | None = None) -> Launch | None:
    """A ``Launch`` when started by torchrun for several ranks, else None (one process, no process group).

    ``timeout_s``: the collective timeout (s); None: ``DistributedConfig``'s default. The backend
    is ``TANKODE_DIST_BACKEND`` when set (gloo or nccl), else gloo.
    """
    if not in_distributed_environment():
        return None
    backend = os.environ.get("TANKODE_DIST_BACKEND", "gloo")
    config = DistributedConfig(backend=backend) if timeout_s is None else DistributedConfig(backend, timeout_s)
    launch = Launch.from_environment(config)
    if launch.rank != 0:
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - rank 0 alone reports; errors still go to stderr
    return launch


__all__ = ["DataParallel", "DistributedConfig", "Launch", "RankFailure", "ShardCost", "SingleProcess", "Timings",
           "group_sum", "launch_from_environment", "probe_batches", "probe_costs", "restart_rates", "shard_by_cost", "in_distributed_environment"]

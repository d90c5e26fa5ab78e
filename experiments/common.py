"""Shared helpers of the study scripts: the NASA MHTB tests and the EBM's published predictions.

The scripts import this module by name (``from common import ...``): a script's own directory
is first on ``sys.path`` when it runs as ``python experiments/SCRIPT.py``.
"""

from __future__ import annotations

from pathlib import Path

from tankode.compare import channel_rmse, read_peer_prediction, solution_observations
from tankode.errors import SimulationError
from tankode.run import Observations, Run
from tankode.run_io import read_run
from tankode.simulation import simulate

# The two digitised liquid-hydrogen tests (P263968K: 25 % fill, 18.5 h; P263981D: 90 % fill,
# 5.4 h), read in place from the shared data beside the project (run from the repository root).
MHTB_DATA = Path("../shared/data/mhtb")
MHTB_RUNS = ("P263968K", "P263981D")
# All three tests (P263981T: 50 % fill, 13.9 h), as the rotation study uses them.
MHTB_ALL_RUNS = ("P263968K", "P263981D", "P263981T")
MHTB_FLUID = "ParaHydrogen"
# The channels the tests measure and the EBM predicts.
MHTB_CHANNELS = ("p_v_Pa", "T_v_K", "T_l_K")


def mhtb_runs(until_s: float | None = None, names=MHTB_RUNS) -> list[Run]:
    """The MHTB tests ``names`` in that order, each cut to its first ``until_s`` seconds if given."""
    runs = [read_run(MHTB_DATA / f"{n}.json") for n in names]
    return [r.until(until_s) for r in runs] if until_s is not None else runs


def ebm_predictions(runs) -> dict[str, Observations]:
    """The EBM's published prediction of each of ``runs`` (MHTB tests), by run name."""
    return {r.name: read_peer_prediction(MHTB_DATA / f"{r.name}.ebm.csv", MHTB_FLUID) for r in runs}


def score_on_ebm_samples(run: Run, closure, mechanisms, ebm: Observations, channels=MHTB_CHANNELS):
    """``(rmse by channel, solution, "")`` of a prediction of ``run`` (from its initial state and
    inputs) on the samples the EBM's prediction ``ebm`` covers, or ``(None, None, the solver's
    message)`` where the prediction cannot be integrated."""
    try:
        sol = simulate(run, closure, output_dt_s=60.0, mechanisms=mechanisms)
    except SimulationError as err:
        return None, None, str(err).splitlines()[0]
    rmse = channel_rmse(run, solution_observations(sol), channels, within=ebm)
    return {c: rmse[c]["rmse"] for c in channels}, sol, ""


__all__ = ["MHTB_DATA", "MHTB_RUNS", "MHTB_ALL_RUNS", "MHTB_FLUID", "MHTB_CHANNELS", "mhtb_runs", "ebm_predictions", "score_on_ebm_samples"]

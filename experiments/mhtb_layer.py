"""MHTB tests with the liquid surface layer (issue 6): calibrated on both tests and leave one test out.

The four closure factors and ``surface_layer``'s three parameters are fitted together
(``tankode.diagnosis.fit``), from the layer absent and from a 1 cm layer taking all of the
wetted wall's heat and mixing in 5 h (the layer's wall-fed source has no slope at 0, so a fit
from 0 cannot find it). Pressure RMSE on the EBM's samples, as in ``mhtb.py``.

Usage: ``python experiments/mhtb_layer.py [--quick] [--out results/mhtb_layer]``
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from mhtb import _calibrate_on, _ebm, _p_rmse, _predict, _runs, _values
from tankode._threads import single_threaded
from tankode.compare import solution_observations

# ---- configuration ---------------------------------------------------------------------------
MECHANISM = "surface_layer"
# (1/delta [1/m], phi, k [1/s]): absent, and the probe's layer (1 cm, all the wall's heat, 5 h)
STARTS = {"absent": (0.0, 0.0, 0.0), "1 cm layer": (100.0, 1.0, 1.0 / 18000.0)}
MAX_ITERATIONS = 8  # as mhtb.py's calibrations
QUICK_ITERATIONS = 1  # --quick: both tests cut to 2 h (mhtb.py's QUICK_UNTIL_S), one iteration
# -----------------------------------------------------------------------------------------------


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="both tests cut to 2 h, one iteration (CI smoke run)")
    ap.add_argument("--out", default="results/mhtb_layer")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    runs = _runs(args.quick)
    iterations = QUICK_ITERATIONS if args.quick else MAX_ITERATIONS
    ebm = _ebm(runs)
    rows = []
    with single_threaded():
        for label, start in STARTS.items():
            for held in [None, *runs]:
                t = time.perf_counter()
                train = [r for r in runs if r is not held]
                closure, mechs, f = _calibrate_on(train, MECHANISM, iterations, start)
                for r in ([held] if held is not None else runs):
                    sol = solution_observations(_predict(r, closure, mechs))
                    rows.append({
                        "start": label, "calibrated_on": "+".join(x.name for x in train), "test": r.name,
                        "p_rmse_Pa": _p_rmse(r, sol, within=ebm[r.name]),
                        "p_rmse_all_samples_Pa": _p_rmse(r, sol),
                        "ebm_p_rmse_Pa": _p_rmse(r, ebm[r.name], within=ebm[r.name]),
                        "values": _values(f), "fit_status": f.status, "wall_s": time.perf_counter() - t,
                    })
                    print(json.dumps(rows[-1], default=float), flush=True)
    (out / "summary.json").write_text(json.dumps(rows, indent=2, default=float) + "\n")
    return rows


if __name__ == "__main__":
    main()

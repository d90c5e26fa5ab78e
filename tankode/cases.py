"""The paper's five environments (section 6): one LH2 tank under different operations.

All share the paper's tank: an upright cylinder 1.8 m in diameter and 2.2 m high (5.6 m^3)
with a wall heat capacity of 2.44e6 J/K, filled with para-hydrogen. Each case is a ``Run``
without observations: metadata, initial state and the schedule of operations.

Case 1 follows its description in the paper: a stratified tank (ullage 32 K at 4.8 bar over
a liquid subcooled at 20.09 K, wall at 29.1 K, 65 % full) at rest for 10 minutes, then
moderate sloshing below the first resonance that condenses vapour and drops the pressure,
then 6 minutes of 4.2 g/s vapour injection that recovers it, and a second sloshing phase.
Cases 2 to 5 vary the fill, the initial stratification, the excitation (closer to and above
resonance, larger amplitude) and the operations (venting, heat ingress, draining) as the
paper's environments do; their exact timings are tankode's, chosen so that every case has
rest, sloshing and an operation. Case 5 is the validation environment of the
multi-environment study.
"""

from __future__ import annotations


from .closures.reference import first_slosh_frequency_Hz
from .run import InitialState, Run, TankSpec
from .schedule import Schedule

import torch

TANK = {"shape": "vertical_cylinder", "radius_m": 0.9, "height_m": 2.2}
WALL_HEAT_CAPACITY_J_PER_K = 2.44e6
DURATION_S = 3600.0
FLUID = "ParaHydrogen"


def _f11(fill_ratio: float) -> float:
    H_l = fill_ratio * TANK["height_m"]
    return float(first_slosh_frequency_Hz(torch.tensor(TANK["radius_m"]), torch.tensor(H_l)))


def _slosh(fill: float, ratio: float, amplitude_m: float) -> dict[str, float]:
    """Sloshing at ``ratio`` times the first natural frequency, rounded to the mHz."""
    return {"slosh_amplitude_m": amplitude_m, "slosh_frequency_Hz": round(ratio * _f11(fill), 3)}


_STILL = {"slosh_amplitude_m": 0.0, "slosh_frequency_Hz": 0.0}


def _inject(mdot_kg_s: float) -> dict[str, float]:
    # Injected gas from a 6 bar supply (above the tank pressure, as a pressurant line is) at 32 K.
    return {"mdot_v_in_kg_s": mdot_kg_s, "T_v_in_K": 32.0, "p_v_in_Pa": 6.0e5}


def _case(name: str, fill: float, p: float, T_v: float, T_l: float, T_w: float, steps, note: str) -> Run:
    tank = TankSpec.from_dict({**TANK, "wall_heat_capacity_J_per_K": WALL_HEAT_CAPACITY_J_PER_K})
    return Run(
        name=name,
        fluid=FLUID,
        source=f"tankode synthetic environment {name} (paper, section 6): {note}",
        tank=tank,
        initial=InitialState(p_v_Pa=p, T_v_K=T_v, T_l_K=T_l, T_w_K=T_w, fill_ratio=fill),
        duration_s=DURATION_S,
        inputs=Schedule.from_steps(steps, t_end=DURATION_S),
    )


def case1() -> Run:
    f = 0.65
    return _case("case1", f, 4.8e5, 32.0, 20.09, 29.1, [
        (0, {}),
        (600, _slosh(f, 0.8, 0.01)),
        (1800, {**_STILL, **_inject(4.2e-3)}),
        (2160, {"mdot_v_in_kg_s": 0.0}),
        (2700, _slosh(f, 0.8, 0.01)),
    ], "rest, moderate sloshing (pressure drop), 6 min of 4.2 g/s injection (recovery), sloshing")


def case2() -> Run:
    f = 0.50
    return _case("case2", f, 3.5e5, 30.0, 20.5, 27.0, [
        (0, {}),
        (300, _slosh(f, 0.9, 0.006)),
        (1500, {**_STILL, "mdot_v_out_kg_s": 2.0e-3}),
        (1800, {"mdot_v_out_kg_s": 0.0}),
        (2400, _slosh(f, 0.9, 0.006)),
    ], "half full, sloshing close to resonance, 5 min of venting")


def case3() -> Run:
    f = 0.80
    return _case("case3", f, 4.0e5, 31.0, 20.3, 28.0, [
        (0, {"Q_aw_W": 300.0}),
        (900, _slosh(f, 0.7, 0.015)),
        (2100, _STILL),
        (2400, _inject(4.0e-3)),
        (2640, {"mdot_v_in_kg_s": 0.0}),
    ], "80 % full, 300 W heat ingress, larger sloshing further from resonance, injection")


def case4() -> Run:
    f = 0.35
    return _case("case4", f, 5.0e5, 33.0, 20.2, 30.0, [
        (0, {}),
        (600, {**_slosh(f, 1.15, 0.01), "mdot_l_out_kg_s": 0.05}),
        (1800, {**_STILL, "mdot_l_out_kg_s": 0.0}),
        (2400, _slosh(f, 1.15, 0.01)),
    ], "35 % full, sloshing above resonance while draining 0.05 kg/s")


def case5() -> Run:
    f = 0.60
    return _case("case5", f, 4.5e5, 31.5, 20.1, 29.0, [
        (0, {}),
        (600, _slosh(f, 0.85, 0.012)),
        (1500, {**_STILL, **_inject(4.2e-3)}),
        (1860, {"mdot_v_in_kg_s": 0.0}),
        (2400, _slosh(f, 0.75, 0.012)),
        (3300, _STILL),
    ], "60 % full, two sloshing phases at different frequencies around an injection (validation)")


CASES = {"case1": case1, "case2": case2, "case3": case3, "case4": case4, "case5": case5}


def get_case(name: str) -> Run:
    """The named environment ("case1".."case5") as a ``Run`` without observations."""
    if name not in CASES:
        raise ValueError(f"unknown case {name!r}; known cases: {', '.join(CASES)}")
    return CASES[name]()


__all__ = ["get_case", "CASES", "case1", "case2", "case3", "case4", "case5", "TANK", "WALL_HEAT_CAPACITY_J_PER_K"]

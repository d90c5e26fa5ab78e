"""The agent: a small MLP closure theta = g(s; w) learned from data (paper, section 5.2).

Dimensionless inputs, chosen by name in ``MLPConfig.features``, in sets named by
``INPUT_SETS``:

* ``"paper"`` (``FEATURE_NAMES``, ``MLPConfig``'s default): the paper's seven plus
  ``f_over_f11`` (8 inputs, 484 weights, as the paper);
* ``"operations"`` (``OPERATION_FEATURES``, the default of ``AssimilationConfig``): those eight
  plus the four operations' turnovers (12 inputs, 548 weights; see "Operations" below);
* ``"extended"`` (``EXTENDED_FEATURES``): ``f_over_f11`` replaced by ``lnRe_wave`` and
  ``lnGr_li_signed`` (9 inputs, 500 weights; see "Extended inputs" below).

================  ==========================================================  ==============
 name             feature                                                     scaling
================  ==========================================================  ==============
 Pr_v             Pr_v = mu_v c_p,v / k_v                                     ``/ 2``
 Pr_l             Pr_l                                                        ``/ 2``
 R_over_H         aspect ratio R/H of the tank                                as is
 Re_1e4           Re = f_e A_0 R / nu_l, divided by 1e4 (paper)               as is
 lnGr_wv          ln(|Gr_wv| + 1), Gr = g beta |dT| R^3 / nu^2, wall-vapour   ``/ 30``
 lnGr_wl          ln(|Gr_wl| + 1), wall-liquid                                ``/ 30``
 lnGr_vl          ln(|Gr_vl| + 1), vapour-liquid (liquid properties)          ``/ 30``
 lnRe_wave        ln(1 + Re_b / 1e4), Re_b = 2 pi f_e b R / nu_l (ours)       ``/ 5``
 lnGr_li_signed   sign(T_l - T_sat) ln(|Gr_li| + 1), liquid-interface (ours)  ``/ 30``
 f_over_f11       f_e / f_11, excitation over first sloshing frequency        as is
 dT_wv_signed     tanh((T_w - T_v) / 1 K): wall warmer or colder than ullage  as is
 dT_vi_signed     tanh((T_v - T_sat) / 1 K): superheated or subcooled ullage  as is
 fill             H_l / H, the level's share of the tank's height             as is
 lnTurn_v_in      ln(1 + mdot_v_in t_op / m_v): vapour injected (ours)        as is
 lnTurn_v_out     ln(1 + mdot_v_out t_op / m_v): vapour vented (ours)         as is
 lnTurn_l_in      ln(1 + mdot_l_in t_op / m_l): liquid filled (ours)          as is
 lnTurn_l_out     ln(1 + mdot_l_out t_op / m_l): liquid drained (ours)        as is
================  ==========================================================  ==============

The paper's ``ln(|Gr| + 1)`` inputs carry the size of a temperature difference, not its sign:
they cannot tell a warm ullage over a cold wall from a cold one under a warm wall, which
convect differently. The signed inputs (tankode's) say which side is warmer. ``T_w`` in the
wall features is the wall each phase touches (``ClosureInputs.wall_temperatures_K``: a two-node
wall's dry node for the ullage, its wetted node for the liquid), not the wall's mean.

``|dT|`` is smoothed as ``sqrt(dT^2 + (0.05 K)^2)``: with ``g beta R^3/nu^2`` ~ 1e13 per kelvin
for LH2, the raw ``ln(|Gr| + 1)`` climbs from 0 to 16 within a microkelvin of ``dT = 0`` with an
infinite slope there, so an agent using it switches its coefficients abruptly whenever two
temperatures cross and the ODE solver stalls (observed: 200,000 evaluations in one window of
case 1, where wall, vapour and liquid end within 0.2 K). 0.05 K is below the sensors' noise,
so nothing measurable is lost. The sign of ``lnGr_li_signed`` is smoothed the same way
(``tanh(dT / 0.05 K)``).

``f_over_f11`` is tankode's (not in the paper): the wave a given forcing raises
depends on how close ``f_e`` is to the tank's first natural frequency ``f_11`` (which moves
with the fill level), which ``Re`` alone cannot tell.

Operations (tankode's, not the paper's). The paper's inputs describe the tank at rest and its
sloshing; they cannot tell a hold from a fill or a vent at the same temperatures, although an
inflow or outflow stirs the phase it crosses (a subcooled fill mixes the liquid under the
interface; a warm-gas jet or a vent stirs the ullage). The turnovers are each flow's share of
its phase's mass moved per ``t_op = 10 h`` (``OPERATION_TIME_S``), logarithmic so that a
trickle and a fast transfer both stay O(1): a flow moving 1 % of its phase per hour reads
ln 1.1 = 0.095, about one domain margin (below), and a drain of the whole liquid in an hour
reads 2.4. They are 0 at rest. With the seen box, their main use: an operation the stream
has not shown (a fill after a drain and a hold) lies outside the box, so the agent falls back
to its base there instead of carrying a coefficient learned on another operation (measured on
another simulator's horizontal cylinder, ``experiments/README.md`` section 5).

Extended inputs (a measured experiment, not the default). The paper's seven inputs cannot tell
two things the interface heat transfer depends on:

* the sloshing wave itself: ``lnRe_wave`` uses the wave height ``b`` of linear sloshing theory
  (Abramson, NASA SP-106; ``tankode.closures.reference.wave_height_m``) with a modal damping
  ratio of 0.1, a textbook engineering estimate, deliberately not the reference correlation's
  0.05, so that the agent is not handed the synthetic truth's internals;
* whether the liquid under the interface is stably stratified (colder than saturation:
  conduction only) or unstably (warmer: natural convection): ``lnGr_vl`` measures the
  vapour-liquid difference, not the liquid's position relative to ``T_sat``.

Fitted directly to the reference coefficients along the true trajectories of the training
cases, the extended inputs predict an unseen case far better than the default ones; learned
by assimilation (fixed 10-minute windows) the extended agent does worse than the default on
every measure of the studies (``experiments/README.md``), so the default stays the paper's.

The scalings bring every feature to O(1) for LH2 tanks of metres; they are fixed constants
(not fitted), so a model trained on one tank applies unchanged to another.

Outputs: ``h_j = base_j(s) * exp(span * tanh(o_j))``, a learned factor on a base closure,
positive and bounded in ``[base/e^span, base e^span]`` whatever the weights; the last layer
starts at zero so an untrained agent *is* its base closure and the first ODE of training never
blows up. The base (``MLPConfig.base``):

* ``"natural"``: ``tankode.closures.natural.NaturalConvectionClosure``, textbook convection on
  each surface from its own temperature difference, plus a sloshing term: the untrained agent is
  a physical closure, and training learns corrections to it (a residual model, as universal
  differential equations build them);
* ``"reference"``: the paper's correlations (``ReferenceClosure``);
* ``"constant"``: the fixed mid-range coefficients ``h_ref_W_m2K`` (the paper's agent, which
  learns the coefficients' levels and shapes from nothing).

Outside the seen inputs (``MLPConfig.domain_margin``, not the paper's). A network says nothing
reliable about inputs it was never trained on, and a residual agent trained on a quiet hold
applies its learned factors to a fill or a sloshing it has not seen (measured on other
simulators' tanks: a forecast worse than the untrained agent's, ``experiments/README.md``,
section 5). With a margin, the agent keeps the box of the features it was trained on
(``seen_lo``, ``seen_hi``: buffers saved with the weights) and its learned correction fades
to the base outside it::

    ln h_j = ln base_j(s) + span * g(x) * tanh(o_j(P x)),   g(x) = exp(-sum_i (d_i / margin)^2),

with ``d_i`` how far feature ``i`` lies outside ``[seen_lo_i, seen_hi_i]`` (0 inside, where
``g = 1`` and nothing changes). Two kinds of feature leave the box differently
(``MLPConfig.clamped_features``):

* an *operation* (a sloshing wave, a turnover: ``Re_1e4``, ``f_over_f11``, ``lnRe_wave``,
  ``lnTurn_*``) the stream has not shown is another regime of heat transfer, which the base
  describes better than a factor learned without it: these features fade (they count in ``d``);
* a *state* beyond the seen ones (``STATE_FEATURES``: a warmer ullage on the second warm-gas
  injection, a fuller tank, another Grashof number) continues a regime the stream has shown:
  these features are clamped, ``P`` projects them onto the box, so the network is evaluated at
  the nearest seen state and its correction is carried, not dropped. Fading on them too sent a
  tank whose law is far from the base (the printed correlations hold the ullage to the dry wall,
  ``h_wv`` 13-18 times the base's) back to the base as soon as a repeated operation met a
  slightly other state (measured on another simulator's runs, ``experiments/README.md``,
  section 5).

An agent that has seen nothing is not gated; the assimilation widens the box with each window's
trajectory before and after training on it (``extend_domain``). Limits: a box, not the seen
inputs' joint distribution (a combination of values each seen apart counts as seen); a clamped
state carries the nearest seen correction however far away it lies; and the base must be a
physical closure for the fade to mean anything (the ``"constant"`` base fades to mid-range
constants).

Architecture: 8 -> 16 -> 16 -> 4, tanh, 484 weights (paper); 548 with the operations, 500 with the
extended inputs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from .base import GRAVITY_M_S2, Closure, ClosureInputs
from .reference import first_slosh_frequency_Hz, wave_height_m

DT_SMOOTH_K = 0.05  # temperature differences are resolved down to this (module docstring)
WAVE_DAMPING = 0.1  # modal damping ratio of the lnRe_wave estimate (module docstring)
SIGNED_SCALE_K = 1.0  # K; the signed differences saturate beyond a few kelvin (module docstring)
_PAPER_SEVEN = ("Pr_v", "Pr_l", "R_over_H", "Re_1e4", "lnGr_wv", "lnGr_wl", "lnGr_vl")
OPERATION_TIME_S = 36_000.0  # s; t_op of the turnovers: 1 %/h of a phase reads ~0.1 (module docstring)
FEATURE_NAMES = (*_PAPER_SEVEN, "f_over_f11")  # MLPConfig's default: eight inputs, 484 weights (paper)
OPERATION_FEATURES = (*FEATURE_NAMES, "lnTurn_v_in", "lnTurn_v_out", "lnTurn_l_in", "lnTurn_l_out")  # docstring
EXTENDED_FEATURES = (*_PAPER_SEVEN, "lnRe_wave", "lnGr_li_signed")  # nine inputs, 500 weights (docstring)
N_FEATURES = len(FEATURE_NAMES)
INPUT_SETS = {"paper": FEATURE_NAMES, "operations": OPERATION_FEATURES, "extended": EXTENDED_FEATURES}  # by name
# Features of the tank's state and shape, not of its operations: clamped to the seen box, not faded
# (module docstring, "Outside the seen inputs").
STATE_FEATURES = ("Pr_v", "Pr_l", "R_over_H", "lnGr_wv", "lnGr_wl", "lnGr_vl", "lnGr_li_signed", "dT_wv_signed",
                  "dT_vi_signed", "fill")


@dataclass(frozen=True)
class MLPConfig:
    """Architecture and output ranges of the MLP closure.

    Attributes:
        features: input feature names, in order (module docstring); the default is the
            paper's seven plus ``f_over_f11``; ``EXTENDED_FEATURES`` replaces the latter by
            ``lnRe_wave`` and ``lnGr_li_signed``.
        hidden: hidden layer widths (paper: two layers of 16).
        h_ref_W_m2K: mid-range coefficients ``(h_vi, h_li, h_wv, h_wl)`` in W/(m^2 K); an
            untrained agent returns these. Chosen at the order of magnitude of LH2 tanks at
            rest to moderately sloshing.
        span: half-width of the output range in natural-log units (4.6 = factor 100 each way).
        seed: weight initialisation seed.
        base: the closure the learned factor multiplies (module docstring): ``"natural"``,
            ``"reference"`` or ``"constant"`` (``h_ref_W_m2K``; the only use of that field).
        domain_margin: distance in feature units over which the learned correction fades to
            the base outside the inputs seen in training (module docstring, "Outside the seen
            inputs"); None: no fade (the paper's agent, which extrapolates freely).
        clamped_features: features among ``features`` that are projected onto the seen box
            instead of fading (module docstring; ``STATE_FEATURES`` are the tank's state). Empty:
            every feature fades. Without a ``domain_margin`` there is no box and nothing is clamped.
    """

    features: tuple[str, ...] = FEATURE_NAMES
    hidden: tuple[int, ...] = (16, 16)
    h_ref_W_m2K: tuple[float, float, float, float] = (3.0, 10.0, 60.0, 100.0)
    span: float = math.log(100.0)
    seed: int = 0
    base: str = "natural"
    domain_margin: float | None = None
    clamped_features: tuple[str, ...] = ()

    def __post_init__(self):
        unknown = [f for f in self.features if f not in _FEATURES]
        if not self.features or unknown or len(set(self.features)) != len(self.features):
            raise ValueError(f"MLPConfig.features must be distinct names among {sorted(_FEATURES)}, "
                             f"got {self.features}")
        if not self.hidden or any(int(h) < 1 for h in self.hidden):
            raise ValueError(f"MLPConfig.hidden must be positive layer widths, got {self.hidden}")
        if len(self.h_ref_W_m2K) != 4 or any(not (h > 0 and math.isfinite(h)) for h in self.h_ref_W_m2K):
            raise ValueError(f"MLPConfig.h_ref_W_m2K must be 4 positive values in W/(m^2 K), got {self.h_ref_W_m2K}")
        if not (0 < self.span <= 10):
            raise ValueError(f"MLPConfig.span must be in (0, 10] (log units), got {self.span}")
        if self.base not in BASES:
            raise ValueError(f"MLPConfig.base must be one of {BASES}, got {self.base!r}")
        if self.domain_margin is not None and not (math.isfinite(self.domain_margin) and self.domain_margin > 0):
            raise ValueError(f"MLPConfig.domain_margin must be None or finite and > 0 (feature units), "
                             f"got {self.domain_margin}")
        if set(self.clamped_features) - set(self.features) or len(set(self.clamped_features)) != len(self.clamped_features):
            raise ValueError(f"MLPConfig.clamped_features must be distinct names among its features {self.features}, "
                             f"got {self.clamped_features}")


def _ln_gr(beta: Tensor, dT: Tensor, nu: Tensor, R: Tensor) -> Tensor:
    return torch.log1p(GRAVITY_M_S2 * beta.abs() * torch.sqrt(dT * dT + DT_SMOOTH_K**2) * R**3 / nu**2)


def _nu_v(x: ClosureInputs) -> Tensor:
    return x.vapor.mu / x.rho_v_kg_m3


def _nu_l(x: ClosureInputs) -> Tensor:
    return x.liquid.mu / x.rho_l_kg_m3


def _re_wave(x: ClosureInputs) -> Tensor:
    b = wave_height_m(x.slosh_amplitude_m, x.slosh_frequency_Hz, x.radius_m, x.H_l_m, WAVE_DAMPING)
    return torch.log1p(2 * math.pi * x.slosh_frequency_Hz * b * x.radius_m / _nu_l(x) / 1e4) / 5


def _gr_li_signed(x: ClosureInputs) -> Tensor:
    dT = x.T_l_K - x.T_sat_K
    return torch.tanh(dT / DT_SMOOTH_K) * _ln_gr(x.liquid.beta, dT, _nu_l(x), x.radius_m) / 30


def _turnover(mdot_kg_s: Tensor, m_kg: Tensor) -> Tensor:
    return torch.log1p(mdot_kg_s * OPERATION_TIME_S / m_kg)


# name -> scaled feature (env,) (module docstring)
_FEATURES = {
    "Pr_v": lambda x: x.vapor.mu * x.vapor.cp / x.vapor.k / 2,
    "Pr_l": lambda x: x.liquid.mu * x.liquid.cp / x.liquid.k / 2,
    "R_over_H": lambda x: x.aspect_ratio,
    "Re_1e4": lambda x: x.slosh_frequency_Hz * x.slosh_amplitude_m * x.radius_m / _nu_l(x) / 1e4,
    "lnGr_wv": lambda x: _ln_gr(x.vapor.beta, x.wall_temperatures_K()[0] - x.T_v_K, _nu_v(x), x.radius_m) / 30,
    "lnGr_wl": lambda x: _ln_gr(x.liquid.beta, x.wall_temperatures_K()[1] - x.T_l_K, _nu_l(x), x.radius_m) / 30,
    "lnGr_vl": lambda x: _ln_gr(x.liquid.beta, x.T_v_K - x.T_l_K, _nu_l(x), x.radius_m) / 30,
    "lnRe_wave": _re_wave,
    "lnGr_li_signed": _gr_li_signed,
    "f_over_f11": lambda x: x.slosh_frequency_Hz / first_slosh_frequency_Hz(x.radius_m, x.H_l_m),
    "dT_wv_signed": lambda x: torch.tanh((x.wall_temperatures_K()[0] - x.T_v_K) / SIGNED_SCALE_K),
    "dT_vi_signed": lambda x: torch.tanh((x.T_v_K - x.T_sat_K) / SIGNED_SCALE_K),
    "fill": lambda x: x.H_l_m * x.aspect_ratio / x.radius_m,
    "lnTurn_v_in": lambda x: _turnover(x.mdot_v_in_kg_s, x.m_v_kg),
    "lnTurn_v_out": lambda x: _turnover(x.mdot_v_out_kg_s, x.m_v_kg),
    "lnTurn_l_in": lambda x: _turnover(x.mdot_l_in_kg_s, x.m_l_kg),
    "lnTurn_l_out": lambda x: _turnover(x.mdot_l_out_kg_s, x.m_l_kg),
}


def mlp_features(x: ClosureInputs, names: tuple[str, ...] = FEATURE_NAMES) -> Tensor:
    """The scaled features ``(env, len(names))`` of the module docstring."""
    return torch.stack([_FEATURES[n](x) for n in names], dim=-1)


BASES = ("natural", "reference", "constant")  # MLPConfig.base (module docstring)


def _base_closure(name: str) -> Closure | None:
    from .natural import NaturalConvectionClosure
    from .reference import ReferenceClosure

    return {"natural": NaturalConvectionClosure, "reference": ReferenceClosure}[name]() if name != "constant" else None


class MLPClosure(Closure):
    """theta = base(s) * exp(span * tanh(MLP(features))), see the module docstring."""

    def __init__(self, config: MLPConfig = MLPConfig()):
        super().__init__()
        self.config = config
        gen = torch.Generator().manual_seed(config.seed)
        widths = (len(config.features), *config.hidden, 4)
        layers: list[nn.Module] = []
        for i, (a, b) in enumerate(zip(widths[:-1], widths[1:])):
            lin = nn.Linear(a, b, dtype=torch.float64)
            bound = 1.0 / math.sqrt(a)
            with torch.no_grad():
                lin.weight.uniform_(-bound, bound, generator=gen)
                lin.bias.uniform_(-bound, bound, generator=gen)
                if i == len(widths) - 2:  # start at h_ref (see module docstring)
                    lin.weight.zero_()
                    lin.bias.zero_()
            layers.append(lin)
            if i < len(widths) - 2:
                layers.append(nn.Tanh())
        self.net = nn.Sequential(*layers)
        self.register_buffer("log_h_ref", torch.log(torch.tensor(config.h_ref_W_m2K, dtype=torch.float64)))
        self.base = _base_closure(config.base)
        if config.domain_margin is not None:  # an empty box (lo > hi): nothing seen yet, no gate
            n = len(config.features)
            self.register_buffer("seen_lo", torch.full((n,), math.inf, dtype=torch.float64))
            self.register_buffer("seen_hi", torch.full((n,), -math.inf, dtype=torch.float64))
        # (n_features,) True where a feature is clamped to the box rather than faded over.
        self.register_buffer("clamped", torch.tensor([f in config.clamped_features for f in config.features]),
                             persistent=False)

    def features(self, x: ClosureInputs) -> Tensor:
        """The agent's scaled input features ``(env, n_features)`` at ``x`` (module docstring)."""
        return mlp_features(x, self.config.features)

    def extend_domain(self, points: Tensor) -> bool:
        """Widen the seen box to hold ``points`` ``(..., n_features)`` (feature units); a non-finite
        value is skipped (its point's other features still count). Returns whether the box
        changed (never without a ``domain_margin``)."""
        if self.config.domain_margin is None:
            return False
        f = points.detach().to(torch.float64).reshape(-1, len(self.config.features))
        if not len(f):
            return False
        ok = torch.isfinite(f)
        with torch.no_grad():
            lo = torch.minimum(self.seen_lo, torch.where(ok, f, math.inf).amin(0))
            hi = torch.maximum(self.seen_hi, torch.where(ok, f, -math.inf).amax(0))
            changed = not (torch.equal(lo, self.seen_lo) and torch.equal(hi, self.seen_hi))
            self.seen_lo.copy_(lo)
            self.seen_hi.copy_(hi)
        return changed

    def gate(self, features: Tensor) -> Tensor | None:
        """``g(x)`` ``(..., 1)`` of the module docstring at scaled ``features``, or None (no gate:
        no margin, or nothing seen yet)."""
        if self.config.domain_margin is None or not bool((self.seen_lo <= self.seen_hi).all()):
            return None
        outside = torch.relu(self.seen_lo - features) + torch.relu(features - self.seen_hi)
        outside = torch.where(self.clamped, 0.0, outside)
        return torch.exp(-((outside / self.config.domain_margin) ** 2).sum(-1, keepdim=True))

    def _correction(self, features: Tensor) -> Tensor:
        """``g(x) tanh(o(P x))`` ``(..., 4)``: the learned correction in units of ``span``."""
        g = self.gate(features)
        if g is None:
            return torch.tanh(self.net(features))
        nearest = torch.where(self.clamped, torch.clamp(features, self.seen_lo, self.seen_hi), features)
        return g * torch.tanh(self.net(nearest))

    def log_base(self, x: ClosureInputs) -> Tensor:
        """``ln`` of the base coefficients ``(env, 4)`` at ``x`` (the untrained agent's closure)."""
        if self.base is None:
            return self.log_h_ref.expand(*x.T_v_K.shape, 4)
        return torch.log(self.base(x))

    def log_theta(self, features: Tensor, log_base: Tensor | None = None) -> Tensor:
        """``ln theta`` ``(..., 4)`` from scaled features ``(..., len(config.features))`` and the base's
        ``ln h`` at the same states (``log_base``; None for the constant base, whose is ``ln h_ref``)."""
        if log_base is None:
            if self.base is not None:
                raise ValueError(f"an agent on the {self.config.base!r} base needs log_base (its ln h at the states)")
            log_base = self.log_h_ref
        return log_base + self.config.span * self._correction(features)

    def forward(self, x: ClosureInputs) -> Tensor:
        return torch.exp(self.log_theta(self.features(x), self.log_base(x)))

    def output_position(self, x: ClosureInputs) -> Tensor:
        """``g(x) tanh(o)`` ``(env, 4)`` at ``x``: -1 and +1 are the output bounds ``base e^-span`` and
        ``base e^span``, where the slope vanishes."""
        return self._correction(self.features(x))


__all__ = ["MLPClosure", "MLPConfig", "BASES", "mlp_features", "FEATURE_NAMES", "OPERATION_FEATURES",
           "STATE_FEATURES", "EXTENDED_FEATURES", "INPUT_SETS", "N_FEATURES", "OPERATION_TIME_S"]

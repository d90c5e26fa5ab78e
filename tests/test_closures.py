"""Closures: the reference correlation's limits and the MLP agent's guarantees."""

import json
import math

import pytest
import torch

from tankode.analytic import AnalyticFluid
from tankode.closures import (EXTENDED_FEATURES, FEATURE_NAMES, ClosureInputs, MLPClosure, MLPConfig,
                              NaturalConvectionClosure, ReferenceClosure, ReferenceCorrelation, ScaledClosure,
                              mlp_features)
from tankode.closures.mlp import WAVE_DAMPING
from tankode.closures.reference import XI_11, first_slosh_frequency_Hz, wave_height_m

R = 0.9


def _inputs(T_v=30.0, T_l=20.0, T_w=25.0, A0=0.0, f=0.0, H_l=1.4, n=1, m_v=5.0, m_l=300.0, mdot_v_in=0.0,
            mdot_v_out=0.0, mdot_l_in=0.0, mdot_l_out=0.0):
    fluid = AnalyticFluid()
    c = fluid.params
    u_v = torch.full((n,), c.L_J_per_kg + c.cv_v_J_per_kgK * (T_v - c.T0_K), dtype=torch.float64)
    u_l = torch.full((n,), c.c_l_J_per_kgK * (T_l - c.T0_K), dtype=torch.float64)
    rho_v = torch.full((n,), 3e5 / (c.R_J_per_kgK * T_v), dtype=torch.float64)
    rho_l = torch.full((n,), c.rho_l0_kg_m3 * (1 + 2e5 / c.bulk_modulus_Pa), dtype=torch.float64)
    pv, pl = fluid.vapor(u_v, rho_v), fluid.liquid(u_l, rho_l)
    full = lambda v: torch.full((n,), float(v), dtype=torch.float64)  # noqa: E731
    return ClosureInputs(pv.T, pl.T, full(T_w), pv.T_sat, rho_v, rho_l, pv, pl, full(H_l), full(R), full(R / 2.2),
                         full(A0), full(f), full(m_v), full(m_l), full(mdot_v_in), full(mdot_v_out), full(mdot_l_in),
                         full(mdot_l_out))


def test_reference_at_rest_and_stably_stratified_is_the_conduction_floor():
    x = _inputs(T_v=30.0, T_l=18.0)  # vapour above, liquid below the saturation temperature: stable both sides
    assert float(x.T_sat_K) > 18.5 and float(x.T_sat_K) < 29.0
    c = ReferenceCorrelation()
    h = ReferenceClosure(c)(x)[0]
    assert h[0].item() == pytest.approx(c.nu_0 * x.vapor.k.item() / R, rel=1e-6)
    assert h[1].item() == pytest.approx(c.nu_0 * x.liquid.k.item() / R, rel=1e-6)
    assert h[2].item() == pytest.approx(20 * h[0].item(), rel=1e-12)
    assert h[3].item() == pytest.approx(10 * h[1].item(), rel=1e-12)


def test_reference_natural_convection_only_when_unstable():
    stable = ReferenceClosure()(_inputs(T_l=18.0))[0, 1]
    x = _inputs(T_l=27.0)  # liquid warmer than the interface: cooled from above, convects
    unstable = ReferenceClosure()(x)[0, 1]
    c = ReferenceCorrelation()
    nu = x.liquid.mu / x.rho_l_kg_m3
    alpha = x.liquid.k / (x.rho_l_kg_m3 * x.liquid.cp)
    ra = 9.80665 * x.liquid.beta * (x.T_l_K - x.T_sat_K) * R**3 / (nu * alpha)
    expected = (c.nu_0 + c.c_nat_liquid * ra ** (1 / 3)) * x.liquid.k / R
    # 1e-3: the switch and |dT| are smoothed over 0.05 K, which shifts Ra^(1/3) by ~2e-4 at dT = 1.4 K.
    assert unstable.item() == pytest.approx(expected.item(), rel=1e-3)
    assert unstable > 10 * stable


def test_stable_mixing_adds_the_symmetric_natural_convection_under_a_subcooled_liquid():
    # Liquid 1.4 K colder than the interface (stable) and 1.4 K warmer (unstable), same |dT|.
    x_stable = _inputs(T_l=18.0)
    dT = float(x_stable.T_sat_K) - 18.0
    x_unstable = _inputs(T_l=float(x_stable.T_sat_K) + dT)
    f = torch.tensor([1.0, 2.0, 1.0, 1.0], dtype=torch.float64)
    ref = ReferenceClosure()
    for c in (0.0, 0.5, 1.0):
        closure = ScaledClosure(ref, f, stable_mixing=c)
        h_stable = closure(x_stable)[0]
        c_ref = ReferenceCorrelation()
        nu = x_stable.liquid.mu / x_stable.rho_l_kg_m3
        alpha = x_stable.liquid.k / (x_stable.rho_l_kg_m3 * x_stable.liquid.cp)
        ra = 9.80665 * x_stable.liquid.beta.abs() * dT * R**3 / (nu * alpha)
        expected = (c_ref.nu_0 + c * c_ref.c_nat_liquid * ra ** (1 / 3)) * x_stable.liquid.k / R * 2.0
        assert h_stable[1].item() == pytest.approx(expected.item(), rel=2e-3)  # 2e-3: the 0.05 K smoothing
        # The other coefficients and the unstable side are untouched (the wall keeps 10 x the reference h_li).
        assert torch.equal(h_stable[[0, 2, 3]], (ref(x_stable)[0] * f)[[0, 2, 3]])
        assert torch.allclose(closure(x_unstable), ref(x_unstable) * f, rtol=1e-6)
    with pytest.raises(ValueError, match=r"stable_mixing must be a share in \[0, 1\]"):
        ScaledClosure(ref, f, stable_mixing=1.5)


def test_wave_height_limits():
    Hl = torch.tensor(1.43, dtype=torch.float64)
    Rt = torch.tensor(R, dtype=torch.float64)
    f11 = first_slosh_frequency_Hz(Rt, Hl)
    # Deep-liquid limit of the natural frequency: sqrt(g xi / R) / 2 pi.
    assert f11.item() == pytest.approx(math.sqrt(9.80665 * XI_11 / R * math.tanh(XI_11 * 1.43 / R)) / (2 * math.pi))
    A0 = torch.tensor(0.01, dtype=torch.float64)
    gain = 2 * XI_11 / (XI_11**2 - 1) * math.tanh(XI_11 * 1.43 / R)
    # At resonance the response is bounded by the damping: b = A0 gain / (2 zeta).
    assert wave_height_m(A0, f11, Rt, Hl, 0.05).item() == pytest.approx(0.01 * gain / 0.1, rel=1e-12)
    assert wave_height_m(A0, 0.0 * f11, Rt, Hl, 0.05).item() == 0.0
    # Far above resonance the tank moves under a still liquid: b -> A0 gain.
    assert wave_height_m(A0, 100 * f11, Rt, Hl, 0.05).item() == pytest.approx(0.01 * gain, rel=1e-3)


def test_sloshing_raises_interface_coefficients_in_the_expected_range():
    f = 0.8 * first_slosh_frequency_Hz(torch.tensor(R), torch.tensor(1.4)).item()
    rest = ReferenceClosure()(_inputs())[0]
    slosh = ReferenceClosure()(_inputs(A0=0.01, f=f))[0]
    assert (slosh > 3 * rest).all()
    # Calibrated to O(10-100) W/(m^2 K) for moderate sloshing (module docstring), not the raw-Re_s 1e4.
    assert 5.0 < slosh[1].item() < 300.0


def test_mlp_has_484_weights_500_with_the_extended_inputs_and_starts_at_h_ref():
    extended = MLPClosure(MLPConfig(features=EXTENDED_FEATURES))
    assert sum(p.numel() for p in extended.parameters()) == 9 * 16 + 16 + 16 * 16 + 16 + 16 * 4 + 4 == 500
    cfg = MLPConfig(base="constant")
    mlp = MLPClosure(cfg)
    assert len(cfg.features) == 8
    assert sum(p.numel() for p in mlp.parameters()) == 484
    h = mlp(_inputs(A0=0.01, f=0.6, n=3))
    assert torch.allclose(h, torch.tensor(cfg.h_ref_W_m2K, dtype=torch.float64).expand(3, 4), rtol=1e-14)


@pytest.mark.parametrize("base, closure", [("natural", NaturalConvectionClosure), ("reference", ReferenceClosure)])
def test_an_untrained_residual_agent_is_its_base_closure_and_its_factor_is_bounded(base, closure):
    x = _inputs(A0=0.01, f=0.6, T_v=30.0, T_w=26.0, n=3)
    mlp = MLPClosure(MLPConfig(base=base))
    assert sum(p.numel() for p in mlp.parameters()) == 484  # the base has no weights
    assert torch.allclose(mlp(x), closure()(x), rtol=1e-14)
    assert torch.equal(mlp.output_position(x), torch.zeros(3, 4, dtype=torch.float64))
    with torch.no_grad():
        for p in mlp.parameters():
            p.normal_(0, 50.0)
    factor = mlp(x) / closure()(x)
    assert (factor >= math.exp(-mlp.config.span) * (1 - 1e-12)).all() and (factor <= math.exp(mlp.config.span) * (1 + 1e-12)).all()


def test_natural_convection_closure_follows_each_surface_and_the_stable_side():
    # A warmer wall convects more into the ullage; a liquid colder than saturation (stable) exchanges less.
    warm = NaturalConvectionClosure()(_inputs(T_v=25.0, T_w=30.0, n=1))
    cool = NaturalConvectionClosure()(_inputs(T_v=25.0, T_w=25.5, n=1))
    assert warm[0, 2] > cool[0, 2]
    T_sat = float(_inputs().T_sat_K)
    unstable = NaturalConvectionClosure()(_inputs(T_l=T_sat + 1.0, n=1))
    stable = NaturalConvectionClosure()(_inputs(T_l=T_sat - 1.0, n=1))
    assert (unstable[0, 1] > stable[0, 1]) and torch.isfinite(stable).all() and (stable > 0).all()


def test_mlp_outputs_stay_bounded_for_any_weights():
    cfg = MLPConfig(base="constant")
    mlp = MLPClosure(cfg)
    with torch.no_grad():
        for p in mlp.parameters():
            p.normal_(0, 50.0)
    h = mlp(_inputs(A0=0.05, f=2.0, T_v=45.0, T_w=40.0, n=4))
    lo = torch.tensor(cfg.h_ref_W_m2K, dtype=torch.float64) * math.exp(-cfg.span)
    hi = torch.tensor(cfg.h_ref_W_m2K, dtype=torch.float64) * math.exp(cfg.span)
    assert torch.isfinite(h).all() and (h >= lo * (1 - 1e-12)).all() and (h <= hi * (1 + 1e-12)).all()


def test_mlp_gradcheck_wrt_weights():
    mlp = MLPClosure(MLPConfig(seed=3))
    with torch.no_grad():
        for p in mlp.parameters():
            p.add_(0.1 * torch.randn_like(p))
    x = _inputs(A0=0.01, f=0.6, n=2)
    params = tuple(mlp.parameters())

    def f(*ps):
        out = torch.func.functional_call(mlp, {n: p for (n, _), p in zip(mlp.named_parameters(), ps)}, (x,))
        return out

    torch.autograd.gradcheck(f, tuple(p.detach().clone().requires_grad_(True) for p in params))


def test_mlp_config_validation():
    with pytest.raises(ValueError, match="h_ref_W_m2K"):
        MLPConfig(h_ref_W_m2K=(1.0, -1.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="span"):
        MLPConfig(span=0.0)


def test_wave_reynolds_feature_is_zero_at_rest_and_follows_the_linear_wave():
    def wave(**kw):
        x = _inputs(**kw)
        return x, mlp_features(x, ("lnRe_wave",))[0, 0].item()

    assert wave(A0=0.0, f=0.0)[1] == 0.0
    f11 = first_slosh_frequency_Hz(torch.tensor(R), torch.tensor(1.4)).item()
    x, value = wave(A0=0.01, f=0.8 * f11)
    b = wave_height_m(x.slosh_amplitude_m, x.slosh_frequency_Hz, x.radius_m, x.H_l_m, WAVE_DAMPING)
    re_b = (2 * math.pi * 0.8 * f11 * b * R / (x.liquid.mu / x.rho_l_kg_m3)).item()
    assert value == pytest.approx(math.log1p(re_b / 1e4) / 5, rel=1e-12)
    # The same forcing amplitude closer to resonance raises a larger wave, which Re = f A_0 R / nu cannot tell.
    assert wave(A0=0.01, f=0.95 * f11)[1] > wave(A0=0.01, f=0.8 * f11)[1] + 0.1


def test_liquid_interface_grashof_feature_has_the_sign_of_the_stratification():
    def feature(T_l):
        x = _inputs(T_l=T_l)
        return float(x.T_l_K - x.T_sat_K), mlp_features(x, ("lnGr_li_signed", "lnGr_vl"))[0]

    T_sat = float(_inputs().T_sat_K)  # set by the vapour alone
    d_stable, (stable, vl_stable) = feature(T_sat - 1.0)
    d_unstable, (unstable, vl_unstable) = feature(T_sat + 1.0)
    assert d_stable == pytest.approx(-1.0, abs=0.05) and d_unstable == pytest.approx(1.0, abs=0.05)
    assert stable.item() < -0.3 and unstable.item() > 0.3  # |ln Gr| / 30 ~ 0.8 at a kelvin
    # the paper's vapour-liquid feature does not see on which side of T_sat the liquid is
    assert vl_stable.item() > 0 and vl_unstable.item() > 0


def test_models_saved_before_the_feature_set_was_configurable_still_load(tmp_path):
    from tankode.saved import load_model, save_model

    old = MLPClosure(MLPConfig(seed=2))
    path = save_model(tmp_path / "m", old, "ParaHydrogen")
    meta = json.loads((path / "model.json").read_text())
    del meta["closure"]["config"]["features"]  # as written before the feature set was configurable
    (path / "model.json").write_text(json.dumps(meta))
    loaded = load_model(path).closure
    assert loaded.config.features == FEATURE_NAMES
    x = _inputs(A0=0.01, f=0.6, n=2)
    assert torch.equal(loaded(x), old(x))


def test_mlp_rejects_unknown_or_repeated_features():
    with pytest.raises(ValueError, match="lnGr_li_signed"):
        MLPConfig(features=("Pr_v", "Pr_v"))
    with pytest.raises(ValueError, match="features"):
        MLPConfig(features=("Nu",))


def test_supervised_fit_recovers_coefficients_an_mlp_can_represent():
    from trainers.supervised import fit_supervised, log_error

    torch.manual_seed(0)
    features = torch.rand(200, 8, dtype=torch.float64)
    teacher = MLPClosure(MLPConfig(seed=5, base="constant"))
    with torch.no_grad():
        teacher.net[-1].weight.normal_(0, 0.3)  # a non-trivial target inside the output range
        theta = torch.exp(teacher.log_theta(features))
    student = MLPClosure(MLPConfig(seed=1, base="constant"))
    assert log_error(student, features, theta).mean() > 0.1
    mse = fit_supervised(student, features, theta, weight_decay=0.0, max_iter=500)
    assert mse < 1e-4
    assert log_error(student, features, theta).max() < 0.05
    with pytest.raises(ValueError, match="columns"):
        fit_supervised(student, features[:, :7], theta, weight_decay=0.0, max_iter=1)


def _trained(config: MLPConfig) -> MLPClosure:
    mlp = MLPClosure(config)
    with torch.no_grad():
        for p in mlp.parameters():
            p.copy_(0.3 * torch.randn(p.shape, generator=torch.Generator().manual_seed(p.numel()), dtype=torch.float64))
    return mlp


def test_the_learned_correction_fades_to_the_base_outside_the_seen_box_and_only_there():
    margin = 0.1
    gated, free = _trained(MLPConfig(domain_margin=margin)), _trained(MLPConfig())
    seen = _inputs(T_v=28.0, T_w=26.0, T_l=20.0, n=1)
    f_seen = gated.features(seen)
    assert torch.equal(gated(seen), free(seen))  # nothing seen yet: no gate
    gated.extend_domain(torch.cat([f_seen - 0.05, f_seen + 0.05]))
    assert torch.equal(gated(seen), free(seen))  # inside the box the agent is unchanged
    # A point outside the box by d in one feature: the correction is scaled by exp(-(d/margin)^2).
    f_out = f_seen.clone()
    f_out[0, 3] = f_seen[0, 3] + 0.05 + 0.12  # Re_1e4: a sloshing the agent has not seen
    log_base = torch.zeros(1, 4, dtype=torch.float64)
    expected = math.exp(-(0.12 / margin) ** 2) * free.log_theta(f_out, log_base)
    assert torch.allclose(gated.log_theta(f_out, log_base), expected, rtol=1e-12, atol=0)
    # Far outside, the agent is its base.
    f_far = f_out.clone()
    f_far[0, 3] += 1.0
    assert gated.log_theta(f_far, log_base).abs().max() < 1e-30
    # The box only widens; a non-finite value is skipped, its point's other features still count.
    assert not gated.extend_domain(torch.tensor([[math.nan] * f_seen.shape[1]], dtype=torch.float64))
    assert not gated.extend_domain(f_seen)  # inside: the box, and so the agent, did not change
    assert torch.allclose(gated.seen_hi - gated.seen_lo, torch.full_like(gated.seen_lo, 0.1), rtol=1e-12)
    partial = f_seen + 0.2
    partial[0, 0] = math.inf
    assert gated.extend_domain(partial)
    assert float(gated.seen_hi[1]) == pytest.approx(float(f_seen[0, 1]) + 0.2, abs=1e-15)
    assert float(gated.seen_hi[0]) == pytest.approx(float(f_seen[0, 0]) + 0.05, abs=1e-15)


def test_a_clamped_state_feature_carries_the_nearest_seen_correction_while_an_operation_fades():
    from tankode.closures import STATE_FEATURES

    margin = 0.1
    config = MLPConfig(domain_margin=margin, clamped_features=tuple(f for f in FEATURE_NAMES if f in STATE_FEATURES))
    assert config.clamped_features == ("Pr_v", "Pr_l", "R_over_H", "lnGr_wv", "lnGr_wl", "lnGr_vl")
    clamped, free = _trained(config), _trained(MLPConfig())
    f_seen = clamped.features(_inputs(T_v=28.0, T_w=26.0, T_l=20.0, n=1))
    clamped.extend_domain(torch.cat([f_seen - 0.05, f_seen + 0.05]))
    log_base = torch.zeros(1, 4, dtype=torch.float64)
    assert torch.equal(clamped.log_theta(f_seen, log_base), free.log_theta(f_seen, log_base))  # inside: unchanged
    # lnGr_wv (a state) far beyond the box: the network sees the box's edge, no fade.
    f_state = f_seen.clone()
    f_state[0, 4] += 0.05 + 1.0
    edge = f_seen.clone()
    edge[0, 4] += 0.05
    got = clamped.log_theta(f_state, log_base)
    assert torch.allclose(got, free.log_theta(edge, log_base), rtol=1e-12, atol=0)
    assert got.abs().min() > 1e-3  # the learned correction is carried, not dropped
    # Re_1e4 (an operation) beyond the box fades as before, on top of the clamped state.
    f_both = f_state.clone()
    f_both[0, 3] += 0.05 + 0.12
    edge_op = edge.clone()
    edge_op[0, 3] = f_both[0, 3]
    expected = math.exp(-(0.12 / margin) ** 2) * free.log_theta(edge_op, log_base)
    assert torch.allclose(clamped.log_theta(f_both, log_base), expected, rtol=1e-12, atol=0)
    # Smooth enough to train through: gradcheck away from the box's edges.
    points = (f_seen + torch.tensor([-0.3, -0.01, 0.02, 0.3], dtype=torch.float64)[:, None]).requires_grad_(True)
    torch.autograd.gradcheck(lambda z: clamped.log_theta(z, torch.zeros(4, 4, dtype=torch.float64)), (points,))
    with pytest.raises(ValueError, match="clamped_features"):
        MLPConfig(clamped_features=("fill",))  # not among the features
    from trainers.assimilate import AssimilationConfig

    assert AssimilationConfig().agent().config.clamped_features == tuple(
        f for f in AssimilationConfig.agent_features if f in STATE_FEATURES)
    with pytest.raises(ValueError, match="agent_clamped_features"):
        AssimilationConfig(agent_clamped_features=("lnGr_xx",))


def test_operation_turnovers_are_zero_at_rest_and_an_unseen_fill_returns_the_base():
    from tankode.closures import OPERATION_FEATURES
    from tankode.closures.mlp import OPERATION_TIME_S

    names = ("lnTurn_v_in", "lnTurn_v_out", "lnTurn_l_in", "lnTurn_l_out")
    assert OPERATION_FEATURES[-4:] == names and OPERATION_FEATURES[:8] == FEATURE_NAMES
    rest = mlp_features(_inputs(), names)
    assert torch.equal(rest, torch.zeros(1, 4, dtype=torch.float64))
    flows = dict(mdot_v_in=0.004, mdot_v_out=0.002, mdot_l_in=0.12, mdot_l_out=0.15)
    got = mlp_features(_inputs(m_v=5.0, m_l=300.0, **flows), names)[0]
    want = [math.log1p(0.004 * OPERATION_TIME_S / 5.0), math.log1p(0.002 * OPERATION_TIME_S / 5.0),
            math.log1p(0.12 * OPERATION_TIME_S / 300.0), math.log1p(0.15 * OPERATION_TIME_S / 300.0)]
    assert got.tolist() == pytest.approx(want, rel=1e-14)
    # 1 % of the liquid per hour reads about one domain margin (0.1), as documented.
    trickle = mlp_features(_inputs(m_l=300.0, mdot_l_in=0.01 * 300.0 / 3600), ("lnTurn_l_in",))
    assert float(trickle) == pytest.approx(math.log(1.1), rel=1e-12)
    # An agent that has seen a drain but no fill is its base closure during a fill of the same
    # rate, and keeps its learning during the drain.
    gated = _trained(MLPConfig(features=OPERATION_FEATURES, domain_margin=0.1, base="natural"))
    drain = _inputs(m_l=300.0, mdot_l_out=0.15)
    fill = _inputs(m_l=300.0, mdot_l_in=0.15)
    gated.extend_domain(gated.features(drain))
    base = gated.base(fill)
    assert torch.allclose(gated(fill), base, rtol=1e-12)
    assert not torch.allclose(gated(drain), gated.base(drain), rtol=1e-3)


def test_the_fade_is_smooth_across_the_box_edge_gradcheck():
    gated = _trained(MLPConfig(domain_margin=0.1))
    f = gated.features(_inputs(n=1))
    gated.extend_domain(torch.cat([f - 0.02, f + 0.02]))
    # Points inside, on the edge's two sides and outside, in every feature.
    points = (f + torch.linspace(-0.08, 0.08, 5, dtype=torch.float64)[:, None]).requires_grad_(True)
    torch.autograd.gradcheck(lambda z: gated.log_theta(z, torch.zeros(5, 4, dtype=torch.float64)), (points,))


def test_the_seen_box_is_saved_with_the_agent(tmp_path):
    from tankode.saved import load_model, save_model

    gated = _trained(MLPConfig(domain_margin=0.1, clamped_features=("lnGr_wv",)))
    f = gated.features(_inputs(n=1))
    gated.extend_domain(torch.cat([f - 0.01, f + 0.01]))
    loaded = load_model(save_model(tmp_path / "m", gated, "ParaHydrogen")).closure
    assert loaded.config.domain_margin == 0.1 and loaded.config.clamped_features == ("lnGr_wv",)
    assert torch.equal(loaded.seen_lo, gated.seen_lo) and torch.equal(loaded.seen_hi, gated.seen_hi)
    far = _inputs(T_v=40.0, T_w=21.0, A0=0.02, f=0.7, n=1)
    assert torch.equal(loaded(far), gated(far)) and not torch.allclose(loaded(far), _trained(MLPConfig())(far))
    with pytest.raises(ValueError, match="domain_margin"):
        MLPConfig(domain_margin=0.0)

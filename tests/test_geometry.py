"""Tests of tankode.geometry against independent closed forms and numerical integrals.

References are written here from the shapes' meridian / cross-section equations (numpy + scipy
quadrature), not from the module's formulas, so a wrong formula in the module fails a test.
"""

import math

import numpy as np
import pytest
import torch
from scipy import integrate

from tankode.geometry import (
    SHAPES,
    HorizontalCylinder,
    Sphere,
    TankGeometry,
    VerticalCylinder,
    VerticalCylinderEllipticalHeads,
    geometry_from_spec,
    stack_geometries,
)

F64 = torch.float64

# name -> (class, dims); MHTB and the paper's tank plus head variants that exercise the
# oblate (k > 1), hemispherical (k = 1), prolate (k < 1) and zero-straight-length branches.
CASES = {
    "paper_vcyl": (VerticalCylinder, dict(radius_m=0.9, height_m=2.2)),
    "mhtb_heads": (VerticalCylinderEllipticalHeads,
                   dict(radius_m=1.525, cylinder_length_m=1.4593, head_aspect=2.0)),
    "hemi_heads": (VerticalCylinderEllipticalHeads,
                   dict(radius_m=0.8, cylinder_length_m=1.0, head_aspect=1.0)),
    "shallow_heads": (VerticalCylinderEllipticalHeads,
                      dict(radius_m=1.0, cylinder_length_m=0.3, head_aspect=4.0)),
    "prolate_heads": (VerticalCylinderEllipticalHeads,
                      dict(radius_m=0.6, cylinder_length_m=0.2, head_aspect=0.5)),
    "oblate_spheroid": (VerticalCylinderEllipticalHeads,
                        dict(radius_m=0.9, cylinder_length_m=0.0, head_aspect=1.6)),
    "sphere": (Sphere, dict(radius_m=0.7)),
    "hcyl": (HorizontalCylinder, dict(radius_m=1.1, cylinder_length_m=3.0)),
}


def make(name):
    cls, dims = CASES[name]
    return cls(**dims)


def levels(geom, n=41, lo=0.0, hi=1.0):
    return torch.linspace(lo, hi, n, dtype=F64) * geom.height_m


# ---------------------------------------------------------------- independent references (numpy)
def ref_height(name):
    cls, d = CASES[name]
    if cls is VerticalCylinder:
        return d["height_m"]
    if cls is VerticalCylinderEllipticalHeads:
        return d["cylinder_length_m"] + 2 * d["radius_m"] / d["head_aspect"]
    return 2 * d["radius_m"]


def ref_r2_and_half_dr2(name, h):
    """Squared section radius r(h)^2 and r r' = (r^2)'/2 of a vertical surface of revolution."""
    cls, d = CASES[name]
    R = d["radius_m"]
    if cls is VerticalCylinder:
        return R**2, 0.0
    if cls is Sphere:
        return R**2 - (h - R) ** 2, -(h - R)
    a = R / d["head_aspect"]
    top = d["cylinder_length_m"] + a  # start of the top head
    if h < a:  # ellipse (r/R)^2 + ((h - a)/a)^2 = 1
        return R**2 * (1 - ((h - a) / a) ** 2), -(R**2) * (h - a) / a**2
    if h > top:
        return R**2 * (1 - ((h - top) / a) ** 2), -(R**2) * (h - top) / a**2
    return R**2, 0.0


def ref_interface(name, h):
    cls, d = CASES[name]
    if cls is HorizontalCylinder:
        R, L = d["radius_m"], d["cylinder_length_m"]
        return 2 * math.sqrt(max(R**2 - (R - h) ** 2, 0.0)) * L
    return math.pi * ref_r2_and_half_dr2(name, h)[0]


def breakpoints(name):
    cls, d = CASES[name]
    if cls is VerticalCylinderEllipticalHeads:
        a = d["radius_m"] / d["head_aspect"]
        return [a, a + d["cylinder_length_m"]]
    return None


def ref_volume(name, h):
    return integrate.quad(lambda t: ref_interface(name, t), 0.0, h, points=breakpoints(name),
                          epsabs=1e-13, epsrel=1e-12, limit=200)[0]


def ref_wetted(name, h):
    """Wall area below h: bottom end + surface-of-revolution integral (or horizontal formula)."""
    cls, d = CASES[name]
    R = d["radius_m"]
    if cls is HorizontalCylinder:
        L = d["cylinder_length_m"]
        ends = 2 * integrate.quad(lambda t: 2 * math.sqrt(max(R**2 - (R - t) ** 2, 0.0)), 0.0, h)[0]
        return 2 * R * math.acos((R - h) / R) * L + ends

    def ds(t):  # 2 pi r sqrt(1 + r'^2) = 2 pi sqrt(r^2 + (r r')^2), finite at the apex
        r2, rr = ref_r2_and_half_dr2(name, t)
        return 2 * math.pi * math.sqrt(max(r2, 0.0) + rr**2)

    bottom = math.pi * R**2 if cls is VerticalCylinder else 0.0
    zone = integrate.quad(ds, 0.0, h, points=breakpoints(name), epsabs=1e-13, epsrel=1e-12, limit=200)[0]
    return bottom + zone


def spheroid_area(R, a):
    """Closed-form total surface of a spheroid with equatorial radius R and polar semi-axis a."""
    if a < R:  # oblate
        e = math.sqrt(1 - a**2 / R**2)
        return 2 * math.pi * R**2 * (1 + (1 - e**2) / e * math.atanh(e))
    if a > R:  # prolate
        e = math.sqrt(1 - R**2 / a**2)
        return 2 * math.pi * R**2 * (1 + a / (R * e) * math.asin(e))
    return 4 * math.pi * R**2


def ref_totals(name):
    cls, d = CASES[name]
    R = d["radius_m"]
    if cls is VerticalCylinder:
        H = d["height_m"]
        return math.pi * R**2 * H, 2 * math.pi * R**2 + 2 * math.pi * R * H
    if cls is Sphere:
        return 4 / 3 * math.pi * R**3, 4 * math.pi * R**2
    if cls is HorizontalCylinder:
        L = d["cylinder_length_m"]
        return math.pi * R**2 * L, 2 * math.pi * R * L + 2 * math.pi * R**2
    L, a = d["cylinder_length_m"], R / d["head_aspect"]
    return math.pi * R**2 * L + 2 * (2 / 3 * math.pi * R**2 * a), 2 * math.pi * R * L + spheroid_area(R, a)


# ---------------------------------------------------------------- totals and end points
@pytest.mark.parametrize("name", CASES)
def test_total_volume_area_height_closed_forms(name):
    g = make(name)
    vol, area = ref_totals(name)
    assert g.volume_m3.dtype == F64 and g.volume_m3.shape == ()
    assert g.volume_m3.item() == pytest.approx(vol, rel=1e-13)
    assert g.wall_area_m2.item() == pytest.approx(area, rel=1e-13)
    assert g.height_m.item() == pytest.approx(ref_height(name), rel=1e-14)
    assert g.aspect_ratio.item() == pytest.approx(CASES[name][1]["radius_m"] / ref_height(name), rel=1e-14)


def test_hemispherical_heads_are_sphere_plus_cylinder():
    g = VerticalCylinderEllipticalHeads(radius_m=0.5, cylinder_length_m=2.0, head_aspect=1.0)
    s, c = Sphere(0.5), VerticalCylinder(0.5, 2.0)
    assert g.wall_area_m2.item() == pytest.approx(s.wall_area_m2.item() + 2 * math.pi * 0.5 * 2.0, rel=1e-14)
    h = torch.tensor([0.1, 0.4, 1.3, 2.7], dtype=F64)
    # the bottom head is a hemisphere, then a cylinder
    assert torch.allclose(g.volume_at_level(h[:2]), s.volume_at_level(h[:2]), rtol=1e-14)
    assert torch.allclose(g.wetted_areas_m2(h[:2])[0], s.wetted_areas_m2(h[:2])[0], rtol=1e-14)
    expected = s.volume_m3 / 2 + c.volume_at_level(h[2] - 0.5)
    assert g.volume_at_level(h[2]).item() == pytest.approx(expected.item(), rel=1e-14)


@pytest.mark.parametrize("name", CASES)
def test_end_levels_and_clamping(name):
    g = make(name)
    ht, vt = g.height_m, g.volume_m3
    assert g.volume_at_level(0.0).item() == 0.0
    assert g.volume_at_level(ht).item() == pytest.approx(vt.item(), rel=1e-14)
    # out-of-range levels clamp to the ends
    assert g.volume_at_level(-1.0).item() == 0.0
    assert g.volume_at_level(ht + 1.0).item() == pytest.approx(vt.item(), rel=1e-14)
    bottom = math.pi * CASES[name][1]["radius_m"] ** 2 if isinstance(g, VerticalCylinder) else 0.0
    wl, wv = g.wetted_areas_m2(0.0)
    assert wl.item() == pytest.approx(bottom, abs=1e-14)
    assert wv.item() == pytest.approx(g.wall_area_m2.item() - bottom, rel=1e-14)
    wl, wv = g.wetted_areas_m2(ht)
    assert wl.item() == pytest.approx(g.wall_area_m2.item() - bottom, rel=1e-14)
    assert wv.item() == pytest.approx(bottom, abs=1e-14)
    assert g.level_at_volume(0.0).item() == pytest.approx(0.0, abs=1e-12)
    assert g.level_at_volume(vt).item() == pytest.approx(ht.item(), rel=1e-12)


@pytest.mark.parametrize("name", CASES)
def test_half_full_and_top_bottom_symmetry(name):
    g = make(name)
    vt, ht = g.volume_m3, g.height_m
    assert g.volume_at_level(ht / 2).item() == pytest.approx(vt.item() / 2, rel=1e-14)
    h = levels(g)
    assert torch.allclose(g.volume_at_level(h) + g.volume_at_level(ht - h), vt.expand_as(h), rtol=1e-13)


def test_sphere_and_horizontal_cylinder_half_volume_at_radius():
    s, c = Sphere(1.3), HorizontalCylinder(0.4, 7.0)
    assert s.volume_at_level(1.3).item() == pytest.approx(2 / 3 * math.pi * 1.3**3, rel=1e-14)
    assert c.volume_at_level(0.4).item() == pytest.approx(0.5 * math.pi * 0.4**2 * 7.0, rel=1e-14)
    assert c.level_at_volume(0.5 * math.pi * 0.4**2 * 7.0).item() == pytest.approx(0.4, rel=1e-13)


def test_mhtb_volume():
    g = geometry_from_spec(
        {"shape": "vertical_cylinder_elliptical_heads", "radius_m": 1.525, "cylinder_length_m": 1.4593,
         "head_aspect": 2.0}
    )
    assert g.volume_m3.item() == pytest.approx(18.09, rel=1e-3)
    assert g.height_m.item() == pytest.approx(1.4593 + 1.525, rel=1e-14)


# ---------------------------------------------------------------- level functions vs references
@pytest.mark.parametrize("name", CASES)
def test_volume_interface_wetted_match_independent_integrals(name):
    g = make(name)
    ht = g.height_m.item()
    hs = [0.013 * ht, 0.1 * ht, 0.2 * ht, 0.37 * ht, 0.5 * ht, 0.81 * ht, 0.96 * ht]
    h = torch.tensor(hs, dtype=F64)
    vol, ai = g.volume_at_level(h), g.interface_area_m2(h)
    wl, _ = g.wetted_areas_m2(h)
    for i, hi in enumerate(hs):
        assert ai[i].item() == pytest.approx(ref_interface(name, hi), rel=1e-12), f"A_i at h={hi}"
        assert vol[i].item() == pytest.approx(ref_volume(name, hi), rel=1e-10), f"V at h={hi}"
        assert wl[i].item() == pytest.approx(ref_wetted(name, hi), rel=1e-9), f"A_wl at h={hi}"


@pytest.mark.parametrize("name", CASES)
def test_wetted_areas_sum_to_total_and_liquid_part_increases(name):
    g = make(name)
    h = levels(g, n=2001)
    wl, wv = g.wetted_areas_m2(h)
    assert torch.allclose(wl + wv, g.wall_area_m2.expand_as(h), rtol=1e-13, atol=0)
    assert (wl.diff() > 0).all() and (wv.diff() < 0).all()


# ---------------------------------------------------------------- inverse and derivatives
def batched(name):
    """Three tanks of the case's shape with different dimensions, stacked to env = 3."""
    cls, d = CASES[name]
    scales = [(1.0, 1.0), (0.5, 1.7), (2.0, 0.6)]
    geoms = []
    for sr, sl in scales:
        dd = dict(d)
        dd["radius_m"] = d["radius_m"] * sr
        for key in ("height_m", "cylinder_length_m"):
            if key in dd:
                dd[key] = dd[key] * sl
        geoms.append(cls(**dd))
    return stack_geometries(geoms), geoms


@pytest.mark.parametrize("name", CASES)
def test_level_volume_roundtrip_batched(name):
    g, singles = batched(name)
    assert g.batch_shape == (3,)
    frac = torch.linspace(0.0, 1.0, 401, dtype=F64)
    h = g.height_m[:, None] * frac  # (env, n)
    v = g.volume_at_level(h)
    assert v.shape == (3, 401)
    h_back = g.level_at_volume(v)
    v_back = g.volume_at_level(h_back)
    assert torch.allclose(v_back, v, rtol=0, atol=1e-13 * g.volume_m3.max().item())
    # H itself is ill-conditioned where A_i -> 0 (ends of sphere/heads/horizontal cylinder)
    inner = (frac > 1e-3) & (frac < 1 - 1e-3)
    assert torch.allclose(h_back[:, inner], h[:, inner], rtol=0, atol=1e-10 * g.height_m.max().item())
    # batch row i equals the unbatched tank i
    for i, s in enumerate(singles):
        assert torch.allclose(v[i], s.volume_at_level(h[i]), rtol=1e-15, atol=0)
        assert torch.allclose(h_back[i], s.level_at_volume(v[i]), rtol=1e-15, atol=1e-15)


@pytest.mark.parametrize("name", CASES)
def test_dV_dH_equals_interface_area(name):
    g = make(name)
    h = levels(g, n=97, lo=0.004, hi=0.996).requires_grad_(True)
    (dv,) = torch.autograd.grad(g.volume_at_level(h).sum(), h)
    assert torch.allclose(dv, g.interface_area_m2(h.detach()), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", CASES)
def test_dH_dV_autograd_and_finite_difference(name):
    g = make(name)
    vt = g.volume_m3.item()
    v = torch.linspace(0.02, 0.98, 37, dtype=F64).mul(vt).requires_grad_(True)
    h = g.level_at_volume(v)
    (dh,) = torch.autograd.grad(h.sum(), v)
    inv_area = 1.0 / g.interface_area_m2(h.detach())
    assert torch.allclose(dh, inv_area, rtol=1e-12, atol=0)
    step = 1e-6 * vt
    fd = (g.level_at_volume(v.detach() + step) - g.level_at_volume(v.detach() - step)) / (2 * step)
    assert torch.allclose(fd, inv_area, rtol=1e-6, atol=0)


@pytest.mark.parametrize("name", CASES)
def test_gradcheck_level_at_volume_wrt_volume_and_dims(name):
    cls, d = CASES[name]
    g0 = make(name)
    v = (torch.tensor([0.07, 0.31, 0.55, 0.93], dtype=F64) * g0.volume_m3).requires_grad_(True)
    keys = [k for k, x in d.items() if x > 0]  # a zero straight length cannot be perturbed below 0
    dims = [torch.tensor(d[k], dtype=F64, requires_grad=True) for k in keys]

    def f(v, *dims):
        return cls(**{**d, **dict(zip(keys, dims))}).level_at_volume(v)

    assert torch.autograd.gradcheck(f, (v, *dims), eps=1e-6, atol=1e-8, rtol=1e-6)


@pytest.mark.parametrize("name", CASES)
def test_gradcheck_wetted_areas_wrt_level_and_dims(name):
    cls, d = CASES[name]
    g0 = make(name)
    # away from the head/cylinder junctions so the finite-difference stencil stays in one piece
    h = (torch.tensor([0.05, 0.43, 0.61, 0.985], dtype=F64) * g0.height_m).requires_grad_(True)
    keys = [k for k, x in d.items() if x > 0]
    dims = [torch.tensor(d[k], dtype=F64, requires_grad=True) for k in keys]

    def f(h, *dims):
        return cls(**{**d, **dict(zip(keys, dims))}).wetted_areas_m2(h)

    assert torch.autograd.gradcheck(f, (h, *dims), eps=1e-6, atol=1e-8, rtol=1e-6)


@pytest.mark.parametrize("name", ["mhtb_heads", "hemi_heads", "prolate_heads", "oblate_spheroid"])
def test_derivatives_exactly_at_head_junctions(name):
    # piecewise shapes must not double-count the slope where two pieces meet
    g = make(name)
    r, a, lc = g.radius_m.item(), g.head_depth_m.item(), g.cylinder_length_m.item()
    h = torch.tensor([a, a + lc], dtype=F64, requires_grad=True)
    (dv,) = torch.autograd.grad(g.volume_at_level(h).sum(), h)
    wl, wv = g.wetted_areas_m2(h)
    (dwl,) = torch.autograd.grad(wl.sum(), h, retain_graph=True)
    (dwv,) = torch.autograd.grad(wv.sum(), h)
    assert dv.tolist() == pytest.approx([math.pi * r**2] * 2, rel=1e-12)
    assert dwl.tolist() == pytest.approx([2 * math.pi * r] * 2, rel=1e-12)
    assert dwv.tolist() == pytest.approx([-2 * math.pi * r] * 2, rel=1e-12)


@pytest.mark.parametrize("name", CASES)
def test_derivatives_at_half_height(name):
    g = make(name)
    h = (g.height_m / 2).clone().requires_grad_(True)
    (dv,) = torch.autograd.grad(g.volume_at_level(h), h)
    assert dv.item() == pytest.approx(ref_interface(name, h.item()), rel=1e-12)


def test_spheroid_zone_series_branch():
    # asin(sqrt u)/sqrt u (u > 0) and asinh(sqrt -u)/sqrt -u (u < 0) switch to a Taylor series for
    # |u| < 0.01; compare with a 40-term series C(2n, n) u^n / (4^n (2n + 1)) summed in float64.
    from tankode.geometry import _asin_over_x

    u = np.linspace(-0.03, 0.03, 601)
    ref = sum(math.comb(2 * n, n) / (4**n * (2 * n + 1)) * u**n for n in range(40))
    got = _asin_over_x(torch.tensor(u, dtype=F64)).numpy()
    assert np.allclose(got, ref, rtol=2e-16 * 8, atol=0)


def test_level_clamping_gradient_at_and_beyond_the_ends():
    # at H = 0 and H = height the one-sided slope is kept in full; beyond the ends it is 0
    g = VerticalCylinder(0.9, 2.2)
    h = torch.tensor([0.0, 2.2, -0.1, 2.5], dtype=F64, requires_grad=True)
    (dv,) = torch.autograd.grad(g.volume_at_level(h).sum(), h)
    assert dv.tolist() == pytest.approx([math.pi * 0.81, math.pi * 0.81, 0.0, 0.0], rel=1e-14)


def test_level_derivative_wrt_radius_is_implicit_function_derivative():
    # vertical cylinder: H = V / (pi R^2) -> dH/dR = -2 V / (pi R^3)
    r = torch.tensor(0.9, dtype=F64, requires_grad=True)
    g = VerticalCylinder(r, 2.2)
    h = g.level_at_volume(3.0)
    (dr,) = torch.autograd.grad(h, r)
    assert dr.item() == pytest.approx(-2 * 3.0 / (math.pi * 0.9**3), rel=1e-13)


# ---------------------------------------------------------------- broadcasting and batching
def test_broadcasting_rule():
    g = stack_geometries([Sphere(1.0), Sphere(2.0)])
    assert g.volume_at_level(0.5).shape == (2,)  # 0-d level for every tank
    per_tank = g.volume_at_level(torch.tensor([0.5, 1.0], dtype=F64))
    expected = torch.stack([Sphere(1.0).volume_at_level(0.5), Sphere(2.0).volume_at_level(1.0)])
    assert torch.allclose(per_tank, expected, rtol=1e-15, atol=0)
    h = torch.tensor([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]], dtype=F64)
    out = g.interface_area_m2(h)
    assert out.shape == (2, 3)
    assert torch.allclose(out[1], Sphere(2.0).interface_area_m2(h[1]))
    with pytest.raises(ValueError, match="leading axis"):
        g.volume_at_level(torch.zeros(3, dtype=F64))
    # unbatched geometry: ordinary broadcasting for any shape, float32 input promoted to float64
    s = Sphere(1.0)
    assert s.volume_at_level(torch.zeros(4, 5, dtype=torch.float32)).dtype == F64


def test_stack_mixed_shapes_rejected_and_unbind_roundtrip():
    with pytest.raises(ValueError, match="mixed shapes are not supported"):
        stack_geometries([Sphere(1.0), HorizontalCylinder(1.0, 2.0)])
    with pytest.raises(ValueError):
        stack_geometries([])
    g = stack_geometries([make("mhtb_heads"), stack_geometries([make("shallow_heads"), make("hemi_heads")])])
    assert g.batch_shape == (3,)
    specs = [x.to_spec() for x in g.unbind()]
    assert specs[0] == make("mhtb_heads").to_spec()
    with pytest.raises(ValueError, match="unbind"):
        g.to_spec()


def test_stack_keeps_autograd_to_dims():
    r = torch.tensor(0.9, dtype=F64, requires_grad=True)
    g = stack_geometries([VerticalCylinder(r, 2.2), VerticalCylinder(1.0, 2.0)])
    g.volume_m3.sum().backward()
    assert r.grad.item() == pytest.approx(2 * math.pi * 0.9 * 2.2, rel=1e-14)


def test_level_at_volume_range_check_with_tolerance():
    g = VerticalCylinder(0.9, 2.2)
    vt = g.volume_m3.item()
    # solver overshoot within rtol is clamped
    h = g.level_at_volume(torch.tensor([-1e-9 * vt, vt * (1 + 1e-9)], dtype=F64))
    assert h.tolist() == pytest.approx([0.0, 2.2], abs=1e-12)
    with pytest.raises(ValueError, match="outside"):
        g.level_at_volume(1.01 * vt)
    with pytest.raises(ValueError, match="outside"):
        g.level_at_volume(-0.01 * vt)
    with pytest.raises(ValueError, match="outside"):
        g.level_at_volume(float("nan"))


# ---------------------------------------------------------------- interchange format
def test_spec_roundtrip_and_passthrough_keys():
    for name in CASES:
        g = make(name)
        spec = g.to_spec()
        assert spec["shape"] in SHAPES
        g2 = geometry_from_spec(spec)
        assert type(g2) is type(g)
        assert g2.volume_m3.item() == pytest.approx(g.volume_m3.item(), rel=1e-15)
    spec = {"shape": "vertical_cylinder", "radius_m": 0.9, "height_m": 2.2, "wall_heat_capacity_J_per_K": 1e5,
            "volume_m3": math.pi * 0.81 * 2.2 * 1.009}
    assert isinstance(geometry_from_spec(spec), TankGeometry)  # 0.9 % off: accepted
    spec.update(volume_m3=None, wall_heat_capacity_J_per_K=None)  # null = not stated
    assert isinstance(geometry_from_spec(spec), VerticalCylinder)


def test_spec_unknown_shape_lists_valid_shapes():
    with pytest.raises(ValueError) as err:
        geometry_from_spec({"shape": "cone", "radius_m": 1.0})
    msg = str(err.value)
    assert "cone" in msg and all(s in msg for s in SHAPES)


def test_spec_negative_radius_names_key_and_range():
    with pytest.raises(ValueError, match=r"radius_m.*-0\.5.*\(0, inf\)"):
        geometry_from_spec({"shape": "sphere", "radius_m": -0.5})
    with pytest.raises(ValueError, match="head_aspect"):
        geometry_from_spec({"shape": "vertical_cylinder_elliptical_heads", "radius_m": 1.0,
                            "cylinder_length_m": 1.0, "head_aspect": 0.0})
    with pytest.raises(ValueError, match="height_m"):
        geometry_from_spec({"shape": "vertical_cylinder", "radius_m": 1.0, "height_m": True})
    with pytest.raises(ValueError, match="radius_m"):  # constructor checks too
        Sphere(torch.tensor([1.0, -1.0], dtype=F64))


def test_spec_missing_and_unknown_keys():
    with pytest.raises(ValueError, match=r"missing key 'cylinder_length_m'"):
        geometry_from_spec({"shape": "horizontal_cylinder", "radius_m": 1.0})
    with pytest.raises(ValueError, match=r"unknown spec key.*'height_m'"):
        geometry_from_spec({"shape": "sphere", "radius_m": 1.0, "height_m": 2.0})
    with pytest.raises(ValueError, match="no 'shape'"):
        geometry_from_spec({"radius_m": 1.0})


def test_spec_volume_mismatch_names_both_values():
    v_true = 4 / 3 * math.pi
    with pytest.raises(ValueError) as err:
        geometry_from_spec({"shape": "sphere", "radius_m": 1.0, "volume_m3": 4.3})
    msg = str(err.value)
    assert "4.3" in msg and f"{v_true:.6g}" in msg


def ref_contact_line(name, h):
    """Length of the liquid line on the wall: 2 pi r(h), or two lengths and two chords (horizontal)."""
    cls, d = CASES[name]
    if cls is HorizontalCylinder:
        R, L = d["radius_m"], d["cylinder_length_m"]
        chord = 2 * math.sqrt(max(R**2 - (R - h) ** 2, 0.0))
        return 2 * (L + chord) if chord > 0 else 0.0
    return 2 * math.pi * math.sqrt(max(ref_r2_and_half_dr2(name, h)[0], 0.0))


@pytest.mark.parametrize("name", CASES)
def test_contact_line_is_the_interface_perimeter(name):
    g = make(name)
    H = levels(g, 23, 0.01, 0.99)
    got = g.contact_line_m(H)
    want = torch.tensor([ref_contact_line(name, float(h)) for h in H], dtype=F64)
    assert torch.allclose(got, want, rtol=1e-10, atol=1e-10)
    # finite gradients everywhere, the ends included (where the line vanishes for a sphere)
    H = levels(g, 9).requires_grad_(True)
    line = g.contact_line_m(H)
    if line.requires_grad:  # (an upright cylinder's is a constant)
        (grad,) = torch.autograd.grad(line.sum(), H)
        assert torch.isfinite(grad).all()


@pytest.mark.parametrize("head_aspect", [2.0, 1.0, 0.7])
def test_the_wetted_wall_gained_per_metre_of_level_is_the_heads_meridian_integrand(head_aspect):
    """``wetted_area_slope_m`` of elliptical heads in closed form, ``2 pi R sqrt(1 - u)`` in a head
    and ``2 pi R`` along the straight part, against a central difference of the wetted area
    (oblate, hemispherical and prolate heads; levels through both heads and the cylinder)."""
    from tankode.geometry import VerticalCylinderEllipticalHeads

    g = VerticalCylinderEllipticalHeads(torch.tensor([1.5, 1.0], dtype=torch.float64),
                                        torch.tensor([2.0, 0.5], dtype=torch.float64),
                                        torch.tensor([head_aspect, head_aspect], dtype=torch.float64))
    H = torch.stack([torch.linspace(0.01, float(h) - 0.01, 300, dtype=torch.float64) for h in g.height_m])
    dH = 1e-5 * g.radius_m[:, None]
    central = (g.wetted_areas_m2(H + dH)[0] - g.wetted_areas_m2(H - dH)[0]) / (2 * dH)
    slope = g.wetted_area_slope_m(H)
    assert float(((slope - central).abs() / central).max()) < 1e-7
    a = g.head_depth_m[:, None]
    straight = (H > a + 1e-6) & (H < a + g.cylinder_length_m[:, None] - 1e-6)
    assert torch.allclose(slope[straight], (2 * math.pi * g.radius_m[:, None]).expand_as(H)[straight], rtol=1e-14)

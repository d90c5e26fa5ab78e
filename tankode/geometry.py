"""Tank geometry: volume, free-surface area and wetted wall areas as functions of the liquid level.

Four shapes of the interchange format are supported, all with a vertical symmetry plane at half
height (so the wall above level ``H`` equals the wall below level ``height - H``):

====================================  ===========================================================
``vertical_cylinder``                 ``radius_m``, ``height_m``; flat bottom and top.
``vertical_cylinder_elliptical_heads``  ``radius_m``, ``cylinder_length_m`` (straight part),
                                      ``head_aspect`` = radius / head depth (2.0 for 2:1 heads);
                                      one semi-ellipsoidal head at each end.
``sphere``                            ``radius_m``.
``horizontal_cylinder``               ``radius_m``, ``cylinder_length_m``; flat circular ends.
====================================  ===========================================================

Conventions
-----------
* float64 tensors throughout; every dimension is stored as a tensor of shape ``()`` (one tank) or
  ``(env,)`` (a batch of tanks of the same shape, see :func:`stack_geometries`).
* Broadcasting rule: a batched dimension of shape ``(env,)`` is aligned with the **leading** axis of
  the argument (``H_m`` or ``V_m3``); the argument's remaining axes broadcast. So ``H_m`` may be
  ``()`` (one level for every tank, result ``(env,)``), ``(env,)`` (one level per tank) or
  ``(env, n, ...)`` (``n`` levels per tank). For an unbatched geometry ordinary torch broadcasting
  applies to any argument shape.
* Levels are measured from the lowest point of the inner wall. ``volume_at_level``,
  ``interface_area_m2`` and ``wetted_areas_m2`` clamp levels to ``[0, height_m]`` (zero gradient
  outside); ``level_at_volume`` rejects volumes outside ``[0, volume_m3]`` beyond a tolerance.
* All methods are branch-free on tensor values (``torch.where``/``clamp``), differentiable with
  respect to the level/volume and to the dimensions. The only data-dependent Python checks are the
  range validations (constructor, ``level_at_volume``), which synchronise with the device.
"""

from __future__ import annotations

import math
import numbers
from typing import Any, ClassVar, Iterable, Mapping

import torch
from torch import Tensor

__all__ = [
    "TankGeometry",
    "VerticalCylinder",
    "VerticalCylinderEllipticalHeads",
    "Sphere",
    "HorizontalCylinder",
    "SHAPES",
    "geometry_from_spec",
    "stack_geometries",
]

_F64 = torch.float64

# Keys the interchange format may carry next to the dimensions; geometry ignores them
# (wall_heat_capacity_J_per_K belongs to the thermal model, volume_m3 is only cross-checked).
_PASSTHROUGH_KEYS = ("volume_m3", "wall_heat_capacity_J_per_K")

# A spec volume may deviate this much from the shape's volume (rounded published dimensions).
_SPEC_VOLUME_RTOL = 0.01

# Floor for the free-surface area in the implicit-derivative step of level_at_volume, relative to
# the mean cross-section volume/height. Only matters where A_i -> 0 (bottom/top of a sphere,
# horizontal cylinder or head), where dH/dV is truly infinite; the floor keeps it finite.
_AREA_FLOOR_REL = 1e-12

# Newton iterations for the horizontal cylinder (theta - sin(theta) = c). From the cubic starting
# guess the worst case over c in [0, pi] reaches machine precision in 4; 6 leaves margin.
_N_NEWTON_HCYL = 6


class _DimSpec:
    """Name, lower bound and unit of one shape dimension (for validation and error messages)."""

    def __init__(self, name: str, lower: float, inclusive: bool, unit: str, note: str = ""):
        self.name, self.lower, self.inclusive, self.unit, self.note = name, lower, inclusive, unit, note

    def allowed_range(self) -> str:
        lo = "[" if self.inclusive else "("
        text = f"{lo}{self.lower:g}, inf)"
        if self.unit:
            text += f" {self.unit}"
        if self.note:
            text += f" ({self.note})"
        return text

    def ok(self, value: Tensor) -> bool:
        finite = bool(torch.isfinite(value).all())
        above = bool((value >= self.lower).all()) if self.inclusive else bool((value > self.lower).all())
        return finite and above


class TankGeometry:
    """Base class of the tank shapes: derived sizes and level-dependent areas/volumes as tensors.

    Subclasses implement the four private kernels ``_volume_below``, ``_interface``,
    ``_wall_below`` and ``_level_from_volume`` on levels already clamped to ``[0, height_m]``; the
    public methods here handle dtype/device conversion, the batch broadcasting rule (see module
    docstring), clamping and the implicit-function derivative of :meth:`level_at_volume`.

    Plain Python object (not an ``nn.Module``): dimensions may be tensors that require grad (for
    estimating a geometry) and derived quantities are recomputed on access so they stay connected
    to them. Use :meth:`to` to move to another device.
    """

    shape: ClassVar[str] = ""
    _dim_specs: ClassVar[tuple[_DimSpec, ...]] = ()

    # ------------------------------------------------------------------ construction
    def __init__(self, **dims: Any):
        names = [d.name for d in self._dim_specs]
        if sorted(dims) != sorted(names):
            raise TypeError(f"{type(self).__name__} takes dimensions {names}, got {sorted(dims)}")
        device = next((v.device for v in dims.values() if isinstance(v, Tensor)), torch.device("cpu"))
        tensors = [_to_f64(dims[n], device) for n in names]
        try:
            tensors = list(torch.broadcast_tensors(*tensors))
        except RuntimeError as exc:
            shapes = {n: tuple(t.shape) for n, t in zip(names, tensors)}
            raise ValueError(f"{self.shape}: dimension shapes do not broadcast: {shapes}") from exc
        if tensors[0].ndim > 1:
            raise ValueError(
                f"{self.shape}: dimensions must be 0-d (one tank) or of shape (env,), "
                f"got shape {tuple(tensors[0].shape)}"
            )
        for spec, t in zip(self._dim_specs, tensors):
            if not spec.ok(t.detach()):
                raise ValueError(
                    f"{self.shape}: {spec.name} = {t.detach().cpu().tolist()} is out of range; "
                    f"allowed {spec.allowed_range()}"
                )
        self._dims: dict[str, Tensor] = dict(zip(names, tensors))

    # ------------------------------------------------------------------ basic attributes
    @property
    def dims(self) -> dict[str, Tensor]:
        """The defining dimensions by interchange-format key (tensors, shape ``()`` or ``(env,)``)."""
        return dict(self._dims)

    @property
    def batch_shape(self) -> torch.Size:
        """``()`` for one tank, ``(env,)`` for a batch."""
        return next(iter(self._dims.values())).shape

    @property
    def device(self) -> torch.device:
        return next(iter(self._dims.values())).device

    def to(self, device: torch.device | str) -> "TankGeometry":
        """Copy of this geometry with its dimensions on ``device`` (float64 kept)."""
        return type(self)(**{n: t.to(device) for n, t in self._dims.items()})

    @property
    def radius_m(self) -> Tensor:
        """Inner radius of the shell [m]."""
        return self._dims["radius_m"]

    @property
    def height_m(self) -> Tensor:
        """Total inner height from the lowest to the highest point of the wall [m]."""
        raise NotImplementedError

    @property
    def volume_m3(self) -> Tensor:
        """Total inner volume [m3]."""
        raise NotImplementedError

    @property
    def wall_area_m2(self) -> Tensor:
        """Total inner wall area including flat ends / heads [m2]."""
        raise NotImplementedError

    @property
    def aspect_ratio(self) -> Tensor:
        """``radius_m / height_m`` (dimensionless), the R/H used by heat-transfer closures.

        The same definition for every shape, with ``height_m`` the total inner height (heads
        included): vertical cylinder R/H; elliptical heads R/(L + 2R/head_aspect); sphere 0.5;
        horizontal cylinder 0.5 (its length is not represented; use ``cylinder_length_m``).
        """
        return self.radius_m / self.height_m

    # ------------------------------------------------------------------ public level functions
    def volume_at_level(self, H_m: Any) -> Tensor:
        """Liquid volume [m3] below level ``H_m`` [m] (clamped to ``[0, height_m]``).

        Args:
            H_m: level above the tank bottom [m]; shape ``()``, ``(env,)`` or ``(env, ...)``
                (see the module broadcasting rule).
        Returns:
            Volume [m3], shape = broadcast of ``H_m`` with the batch.
        """
        return self._volume_below(self._clamp_level(H_m))

    def interface_area_m2(self, H_m: Any) -> Tensor:
        """Free-surface (liquid-vapour interface) area [m2] at level ``H_m`` [m]; equals dV/dH.

        Levels are clamped to ``[0, height_m]``. Where the true derivative of the area is
        infinite (the area vanishes like sqrt at the bottom/top of a horizontal cylinder) its
        autograd derivative at exactly that point is 0.
        """
        return self._interface(self._clamp_level(H_m))

    def contact_line_m(self, H_m: Any) -> Tensor:
        """Length [m] of the line where the free surface meets the wall at level ``H_m`` [m].

        The perimeter of the interface: a circle for the upright shapes (``2 sqrt(pi A_i)``),
        two lengths and two chords for the horizontal cylinder. It is the width through which
        the wall conducts heat across the liquid line (``dry_wall_node``). 0 where the
        interface vanishes (an empty or full horizontal cylinder, the poles of a sphere).
        """
        return self._contact_line(self._clamp_level(H_m))

    def wetted_areas_m2(self, H_m: Any) -> tuple[Tensor, Tensor]:
        """Inner wall area [m2] in contact with liquid and with vapour at level ``H_m`` [m].

        Args:
            H_m: level above the tank bottom [m] (clamped to ``[0, height_m]``), shapes as in
                :meth:`volume_at_level`.
        Returns:
            ``(A_wall_liquid, A_wall_vapor)``, each shaped like the broadcast of ``H_m`` with the
            batch. The liquid part includes the bottom end/head; the two sum to ``wall_area_m2``
            (to rounding). At exactly ``H = 0`` or ``H = height`` the autograd derivative of the
            curved-wall zones may be 0 where the true one is infinite (horizontal cylinder).
        """
        h = self._clamp_level(H_m)
        # Every supported shape is symmetric about half height: the dry wall above h equals the
        # wetted wall below height - h, which keeps the vapour area accurate when it is small.
        # Both levels go through one kernel call along a trailing axis: the tensors are tiny,
        # so the right-hand side's cost is the number of operations, not their size.
        both = torch.stack(torch.broadcast_tensors(h, self._b(self.height_m, h) - h), dim=-1)
        return self._wall_below(both).unbind(-1)

    def wetted_area_slope_m(self, H_m: Any) -> Tensor:
        """d A_wall_liquid / dH [m] at level ``H_m`` [m], detached: the wetted wall gained per metre.

        A central difference of the wetted area (step 1e-4 of the radius, levels clamped) unless a
        shape gives it in closed form.
        """
        with torch.no_grad():
            H = torch.as_tensor(H_m, dtype=torch.float64)
            dH = 1e-4 * self._b(self.radius_m, H)
            return (self._wall_below(self._clamp_level(H + dH)) - self._wall_below(self._clamp_level(H - dH))) / (2 * dH)

    def level_at_volume(self, V_m3: Any, *, rtol: float = 1e-6) -> Tensor:
        """Liquid level [m] for liquid volume ``V_m3`` [m3]; inverse of :meth:`volume_at_level`.

        The value comes from a closed form (cylinder, sphere, heads: trigonometric root of the
        cap cubic) or a fixed number of Newton iterations (horizontal cylinder) evaluated without
        autograd. The result is then re-attached as ``H0 + (r - r.detach()) / A_i(H0)`` with
        ``r = V - V(H0)``: the value stays ``H0`` while autograd gives the implicit-function
        derivatives ``dH/dV = 1 / A_i(H)`` and ``dH/dθ = -(∂V/∂θ)(H) / A_i(H)`` for dimensions θ
        exactly. Higher-order derivatives through this function are not correct.

        Args:
            V_m3: liquid volume [m3], shapes as ``H_m`` in :meth:`volume_at_level`.
            rtol: volumes within ``[-rtol*V, (1+rtol)*V]`` (solver overshoot) are clamped to
                ``[0, V]`` for the value; outside that a ValueError is raised.
        Returns:
            Level above the tank bottom [m], in ``[0, height_m]``.
        Raises:
            ValueError: if any volume is NaN or outside ``[0, volume_m3]`` beyond ``rtol``.
        Limits:
            Where ``A_i -> 0`` (empty/full sphere, horizontal cylinder, headed tank) ``dH/dV`` is
            infinite; it is returned finite but huge (area floored at 1e-12 * volume/height).
        """
        v = self._as_arg(V_m3)
        v_total = self._b(self.volume_m3, v)
        tol = rtol * v_total
        ok = (v >= -tol) & (v <= v_total + tol)  # False for NaN as well
        if not bool(ok.all()):
            bad_v = v.detach().expand_as(ok)[~ok]
            raise ValueError(
                f"{self.shape}: level_at_volume got liquid volume(s) outside [0, tank volume] "
                f"(rtol={rtol:g}): {bad_v.flatten()[:5].cpu().tolist()} m3 "
                f"({int((~ok).sum())} bad); tank volume(s) "
                f"{self.volume_m3.detach().flatten()[:5].cpu().tolist()} m3"
            )
        v_clamped = torch.clamp(v, min=torch.zeros_like(v_total), max=v_total)
        with torch.no_grad():
            h0 = self._level_from_volume(v_clamped.detach())
        h0 = h0.detach()
        residual = v - self.volume_at_level(h0)
        area_floor = _AREA_FLOOR_REL * self._b(self.volume_m3 / self.height_m, h0)
        area = torch.clamp(self.interface_area_m2(h0), min=area_floor)
        return h0 + (residual - residual.detach()) / area

    # ------------------------------------------------------------------ interchange format
    def to_spec(self) -> dict[str, Any]:
        """Interchange-format dict ``{"shape": ..., <dims>: float, "volume_m3": float}`` (one tank).

        Raises:
            ValueError: for a batched geometry (use ``[g.to_spec() for g in geom.unbind()]``).
        """
        if self.batch_shape != torch.Size([]):
            raise ValueError(
                f"to_spec needs one tank, this {self.shape} geometry has batch shape "
                f"{tuple(self.batch_shape)}; use [g.to_spec() for g in geometry.unbind()]"
            )
        spec: dict[str, Any] = {"shape": self.shape}
        spec.update({n: float(t.detach()) for n, t in self._dims.items()})
        spec["volume_m3"] = float(self.volume_m3.detach())
        return spec

    def unbind(self) -> list["TankGeometry"]:
        """Split a batched geometry into unbatched ones (``[self]`` if already unbatched)."""
        if self.batch_shape == torch.Size([]):
            return [self]
        n = self.batch_shape[0]
        return [type(self)(**{k: t[i] for k, t in self._dims.items()}) for i in range(n)]

    def __repr__(self) -> str:
        args = ", ".join(f"{n}={t.detach().cpu().tolist()}" for n, t in self._dims.items())
        return f"{type(self).__name__}({args})"

    # ------------------------------------------------------------------ helpers
    def _as_arg(self, x: Any) -> Tensor:
        t = _to_f64(x, self.device)
        if len(self.batch_shape) == 1 and t.ndim >= 1 and t.shape[0] not in (1, self.batch_shape[0]):
            raise ValueError(
                f"{self.shape}: argument of shape {tuple(t.shape)} does not match the batch of "
                f"{self.batch_shape[0]} tanks; its leading axis must be env={self.batch_shape[0]} "
                "(or the argument 0-d)"
            )
        return t

    def _b(self, dim: Tensor, like: Tensor) -> Tensor:
        """Align a batch quantity of shape () or (env,) with the leading axis of ``like``."""
        if dim.ndim == 1 and like.ndim > 1:
            return dim.reshape(dim.shape + (1,) * (like.ndim - 1))
        return dim

    def _d(self, name: str, like: Tensor) -> Tensor:
        return self._b(self._dims[name], like)

    def _clamp_level(self, H_m: Any) -> Tensor:
        h = self._as_arg(H_m)
        h_top = self._b(self.height_m, h)
        # clamp (not maximum/minimum): at a tie its gradient goes fully to h.
        return torch.clamp(h, min=torch.zeros_like(h_top), max=h_top)

    # kernels, on levels already clamped to [0, height]; see subclasses
    def _volume_below(self, h: Tensor) -> Tensor:
        raise NotImplementedError

    def _interface(self, h: Tensor) -> Tensor:
        raise NotImplementedError

    def _wall_below(self, h: Tensor) -> Tensor:
        raise NotImplementedError

    def _contact_line(self, h: Tensor) -> Tensor:
        # upright shapes: the interface is a disc; sqrt kept away from 0 for autograd
        A = self._interface(h)
        return torch.where(A > 0.0, 2.0 * torch.sqrt(math.pi * torch.clamp(A, min=1e-30)), 0.0)

    def _level_from_volume(self, v: Tensor) -> Tensor:
        """Level for volumes already clamped to [0, volume]; called under no_grad."""
        raise NotImplementedError


# ====================================================================== shapes
class VerticalCylinder(TankGeometry):
    """Upright cylinder with flat bottom and top.

    Args:
        radius_m: inner radius [m], shape ``()`` or ``(env,)``.
        height_m: inner height [m], shape ``()`` or ``(env,)``.
    """

    shape = "vertical_cylinder"
    _dim_specs = (_DimSpec("radius_m", 0.0, False, "m"), _DimSpec("height_m", 0.0, False, "m"))

    def __init__(self, radius_m: Any, height_m: Any):
        super().__init__(radius_m=radius_m, height_m=height_m)

    @property
    def height_m(self) -> Tensor:
        return self._dims["height_m"]

    @property
    def volume_m3(self) -> Tensor:
        return math.pi * self.radius_m**2 * self.height_m

    @property
    def wall_area_m2(self) -> Tensor:
        r = self.radius_m
        return 2.0 * math.pi * r**2 + 2.0 * math.pi * r * self.height_m

    def _volume_below(self, h):
        return math.pi * self._d("radius_m", h) ** 2 * h

    def _interface(self, h):
        return math.pi * self._d("radius_m", h) ** 2 * torch.ones_like(h)

    def _wall_below(self, h):
        r = self._d("radius_m", h)
        return math.pi * r**2 + 2.0 * math.pi * r * h

    def _level_from_volume(self, v):
        return v / (math.pi * self._d("radius_m", v) ** 2)


class Sphere(TankGeometry):
    """Spherical tank.

    Args:
        radius_m: inner radius [m], shape ``()`` or ``(env,)``.
    """

    shape = "sphere"
    _dim_specs = (_DimSpec("radius_m", 0.0, False, "m"),)

    def __init__(self, radius_m: Any):
        super().__init__(radius_m=radius_m)

    @property
    def height_m(self) -> Tensor:
        return 2.0 * self.radius_m

    @property
    def volume_m3(self) -> Tensor:
        return 4.0 / 3.0 * math.pi * self.radius_m**3

    @property
    def wall_area_m2(self) -> Tensor:
        return 4.0 * math.pi * self.radius_m**2

    def _volume_below(self, h):
        r = self._d("radius_m", h)
        return math.pi * h**2 * (r - h / 3.0)

    def _interface(self, h):
        r = self._d("radius_m", h)
        return math.pi * h * (2.0 * r - h)

    def _wall_below(self, h):
        # Archimedes: a spherical zone's area depends only on its height.
        return 2.0 * math.pi * self._d("radius_m", h) * h

    def _level_from_volume(self, v):
        r = self._d("radius_m", v)
        return r * _cap_depth_fraction(v / self._b(self.volume_m3, v)) * 2.0


class VerticalCylinderEllipticalHeads(TankGeometry):
    """Upright cylinder closed by two semi-ellipsoidal (spheroidal) heads, bottom and top.

    Args:
        radius_m: inner radius of the shell [m], shape ``()`` or ``(env,)``.
        cylinder_length_m: length of the straight part [m] (0 gives a spheroid).
        head_aspect: radius / head depth (dimensionless); 2.0 for 2:1 heads, 1.0 hemispherical,
            > 1 oblate (shallow), < 1 prolate (deep) heads.
    Total height = cylinder_length_m + 2 * radius_m / head_aspect.
    """

    shape = "vertical_cylinder_elliptical_heads"
    _dim_specs = (
        _DimSpec("radius_m", 0.0, False, "m"),
        _DimSpec("cylinder_length_m", 0.0, True, "m"),
        _DimSpec("head_aspect", 0.0, False, "", "radius / head depth, 2.0 for 2:1 heads"),
    )

    def __init__(self, radius_m: Any, cylinder_length_m: Any, head_aspect: Any):
        super().__init__(radius_m=radius_m, cylinder_length_m=cylinder_length_m, head_aspect=head_aspect)
        # F(a), a whole head's meridian integral: a constant of the shape that every wetted-area
        # evaluation needs (three times); computed once, unless a dimension is being trained.
        self._head_F = None if any(t.requires_grad for t in self._dims.values()) else self._head_meridian()

    def _head_meridian(self) -> Tensor:
        a = self.head_depth_m
        return _spheroid_meridian_integral(a, a, self.head_aspect)

    def _F_head(self, like):
        return self._b(self._head_meridian() if self._head_F is None else self._head_F, like)

    @property
    def cylinder_length_m(self) -> Tensor:
        return self._dims["cylinder_length_m"]

    @property
    def head_aspect(self) -> Tensor:
        return self._dims["head_aspect"]

    @property
    def head_depth_m(self) -> Tensor:
        """Depth of one head, radius / head_aspect [m]."""
        return self.radius_m / self.head_aspect

    @property
    def height_m(self) -> Tensor:
        return self.cylinder_length_m + 2.0 * self.head_depth_m

    @property
    def volume_m3(self) -> Tensor:
        r, a = self.radius_m, self.head_depth_m
        return math.pi * r**2 * (self.cylinder_length_m + 4.0 / 3.0 * a)

    @property
    def wall_area_m2(self) -> Tensor:
        r = self.radius_m
        return 2.0 * math.pi * r * (self.cylinder_length_m + 2.0 * self._F_head(r))

    def _parts(self, like):
        r, k = self._d("radius_m", like), self._d("head_aspect", like)
        return r, self._d("cylinder_length_m", like), k, r / k

    def _volume_below(self, h):
        r, lc, k, a = self._parts(h)
        h_top = lc + 2.0 * a
        v_cap = lambda d: math.pi * k**2 * d**2 * (a - d / 3.0)  # noqa: E731  spheroid cap of depth d
        v_head = 2.0 / 3.0 * math.pi * r**2 * a
        # Select the piece with where(), not a sum of clamped pieces: at a junction every clamp
        # passes the gradient at the tie, so a sum would count dV/dH two or three times there.
        # in_top tests the same expression the top piece uses, so rounding cannot put a level in
        # the top piece with a dry depth just above a (where the wall's clamp would cut the slope)
        in_bottom, in_top = h <= a, h_top - h <= a
        v_total = self._b(self.volume_m3, h)
        return torch.where(
            in_bottom,
            v_cap(h),
            torch.where(in_top, v_total - v_cap(h_top - h), v_head + math.pi * r**2 * (h - a)),
        )

    def _interface(self, h):
        r, lc, k, a = self._parts(h)
        h_top = lc + 2.0 * a
        # distance to the nearer end, capped at the head depth (full radius in the straight part);
        # where() rather than minimum() so the tie at half height does not halve the gradient
        d = torch.clamp(torch.where(h <= 0.5 * h_top, h, h_top - h), max=a)
        return math.pi * k**2 * d * (2.0 * a - d)

    def _wall_below(self, h):
        r, lc, k, a = self._parts(h)
        h_top = lc + 2.0 * a
        f = lambda z: _spheroid_meridian_integral(z, a, k)  # noqa: E731
        F_a = self._F_head(h)
        # Clamped depths keep F's argument in [0, a] (sqrt(1 - u) is NaN beyond a prolate head's
        # tip) in the pieces where() discards; piece selection as in _volume_below.
        d_bottom = torch.clamp(h, max=a)
        d_top = torch.clamp(h_top - h, max=a)  # dry depth in the top head
        # z measured from a head's equator: the bottom-head zone is z in [-a, d - a] (F is odd),
        # the wetted part of the top head z in [0, a - d_top]. A level lies in one head at most,
        # so F is evaluated once, at that head's z (0 in the straight part, where it is unused).
        in_bottom, in_top = h <= a, h_top - h <= a
        f_z = f(torch.where(in_bottom, a - d_bottom, torch.where(in_top, a - d_top, torch.zeros_like(h))))
        bottom = F_a - f_z
        middle = F_a + (h - a)
        top = F_a + lc + f_z
        return 2.0 * math.pi * r * torch.where(in_bottom, bottom, torch.where(in_top, top, middle))

    def wetted_area_slope_m(self, H_m: Any) -> Tensor:
        """d A_wall_liquid / dH [m], detached, in closed form: ``2 pi R sqrt(1 - u)`` in a head, with
        ``u = (1 - k^2) (z / a)^2`` at the axial distance ``z`` of the level from the head's equator
        (``F'(z)`` of :func:`_spheroid_meridian_integral`), ``2 pi R`` along the straight part."""
        with torch.no_grad():
            h = self._clamp_level(H_m)
            r, lc, k, a = self._parts(h)
            h_top = lc + 2.0 * a
            z = torch.where(h <= a, a - h, torch.where(h_top - h <= a, h - lc - a, torch.zeros_like(h)))
            return 2.0 * math.pi * r * torch.sqrt(torch.clamp(1.0 - (1.0 - k**2) * (z / a) ** 2, min=0.0))

    def _level_from_volume(self, v):
        r, lc, k, a = self._parts(v)
        v_head = 2.0 / 3.0 * math.pi * r**2 * a
        v_cyl = math.pi * r**2 * lc
        # the same expression level_at_volume clamps against, so V = volume_m3 gives an empty
        # volume of exactly 0 (the cap depth is sqrt-sensitive to it near the apex)
        v_total = self._b(self.volume_m3, v)
        zero = torch.zeros_like(v_head)

        def cap_depth(v_cap):  # depth of a cap of volume v_cap <= v_head in one head
            return 2.0 * a * _cap_depth_fraction(v_cap / (2.0 * v_head))

        return (
            cap_depth(torch.clamp(v, max=v_head))
            + torch.clamp(v - v_head, min=zero, max=v_cyl) / (math.pi * r**2)
            + a
            - cap_depth(torch.clamp(v_total - v, min=zero, max=v_head))
        )


class HorizontalCylinder(TankGeometry):
    """Cylinder lying on its side with flat circular ends.

    Args:
        radius_m: inner radius [m], shape ``()`` or ``(env,)``.
        cylinder_length_m: inner length between the flat ends [m].
    Limits:
        The level inverse uses Newton on the central angle (6 fixed iterations, converged to
        ~1e-15 relative); the circular-segment formulas lose relative accuracy ~1e-16/theta^2
        below levels of ~1e-8 R.
    """

    shape = "horizontal_cylinder"
    _dim_specs = (_DimSpec("radius_m", 0.0, False, "m"), _DimSpec("cylinder_length_m", 0.0, False, "m"))

    def __init__(self, radius_m: Any, cylinder_length_m: Any):
        super().__init__(radius_m=radius_m, cylinder_length_m=cylinder_length_m)

    @property
    def cylinder_length_m(self) -> Tensor:
        return self._dims["cylinder_length_m"]

    @property
    def height_m(self) -> Tensor:
        return 2.0 * self.radius_m

    @property
    def volume_m3(self) -> Tensor:
        return math.pi * self.radius_m**2 * self.cylinder_length_m

    @property
    def wall_area_m2(self) -> Tensor:
        r = self.radius_m
        return 2.0 * math.pi * r * self.cylinder_length_m + 2.0 * math.pi * r**2

    def _lower_half(self, h, r):
        """Level mirrored into the lower half, a safe stand-in where it is 0, and the 0 mask.

        The central angle 4*asin(sqrt(h/2R)) has an infinite derivative at h = 0; evaluating it
        on a stand-in and selecting with where() keeps autograd free of inf*0 = NaN there.
        """
        upper = h > r
        h_low = torch.where(upper, 2.0 * r - h, h)
        empty = h_low <= 0.0
        h_safe = torch.where(empty, r, h_low)
        theta = 4.0 * torch.asin(torch.sqrt(h_safe / (2.0 * r)))  # central angle of the segment
        return upper, empty, theta

    def _volume_below(self, h):
        r, length = self._d("radius_m", h), self._d("cylinder_length_m", h)
        upper, empty, theta = self._lower_half(h, r)
        v_low = torch.where(empty, 0.0, 0.5 * r**2 * _theta_minus_sin(theta) * length)
        return torch.where(upper, math.pi * r**2 * length - v_low, v_low)

    def _interface(self, h):
        r, length = self._d("radius_m", h), self._d("cylinder_length_m", h)
        q = h * (2.0 * r - h)
        pos = q > 0.0
        chord = 2.0 * torch.sqrt(torch.where(pos, q, r**2))
        return torch.where(pos, chord, 0.0) * length

    def _contact_line(self, h):
        # the interface is a rectangle (length x chord): two wetted lines along the shell, one
        # chord on each flat end
        length = self._d("cylinder_length_m", h)
        A = self._interface(h)
        return torch.where(A > 0.0, 2.0 * (length + A / length), 0.0)

    def _wall_below(self, h):
        r, length = self._d("radius_m", h), self._d("cylinder_length_m", h)
        upper, empty, theta = self._lower_half(h, r)
        # wetted arc R*theta along the length, plus the two flat circular segments
        w_low = torch.where(empty, 0.0, r * theta * length + r**2 * _theta_minus_sin(theta))
        total = 2.0 * math.pi * r * length + 2.0 * math.pi * r**2
        return torch.where(upper, total - w_low, w_low)

    def _level_from_volume(self, v):
        r = self._d("radius_m", v)
        frac = v / self._b(self.volume_m3, v)
        upper = frac > 0.5
        # segment area R^2 (theta - sin theta)/2 = frac * pi R^2, solved in the lower half where
        # g(theta) = theta - sin(theta) - c is increasing and convex on [0, pi]
        c = 2.0 * math.pi * torch.where(upper, 1.0 - frac, frac)
        theta = (6.0 * c) ** (1.0 / 3.0)  # theta^3/6 <= theta - sin: starts left of the root
        for _ in range(_N_NEWTON_HCYL):
            slope = 2.0 * torch.sin(0.5 * theta) ** 2  # 1 - cos(theta) without cancellation
            moving = slope > 0.0  # only theta = 0 (empty/full tank, c = 0) has zero slope
            step = torch.where(moving, (_theta_minus_sin(theta) - c) / torch.where(moving, slope, 1.0), 0.0)
            # after the first (overshooting) step the iterate is right of the root and convexity
            # makes Newton monotone; pi is always right of the root for c <= pi
            theta = torch.clamp(theta - step, min=0.0, max=math.pi)
        h_low = 2.0 * r * torch.sin(0.25 * theta) ** 2
        return torch.where(upper, 2.0 * r - h_low, h_low)


# ====================================================================== math helpers
def _to_f64(x: Any, device: torch.device) -> Tensor:
    if isinstance(x, Tensor):
        return x.to(device=device, dtype=_F64)
    return torch.as_tensor(x, dtype=_F64, device=device)


def _theta_minus_sin(theta: Tensor) -> Tensor:
    """theta - sin(theta) without cancellation at small theta (Taylor series below 0.5)."""
    small = theta < 0.5
    if not bool(small.any()):  # the common case (a level off the very bottom or top): no series
        return theta - torch.sin(theta)
    t = torch.where(small, theta, 0.0)
    t2 = t * t
    # alternating series theta^3/3! - theta^5/5! + ... ; truncation < 1e-16 relative at 0.5
    series = t * t2 / 6.0
    inner = torch.ones_like(t2)
    for denom in (210.0, 156.0, 110.0, 72.0, 42.0, 20.0):  # (2n)(2n+1) of consecutive terms
        inner = 1.0 - t2 / denom * inner
    series = series * inner
    return torch.where(small, series, theta - torch.sin(theta))


def _cap_depth_fraction(frac: Tensor) -> Tensor:
    """Depth/(2a) of a spheroid cap holding ``frac`` of the full spheroid volume, frac in [0, 1].

    Root of the cap cubic x^3 - 3x + (4 frac - 2) = 0 with x = d/a - 1, written as
    d/a = 4 sin(alpha/3) sin((2 pi - alpha)/3), alpha = asin(sqrt(frac)), which is free of the
    cancellation of the textbook 1 + 2 cos(...) form near the bottom.
    """
    alpha = torch.asin(torch.sqrt(torch.clamp(frac, 0.0, 1.0)))
    return 2.0 * torch.sin(alpha / 3.0) * torch.sin((2.0 * math.pi - alpha) / 3.0)


_ASIN_SERIES = (1.0, 1.0 / 6.0, 3.0 / 40.0, 5.0 / 112.0, 35.0 / 1152.0, 63.0 / 2816.0, 231.0 / 13312.0)


def _asin_over_x(u: Tensor) -> Tensor:
    """asin(sqrt(u))/sqrt(u) for u < 1, continued as asinh(sqrt(-u))/sqrt(-u) for u < 0.

    Analytic in u; a Taylor series is used for |u| < 0.01 where the closed forms cancel. Both
    closed forms are evaluated on safe stand-ins so where() never sees NaN gradients.
    """
    small, pos, neg = u.abs() < 0.01, u >= 0.01, u <= -0.01
    out = torch.zeros_like(u)
    # Only the pieces some element needs are evaluated (a level in the straight part has u = 0;
    # an oblate head never has u > 0): on the right-hand side's tiny tensors each skipped
    # operation is time saved, and where() keeps the result and its gradient piecewise.
    if bool(small.any()):
        us = torch.where(small, u, 0.0)
        series = torch.zeros_like(us)
        for coef in reversed(_ASIN_SERIES):
            series = series * us + coef
        out = torch.where(small, series, out)
    if bool(pos.any()):
        u_pos = torch.where(pos, u, 0.5)
        out = torch.where(pos, torch.asin(torch.sqrt(u_pos)) / torch.sqrt(u_pos), out)
    if bool(neg.any()):
        u_neg = torch.where(neg, -u, 0.5)
        out = torch.where(neg, torch.asinh(torch.sqrt(u_neg)) / torch.sqrt(u_neg), out)
    return out


def _spheroid_meridian_integral(z: Tensor, a: Tensor, k: Tensor) -> Tensor:
    """F(z) = integral_0^z sqrt(1 - e t^2) dt, e = (a^2 - R^2)/a^4, for a spheroid of semi-axes R, a.

    The zone area of the spheroid between axial coordinates z1 < z2 (from the equator) is
    2 pi R (F(z2) - F(z1)). With u = e z^2 = (1 - k^2)(z/a)^2 and k = R/a this is
    F = z/2 (sqrt(1 - u) + asin(sqrt u)/sqrt u), valid for oblate (u <= 0) and prolate (0 <= u < 1)
    heads alike. z in [-a, a].
    """
    u = (1.0 - k**2) * (z / a) ** 2
    return 0.5 * z * (torch.sqrt(1.0 - u) + _asin_over_x(u))


# ====================================================================== registry and spec I/O
SHAPES: dict[str, type[TankGeometry]] = {
    cls.shape: cls for cls in (VerticalCylinder, VerticalCylinderEllipticalHeads, Sphere, HorizontalCylinder)
}


def _spec_number(shape: str, spec: _DimSpec | None, key: str, value: Any) -> float:
    rng = spec.allowed_range() if spec is not None else "(0, inf) m3"
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{shape}: spec key {key!r} must be a number in {rng}, got {value!r}")
    x = float(value)
    lower, inclusive = (spec.lower, spec.inclusive) if spec is not None else (0.0, False)
    if not math.isfinite(x) or x < lower or (x == lower and not inclusive):
        raise ValueError(f"{shape}: spec key {key!r} = {x!r} is out of range; allowed {rng}")
    return x


def geometry_from_spec(spec: Mapping[str, Any]) -> TankGeometry:
    """Build and validate a geometry from an interchange-format dict (one tank).

    Args:
        spec: ``{"shape": <name>, <dimension keys>: float, ...}``; ``volume_m3`` (cross-checked
            against the shape's volume within 1 %; None = not stated) and
            ``wall_heat_capacity_J_per_K`` (thermal model, ignored here) may also be present.
    Returns:
        An unbatched :class:`TankGeometry` of the named shape.
    Raises:
        ValueError: unknown shape (lists the valid ones), missing or unknown keys, non-numeric or
            out-of-range dimensions (names the key and its allowed range), volume mismatch > 1 %
            (names both values).
    """
    if not isinstance(spec, Mapping):
        raise TypeError(f"tank spec must be a mapping, got {type(spec).__name__}")
    valid = ", ".join(sorted(SHAPES))
    if "shape" not in spec:
        raise ValueError(f"tank spec has no 'shape' key; valid shapes: {valid}")
    shape = spec["shape"]
    cls = SHAPES.get(shape) if isinstance(shape, str) else None
    if cls is None:
        raise ValueError(f"unknown tank shape {shape!r}; valid shapes: {valid}")
    dim_specs = {d.name: d for d in cls._dim_specs}
    allowed = ["shape", *dim_specs, *_PASSTHROUGH_KEYS]
    unknown = sorted(str(k) for k in spec if k not in allowed)
    if unknown:
        raise ValueError(f"{shape}: unknown spec key(s) {unknown}; allowed keys: {allowed}")
    values = {}
    for name, d in dim_specs.items():
        if name not in spec:
            raise ValueError(f"{shape}: spec is missing key {name!r}; allowed range {d.allowed_range()}")
        values[name] = _spec_number(shape, d, name, spec[name])
    geometry = cls(**values)
    if spec.get("volume_m3") is not None:  # null means "not stated" in the interchange format
        v_spec = _spec_number(shape, None, "volume_m3", spec["volume_m3"])
        v_shape = float(geometry.volume_m3)
        if abs(v_shape - v_spec) > _SPEC_VOLUME_RTOL * v_spec:
            raise ValueError(
                f"{shape}: spec volume_m3 = {v_spec:.6g} m3 disagrees with the volume from its "
                f"dimensions, {v_shape:.6g} m3 ({abs(v_shape - v_spec) / v_spec:.2%} > "
                f"{_SPEC_VOLUME_RTOL:.0%})"
            )
    return geometry


def stack_geometries(geometries: Iterable[TankGeometry]) -> TankGeometry:
    """Batch geometries of one shape into one with a leading ``(env,)`` dimension.

    Unbatched inputs contribute one tank each, batched ones all of theirs (concatenated in order).
    Autograd connections to the input dimensions are kept; tensors go to the first one's device.

    Raises:
        ValueError: empty input, or mixed shapes (not supported in one batch).
    """
    geoms = list(geometries)
    if not geoms:
        raise ValueError("stack_geometries needs at least one geometry")
    classes = {type(g) for g in geoms}
    if len(classes) > 1:
        names = sorted({g.shape for g in geoms})
        raise ValueError(
            f"mixed shapes are not supported in one batch: got {names}; "
            "batch tanks of each shape separately"
        )
    cls = type(geoms[0])
    device = geoms[0].device
    dims = {
        name: torch.cat([g._dims[name].to(device).reshape(-1) for g in geoms])
        for name in geoms[0]._dims
    }
    return cls(**dims)

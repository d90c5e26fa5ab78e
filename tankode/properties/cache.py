"""Disk cache and in-process memo of fitted surrogates, so that import and simulation never refit.

File: ``$TANKODE_CACHE_DIR`` (else ``~/.cache/tankode``) / ``surrogate-<fluid>-<hash>.pt``, the
hash covering the fluid, ``Domain``, ``SurrogateConfig``, the CoolProp version, the file
format version and the source of the property modules (``tankode/properties/*.py``): any change
to those refits, so an upgraded tankode never reads a surrogate fitted by older fitting code
under the same settings (such a file had given a vapour pressure error of 5.7e-4 where a fresh
fit gives 7.4e-6). Files hold only tensors and plain python values
(``torch.save`` of ``Surrogate.state()``) and are read with ``torch.load(weights_only=True)``,
which refuses to unpickle arbitrary objects. Writes go to a temporary file then ``os.replace``,
so a crashed or concurrent fit never leaves a truncated cache file behind.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import warnings
from dataclasses import replace
from pathlib import Path

import CoolProp
import torch

from ..errors import BeyondPropertyDomain
from .config import SurrogateConfig
from .domain import Domain, covers, default_domain, hot_domain, low_domain, wide_domain
from .fit import FORMAT_VERSION, fit_surrogate
from .model import Surrogate

_MEMO: dict[tuple, Surrogate] = {}
# The fitting code's identity: the property modules' source (this cache module's own aside).
CODE_DIGEST = hashlib.sha256(b"".join(
    p.name.encode() + p.read_bytes() for p in sorted(Path(__file__).parent.glob("*.py")) if p.name != "cache.py"
)).hexdigest()[:16]


def cache_dir() -> Path:
    """Directory of cached surrogates: ``$TANKODE_CACHE_DIR`` or ``~/.cache/tankode``."""
    env = os.environ.get("TANKODE_CACHE_DIR")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "tankode"


def cache_key(fluid_name: str, domain: Domain, config: SurrogateConfig) -> str:
    """Hex digest identifying a fit: fluid, domain, config, CoolProp version, format version, and
    the property modules' source (``CODE_DIGEST``)."""
    payload = {
        "fluid": fluid_name, "domain": domain.as_dict(), "config": config.as_dict(),
        "coolprop": CoolProp.__version__, "format": FORMAT_VERSION, "code": CODE_DIGEST,
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:20]


def cache_path(fluid_name: str, domain: Domain, config: SurrogateConfig) -> Path:
    """Where ``load_surrogate`` reads/writes this fit."""
    return cache_dir() / f"surrogate-{fluid_name}-{cache_key(fluid_name, domain, config)}.pt"


def save_surrogate(surrogate: Surrogate, path: Path | str) -> None:
    """Atomically write ``surrogate.state()`` with ``torch.save``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name, suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            torch.save(surrogate.state(), fh)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def read_surrogate(path: Path | str) -> Surrogate:
    """Load a surrogate file written by ``save_surrogate`` (``weights_only=True``: no arbitrary code)."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
        return Surrogate.from_state(state)
    except Exception as err:
        raise RuntimeError(
            f"cannot read cached surrogate {path}: {err}. Delete the file to refit."
        ) from err


def load_surrogate(fluid_name: str = "ParaHydrogen", domain: Domain | None = None,
                   config: SurrogateConfig = SurrogateConfig()) -> Surrogate:
    """The surrogate for (fluid, domain, config): memoised in-process, cached on disk, else fitted.

    ``domain`` None is the fluid's default tier (``default_domain``).

    Same arguments (and cache directory) return the same object within a process. A missing
    cache file triggers ``fit_surrogate`` (~1-2 s) and writes the file (a warning if the directory
    is not writable); an unreadable one raises ``RuntimeError`` naming it (no silent refit over a
    file someone may be inspecting).
    """
    if domain is None:
        domain = default_domain(fluid_name)
    elif domain.fluid_name != fluid_name:
        domain = replace(domain, fluid_name=fluid_name)
    path = cache_path(fluid_name, domain, config)
    key = (fluid_name, domain, config, str(path))
    hit = _MEMO.get(key)
    if hit is not None:
        return hit
    if path.exists():
        surrogate = read_surrogate(path)
        if surrogate.fluid_name != fluid_name or surrogate.domain != domain:
            raise RuntimeError(f"cached surrogate {path} is for {surrogate.fluid_name} on {surrogate.domain}, "
                               f"expected {fluid_name} on {domain}; delete the file to refit")
    else:
        surrogate = fit_surrogate(fluid_name, domain, config)
        try:
            save_surrogate(surrogate, path)
        except OSError as err:
            # The fit itself is valid; only the cache is lost (every process will refit).
            warnings.warn(f"could not write the surrogate cache {path}: {err}; set TANKODE_CACHE_DIR to a "
                          f"writable directory to avoid refitting", UserWarning, stacklevel=2)
    _MEMO[key] = surrogate
    return surrogate


# The wide domain spans ~35 times the default's pressure range and the near-critical liquid:
# three times the RBF centres and more samples keep its held-out errors near the 0.1 % target
# (ParaHydrogen, 3000 points per phase: liquid p 7e-4, T_sat 1.5e-4, h_lsat 9e-4 of L).
WIDE_CONFIG = SurrogateConfig(n_centres=300, n_train=4000)
# The hot tier's vapour spans 3-350 K for hydrogen: with the wide tier's 300 centres its held-out
# errors are 0.35 % in p and 0.2 % in T, with 600 centres and twice the samples 0.2 % in both
# (a fit of 40 s on this machine, once per cache).
HOT_CONFIG = SurrogateConfig(n_centres=600, n_train=8000)


def property_tiers(fluid_name: str) -> tuple[tuple[Domain, SurrogateConfig, bool], ...]:
    """The domains tankode fits for ``fluid_name``, in the order a run is matched to them.

    Each entry is ``(domain, config, relative)``, ``relative`` the pressure room of
    ``domain.covers``: the default tier (storage pressures, the finest fit), the wide tier (2.5 %
    to 86 % of the critical pressure), the low tier (a third of the default's lowest pressure
    up to its highest: a vent below the default that the wide tier does not reach) and, where
    the wide tier's vapour stops short of 350 K (hydrogen, nitrogen), the hot tier (the wide
    tier's pressures, the vapour up to 350 K: warm-gas pressurisation with ambient gas).
    """
    tiers = ((default_domain(fluid_name), SurrogateConfig(), False), (wide_domain(fluid_name), WIDE_CONFIG, True),
             (low_domain(fluid_name), WIDE_CONFIG, True))
    hot = hot_domain(fluid_name)
    return tiers + (((hot, HOT_CONFIG, True),) if hot != tiers[1][0] else ())


def surrogate_covering(fluid_name: str, p_Pa=(), T_v_K=(), T_l_K=()) -> Surrogate:
    """The cached surrogate of the first of ``property_tiers`` whose domain holds the given states.

    Args:
        fluid_name: CoolProp fluid name.
        p_Pa, T_v_K, T_l_K: pressures and temperatures a run reaches (measured, initial), any
            iterables (``domain.covers``).

    Raises:
        BeyondPropertyDomain: the states lie beyond every tier (naming the ranges they span).
    """
    tiers = property_tiers(fluid_name)
    for domain, config, relative in tiers:
        if covers(domain, p_Pa, T_v_K, T_l_K, relative=relative):
            return load_surrogate(fluid_name, domain, config)
    ranges = " or ".join(f"pressure {d.p_min_Pa:.4g} to {d.p_max_Pa:.4g} Pa with vapour up to {d.T_v_max_K:.4g} K and "
                         f"liquid down to {d.T_l_min_K:.4g} K" for d, _, _ in tiers[1:])
    raise BeyondPropertyDomain(f"the run reaches states beyond tankode's widest {fluid_name} property domains "
                               f"({ranges}, with 5 % of each pressure and of the temperature range to spare)")


def clear_memo() -> None:
    """Forget the in-process memo (tests; the disk cache is untouched)."""
    _MEMO.clear()


__all__ = ["load_surrogate", "surrogate_covering", "property_tiers", "WIDE_CONFIG", "HOT_CONFIG", "save_surrogate", "read_surrogate", "cache_dir", "cache_path", "cache_key", "clear_memo"]

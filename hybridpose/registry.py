"""Name → factory for each role; third parties add backends through entry points.

Roles: ``object``, ``trajectory``, ``tracker``, ``regressor``, ``fusion``. A package can register
``name = "module:factory"`` under the entry-point group ``hybridpose.<role>``.
"""
from __future__ import annotations

import importlib
import logging
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Callable

log = logging.getLogger(__name__)

ROLES = ("object", "trajectory", "tracker", "regressor", "fusion")

# Modules whose import registers the built-in backends of each role (imported on first use so that
# `import hybridpose` stays light).
_BUILTIN_MODULES: dict[str, tuple[str, ...]] = {
    "object": ("hybridpose.objects.truss", "hybridpose.objects.parts"),
    "trajectory": ("hybridpose.render.trajectories",),
    "tracker": ("hybridpose.trackers.edges", "hybridpose.trackers.klt", "hybridpose.trackers.rapid",
                "hybridpose.trackers.combined"),
    "regressor": ("hybridpose.regressors.predictor",),
    "fusion": ("hybridpose.fusion.ukf", "hybridpose.fusion.passthrough", "hybridpose.fusion.isam2"),
}

_factories: dict[str, dict[str, Callable[..., Any]]] = {role: {} for role in ROLES}
_baselines: dict[str, set[str]] = {role: set() for role in ROLES}
_loaded: set[str] = set()


def _check_role(role: str) -> None:
    if role not in ROLES:
        raise ValueError(f"role: expected one of {ROLES}, got {role!r}")


def register(role: str, name: str, baseline: bool = False) -> Callable:
    """Decorator: ``@register("tracker", "edges")`` on a class or factory function. A ``baseline``
    stays buildable by name (:func:`create`; the benchmarks compare against it) but is not offered
    (:func:`available` leaves it out unless asked): it adds nothing over the backends that are."""
    _check_role(role)
    if baseline:
        _baselines[role].add(name)

    def deco(factory):
        existing = _factories[role].get(name)
        if existing is not None and existing is not factory:
            raise ValueError(f"{role} {name!r} is already registered by {existing!r}")
        _factories[role][name] = factory
        return factory

    return deco


def _load(role: str) -> None:
    if role in _loaded:
        return
    _loaded.add(role)
    for module in _BUILTIN_MODULES[role]:
        importlib.import_module(module)
    for ep in entry_points(group=f"hybridpose.{role}"):
        try:
            _factories[role].setdefault(ep.name, ep.load())
        except Exception:  # noqa: BLE001 — a broken plugin must not break the built-ins
            log.exception("could not load %s plugin %r from %s", role, ep.name, ep.value)


def available(role: str, baselines: bool = False) -> list[str]:
    """Sorted names registered for ``role``; with ``baselines``, the baselines too (:func:`register`)."""
    _check_role(role)
    _load(role)
    return sorted(n for n in _factories[role] if baselines or n not in _baselines[role])


def get(role: str, name: str) -> Callable[..., Any]:
    """The factory registered as ``name``; ValueError listing the known names otherwise."""
    _check_role(role)
    _load(role)
    try:
        return _factories[role][name]
    except KeyError:
        extra = sorted(_baselines[role] & set(_factories[role]))
        raise ValueError(f"unknown {role} {name!r}; available: {', '.join(available(role)) or 'none'}"
                         + (f" (baselines: {', '.join(extra)})" if extra else "")) from None


def create(role: str, name: str, **kwargs) -> Any:
    """Build the backend registered as ``name`` for ``role`` with keyword arguments."""
    return get(role, name)(**kwargs)


def is_checkpoint_path(name: str) -> bool:
    """Whether a regressor ``name`` means a trained checkpoint file rather than a registered name: not
    registered, and ending in ``.pt`` or naming an existing file."""
    return name not in available("regressor", baselines=True) and (Path(name).suffix == ".pt" or Path(name).is_file())


def create_regressor(name: str, **kwargs) -> Any:
    """The regressor registered as ``name``, or the one a checkpoint file (``runs/x/best.pt``, by
    :func:`is_checkpoint_path`) holds, with keyword arguments (``object``, ``threads``, …).
    FileNotFoundError for a checkpoint path that names no file."""
    if not is_checkpoint_path(name):
        return create("regressor", name, **kwargs)
    if not Path(name).is_file():
        raise FileNotFoundError(f"regressor: {name}: no such checkpoint file")
    from .regressors.predictor import CheckpointRegressor

    return CheckpointRegressor(name, **kwargs)

"""Name → factory for each role; third parties add backends through entry points.

Roles: ``object``, ``trajectory``, ``tracker``, ``regressor``, ``fusion``. A package can register
``name = "module:factory"`` under the entry-point group ``hybridpose.<role>``.
"""
from __future__ import annotations

import importlib
import logging
from importlib.metadata import entry_points
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
_loaded: set[str] = set()


def _check_role(role: str) -> None:
    if role not in ROLES:
        raise ValueError(f"role: expected one of {ROLES}, got {role!r}")


def register(role: str, name: str) -> Callable:
    """Decorator: ``@register("tracker", "rapid")`` on a class or factory function."""
    _check_role(role)

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


def available(role: str) -> list[str]:
    """Sorted names registered for ``role``."""
    _check_role(role)
    _load(role)
    return sorted(_factories[role])


def get(role: str, name: str) -> Callable[..., Any]:
    """The factory registered as ``name``; ValueError listing the known names otherwise."""
    _check_role(role)
    _load(role)
    try:
        return _factories[role][name]
    except KeyError:
        raise ValueError(f"unknown {role} {name!r}; available: {', '.join(available(role)) or 'none'}") from None


def create(role: str, name: str, **kwargs) -> Any:
    """Build the backend registered as ``name`` for ``role`` with keyword arguments."""
    return get(role, name)(**kwargs)

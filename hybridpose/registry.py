"""Name → factory for each role; third parties add backends through entry points.

Roles: ``object``, ``trajectory``, ``tracker``, ``regressor``, ``fusion``. A package can register
``name = "module:factory"`` under the entry-point group ``hybridpose.<role>``.
"""
from __future__ import annotations

import importlib
import inspect
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
    "regressor": ("hybridpose.regressors.no_network", "hybridpose.regressors.predictor"),
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


def unregister(role: str, name: str) -> None:
    """Remove the backend ``name`` of ``role`` (to register another factory under its name); KeyError
    naming it where none is registered."""
    _check_role(role)
    _load(role)
    if name not in _factories[role]:
        raise KeyError(f"{role} {name!r} is not registered (registered: {', '.join(sorted(_factories[role]))})")
    del _factories[role][name]
    _baselines[role].discard(name)


def rescan(role: str) -> list[str]:
    """Read the entry points of ``role`` again (a plugin installed after its first use, in a running
    notebook); the names already registered keep their factories. Returns the names it added."""
    _check_role(role)
    _load(role)
    return _load_plugins(role)


def _load(role: str) -> None:
    if role in _loaded:
        return
    _loaded.add(role)
    for module in _BUILTIN_MODULES[role]:
        importlib.import_module(module)
    _load_plugins(role)


def _load_plugins(role: str) -> list[str]:
    added = []
    for ep in entry_points(group=f"hybridpose.{role}"):
        if ep.name in _factories[role]:
            continue
        try:
            _factories[role][ep.name] = ep.load()
            added.append(ep.name)
        except Exception:  # noqa: BLE001 — a broken plugin must not break the built-ins
            log.exception("could not load %s plugin %r from %s", role, ep.name, ep.value)
    return added


def available(role: str, baselines: bool = False) -> list[str]:
    """Sorted names registered for ``role``; with ``baselines``, the baselines too (:func:`register`)."""
    _check_role(role)
    _load(role)
    return sorted(n for n in _factories[role] if baselines or n not in _baselines[role])


def get(role: str, name: str) -> Callable[..., Any]:
    """The factory registered as ``name``; ValueError listing the known names otherwise."""
    _check_role(role)
    factory = _find(role, name)
    if factory is None:
        extra = sorted(_baselines[role] & set(_factories[role]))
        raise ValueError(f"unknown {role} {name!r}; available: {', '.join(available(role)) or 'none'}"
                         + (f" (baselines: {', '.join(extra)})" if extra else ""))
    return factory


def _find(role: str, name: str) -> Callable[..., Any] | None:
    """The factory of ``name``, the built-in modules of ``role`` imported one at a time until one
    registers it (the networks' module imports torch, ~3 s, which ``none`` and the trackers do not
    need), then the plugins; None where nothing registers it."""
    if name not in _factories[role] and role not in _loaded:
        for module in _BUILTIN_MODULES[role]:
            importlib.import_module(module)
            if name in _factories[role]:
                break
        else:
            _load(role)
    return _factories[role].get(name)


def create(role: str, name: str, **kwargs) -> Any:
    """Build the backend registered as ``name`` for ``role`` with keyword arguments."""
    return get(role, name)(**kwargs)


def is_checkpoint_path(name: str) -> bool:
    """Whether a regressor ``name`` means a trained checkpoint file rather than a registered name: not
    registered, and ending in ``.pt`` or naming an existing file."""
    return _find("regressor", name) is None and (Path(name).suffix == ".pt" or Path(name).is_file())


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


def names(text: str) -> tuple[str, ...]:
    """``"a, b,,c"`` → ``("a", "b", "c")``."""
    return tuple(n.strip() for n in text.split(",") if n.strip())


def backend_options(items, factory, flag: str) -> dict:
    """``["explain=false", "lost_quality=0.4"]`` → keyword arguments of the backend ``factory`` (a
    callable or a dataclass of options), each value read as the type of that parameter's default
    (true/false, a number, a word, a comma list where the default is a tuple, ``none`` where the
    default is None); ValueError naming ``flag`` and
    the parameters it takes otherwise (the backend checks the values it is given)."""
    params = {k: p for k, p in inspect.signature(factory).parameters.items()
              if k not in ("self", "object") and p.default is not inspect.Parameter.empty}
    options = {}
    for item in items or ():
        key, _, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if key not in params or not value:
            raise ValueError(f"{flag}: expected NAME=VALUE with a name among {', '.join(params) or 'none'}, got {item!r}")
        default = params[key].default
        if value.lower() == "none" and (default is None or "None" in str(params[key].annotation)):
            options[key] = None
        elif isinstance(default, str):
            options[key] = value
        elif isinstance(default, tuple):
            options[key] = names(value)  # a comma list: modalities=texture,region
        elif isinstance(default, bool):
            if value.lower() not in ("true", "false", "1", "0"):
                raise ValueError(f"{flag}: {key}: expected true or false, got {value!r}")
            options[key] = value.lower() in ("true", "1")
        else:
            try:
                number = float(value)
            except ValueError:
                raise ValueError(f"{flag}: {key}: expected a number, got {value!r}") from None
            options[key] = int(number) if isinstance(default, int) and number.is_integer() else number
    return options

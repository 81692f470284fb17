"""Plugin discovery through entry points.

Every plugin kind is an entry-point group. Listing a group reads package metadata only, so
``guadal plugins`` imports nothing; a mission imports just the plugins it names. A name may
also be ``package.module:ClassName`` for a plugin that is not installed as a package (a file
on ``PYTHONPATH`` or beside the mission).
"""

from __future__ import annotations

import difflib
import importlib
import sys
from dataclasses import dataclass
from functools import cache
from importlib.metadata import entry_points

from .errors import GuadalError

#: plugin kind -> entry-point group
GROUPS = {
    "environment": "guadal.environments",
    "algorithm": "guadal.algorithms",
    "backend": "guadal.backends",
    "ground_truth": "guadal.ground_truths",
    "sensor": "guadal.sensors",
}


@dataclass(frozen=True)
class PluginInfo:
    """What the metadata says about one plugin, without importing it."""

    kind: str
    name: str
    target: str  # "module:attr"
    distribution: str
    version: str


def available(kind: str) -> dict[str, PluginInfo]:
    """All installed plugins of one kind, by name, read from package metadata only."""
    return dict(_available(kind))


@cache
def _available(kind: str) -> dict[str, PluginInfo]:
    # reading every installed package's metadata is slow: once per process is enough
    group = GROUPS[kind]
    found: dict[str, PluginInfo] = {}
    for ep in sorted(entry_points(group=group), key=lambda e: e.name):
        dist = getattr(ep, "dist", None)
        found.setdefault(
            ep.name,
            PluginInfo(
                kind=kind,
                name=ep.name,
                target=ep.value,
                distribution=dist.name if dist else "unknown",
                version=dist.version if dist else "unknown",
            ),
        )
    return found


def _import_target(target: str, kind: str, shown_name: str):
    module_name, _, attr = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise GuadalError(
            f"the {kind} plugin '{shown_name}' could not be imported from module '{module_name}': {exc}."
        ) from exc
    obj = module
    for part in attr.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError as exc:
            raise GuadalError(
                f"the {kind} plugin '{shown_name}' names '{attr}', which module "
                f"'{module_name}' does not define."
            ) from exc
    return obj


def load(kind: str, name: str):
    """The plugin class for ``name``, importing only that plugin.

    Unknown names get the list of known ones and the closest match.
    """
    if ":" in name:
        obj = _import_target(name, kind, name)
        obj.plugin_name = getattr(obj, "plugin_name", name)
        return obj
    known = available(kind)
    if name not in known:
        names = sorted(known)
        close = difflib.get_close_matches(name, names, n=1)
        hint = f" Did you mean '{close[0]}'?" if close else ""
        raise GuadalError(
            f"unknown {kind} '{name}' (known: {', '.join(names) or 'none installed'}; "
            f"or give 'module:Class').{hint}"
        )
    obj = _import_target(known[name].target, kind, name)
    obj.plugin_name = name
    return obj


def describe(kind: str, name: str) -> dict:
    """Name, source and version of a plugin, for the run manifest."""
    if ":" in name:
        module = name.partition(":")[0].split(".")[0]
        version = getattr(sys.modules.get(module), "__version__", "unknown")
        return {"name": name, "distribution": "local", "version": str(version)}
    info = available(kind)[name]
    return {"name": name, "distribution": info.distribution, "version": info.version}


def build_config(kind: str, section, where: str, name_key: str = "type"):
    """Resolve a ``{type: NAME, ...params}`` section: the plugin class and its validated config.

    ``where`` is the field path shown in errors (``environment.ground_truth``); ``name_key`` is
    the key that names the plugin (a backend is named by its ``level``, which stays among its
    settings).
    """
    from pydantic import ValidationError

    from .errors import explain_validation_error

    if isinstance(section, str):
        section = {"type": section}
    if not isinstance(section, dict) or name_key not in section:
        raise GuadalError(f"must be a mapping with a '{name_key}' naming the {kind}.", field=where)
    params = {k: v for k, v in section.items() if k != "type"}
    try:
        cls = load(kind, str(section[name_key]))
    except GuadalError as exc:
        raise exc.within(f"{where}.{name_key}") from None
    try:
        config = cls.Config(**params)
    except ValidationError as exc:
        raise GuadalError(explain_validation_error(exc, cls.Config, prefix=where)) from exc
    return cls, config

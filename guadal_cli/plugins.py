"""Plugin discovery through entry points.

Every plugin kind is an entry-point group, and has a contract: a base class in the ``base.py``
beside its built-in plugins (:data:`BASES`). Listing a group reads package metadata only, so
``guadal plugins`` imports nothing; a mission imports just the plugins it names, and each must
subclass its kind's base. A name may also be ``package.module:ClassName`` for a plugin that is
not installed as a package (a module on ``PYTHONPATH``).

Importing a module runs its top-level code, exactly as an installed plugin's entry point does:
so ``validate`` imports the one module a mission names and nothing else, and refuses names
from Python's standard library (no plugin lives there) before importing anything, so
``type: "this:x"`` prints no Zen of Python. Name only modules you trust, as with any import.
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

#: plugin kind -> the base class its plugins subclass (module:class, imported when needed)
BASES = {
    "environment": "guadal_cli.envs.base:Environment",
    "algorithm": "guadal_cli.planners.base:Planner",
    "backend": "guadal_cli.fleet.base:Backend",
    "ground_truth": "guadal_cli.envs.base:GroundTruth",
    "sensor": "guadal_cli.vehicle.base:Sensor",
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


def import_object(target: str, owner: str, noun: str = "plugin", example: str = "package.module:Class"):
    """The object ``module:attr`` names, for ``owner`` (how messages call it); one sentence on error.

    Used for plugins named by their import path and for policies given as ``module:function``.
    """
    module_name, _, attr = target.partition(":")
    if not module_name or (not attr and ":" in target):
        raise GuadalError(f"{owner} names no module and object; give '{example}'.")
    if module_name.split(".")[0] in sys.stdlib_module_names:
        raise GuadalError(
            f"{owner} names '{module_name}', a module of Python's standard library, which holds no "
            f"guadal {noun}; name the {noun}'s own module, as '{example}'."
        )
    try:
        obj = importlib.import_module(module_name)
    except (ImportError, ValueError, TypeError) as exc:  # '.x', '..': names that are no module
        raise GuadalError(f"{owner} could not be imported from module '{module_name}': {exc}.") from exc
    for part in attr.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError as exc:
            raise GuadalError(
                f"{owner} names '{attr}', which module '{module_name}' does not define."
            ) from exc
    return obj


def base_class(kind: str) -> type:
    """The contract every plugin of ``kind`` subclasses."""
    module_name, _, attr = BASES[kind].partition(":")
    return getattr(importlib.import_module(module_name), attr)


def _checked(obj, kind: str, shown_name: str) -> type:
    base = base_class(kind)
    if not (isinstance(obj, type) and issubclass(obj, base)):
        what = f"class {obj.__name__}" if isinstance(obj, type) else f"a {type(obj).__name__}"
        raise GuadalError(
            f"the {kind} plugin '{shown_name}' is {what}, not a subclass of "
            f"{base.__module__}.{base.__name__} (the {kind} contract)."
        )
    return obj


def load(kind: str, name: str) -> type:
    """The plugin class for ``name``, importing only that plugin and checking its contract.

    Unknown names get the list of known ones and the closest match.
    """
    if ":" in name:
        return _checked(import_object(name, f"the {kind} plugin '{name}'"), kind, name)
    known = available(kind)
    if name not in known:
        names = sorted(known)
        close = difflib.get_close_matches(name, names, n=1)
        hint = f" Did you mean '{close[0]}'?" if close else ""
        raise GuadalError(
            f"unknown {kind} '{name}' (known: {', '.join(names) or 'none installed'}; "
            f"or give 'module:Class').{hint}"
        )
    return _checked(import_object(known[name].target, f"the {kind} plugin '{name}'"), kind, name)


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


def config_union(
    kind: str, name_key: str = "type", shared: dict | None = None, name_required: bool = True
) -> tuple[dict, dict]:
    """JSON Schema of a ``{name_key: NAME, ...params}`` section: one branch per installed plugin
    (its ``Config``, with ``name_key`` fixed to its name), plus one for ``module:Class``.

    Returns ``(schema, defs)``; ``defs`` go into the document's ``$defs`` (prefixed per plugin,
    so two plugins' models of one name do not collide). ``shared`` are properties every branch
    accepts (an algorithm's ``mode``); without ``name_required`` a section may leave the name
    out (a backend's ``level`` defaults to ``sim``). Imports every installed plugin of ``kind``.
    """
    shared = shared or {}
    branches, defs = [], {}
    for name in available(kind):
        cls = load(kind, name)
        schema = cls.Config.model_json_schema(ref_template=f"#/$defs/{kind}.{name}.{{model}}")
        defs.update({f"{kind}.{name}.{key}": value for key, value in schema.pop("$defs", {}).items()})
        properties = {**shared, **schema.get("properties", {}), name_key: {"const": name}}
        required = sorted({name_key, *schema.get("required", [])} - (set() if name_required else {name_key}))
        branch = {**schema, "title": f"{kind} {name}", "properties": properties, "required": required}
        if schema.get("additionalProperties") is False:
            branch["additionalProperties"] = False
        branches.append(branch)
    branches.append(
        {
            "title": f"{kind} from a module",
            "properties": {name_key: {"type": "string", "pattern": r"^[A-Za-z_][\w.]*:[A-Za-z_][\w.]*$"}},
            "required": [name_key],
        }
    )
    if name_required:  # the name tells the branch: a discriminated union
        return {"oneOf": branches, "discriminator": {"propertyName": name_key}}, defs
    return {"anyOf": branches}, defs

"""The sweep file: a base mission, the axes that vary, the seeds, and how to run.

```yaml
name: lake_algorithms
base: lake_greedy.yaml            # a mission file (relative to this file), or the mission inline
grid:                             # every combination of these lists
  algorithm.type: [greedy, expected_improvement, lawnmower, random]
  fleet.vehicles: [1, 3]
zip:                              # lists of one length, taken together (row i with row i)
  environment.kernel.length_scale: [10, 20]
  environment.noise_std: [0.0, 0.1]
seeds: 1..20                      # 'A..B' (inclusive) or a list; sets each mission's seed
retries: 2                        # a failed combination is tried again on re-runs, this many times
workers: 2                        # local processes (default: one per core)
output: ../runs/sweeps/lake       # the sweep directory (default: sweeps/NAME beside this file)
dask: {scheduler: tcp://HOST:8786}  # run on a Dask distributed cluster instead
```

Axis keys are dotted paths into the mission (``a.b.c``; a number indexes a list). Relative paths
inside a combination (maps, ground-truth files) are taken from the base mission's folder, as
``guadal run`` would take them. Seeds vary slowest, so the first results already span every
group and an interrupted sweep leaves comparable groups.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from ..errors import GuadalError, explain_validation_error

#: mission keys a sweep decides itself, so an axis may not set them
_RESERVED = ("output.directory",)
_RANGE = re.compile(r"^\s*(\d+)\s*\.\.\s*(\d+)\s*$")


class DaskSection(BaseModel):
    model_config = ConfigDict(extra="forbid")
    scheduler: str = Field(min_length=1, description="Address of a Dask scheduler, e.g. tcp://HOST:8786.")


class SweepFile(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True)
    name: str | None = Field(
        default=None, pattern=r"^[A-Za-z0-9_.-]+$", description="Default: the file's stem."
    )
    base: str | dict = Field(description="Base mission: a mission file, or the mission inline.")
    grid: dict[str, list[Any]] = Field(default_factory=dict, description="Every combination of these lists.")
    zip_: dict[str, list[Any]] = Field(
        default_factory=dict, alias="zip", description="Lists of one length, taken together."
    )
    seeds: str | list[int] | None = Field(default=None, description="'A..B' or a list of seeds.")
    retries: int = Field(
        default=2, ge=0, description="Further attempts a failed combination gets on re-runs."
    )
    workers: int | None = Field(default=None, ge=1, description="Local worker processes (default: cores).")
    output: str | None = Field(default=None, description="Sweep directory, relative to this file.")
    dask: DaskSection | None = None

    @field_validator("grid", "zip_")
    @classmethod
    def _lists_not_empty(cls, value: dict):
        for key, values in value.items():
            if not values:
                raise ValueError(f"axis '{key}' has an empty list; give at least one value")
        return value


@dataclass
class Sweep:
    """A loaded sweep file: the base mission as data and the axes to vary."""

    path: Path
    name: str
    base: dict
    base_dir: Path  # relative paths inside every combination start here
    grid: dict[str, list]
    zip: dict[str, list]
    seeds: list[int] | None
    retries: int
    workers: int | None
    output: Path
    scheduler: str | None
    axes: list[str] = field(init=False)

    def __post_init__(self):
        self.axes = [*self.grid, *self.zip, *(["seed"] if self.seeds is not None else [])]

    def __len__(self) -> int:
        n = 1
        for values in self.grid.values():
            n *= len(values)
        if self.zip:
            n *= len(next(iter(self.zip.values())))
        return n * (len(self.seeds) if self.seeds is not None else 1)

    def combinations(self) -> Iterator[tuple[dict, dict]]:
        """``(values, mission)`` for every combination: the axis values and the mission they make."""
        grid_rows = list(itertools.product(*self.grid.values()))
        zip_rows = list(zip(*self.zip.values())) if self.zip else [()]
        for seed in self.seeds if self.seeds is not None else [None]:
            for grid_row in grid_rows:
                for zip_row in zip_rows:
                    values = dict(zip(self.grid, grid_row))
                    values.update(zip(self.zip, zip_row))
                    if seed is not None:
                        values["seed"] = seed
                    mission = self.base
                    for key, value in values.items():
                        mission = with_value(mission, key, value)
                    yield values, mission


def with_value(data: dict, dotted: str, value) -> dict:
    """A copy of ``data`` with ``a.b.c`` set; only the mappings along the path are copied."""
    parts = dotted.split(".")
    top = dict(data)
    node = top
    for i, part in enumerate(parts[:-1]):
        child = node[int(part)] if isinstance(node, list) else node.get(part)
        if child is None:
            child = {}
        elif isinstance(child, (dict, list)):
            child = type(child)(child)
        else:
            here = ".".join(parts[: i + 1])
            raise GuadalError(
                f"axis '{dotted}': '{here}' holds a single value ({child!r}), not a section; sweep '{here}' itself."
            )
        if isinstance(node, list):
            node[int(part)] = child
        else:
            node[part] = child
        node = child
    last = parts[-1]
    if isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value
    return top


#: seeds one sweep may list: a million missions is days of a cluster; more is a typo
MAX_SEEDS = 1_000_000


def parse_seeds(value) -> list[int] | None:
    if value is None or isinstance(value, list):
        if value is not None and not value:
            raise GuadalError("seeds: the list is empty; give 'A..B' (e.g. 1..100) or a list of integers.")
        if value is not None and any(s < 0 for s in value):
            raise GuadalError("seeds: seeds must be 0 or greater.")
        return value
    match = _RANGE.match(str(value))
    if not match or int(match[1]) > int(match[2]):
        raise GuadalError(
            f"seeds: give a range 'A..B' with A <= B (e.g. 1..100) or a list of integers (got {value!r})."
        )
    first, last = int(match[1]), int(match[2])
    if last - first + 1 > MAX_SEEDS:
        raise GuadalError(
            f"seeds: the range {first}..{last} holds {last - first + 1:,} seeds; one sweep takes at most {MAX_SEEDS:,}."
        )
    return list(range(first, last + 1))


def _check_axes(grid: dict, zipped: dict, seeds) -> None:
    keys = [*grid, *zipped]
    for key in keys:
        if not re.fullmatch(r"[A-Za-z0-9_]+(\.[A-Za-z0-9_]+)*", key):
            raise GuadalError(
                f"axis '{key}': give a dotted mission key such as algorithm.type or fleet.vehicles."
            )
        if key in _RESERVED or any(key.startswith(r + ".") for r in _RESERVED):
            raise GuadalError(f"axis '{key}': the sweep decides where runs are written; remove this axis.")
    clash = [
        k for k in keys if any(o != k and (o.startswith(k + ".") or k.startswith(o + ".")) for o in keys)
    ]
    if len(set(keys)) != len(keys) or clash:
        raise GuadalError(
            f"axes {', '.join(sorted(set(clash) or {k for k in keys if keys.count(k) > 1}))} overlap; "
            "each mission key may be swept by one axis only."
        )
    if seeds is not None and "seed" in keys:
        raise GuadalError("axis 'seed': sweep seeds with 'seeds:' only, not also as an axis.")
    lengths = {len(v) for v in zipped.values()}
    if len(lengths) > 1:
        shown = ", ".join(f"{k} ({len(v)})" for k, v in zipped.items())
        raise GuadalError(f"zip: its lists must have one length, to be taken together; got {shown}.")


def load_sweep(path: str | Path) -> Sweep:
    """Read and check a sweep file (its combinations are checked by :mod:`.plan`)."""
    from ..mission import read_mission_file

    path = Path(path)
    if not path.is_file():
        raise GuadalError(f"{path}: sweep file does not exist.")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise GuadalError(
            f"{path}: malformed YAML{where}: {getattr(exc, 'problem', None) or 'invalid'}."
        ) from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise GuadalError(f"{path}: cannot read the sweep file ({exc}).") from exc
    if not isinstance(data, dict):
        raise GuadalError(f"{path}: a sweep file must be a YAML mapping (base, grid, zip, seeds, ...).")
    try:
        spec = SweepFile.model_validate(data)
    except ValidationError as exc:
        raise GuadalError(f"{path}: {explain_validation_error(exc, SweepFile)}") from exc
    try:
        seeds = parse_seeds(spec.seeds)
        _check_axes(spec.grid, spec.zip_, seeds)
    except GuadalError as exc:
        raise GuadalError(f"{path}: {exc}") from exc
    folder = path.resolve().parent
    if isinstance(spec.base, str):
        base_path = Path(spec.base) if Path(spec.base).is_absolute() else folder / spec.base
        try:
            base = read_mission_file(base_path)
        except GuadalError as exc:
            raise GuadalError(f"{path}: base: {exc}") from exc
        base_dir = base_path.resolve().parent
    else:
        base, base_dir = spec.base, folder
    name = spec.name or re.sub(r"[^A-Za-z0-9_.-]+", "_", path.stem)
    output = Path(spec.output) if spec.output else Path("sweeps") / name
    return Sweep(
        path=path,
        name=name,
        base=base,
        base_dir=base_dir,
        grid=spec.grid,
        zip=spec.zip_,
        seeds=seeds,
        retries=spec.retries,
        workers=spec.workers,
        output=output if output.is_absolute() else folder / output,
        scheduler=spec.dask.scheduler if spec.dask else None,
    )

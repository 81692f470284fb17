"""Report tables: one row per run, one row per group, and the formats they are written in.

Values are the last row of each run's ``metrics.csv`` (so a killed run still has numbers);
group rows give mean and sample standard deviation across the group's runs, with the count.
Tables keep raw floats; rounding happens only where text is rendered for people.
"""

from __future__ import annotations

import csv
import html
import io
import math

import numpy as np

from .runs import Group, Run, map_labels

#: the general columns every run has, in table order (task metrics follow)
GENERAL_COLUMNS = ("total_distance", "time_s", "samples", "coverage")


def metric_names(runs: list[Run]) -> list[str]:
    """General columns, then every task metric any run recorded, in first-seen order."""
    names = list(GENERAL_COLUMNS)
    for run in runs:
        for name in run.task_metrics:
            if name not in names:
                names.append(name)
    return names


def run_table(runs: list[Run], metrics: list[str]) -> tuple[list[str], list[list]]:
    columns = ["run", "status", "algorithm", "seed", "map", "level", "vehicles", "steps", *metrics]
    maps = map_labels(runs)
    rows = []
    for r in runs:
        vehicles = r.manifest.get("vehicles")
        rows.append(
            [
                r.name,
                r.status,
                r.algorithm,
                r.seed,
                maps[id(r)],
                r.level,
                vehicles,
                r.steps,
                *(r.final(m) for m in metrics),
            ]
        )
    return columns, rows


def _mean_std(values: list[float]) -> tuple[float, float]:
    arr = np.asarray([v for v in values if not math.isnan(v)], dtype=float)
    if arr.size == 0:
        return math.nan, math.nan
    # one run has no spread to speak of: its std is left empty rather than written as 0
    return float(arr.mean()), float(arr.std(ddof=1)) if arr.size > 1 else math.nan


def group_table(
    groups: list[Group], group_fields: list[str], metrics: list[str]
) -> tuple[list[str], list[list]]:
    """Per group: its field values, status, run count, then ``<metric>_mean`` and ``<metric>_std``."""
    columns = [*group_fields, "status", "runs"]
    for m in metrics:
        columns += [f"{m}_mean", f"{m}_std"]
    rows = []
    for g in groups:
        counted = g.counted
        row = [*g.key, g.status, len(counted)]
        for m in metrics:
            row += list(_mean_std([r.final(m) for r in counted]))
        rows.append(row)
    return columns, rows


# --- rendering -----------------------------------------------------------------------------
def cell_text(value) -> str:
    """Numbers as people read them: 4 significant digits, integers whole, NaN blank."""
    if value is None:
        return ""
    if isinstance(value, float):
        if math.isnan(value):
            return ""
        if value.is_integer() and abs(value) < 1e9:
            return str(int(value))
        return format(value, ".4g")
    return str(value)


def folded(columns: list[str], rows: list[list]) -> tuple[list[str], list[list[str]]]:
    """A group table for people: ``x_mean`` and ``x_std`` become one ``x`` column 'mean ± std'."""
    out_cols: list[str] = []
    picks: list = []
    i = 0
    while i < len(columns):
        name = columns[i]
        if name.endswith("_mean") and i + 1 < len(columns) and columns[i + 1] == name[:-5] + "_std":
            out_cols.append(name[:-5])
            picks.append((i, i + 1))
            i += 2
        else:
            out_cols.append(name)
            picks.append(i)
            i += 1
    out_rows = []
    for row in rows:
        cells = []
        for p in picks:
            if isinstance(p, tuple):
                mean, std = row[p[0]], row[p[1]]
                if math.isnan(mean):
                    cells.append("")
                else:
                    cells.append(
                        cell_text(mean) if math.isnan(std) else f"{cell_text(mean)} ± {cell_text(std)}"
                    )
            else:
                cells.append(cell_text(row[p]))
        out_rows.append(cells)
    return out_cols, out_rows


def to_csv(columns: list[str], rows: list[list]) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(columns)
    for row in rows:
        writer.writerow(
            [
                ""
                if v is None or (isinstance(v, float) and math.isnan(v))
                else repr(v)
                if isinstance(v, float)
                else v
                for v in row
            ]
        )
    return buf.getvalue()


def to_records(columns: list[str], rows: list[list]) -> list[dict]:
    """Rows as JSON-ready objects (NaN becomes null, which JSON has and NaN is not)."""

    def clean(v):
        return None if isinstance(v, float) and math.isnan(v) else v

    return [{c: clean(v) for c, v in zip(columns, row)} for row in rows]


def to_markdown(columns: list[str], rows: list[list[str]]) -> str:
    def esc(text: str) -> str:
        return str(text).replace("|", "\\|")

    lines = ["| " + " | ".join(esc(c) for c in columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(esc(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def to_html(columns: list[str], rows: list[list[str]], status_column: str | None = "status") -> str:
    """An HTML table; rows whose status is not 'complete' get a class the page styles."""
    idx = columns.index(status_column) if status_column in columns else None
    head = "".join(f"<th>{html.escape(c)}</th>" for c in columns)
    body = []
    for row in rows:
        odd = idx is not None and row[idx] != "complete"
        cls = ' class="incomplete"' if odd else ""
        body.append(f"<tr{cls}>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def by_environment(
    columns: list[str], rows: list[list[str]], environments: list[str]
) -> list[tuple[str, list[str], list[list[str]]]]:
    """Rendered rows split by environment, each part without the columns it leaves empty.

    Environments record different task metrics, so one wide table of mostly empty cells
    becomes one readable table per environment.
    """
    parts: dict[str, list[list[str]]] = {}
    for env, row in zip(environments, rows):
        parts.setdefault(env, []).append(row)
    out = []
    for env, part in parts.items():
        keep = [i for i in range(len(columns)) if i == 0 or any(r[i] != "" for r in part)]
        out.append((env, [columns[i] for i in keep], [[r[i] for i in keep] for r in part]))
    return out

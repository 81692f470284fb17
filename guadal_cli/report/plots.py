"""Report figures: metric curves with seed bands, final maps, planned path against GPS track.

Figures are built on :class:`matplotlib.figure.Figure` directly (no pyplot), so nothing
global changes and no display is needed. Every figure is written as PNG and SVG.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure

from ..errors import GuadalError
from ..maps.format import LocalProjection, load_map
from .runs import Group, Run, file_stem

X_AXES = {"distance": ("total_distance", "fleet distance (m)"), "time": ("time_s", "mission time (s)")}
GRID_POINTS = 200
LAND = "#d8d4cc"
VEHICLE_COLOURS = colormaps["tab10"].colors


def save(fig: Figure, out_dir: Path, stem: str) -> list[Path]:
    """Write PNG and SVG; return both paths (PNG first)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / f"{stem}.png", out_dir / f"{stem}.svg"]
    fig.savefig(paths[0], dpi=110)
    fig.savefig(paths[1])
    return paths


def vehicle_colour(v: int):
    return VEHICLE_COLOURS[v % len(VEHICLE_COLOURS)]


# --- metric curves ---------------------------------------------------------------------------
def _curve(run: Run, x_col: str, metric: str) -> tuple[np.ndarray, np.ndarray] | None:
    x, y = run.metrics.get(x_col), run.metrics.get(metric)
    if x is None or y is None or len(x) == 0:
        return None
    ok = ~(np.isnan(x) | np.isnan(y))
    x, y = x[ok], y[ok]
    if len(x) == 0:
        return None
    # several steps can share an x (a vehicle waiting): keep the last value at each x
    last = np.r_[np.nonzero(np.diff(x))[0], len(x) - 1]
    return x[last], y[last]


def band(
    curves: list[tuple[np.ndarray, np.ndarray]], grid: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean, std and count per grid point over the curves that reach it (no extrapolation)."""
    stack = np.full((len(curves), len(grid)), np.nan)
    for i, (x, y) in enumerate(curves):
        inside = (grid >= x[0]) & (grid <= x[-1])
        stack[i, inside] = np.interp(grid[inside], x, y)
    count = np.sum(~np.isnan(stack), axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(stack, axis=0)
        std = np.where(count > 1, np.nanstd(stack, axis=0, ddof=1), 0.0)
    return mean, std, count


def group_curve(
    group: Group, x_col: str, metric: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int] | None:
    """A group's mean and std of ``metric`` on a grid of ``x_col``, and how many runs they average.

    The grid spans only what every run covers: past the end of the shortest run a mean would
    jump from n runs to fewer.
    """
    curves = [c for c in (_curve(r, x_col, metric) for r in group.counted) if c is not None]
    if not curves:
        return None
    grid = np.linspace(max(c[0][0] for c in curves), min(c[0][-1] for c in curves), GRID_POINTS)
    mean, std, _ = band(curves, grid)
    return grid, mean, std, len(curves)


def metric_curves(groups: list[Group], metric: str, x_axis: str, out_dir: Path) -> list[Path]:
    """One curve per group (mean over its runs) with a ±1 std band, against distance or time."""
    x_col, x_label = X_AXES[x_axis]
    fig = Figure(figsize=(6.4, 4.0), layout="constrained")
    ax = fig.add_subplot()
    drawn = 0
    for i, group in enumerate(groups):
        curve = group_curve(group, x_col, metric)
        if curve is None:
            continue
        grid, mean, std, n = curve
        colour = colormaps["tab10"].colors[i % 10]
        ax.plot(grid, mean, color=colour, label=f"{group.label} (n={n})")
        if n > 1:
            ax.fill_between(grid, mean - std, mean + std, color=colour, alpha=0.2, linewidth=0)
        drawn += 1
    if not drawn:
        return []
    ax.set_xlabel(x_label)
    ax.set_ylabel(metric)
    ax.set_title(f"{metric} against {x_axis} (mean ± std across runs, up to the shortest run)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small", loc="upper right")
    return save(fig, out_dir, f"metric_{file_stem(metric)}_vs_{x_axis}")


# --- maps ------------------------------------------------------------------------------------
@dataclass
class Grid:
    """Where a run's per-node values go on its map's grid (land stays NaN)."""

    shape: tuple[int, int]
    rows: np.ndarray
    cols: np.ndarray
    projection: LocalProjection | None

    def place(self, values: np.ndarray) -> np.ndarray:
        grid = np.full(self.shape, np.nan)
        grid[self.rows, self.cols] = values
        return grid


def run_grid(run: Run) -> Grid | None:
    """Cells of the run's nodes, indexed by node id, and the map's shape and projection.

    Rows and columns come from fields.csv (what the run used); a run killed before writing it
    falls back to the map file, whose water cells in row-major order are the node ids.
    """
    f = run.fields
    map_ = None
    if run.map_path:
        try:
            map_ = load_map(run.map_path)
        except GuadalError:
            map_ = None
    if "row" in f and len(f["row"]):
        rows, cols = f["row"].astype(int), f["col"].astype(int)
    elif map_ is not None and map_.water_nodes == run.manifest.get("map", {}).get(
        "water_nodes", map_.water_nodes
    ):
        rows, cols = np.nonzero(map_.mask)
    else:
        return None
    if map_ is not None:
        shape = map_.shape
    else:
        shape = tuple(run.manifest.get("map", {}).get("shape") or (int(rows.max()) + 1, int(cols.max()) + 1))
    shape = (max(shape[0], int(rows.max()) + 1), max(shape[1], int(cols.max()) + 1))
    return Grid(shape=shape, rows=rows, cols=cols, projection=map_.projection if map_ is not None else None)


def field_panels(run: Run) -> list[tuple[str, str]]:
    """(column, title) of the per-node fields to show: truth first, then the model's."""
    names = [c for c in run.fields if c not in ("node", "row", "col", "lat", "lon")]
    titles = {"ground_truth": "ground truth", "mean": "estimated mean", "std": "uncertainty (std)"}
    return [(n, titles.get(n, n)) for n in names]


def draw_field(ax, grid: Grid, values: np.ndarray, cmap: str, vmin=None, vmax=None):
    cm = colormaps[cmap].with_extremes(bad=LAND)
    image = ax.imshow(
        grid.place(values), cmap=cm, vmin=vmin, vmax=vmax, interpolation="nearest", origin="upper"
    )
    ax.set_xticks([])
    ax.set_yticks([])
    # show the water and a cell of shore around it, not the whole grid
    ax.set_xlim(grid.cols.min() - 1.5, grid.cols.max() + 1.5)
    ax.set_ylim(grid.rows.max() + 1.5, grid.rows.min() - 1.5)
    return image


def shared_limits(run: Run, column: str) -> tuple[float | None, float | None]:
    """Truth and mean share one colour scale so they can be compared by eye."""
    present = [run.fields[c] for c in ("ground_truth", "mean") if c in run.fields]
    if column in ("ground_truth", "mean") and present:
        vals = np.concatenate(present)
        vals = vals[~np.isnan(vals)]
        if vals.size:
            return float(vals.min()), float(vals.max())
    return None, None


def final_maps(run: Run, out_dir: Path) -> list[Path]:
    """Truth, mean and std at the end, with each vehicle's path, samples and final position."""
    grid = run_grid(run)
    panels = field_panels(run)
    if grid is None or not panels:
        return []
    plan = run.track("plan")
    cols = min(3, len(panels))  # truth, mean, std side by side; more fields wrap onto new rows
    rows_n = -(-len(panels) // cols)
    fig = Figure(figsize=(4.2 * cols, 3.2 * rows_n + 0.4), layout="constrained")
    for k, (column, title) in enumerate(panels):
        ax = fig.add_subplot(rows_n, cols, k + 1)
        vmin, vmax = shared_limits(run, column)
        cmap = "viridis" if column != "std" else "magma"
        image = draw_field(ax, grid, run.fields[column], cmap, vmin, vmax)
        fig.colorbar(image, ax=ax, fraction=0.035, pad=0.02)
        for v, rows in plan.items():
            colour = vehicle_colour(v)
            ax.plot(rows["col"], rows["row"], color=colour, linewidth=1.2, alpha=0.9, label=f"vehicle {v}")
            ax.plot(
                rows["col"][-1:],
                rows["row"][-1:],
                marker="X",
                markersize=10,
                color=colour,
                markeredgecolor="white",
                linestyle="none",
            )
        ax.set_title(title)
    if plan:
        fig.axes[0].legend(fontsize="x-small", loc="lower left")
    label = "" if run.complete else f" [{run.status}]"
    fig.suptitle(f"{run.name}: {run.algorithm}, seed {run.seed}{label}")
    return save(fig, out_dir, f"map_{file_stem(run.name)}")


# --- planned path against GPS ----------------------------------------------------------------
def _projection(run: Run, grid: Grid | None) -> LocalProjection:
    if grid is not None and grid.projection is not None:
        return grid.projection
    plan = run.track("plan")
    first = next(iter(plan.values()))
    return LocalProjection(float(first["lat"][0]), float(first["lon"][0]))


def distance_to_polyline(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Distance of each point (n, 2) to a polyline (m, 2), in the same units."""
    if len(line) == 1:
        return np.hypot(*(points - line[0]).T)
    a, b = line[:-1], line[1:]
    ab = b - a
    length2 = np.maximum((ab**2).sum(axis=1), 1e-12)
    out = np.empty(len(points))
    chunk = max(1, 2_000_000 // len(a))
    for start in range(0, len(points), chunk):
        p = points[start : start + chunk, None, :]
        t = np.clip(((p - a) * ab).sum(axis=2) / length2, 0.0, 1.0)
        nearest = a + t[..., None] * ab
        out[start : start + chunk] = np.sqrt(((p - nearest) ** 2).sum(axis=2)).min(axis=1)
    return out


def track_deviation(run: Run) -> dict[int, np.ndarray]:
    """Per vehicle, how far each GPS fix lay from the planned path (metres)."""
    plan, gps = run.track("plan"), run.track("gps")
    if not plan or not gps:
        return {}
    proj = _projection(run, run_grid(run))
    out = {}
    for v, fixes in gps.items():
        if v not in plan:
            continue
        line = np.column_stack(proj.to_xy(plan[v]["lat"], plan[v]["lon"]))
        pts = np.column_stack(proj.to_xy(fixes["lat"], fixes["lon"]))
        out[v] = distance_to_polyline(pts, line)
    return out


def gps_track(run: Run, out_dir: Path) -> list[Path]:
    """Planned node path against the GPS track per vehicle, in metres on the map's frame."""
    plan, gps = run.track("plan"), run.track("gps")
    if not plan or not gps:
        return []
    grid = run_grid(run)
    proj = _projection(run, grid)
    deviation = track_deviation(run)
    fig = Figure(figsize=(6.4, 5.2), layout="constrained")
    ax = fig.add_subplot()
    if grid is not None and grid.projection is not None:
        map_ = load_map(run.map_path)
        land = np.ma.masked_where(map_.mask, np.ones(map_.shape))
        ax.pcolormesh(
            map_.x,
            map_.y,
            land,
            shading="nearest",
            cmap=colormaps["Greys"].with_extremes(under=LAND, over=LAND),
            vmin=2,
            vmax=3,
        )
        water_x, water_y = map_.x[map_.mask], map_.y[map_.mask]
        pad = map_.cell_size_m * 2
        ax.set_xlim(water_x.min() - pad, water_x.max() + pad)
        ax.set_ylim(water_y.min() - pad, water_y.max() + pad)
    for v, rows in plan.items():
        colour = vehicle_colour(v)
        px, py = proj.to_xy(rows["lat"], rows["lon"])
        ax.plot(
            px,
            py,
            "--",
            color=colour,
            linewidth=1.0,
            marker="o",
            markersize=2.5,
            label=f"vehicle {v} planned",
        )
        if v in gps:
            gx, gy = proj.to_xy(gps[v]["lat"], gps[v]["lon"])
            dev = deviation.get(v)
            extra = f", mean {np.mean(dev):.1f} m off" if dev is not None and len(dev) else ""
            ax.plot(gx, gy, "-", color=colour, linewidth=1.4, alpha=0.8, label=f"vehicle {v} GPS{extra}")
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="x-small", loc="upper right")
    label = "" if run.complete else f" [{run.status}]"
    ax.set_title(f"{run.name}: planned path and GPS track{label}")
    return save(fig, out_dir, f"track_{file_stem(run.name)}")


def deviation_summary(run: Run) -> dict[str, float]:
    dev = track_deviation(run)
    if not dev:
        return {}
    allv = np.concatenate(list(dev.values()))
    return (
        {"gps_offtrack_mean_m": float(allv.mean()), "gps_offtrack_max_m": float(allv.max())}
        if allv.size
        else {}
    )

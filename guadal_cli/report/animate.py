"""A mission step by step, like the simulator's view: fields, trails, samples, vehicles as crosses.

Run directories keep only the final model, so the model at each frame is rebuilt by replaying the
recorded samples into a fresh copy of the run's environment (same plugin, same config, same
seed). Where that is impossible (plugin not installed, map gone) the frames show what the files
hold: the ground truth or the bare map, with the vehicles moving over it.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from PIL import Image

from .. import plugins
from ..errors import GuadalError
from ..fleet.base import Measurement
from ..graph import NavGraph
from ..maps.format import load_map
from .plots import draw_field, field_panels, run_grid, shared_limits, vehicle_colour
from .runs import Run, file_stem

MAX_FRAMES = 120
FPS = 8
DPI = 100
FORMATS = ("gif", "mp4")
TITLES = {
    "ground_truth": "ground truth",
    "mean": "estimated mean",
    "std": "uncertainty (std)",
    "water": "map",
}


def ffmpeg_available() -> bool:
    return shutil.which("ffmpeg") is not None


def frame_steps(last_step: int, max_frames: int = MAX_FRAMES) -> list[int]:
    """Steps to draw: every step when few, else evenly spaced, always first and last."""
    if last_step + 1 <= max_frames:
        return list(range(last_step + 1))
    return sorted({int(round(s)) for s in np.linspace(0, last_step, max_frames)})


class Replay:
    """A fresh environment of the run's kind that takes the recorded samples step by step."""

    def __init__(self, run: Run):
        section = run.mission.get("environment")
        if not isinstance(section, dict) or not run.map_path:
            raise GuadalError(f"run '{run.name}' has no environment section or map to replay.")
        self.graph = NavGraph(load_map(run.map_path))
        env_cls, env_cfg = plugins.build_config("environment", dict(section), "environment")
        self.env = env_cls(env_cfg, self.graph, base_dir=run.path)
        seed = int(run.seed or 0)
        env_seed = int(np.random.SeedSequence(seed).generate_state(2)[0])
        self.env.reset(env_seed)
        m = run.measurements
        self._steps = m.get("step", np.array([]))
        self._rows = [
            Measurement(
                vehicle=int(v), node=int(n), value=float(val), lat=float(la), lon=float(lo), time_s=float(t)
            )
            for v, n, val, la, lo, t in zip(
                m.get("vehicle", []),
                m.get("node", []),
                m.get("value", []),
                m.get("lat", []),
                m.get("lon", []),
                m.get("time_s", []),
            )
        ]
        self._done = 0

    def fields_at(self, step: int) -> dict[str, np.ndarray]:
        """The model after every sample up to and including ``step``."""
        upto = int(np.searchsorted(self._steps, step, side="right"))
        if upto > self._done:
            self.env.update(self._rows[self._done : upto])
            self._done = upto
        return {k: np.asarray(v, dtype=float) for k, v in self.env.observation_fields().items()}


class Scene:
    """The figure of one run's animation, laid out once; ``frame(step)`` redraws what changes.

    One panel per field (ground truth, then the replayed model's fields), each with its colour
    bar, the vehicles' trails and crosses, and the samples taken so far.
    """

    def __init__(self, run: Run, grid, plan: dict, replay: Replay | None, first: dict, truth):
        self.run, self.grid, self.plan, self.replay = run, grid, plan, replay
        panels = ["ground_truth"] if truth is not None else []
        panels += list(first)[: 3 - len(panels)]
        if not panels:
            panels = [c for c, _ in field_panels(run)][:1] or ["water"]
        self.panels = panels
        steps_col = plan[next(iter(plan))]["step"]
        self.last_step = int(np.nanmax(steps_col)) if len(steps_col) else 0
        self.fig = fig = Figure(figsize=(4.6 * max(1, len(panels)), 3.9), layout="constrained")
        self.images, self.trails, self.crosses, self.samples = [], [], [], []
        for k, column in enumerate(panels):
            ax = fig.add_subplot(1, len(panels), k + 1)
            if column == "ground_truth":
                static = truth
            elif column in first:
                static = first[column]  # the replayed model before any sample
            else:
                static = run.fields.get(column)  # no replay: the final field stays behind the vehicles
            vmin, vmax = shared_limits(run, column)
            if column in ("ground_truth", "mean") and vmin is None and truth is not None:
                vmin, vmax = float(np.nanmin(truth)), float(np.nanmax(truth))
            if column == "std" and replay is not None:
                vmin, vmax = 0.0, float(np.nanmax(first["std"])) or 1.0
            image = draw_field(
                ax,
                grid,
                static if static is not None else np.zeros(len(grid.rows)),
                "magma" if column == "std" else "viridis",
                vmin,
                vmax,
            )
            if column != "water":
                fig.colorbar(image, ax=ax, fraction=0.04, pad=0.02)
            self.images.append(image)
            ax.set_title(TITLES.get(column, column), fontsize="small")
            self.samples.append(
                ax.scatter([], [], s=4, c="white", edgecolors="black", linewidths=0.3, zorder=3)
            )
            for v in plan:
                (trail,) = ax.plot([], [], color=vehicle_colour(v), linewidth=1.0, alpha=0.9, zorder=4)
                (cross,) = ax.plot(
                    [],
                    [],
                    marker="x",
                    markersize=9,
                    markeredgewidth=2.2,
                    color=vehicle_colour(v),
                    linestyle="none",
                    zorder=5,
                )
                self.trails.append((v, trail))
                self.crosses.append((v, cross))
        # room for the longest title
        self.title = fig.suptitle(f"{run.name} ({run.algorithm}): step {self.last_step}, 0000 m")
        self.canvas = FigureCanvasAgg(fig)
        fig.set_dpi(DPI)
        self.canvas.draw()
        fig.set_layout_engine("none")  # lay out once; every frame has the same furniture

    def frame(self, step: int) -> np.ndarray:
        """The picture (RGB array) after ``step``."""
        run, grid = self.run, self.grid
        if self.replay is not None:
            fields = self.replay.fields_at(step)
            for column, image in zip(self.panels, self.images):
                if column in fields:
                    image.set_data(grid.place(fields[column]))
        meas_steps = run.measurements.get("step", np.array([]))
        taken = run.measurements.get("node", np.array([])).astype(int)[meas_steps <= step]
        offsets = np.column_stack([grid.cols[taken], grid.rows[taken]]) if len(taken) else np.empty((0, 2))
        for scatter in self.samples:
            scatter.set_offsets(offsets)
        for (v, trail), (_, cross) in zip(self.trails, self.crosses):
            rows = self.plan[v]
            upto = rows["step"] <= step
            trail.set_data(rows["col"][upto], rows["row"][upto])
            cross.set_data(rows["col"][upto][-1:], rows["row"][upto][-1:])
        distance = run.metrics.get("total_distance", np.array([]))
        at = np.searchsorted(run.metrics.get("step", np.array([])), step, side="right") - 1
        dist = f", {distance[at]:.0f} m" if 0 <= at < len(distance) else ""
        self.title.set_text(f"{run.name} ({run.algorithm}): step {step}{dist}")
        self.canvas.draw()
        return np.asarray(self.canvas.buffer_rgba())[..., :3].copy()


def scene(run: Run) -> tuple[Scene | None, str | None]:
    """The run's animation figure, or None; and a warning sentence if it is degraded."""
    grid = run_grid(run)
    plan = run.track("plan")
    if grid is None or not plan:
        return None, f"run '{run.name}' has no trajectory or fields to animate."
    warning = None
    try:
        replay: Replay | None = Replay(run)
        first = replay.fields_at(-1)
    except Exception as exc:  # any plugin failure only degrades the picture
        replay, first = None, {}
        warning = f"run '{run.name}': the model could not be replayed ({exc}); the animation shows the vehicles only."
    truth = run.fields.get("ground_truth")
    if truth is None and replay is not None and replay.env.ground_truth is not None:
        truth = np.asarray(replay.env.ground_truth, dtype=float)  # a killed run wrote no fields.csv
    return Scene(run, grid, plan, replay, first, truth), warning


def animate(
    run: Run, out_dir: Path, fmt: str = "gif", max_frames: int = MAX_FRAMES
) -> tuple[Path | None, str | None]:
    """Write ``animation_<run>.<fmt>``; return its path and a warning sentence if it is degraded."""
    built, warning = scene(run)
    if built is None:
        return None, warning
    path = out_dir / f"animation_{file_stem(run.name)}.{fmt}"
    out_dir.mkdir(parents=True, exist_ok=True)
    frames = [built.frame(step) for step in frame_steps(built.last_step, max_frames)]
    (write_gif if fmt == "gif" else write_mp4)(frames, path)
    return path, warning


def write_gif(frames: list[np.ndarray], path: Path) -> None:
    """One palette for all frames (from the last, which shows the most), no dithering: small and quick."""
    images = [Image.fromarray(f) for f in frames]
    palette = images[-1].quantize(colors=128, method=Image.Quantize.MEDIANCUT)
    quantized = [im.quantize(palette=palette, dither=Image.Dither.NONE) for im in images]
    quantized[0].save(path, save_all=True, append_images=quantized[1:], duration=1000 // FPS, loop=0)


def write_mp4(frames: list[np.ndarray], path: Path) -> None:
    """Raw RGB frames piped to ffmpeg as H.264 (even frame sizes, as the codec needs)."""
    h, w = frames[0].shape[0] // 2 * 2, frames[0].shape[1] // 2 * 2
    cmd = [
        shutil.which("ffmpeg") or "ffmpeg",
        "-y",
        "-loglevel",
        "error",
        "-f",
        "rawvideo",
        "-pix_fmt",
        "rgb24",
        "-s",
        f"{w}x{h}",
        "-r",
        str(FPS),
        "-i",
        "-",
        "-pix_fmt",
        "yuv420p",
        "-vcodec",
        "libx264",
        str(path),
    ]
    data = b"".join(np.ascontiguousarray(f[:h, :w]).tobytes() for f in frames)
    result = subprocess.run(cmd, input=data, capture_output=True, check=False)
    if result.returncode != 0:
        raise GuadalError(
            f"ffmpeg could not write '{path}': {result.stderr.decode(errors='replace').strip()[:300]}"
        )

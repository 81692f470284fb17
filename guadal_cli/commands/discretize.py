"""``guadal discretize``: a satellite image, a grid mask or a lake outline -> a guadal map."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer

from ..console import console, flags, print_json, print_mapping
from ..errors import GuadalError

_HELP = (
    "Turn an image (PNG, JPEG, TIFF), a grid mask (CSV/TXT) or a GeoJSON outline into a guadal map.\n\n"
    "Images need their corners (--bounds) or a world file beside them (.pgw, .jgw, .tfw). "
    "Water in an image: white in a grey mask, 'index>0.1' in a colour photo (index = (B-R)/(B+R)), "
    "or your own rule with --water-color or --threshold. See docs/discretize.md."
)

#: the library's parameter names (DiscretizeOptions, WaterRule, the sources), as this command's flags
_FLAGS = {
    "bounds": "--bounds",
    "water_color": "--water-color",
    "threshold": "--threshold",
    "tolerance": "--tolerance",
    "cell_size_m": "--cell-size",
    "min_fraction": "--min-fraction",
    "supersample": "--supersample",
    "margin_m": "--margin",
    "fill_holes_m2": "--fill-holes",
}

app = typer.Typer()


@app.command("discretize", help=_HELP)
def discretize_map(
    source: Annotated[
        Path, typer.Argument(help="Image (.png .jpg .tif), grid mask (.csv .txt) or outline (.geojson).")
    ],
    output: Annotated[Path, typer.Option("--output", "-o", help="Map file to write (JSON).")],
    cell_size: Annotated[
        float | None,
        typer.Option(
            help="Side of the square cells, in metres (default for a grid mask with --latlon-grid: its own cell size)."
        ),
    ] = None,
    bounds: Annotated[
        str | None, typer.Option(help="Image corners: north,south,east,west in degrees.")
    ] = None,
    water_color: Annotated[str | None, typer.Option(help="Water's colour, R,G,B (0-255) or #RRGGBB.")] = None,
    tolerance: Annotated[
        float | None,
        typer.Option(help="Largest RGB distance from --water-color that is still water (default 40)."),
    ] = None,
    threshold: Annotated[
        str | None,
        typer.Option(
            help="Water rule CHANNEL OP VALUE, e.g. 'blue>120', 'index>0.2' (channels: red green blue gray index)."
        ),
    ] = None,
    invert: Annotated[
        bool,
        typer.Option("--invert", help="Swap water and land of the image rule (e.g. black = water masks)."),
    ] = False,
    water_value: Annotated[
        float | None,
        typer.Option(help="Grid masks: the value that means water (default 1; 0 for inverted files)."),
    ] = None,
    delimiter: Annotated[
        str | None,
        typer.Option(
            help="Grid masks: the cell separator, ',' ';' 'tab' or 'space' (default: read from the first row)."
        ),
    ] = None,
    latlon_grid: Annotated[
        Path | None, typer.Option(help="Grid masks: \"lat,lon\" per cell centre or corner, ';'-separated.")
    ] = None,
    min_fraction: Annotated[
        float, typer.Option(help="A cell is water when at least this fraction of its area is water.")
    ] = 0.5,
    largest_body: Annotated[
        bool, typer.Option("--largest-body", help="Keep only the largest connected body of water.")
    ] = False,
    margin: Annotated[
        float, typer.Option(help="Keep only cells whose centre is at least this many metres from the shore.")
    ] = 0.0,
    fill_holes: Annotated[
        float | None,
        typer.Option(
            help="Fill islands and land pockets smaller than this many m² (default: half a cell; 0 keeps every one)."
        ),
    ] = None,
    supersample: Annotated[
        int, typer.Option(help="Samples per cell side used to measure each cell's water fraction.")
    ] = 8,
    name: Annotated[str | None, typer.Option(help="Map name (default: the output file's name).")] = None,
    preview: Annotated[
        Path | None, typer.Option(help="Preview PNG to write (default: OUTPUT with .png).")
    ] = None,
    no_preview: Annotated[bool, typer.Option("--no-preview", help="Do not write a preview.")] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
) -> None:
    from ..maps.discretize import DiscretizeOptions, discretize
    from ..maps.sources import open_source
    from ..maps.water_rules import WaterRule

    target = _check_output(output)
    preview_path = None if no_preview else (preview or target.with_suffix(".png"))
    if preview_path is not None and preview_path.resolve() == target.resolve():
        raise GuadalError("--preview and --output name the same file; give the preview a .png name.")
    image_options = tuple(
        flag
        for flag, given in (
            ("--water-color", water_color),
            ("--threshold", threshold),
            ("--invert", invert),
        )
        if given
    )
    if tolerance is not None and not water_color:
        raise GuadalError("--tolerance goes with --water-color (the largest RGB distance from that colour).")
    with flags(_FLAGS):
        rule = WaterRule.from_options(
            water_color, 40.0 if tolerance is None else tolerance, threshold, invert
        )
        src = open_source(
            source,
            bounds=bounds,
            rule=rule,
            water_value=water_value,
            latlon_grid=latlon_grid,
            delimiter=delimiter,
            image_only_options=image_options,
        )
        options = DiscretizeOptions(
            cell_size_m=cell_size,
            min_fraction=min_fraction,
            supersample=supersample,
            margin_m=margin,
            fill_holes_m2=fill_holes,
            largest_body=largest_body,
        )
        result = discretize(src, options, name=name or target.stem, description=_describe(src, options))
    _write(result, target, preview_path)
    summary = result.summary()
    summary.update({"output": str(target), "preview": str(preview_path) if preview_path else None})
    if as_json:
        print_json({**summary, "notes": result.notes})
        return
    print_mapping(f"map {target}", summary)
    for note in result.notes:
        console.print(f"[yellow]note:[/] {note}")


def _check_output(output: Path) -> Path:
    if output.exists() and output.is_dir():
        raise GuadalError(
            f"--output '{output}' is a folder; give the map file's name (e.g. {output}/lake.json)."
        )
    if not output.parent.is_dir():
        raise GuadalError(f"--output '{output}': folder '{output.parent}' does not exist.")
    return output


def _describe(src, options) -> str:
    parts = [f"Discretized from {src.path.name} ({src.kind}; water: {src.rule}; georeference: {src.georef})"]
    parts.append(f"cells at least {options.min_fraction:.0%} water")
    if options.fill_holes_m2 is not None:
        parts.append(f"holes under {options.fill_holes_m2:g} m² filled")
    if options.margin_m:
        parts.append(f"{options.margin_m:g} m margin from the shore")
    if options.largest_body:
        parts.append("largest body only")
    return "; ".join(parts) + "."


def _write(result, target: Path, preview_path: Path | None) -> None:
    """Preview to a temporary name, then the map (atomic), then the preview into place."""
    from ..maps.preview import preview_discretized

    staged = None
    if preview_path is not None:
        staged = preview_path.with_name(preview_path.name + ".new.png")
        preview_discretized(result, staged)
    try:
        result.map.save(target)
    except OSError as exc:
        if staged is not None and staged.exists():
            staged.unlink()
        raise GuadalError(f"cannot write map '{target}': {exc.strerror or exc}.") from exc
    if staged is not None:
        os.replace(staged, preview_path)

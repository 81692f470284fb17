"""One self-contained HTML page per report: tables inline, images as data URIs.

A page that embeds everything can be mailed, attached to a lab notebook or opened offline
years later; nothing it shows lives in another file. The files meant for other programs
(tables, GeoJSON, KML, ground-station plans) are linked by relative paths, so the links work
wherever the report folder is moved.
"""

from __future__ import annotations

import base64
import html
from pathlib import Path

from .. import __version__

STYLE = """
body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1200px;color:#222}
table{border-collapse:collapse;font-size:13px;margin:1em 0}
th,td{border:1px solid #ccc;padding:3px 7px;text-align:right}
th{background:#f0f0f0}td:first-child,th:first-child{text-align:left}
tr.incomplete td{background:#fff3cd}
.warning{background:#fff3cd;border-left:4px solid #e0a800;padding:.5em 1em;margin:.5em 0}
figure{display:inline-block;margin:.5em}img,video{max-width:100%}
figcaption{font-size:12px;color:#555}
"""

MIME = {".png": "image/png", ".gif": "image/gif", ".mp4": "video/mp4", ".svg": "image/svg+xml"}


def data_uri(path: Path) -> str:
    return f"data:{MIME[path.suffix]};base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def figure(path: Path, caption: str) -> str:
    src = data_uri(path)
    if path.suffix == ".mp4":
        body = f'<video controls loop src="{src}"></video>'
    else:
        body = f'<img alt="{html.escape(caption)}" src="{src}">'
    return f"<figure>{body}<figcaption>{html.escape(caption)}</figcaption></figure>"


def file_links(out_dir: Path, table_files: list[Path], exports: dict[str, list[Path]]) -> str:
    """A list of links to the report's tables and, per run, its geo and ground-station files."""

    def link(path: Path) -> str:
        rel = path.relative_to(out_dir).as_posix()
        return f'<a href="{html.escape(rel)}">{html.escape(path.name)}</a>'

    items = ["<li>tables: " + ", ".join(link(p) for p in table_files) + "</li>"]
    items += [
        f"<li>{html.escape(name)}: " + ", ".join(link(p) for p in paths) + "</li>"
        for name, paths in exports.items()
        if paths
    ]
    return "<ul>" + "".join(items) + "</ul>"


def page(title: str, warnings: list[str], sections: list[tuple[str, str]]) -> str:
    """``sections`` are (heading, already-rendered HTML) pairs, in order."""
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{html.escape(title)}</title><style>{STYLE}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        f"<p>Made by guadal {html.escape(__version__)}. Rows on a yellow ground are runs that did not complete.</p>",
    ]
    parts += [f'<div class="warning">{html.escape(w)}</div>' for w in warnings]
    for heading, body in sections:
        if body:
            parts.append(f"<h2>{html.escape(heading)}</h2>{body}")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"

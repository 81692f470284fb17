"""Geographic exports of a run: GeoJSON and KML for GIS and globe viewers, and the planned
route of each vehicle as a QGroundControl ``.plan`` and a Mission Planner ``.waypoints`` file.

GeoJSON coordinates are ``[lon, lat]`` (RFC 7946); KML's are ``lon,lat,alt``; both ground-station
formats put latitude before longitude. Routes keep the nodes where a vehicle turns: a straight run
of graph nodes is one leg, which is how a ground station expects a route to look.
"""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from .runs import Run, file_stem

#: MAV_AUTOPILOT_ARDUPILOTMEGA, MAV_TYPE_SURFACE_BOAT, MAV_CMD_NAV_WAYPOINT, MAV_FRAME_GLOBAL_RELATIVE_ALT
FIRMWARE_ARDUPILOT = 3
VEHICLE_SURFACE_BOAT = 11
CMD_NAV_WAYPOINT = 16
FRAME_GLOBAL = 0
FRAME_GLOBAL_RELATIVE_ALT = 3
KML_NS = "http://www.opengis.net/kml/2.2"


def _num(value: float):
    """JSON has no NaN: a missing number becomes null."""
    value = float(value)
    return None if math.isnan(value) else value


def _int(value: float):
    value = float(value)
    return None if math.isnan(value) else int(value)


# --- GeoJSON ---------------------------------------------------------------------------------
def geojson(run: Run) -> dict:
    """Planned paths and GPS tracks as LineStrings, samples as Points, one FeatureCollection."""
    features = []
    for source in ("plan", "gps"):
        for v, rows in run.track(source).items():
            coords = [
                [float(lo), float(la)]
                for la, lo in zip(rows["lat"], rows["lon"])
                if not (math.isnan(la) or math.isnan(lo))
            ]
            if not coords:
                continue
            geometry = (
                {"type": "LineString", "coordinates": coords}
                if len(coords) > 1
                else {"type": "Point", "coordinates": coords[0]}
            )
            features.append(
                {
                    "type": "Feature",
                    "geometry": geometry,
                    "properties": {
                        "kind": "track",
                        "source": source,
                        "vehicle": v,
                        "run": run.name,
                        "algorithm": run.algorithm,
                        "seed": run.seed,
                        "status": run.status,
                    },
                }
            )
    m = run.measurements
    for i in range(len(m.get("step", []))):
        features.append(
            {
                "type": "Feature",
                "geometry": {"type": "Point", "coordinates": [float(m["lon"][i]), float(m["lat"][i])]},
                "properties": {
                    "kind": "sample",
                    "run": run.name,
                    "step": _int(m["step"][i]),
                    "vehicle": _int(m["vehicle"][i]),
                    "node": _int(m["node"][i]),
                    "value": _num(m["value"][i]),
                    "time_s": _num(m["time_s"][i]),
                },
            }
        )
    return {"type": "FeatureCollection", "name": run.name, "features": features}


# --- KML -------------------------------------------------------------------------------------
def _kml_colour(v: int) -> str:
    """KML colours are aabbggrr."""
    from .plots import vehicle_colour

    r, g, b = (int(round(c * 255)) for c in vehicle_colour(v)[:3])
    return f"ff{b:02x}{g:02x}{r:02x}"


def kml(run: Run) -> bytes:
    ET.register_namespace("", KML_NS)
    q = lambda tag: f"{{{KML_NS}}}{tag}"  # noqa: E731
    root = ET.Element(q("kml"))
    doc = ET.SubElement(root, q("Document"))
    ET.SubElement(doc, q("name")).text = f"{run.name} ({run.algorithm}, seed {run.seed}, {run.status})"
    for source, title in (("plan", "planned path"), ("gps", "GPS track")):
        tracks = run.track(source)
        if not tracks:
            continue
        folder = ET.SubElement(doc, q("Folder"))
        ET.SubElement(folder, q("name")).text = title
        for v, rows in tracks.items():
            mark = ET.SubElement(folder, q("Placemark"))
            ET.SubElement(mark, q("name")).text = f"vehicle {v} {title}"
            style = ET.SubElement(ET.SubElement(mark, q("Style")), q("LineStyle"))
            ET.SubElement(style, q("color")).text = _kml_colour(v)
            ET.SubElement(style, q("width")).text = "3" if source == "plan" else "2"
            line = ET.SubElement(mark, q("LineString"))
            ET.SubElement(line, q("tessellate")).text = "1"
            ET.SubElement(line, q("coordinates")).text = " ".join(
                f"{lo:.8f},{la:.8f},0"
                for la, lo in zip(rows["lat"], rows["lon"])
                if not (math.isnan(la) or math.isnan(lo))
            )
    m = run.measurements
    if len(m.get("step", [])):
        folder = ET.SubElement(doc, q("Folder"))
        ET.SubElement(folder, q("name")).text = "samples"
        for i in range(len(m["step"])):
            mark = ET.SubElement(folder, q("Placemark"))
            ET.SubElement(mark, q("name")).text = f"{m['value'][i]:.4g}"
            ET.SubElement(
                mark, q("description")
            ).text = f"step {int(m['step'][i])}, vehicle {int(m['vehicle'][i])}, node {int(m['node'][i])}, t={m['time_s'][i]:.1f} s"
            point = ET.SubElement(mark, q("Point"))
            ET.SubElement(point, q("coordinates")).text = f"{m['lon'][i]:.8f},{m['lat'][i]:.8f},0"
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True)


# --- ground-station routes -------------------------------------------------------------------
def route(rows: dict[str, np.ndarray]) -> list[tuple[float, float]]:
    """(lat, lon) of the planned path, without repeats and without nodes inside straight legs."""
    pts: list[tuple[float, float, float, float]] = []
    for la, lo, r, c in zip(rows["lat"], rows["lon"], rows["row"], rows["col"]):
        if pts and (pts[-1][2], pts[-1][3]) == (r, c):
            continue
        pts.append((float(la), float(lo), float(r), float(c)))
    keep = []
    for i, p in enumerate(pts):
        if 0 < i < len(pts) - 1:
            before = (p[2] - pts[i - 1][2], p[3] - pts[i - 1][3])
            after = (pts[i + 1][2] - p[2], pts[i + 1][3] - p[3])
            if before == after:
                continue  # same heading in and out: a node inside a straight leg
        keep.append((p[0], p[1]))
    return keep


def qgc_plan(points: list[tuple[float, float]], cruise_speed: float, altitude: float = 0.0) -> dict:
    """A QGroundControl plan (file version 1, mission version 2) for an ArduPilot boat.

    The first point is the planned home position; every point, the first included, is a
    waypoint so the route starts where the vehicle started.
    """
    items = [
        {
            "AMSLAltAboveTerrain": None,
            "Altitude": altitude,
            "AltitudeMode": 1,
            "autoContinue": True,
            "command": CMD_NAV_WAYPOINT,
            "doJumpId": i + 1,
            "frame": FRAME_GLOBAL_RELATIVE_ALT,
            "params": [0, 0, 0, None, lat, lon, altitude],
            "type": "SimpleItem",
        }
        for i, (lat, lon) in enumerate(points)
    ]
    home = [points[0][0], points[0][1], altitude] if points else [0.0, 0.0, 0.0]
    return {
        "fileType": "Plan",
        "version": 1,
        "groundStation": "QGroundControl",
        "mission": {
            "version": 2,
            "firmwareType": FIRMWARE_ARDUPILOT,
            "vehicleType": VEHICLE_SURFACE_BOAT,
            "cruiseSpeed": cruise_speed,
            "hoverSpeed": cruise_speed,
            "globalPlanAltitudeMode": 1,
            "plannedHomePosition": home,
            "items": items,
        },
        "geoFence": {"version": 2, "circles": [], "polygons": []},
        "rallyPoints": {"version": 2, "points": []},
    }


def waypoints_file(points: list[tuple[float, float]], altitude: float = 0.0) -> str:
    """Mission Planner's ``QGC WPL 110`` text: line 0 is home, then one waypoint per line, tab-separated."""
    lines = ["QGC WPL 110"]
    if not points:
        return "\n".join(lines) + "\n"
    home = points[0]
    rows = [(0, 1, FRAME_GLOBAL, home)] + [
        (i + 1, 0, FRAME_GLOBAL_RELATIVE_ALT, p) for i, p in enumerate(points)
    ]
    for index, current, frame, (lat, lon) in rows:
        fields = [
            index,
            current,
            frame,
            CMD_NAV_WAYPOINT,
            0,
            0,
            0,
            0,
            f"{lat:.8f}",
            f"{lon:.8f}",
            f"{altitude:.6f}",
            1,
        ]
        lines.append("\t".join(str(f) for f in fields))
    return "\n".join(lines) + "\n"


def export_run(run: Run, out_dir: Path) -> list[Path]:
    """All geo files of one run: ``<run>.geojson``, ``<run>.kml`` and per vehicle ``.plan``/``.waypoints``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = file_stem(run.name)
    written = []
    path = out_dir / f"{stem}.geojson"
    path.write_text(json.dumps(geojson(run)) + "\n")
    written.append(path)
    path = out_dir / f"{stem}.kml"
    path.write_bytes(kml(run))
    written.append(path)
    speed = run.mission.get("fleet", {}).get("speed") if isinstance(run.mission.get("fleet"), dict) else None
    for v, rows in run.track("plan").items():
        points = route(rows)
        path = out_dir / f"{stem}_v{v}.plan"
        path.write_text(json.dumps(qgc_plan(points, float(speed or 1.0)), indent=2) + "\n")
        written.append(path)
        path = out_dir / f"{stem}_v{v}.waypoints"
        path.write_text(waypoints_file(points))
        written.append(path)
    return written

import json
import subprocess
import sys

from support import ROOT, run_cli

from guadal_cli import __version__


def test_version():
    proc = run_cli("--version")
    assert proc.returncode == 0 and proc.stdout.strip() == f"guadal {__version__}"


def test_schema_is_a_json_schema_of_the_mission_sections():
    schema = json.loads(run_cli("schema").stdout)
    assert schema["$schema"].endswith("2020-12/schema")
    assert {"name", "map", "environment", "algorithm", "fleet", "backend", "output"} <= set(
        schema["properties"]
    )
    assert set(schema["required"]) >= {"name", "map", "environment", "algorithm", "fleet"}


def test_plugins_are_listed_without_importing_them():
    code = (
        "import sys, json; from guadal_cli import plugins;"
        "rows = {k: sorted(plugins.available(k)) for k in plugins.GROUPS};"
        "loaded = [m for m in sys.modules if m.startswith(('guadal_cli.planners.', 'guadal_cli.envs.'))];"
        "print(json.dumps({'rows': rows, 'loaded': loaded}))"
    )
    out = json.loads(
        subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    )
    assert {"greedy", "expected_improvement", "lawnmower", "random"} <= set(out["rows"]["algorithm"])
    assert "gp" in out["rows"]["environment"] and "sim" in out["rows"]["backend"]
    assert out["loaded"] == []


def test_map_info_json_reports_the_shipped_lake():
    info = json.loads(run_cli("map", "info", ROOT / "maps" / "urban_lake.json", "--json").stdout)
    assert info["shape"] == [30, 49] and info["water_nodes"] == 351
    assert info["area_m2"] == 351 * 25.0 and info["cell_size_m"] == 5.0
    assert 37.41 < info["lat_bounds"][0] < info["lat_bounds"][1] < 37.42


def test_validate_summarises_a_good_mission():
    proc = run_cli("validate", ROOT / "missions" / "lake_greedy.yaml", "--json")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["mode"] == "sequential" and len(summary["initial_nodes"]) == 3

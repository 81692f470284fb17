"""The console in a real browser (Debian's Chromium) while a real, slowed sim mission runs."""

from __future__ import annotations

import csv
import json
import re
import time

import pytest
import yaml
from console_support import SECRET, Console, browser, slow_mission, start_mission, wait_for
from support import ROOT

from guadal_cli.db import queries
from guadal_cli.db.queries import open_database
from guadal_cli.web.security import TOKEN_ENV

pytest.importorskip("selenium")
By = pytest.importorskip("selenium.webdriver.common.by").By
ARTIFACTS = ROOT / "test-artifacts"
#: each boat's budget: at 0.25 s a decision the mission outlasts the test (which aborts it) on a
#: loaded machine too (2,000 m lasted 81 s, and a control sent after the end is refused)
BUDGET_M = 20000.0


def _rows(path) -> list[dict]:
    with open(path, newline="") as fh:
        return [r for r in csv.DictReader(fh)]


def _manifest(run_dir) -> dict:
    return json.loads((run_dir / "manifest.json").read_text())


def _control_events(run_dir) -> list[dict]:
    return [e for e in _manifest(run_dir).get("events", []) if e["kind"] == "control"]


def _click(driver, css: str) -> None:
    """Click what the page may still be drawing: retried until the element is there and holds still."""
    from selenium.common.exceptions import NoSuchElementException, StaleElementReferenceException

    def attempt():
        try:
            driver.find_element(By.CSS_SELECTOR, css).click()
            return True
        except (NoSuchElementException, StaleElementReferenceException):
            return False

    wait_for(attempt, timeout=10, what=f"a clickable {css}")


def _visible(driver, element_id: str) -> bool:
    from selenium.common.exceptions import NoSuchElementException, StaleElementReferenceException

    try:
        return driver.find_element(By.ID, element_id).is_displayed()
    except (NoSuchElementException, StaleElementReferenceException):
        return False


def _boat_cells(driver, vehicle: int) -> dict[str, str] | None:
    """The boats panel's cells for one boat (mode, armed, battery, link, ...); None while redrawn."""
    from selenium.common.exceptions import StaleElementReferenceException

    try:
        row = driver.find_elements(By.CSS_SELECTOR, f'#boats tr[data-vehicle="{vehicle}"] td[data-field]')
        return {td.get_attribute("data-field"): td.text for td in row} or None
    except StaleElementReferenceException:
        return None


def _target_nodes(driver) -> dict[str, int] | None:
    """Each drawn target marker's node, by boat; None while the page is redrawing one."""
    from selenium.common.exceptions import StaleElementReferenceException

    out = {}
    try:
        for marker in driver.find_elements(By.CSS_SELECTOR, ".leaflet-marker-icon.target"):
            name = next(c for c in marker.get_attribute("class").split() if c.startswith("target-"))
            out[name] = int(marker.get_attribute("data-node"))
    except (StaleElementReferenceException, TypeError):
        return None
    return out


def _markers(driver) -> dict[str, tuple] | None:
    """Each boat marker's place on the screen; None while the page is redrawing one."""
    from selenium.common.exceptions import StaleElementReferenceException

    out = {}
    try:
        for marker in driver.find_elements(By.CSS_SELECTOR, ".leaflet-marker-icon.boat"):
            name = next(c for c in marker.get_attribute("class").split() if c.startswith("boat-"))
            out[name] = (marker.location["x"], marker.location["y"])
    except StaleElementReferenceException:
        return None
    return out


@pytest.fixture
def console_and_browser(tmp_path):
    db = f"sqlite:///{tmp_path / 'guadal.db'}"
    console = Console(db, "--control", env={TOKEN_ENV: SECRET})
    driver = browser()
    yield db, console, driver
    driver.quit()
    output = console.stop()
    assert SECRET not in output


def test_a_running_mission_shows_live_and_obeys_pause_resume_hold_and_abort(
    tmp_path, write_mission, console_and_browser
):
    db, console, driver = console_and_browser
    driver.get(console.url + "/")
    run_dir = tmp_path / "run"
    mission = write_mission(slow_mission(db, delay_s=0.25, max_distance=BUDGET_M))
    proc = start_mission(mission, run_dir)
    try:
        # the new run appears in the open list without a reload, and its row opens its page
        wait_for(lambda: driver.find_elements(By.CSS_SELECTOR, "#runs tbody tr"), what="the run in the list")
        link = driver.find_element(By.CSS_SELECTOR, "#runs tbody tr td:nth-child(2) a")
        listed = driver.find_element(By.CSS_SELECTOR, "#runs tbody tr td:nth-child(7)").text
        wait_for(
            lambda: driver.find_element(By.CSS_SELECTOR, "#runs tbody tr td:nth-child(7)").text != listed,
            what="the list to show the run moving on",
        )
        link.click()  # the element found before the update: rows change in place, a click is never lost
        wait_for(lambda: len(_markers(driver) or {}) == 3, what="three boat markers")

        # the step counter follows the database: never ahead of it, and catching up with it
        engine = open_database(db)
        run_id = queries.list_runs(engine)[0]["id"]
        shown = []
        for _ in range(3):
            in_db = queries.get_run(engine, run_id)["steps"]
            page = wait_for(
                lambda: (n := int(driver.find_element(By.ID, "step").text)) >= in_db and n,  # noqa: B023
                what=f"the page to show step {in_db}",
            )
            assert page <= queries.get_run(engine, run_id)["steps"]
            shown.append(page)
            wait_for(lambda: queries.get_run(engine, run_id)["steps"] > page, what="the mission to go on")  # noqa: B023
        assert shown == sorted(shown) and shown[0] < shown[-1]

        # the boats' markers move on the map
        before = wait_for(lambda: _markers(driver), what="the boat markers")
        wait_for(lambda: _markers(driver) not in (None, before), what="a boat marker to move")

        # each boat's state as recorded (simulated boats: GUIDED, armed, no battery, no link),
        # and a marker on the target the planner last gave it, one of those in targets.csv
        cells = wait_for(lambda: _boat_cells(driver, 1), what="boat 1's row")
        assert (cells["mode"], cells["armed"], cells["battery"], cells["link"]) == ("GUIDED", "yes", "—", "—")
        assert float(cells["remaining"]) <= BUDGET_M
        drawn = wait_for(
            lambda: len(_target_nodes(driver) or {}) == 3 and _target_nodes(driver), what="targets"
        )
        sent = {f"target-{r['vehicle']}": set() for r in _rows(run_dir / "targets.csv")}
        for r in _rows(run_dir / "targets.csv"):
            sent[f"target-{r['vehicle']}"].add(int(r["node"]))
        assert all(node in sent[name] for name, node in drawn.items())

        # the model's std arrives while the mission runs, and is redrawn as it learns
        _click(driver, '#field option[value="std"]')
        first = wait_for(
            lambda: re.search(r"step (\d+)", driver.find_element(By.ID, "legend").text), what="a legend"
        )
        wait_for(
            lambda: (
                int(re.search(r"step (\d+)", driver.find_element(By.ID, "legend").text).group(1))
                > int(first.group(1))
            ),
            what="a newer std map",
        )
        ARTIFACTS.mkdir(exist_ok=True)
        driver.save_screenshot(str(ARTIFACTS / "console-live.png"))

        # an operator logs in through the form; the controls appear
        driver.get(f"{console.url}/login?next=/runs/{run_id}")
        driver.find_element(By.NAME, "secret").send_keys(SECRET)
        driver.find_element(By.CSS_SELECTOR, "form button").click()
        wait_for(lambda: _visible(driver, "controls"), what="the operator controls")

        # pause: the mission stops between hops and records who paused it
        _click(driver, '#controls button[data-action="pause"]')
        wait_for(lambda: _control_events(run_dir), what="the pause in the run's events")
        assert _control_events(run_dir)[0]["action"] == "pause"
        assert _control_events(run_dir)[0]["who"] == "operator"
        steps_paused = len(_rows(run_dir / "metrics.csv"))
        time.sleep(1.5)  # several planner decisions' worth of time
        assert len(_rows(run_dir / "metrics.csv")) == steps_paused

        # resume: it goes on
        _click(driver, '#controls button[data-action="resume"]')
        wait_for(lambda: len(_rows(run_dir / "metrics.csv")) > steps_paused + 2, what="steps after resuming")

        # hold boat 1: it stays on its node while the others sail on; release it again
        _click(driver, 'button[data-action="hold"][data-vehicle="1"]')
        wait_for(lambda: len(_control_events(run_dir)) == 3, what="the hold in the run's events")
        held_from = int(_rows(run_dir / "metrics.csv")[-1]["step"])
        release = wait_for(
            lambda: driver.find_elements(By.CSS_SELECTOR, 'button[data-action="release"][data-vehicle="1"]'),
            what="the release button",
        )[0]
        wait_for(
            lambda: int(_rows(run_dir / "metrics.csv")[-1]["step"]) > held_from + 4, what="steps while held"
        )
        release.click()  # found before the panel was redrawn for those steps: it is updated in place
        wait_for(lambda: len(_control_events(run_dir)) == 4, what="the release in the run's events")
        released_at = int(_rows(run_dir / "metrics.csv")[-1]["step"])
        plan = [r for r in _rows(run_dir / "trajectory.csv") if r["source"] == "plan"]
        held_nodes = {
            r["node"] for r in plan if r["vehicle"] == "1" and held_from < int(r["step"]) < released_at
        }
        others = {r["node"] for r in plan if r["vehicle"] == "0" and held_from < int(r["step"]) < released_at}
        assert len(held_nodes) == 1 and len(others) > 1

        # abort: the run ends interrupted, with its data, and says who ended it
        _click(driver, '#controls button[data-action="abort"]')
        assert proc.wait(timeout=60) == 0, proc.stderr.read()
        manifest = _manifest(run_dir)
        assert manifest["status"] == "interrupted"
        assert manifest["error"] == "aborted by operator operator"
        assert [e["action"] for e in _control_events(run_dir)] == [
            "pause",
            "resume",
            "hold",
            "release",
            "abort",
        ]
        assert len(_rows(run_dir / "metrics.csv")) == manifest["steps"] + 1
        wait_for(
            lambda: driver.find_element(By.ID, "status").text == "interrupted", what="the page to say so"
        )
        # replayed at an earlier step: the targets drawn are those of the decision then in force,
        # and the held boat's row says it was held then
        targets = _rows(run_dir / "targets.csv")
        back = held_from + 2  # after the hold was applied, before the release (3 steps later at least)
        driver.execute_script(
            "const s = document.getElementById('slider'); s.value = arguments[0];"
            "s.dispatchEvent(new Event('input'));",
            back,
        )
        expected = {f"target-{r['vehicle']}": int(r["node"]) for r in targets if int(r["step"]) <= back}
        wait_for(lambda: _target_nodes(driver) == expected, what=f"the targets of step {back}")
        wait_for(
            lambda: (_boat_cells(driver, 1) or {}).get("mode") == "GUIDED · held", what="boat 1 held then"
        )
        driver.save_screenshot(str(ARTIFACTS / "console-replay.png"))
        db_events = [e for e in queries.events(engine, run_id) if e["kind"] == "control"]
        assert [e["detail"]["action"] for e in db_events] == ["pause", "resume", "hold", "release", "abort"]
        assert all(e["detail"]["who"] == "operator" for e in db_events)
        status, body = console.call(f"/api/runs/{run_id}/control", {"action": "resume"}, token=SECRET)
        assert (
            status == 409
            and body["error"] == f"run {run_id} is interrupted; only a running mission takes controls."
        )
        status, body = console.call(f"/api/runs/{run_id}/control", {"action": "explode"}, token=SECRET)
        assert status == 400
        assert (
            body["error"]
            == "control action 'explode' is not known; use one of pause, resume, abort, hold, release."
        )
        status, body = console.call(
            f"/api/runs/{run_id}/control", {"action": "hold", "vehicle": 7}, token=SECRET
        )
        assert status == 400 and body["error"] == "'hold' needs a vehicle number from 0 to 2 (got 7)."
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert yaml.safe_load((run_dir / "mission.resolved.yaml").read_text())["output"]["database"] == db


def _link_age(driver, vehicle: int) -> float | None:
    cell = (_boat_cells(driver, vehicle) or {}).get("link", "—")
    return None if cell in ("—", "") else float(cell.split()[0])


def test_a_boats_link_age_keeps_growing_on_screen_when_its_reports_stop(
    tmp_path, write_mission, console_and_browser
):
    """A stalled mission (here: stopped with SIGSTOP) sends no more rows; the page must not go on
    showing the last, healthy link age as if the boat were still heard."""
    import os
    import signal

    db, console, driver = console_and_browser
    mission = yaml.safe_load((ROOT / "missions" / "lake_greedy_sitl.yaml").read_text())
    mission["map"] = str(ROOT / "maps" / "urban_lake.json")
    mission["backend"].update(speedup=20)
    mission["output"] = {"database": db}
    proc = start_mission(write_mission(mission), tmp_path / "run")
    try:
        engine = open_database(db)
        runs = wait_for(lambda: queries.list_runs(engine), timeout=60, what="the run in the database")
        run_id = runs[0]["id"]
        driver.get(f"{console.url}/runs/{run_id}")
        wait_for(lambda: _link_age(driver, 0) is not None, timeout=90, what="boat 0's link age")
        os.kill(proc.pid, signal.SIGSTOP)
        time.sleep(1.5)  # rows already on their way arrive
        first = _link_age(driver, 0)
        time.sleep(3)
        assert _link_age(driver, 0) >= first + 2
        # a page opened now counts from when the boat was last heard, not from its own load
        driver.get(f"{console.url}/runs/{run_id}")
        wait_for(lambda: _link_age(driver, 0) is not None, timeout=30, what="boat 0's link age, again")
        assert _link_age(driver, 0) >= first + 2.5
    finally:
        os.kill(proc.pid, signal.SIGCONT)
        proc.terminate()
        proc.wait(timeout=60)

"""The console under test: a real ``guadal serve`` process, a real browser, a real mission."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

from support import base_mission

HERE = Path(__file__).resolve().parent
SECRET = "correct-horse-battery-staple"
CHROMIUM_FLAGS = (
    "--headless --no-sandbox --disable-gpu --disable-quic --no-first-run --disable-background-networking "
    "--disable-component-update --disable-sync --window-size=1400,900"
).split()


class Console:
    """``guadal serve`` on a free loopback port; stopped (and its output kept) by :meth:`stop`."""

    def __init__(self, db_url: str, *args: str, env: dict | None = None):
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "guadal_cli", "serve", "--db", db_url, "--port", "0", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env={**os.environ, "COLUMNS": "300", **(env or {})},
        )
        line = self.proc.stdout.readline()
        found = re.search(r"http://\S+/", line)
        if not found:
            self.proc.kill()
            raise AssertionError(f"serve did not start: {line}{self.proc.stdout.read()}")
        self.url = found.group(0).rstrip("/")
        self.output = line

    def stop(self) -> str:
        self.proc.terminate()
        try:
            rest, _ = self.proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            rest, _ = self.proc.communicate()
        self.output += rest or ""
        return self.output

    def call(self, path: str, body=None, token: str | None = None, headers: dict | None = None):
        """(status, parsed JSON or raw bytes) of one HTTP request."""
        data = json.dumps(body).encode() if body is not None else None
        request = urllib.request.Request(self.url + path, data=data, headers=headers or {})
        if data is not None:
            request.add_header("Content-Type", "application/json")
        if token:
            request.add_header("Authorization", f"Bearer {token}")
        try:
            with urllib.request.urlopen(request, timeout=10) as response:
                status, raw, kind = response.status, response.read(), response.headers.get("content-type", "")
        except urllib.error.HTTPError as exc:
            status, raw, kind = exc.code, exc.read(), exc.headers.get("content-type", "")
        return status, json.loads(raw) if "json" in kind and "geo" not in kind else raw


def slow_mission(db_url: str, delay_s: float = 0.25, max_distance: float = 400.0, vehicles: int = 3) -> dict:
    return base_mission(
        algorithm={"type": "slow_planner:SlowGreedy", "delay_s": delay_s},
        fleet={"vehicles": vehicles, "initial_positions": "auto", "max_distance": max_distance, "speed": 0.5},
        output={"database": db_url},
    )


def start_mission(mission_path: Path, out: Path) -> subprocess.Popen:
    """``guadal run`` in the background, with the slow planner importable."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")])}
    return subprocess.Popen(
        [sys.executable, "-m", "guadal_cli", "run", str(mission_path), "-o", str(out), "-q"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )


def wait_for(condition, timeout: float = 60.0, every: float = 0.1, what: str = "condition"):
    """Poll until ``condition()`` is truthy; its value, or AssertionError naming what never came."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(every)
    raise AssertionError(f"timed out waiting for {what}")


def browser():
    """Headless Debian Chromium through chromedriver, with a fresh profile.

    Without them (``apt-get install chromium chromium-driver``) the browser tests skip, except in
    CI, which installs them (``.ci/run``) and must not pass without having run them.
    """
    import shutil

    import pytest

    missing = [name for name in ("chromium", "chromedriver") if shutil.which(name) is None]
    if missing and not os.environ.get("CI"):
        pytest.skip(f"{' and '.join(missing)} not installed (apt-get install chromium chromium-driver)")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    for flag in CHROMIUM_FLAGS:
        options.add_argument(flag)
    options.add_argument("--user-data-dir=" + tempfile.mkdtemp(prefix="guadal-chromium-"))
    options.binary_location = shutil.which("chromium") or "chromium"
    return webdriver.Chrome(options=options, service=Service(shutil.which("chromedriver") or "chromedriver"))

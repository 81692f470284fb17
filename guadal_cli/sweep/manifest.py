"""The sweep's own manifest, ``SWEEP_DIR/sweep.json``: every combination, its status and run dir.

It is rewritten atomically (a temporary file renamed over the old one) as the sweep goes, at
most every ``interval`` seconds and at every end, so a reader never sees half a file. A sweep
killed outright may lose the last fraction of a second of updates; nothing is lost with it,
because each run directory has its own manifest, and :meth:`SweepManifest.open` reads the run
directories of unfinished entries: a run that completed is adopted, one that did not is retried.

Statuses: ``pending`` (not tried yet), ``running``, ``complete``, ``failed`` (its error is kept;
retried on re-runs while ``attempts`` <= ``retries``), ``interrupted`` (stopped by Ctrl-C or a
kill: not the mission's fault, so it does not count as an attempt).
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

from ..errors import GuadalError
from ..records import now_iso
from .plan import Plan

SWEEP_FORMAT = "guadal-sweep"
SWEEP_VERSION = 1
MANIFEST = "sweep.json"


def read_run_manifest(run_dir: Path) -> dict | None:
    try:
        data = json.loads((Path(run_dir) / "manifest.json").read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    return data if isinstance(data, dict) else None


def read_sweep_manifest(directory: Path) -> dict | None:
    """A sweep directory's manifest, or None where the folder is not a sweep directory."""
    path = Path(directory) / MANIFEST
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise GuadalError(f"'{path}' is unreadable ({exc}); it is the sweep's manifest.") from exc
    if not isinstance(data, dict) or data.get("format") != SWEEP_FORMAT:
        raise GuadalError(f"'{path}' is not a guadal sweep manifest: 'format' must be '{SWEEP_FORMAT}'.")
    entries = data.get("combinations", [])
    if not isinstance(entries, list) or not all(
        isinstance(e, dict) and isinstance(e.get("id"), str) for e in entries
    ):
        raise GuadalError(
            f"'{path}' is damaged: 'combinations' must be a list of entries, each with a text 'id'."
        )
    return data


class SweepManifest:
    """Owns ``sweep.json``: entries by combination id, in the plan's order."""

    def __init__(self, directory: Path, plan: Plan, interval: float = 0.5):
        self.directory = Path(directory)
        self.plan = plan
        self.interval = interval
        self._saved_at = 0.0
        self.dropped = 0  # entries of an earlier manifest whose combination left the sweep file
        sweep = plan.sweep
        self.data = {
            "format": SWEEP_FORMAT,
            "version": SWEEP_VERSION,
            "name": sweep.name,
            "sweep_file": str(sweep.path),
            "axes": sweep.axes,
            "retries": sweep.retries,
            "total": len(plan),
            "status": "running",
            "started_at": now_iso(),
            "updated_at": None,
            "combinations": [],
        }
        self.entries: dict[str, dict] = {}
        for combo in plan.combinations:
            entry = {
                "index": combo.index,
                "id": combo.id,
                "values": combo.values,
                "status": "pending",
                "attempts": 0,
                "run_dir": f"runs/{combo.id}",
                "error": None,
                "final_metrics": None,
                "worker": None,
                "started_at": None,
                "ended_at": None,
            }
            self.entries[combo.id] = entry
            self.data["combinations"].append(entry)

    @classmethod
    def open(cls, directory: Path, plan: Plan) -> SweepManifest:
        """A new manifest, or the earlier one of this directory carried over and checked."""
        manifest = cls(directory, plan)
        previous = read_sweep_manifest(directory)
        if previous is None:
            if Path(directory).is_dir() and any(Path(directory).iterdir()):
                raise GuadalError(
                    f"sweep directory '{directory}' is not empty and holds no {MANIFEST}; choose another output."
                )
            return manifest
        old = {e.get("id"): e for e in previous.get("combinations", []) if isinstance(e, dict)}
        manifest.dropped = len(set(old) - set(manifest.entries))
        manifest.data["started_at"] = previous.get("started_at") or manifest.data["started_at"]
        for combo_id, entry in manifest.entries.items():
            before = old.get(combo_id)
            if before:
                for key in (
                    "status",
                    "attempts",
                    "error",
                    "final_metrics",
                    "worker",
                    "started_at",
                    "ended_at",
                ):
                    entry[key] = before.get(key, entry[key])
            if entry["status"] != "complete":
                manifest._reconcile(entry)
        return manifest

    def _reconcile(self, entry: dict) -> None:
        """An unfinished entry whose run directory completed is complete; a 'running' one was killed."""
        run = read_run_manifest(self.directory / entry["run_dir"])
        if run and run.get("status") == "complete":
            entry.update(status="complete", error=None, final_metrics=run.get("final_metrics"))
            entry["ended_at"] = run.get("ended_at")
        elif entry["status"] == "running":
            entry["status"] = "interrupted"

    # --- updates ------------------------------------------------------------------------------
    def counts(self) -> dict[str, int]:
        out = dict.fromkeys(("pending", "running", "complete", "failed", "interrupted"), 0)
        for entry in self.entries.values():
            out[entry["status"]] += 1
        return out

    def start(self, combo_id: str) -> int:
        entry = self.entries[combo_id]
        entry.update(status="running", started_at=now_iso(), ended_at=None)
        self.save()
        return entry["attempts"] + 1

    def finish(self, combo_id: str, result: dict) -> None:
        entry = self.entries[combo_id]
        status = result.get("status", "failed")
        entry.update(
            status=status,
            error=result.get("error"),
            final_metrics=result.get("final_metrics"),
            worker=result.get("worker"),
            ended_at=now_iso(),
        )
        if status != "interrupted":
            entry["attempts"] += 1
        self.save()

    def interrupt_running(self) -> None:
        """After the workers stopped: a mission that completed just before is complete, the rest interrupted."""
        for entry in self.entries.values():
            if entry["status"] == "running":
                self._reconcile(entry)

    def save(self, force: bool = False, status: str | None = None) -> None:
        if status:
            self.data["status"] = status
        now = time.monotonic()
        if not force and now - self._saved_at < self.interval:
            return
        self._saved_at = now
        self.data["updated_at"] = now_iso()
        self.directory.mkdir(parents=True, exist_ok=True)
        tmp = self.directory / f".{MANIFEST}.{os.getpid()}.partial"
        tmp.write_text(json.dumps(self.data, indent=1, default=str) + "\n")
        os.replace(tmp, self.directory / MANIFEST)

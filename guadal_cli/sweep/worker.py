"""The one task a worker runs: a combination's mission, prepared from its dict and run.

It is a plain function of plain data, so a local process and a Dask worker on another host run
it alike (it only needs guadal installed there, and the maps at the same paths). It never
raises for a mission that fails: the failure comes back as a result, and the sweep goes on.
"""

from __future__ import annotations

import os
import socket
from pathlib import Path

from ..errors import GuadalError


def run_combination(task: dict) -> dict:
    """Run one combination into ``task['run_dir']``; returns its status, final metrics and error."""
    from threadpoolctl import threadpool_limits

    from ..mission import prepare_dict
    from ..runner import MissionRunner
    from .manifest import read_run_manifest

    run_dir = Path(task["run_dir"])
    result = {"id": task["id"], "worker": f"{socket.gethostname()}:{os.getpid()}", "error": None}
    earlier = read_run_manifest(run_dir)
    if earlier and earlier.get("status") == "complete":  # finished before the sweep's record of it was saved
        return {**result, "status": "complete", "final_metrics": earlier.get("final_metrics")}
    _set_aside(run_dir, task["attempt"])
    try:
        with threadpool_limits(limits=1):  # one core per worker: workers, not BLAS threads, share the machine
            prep = prepare_dict(task["mission"], task["base_dir"], task["source"])
            run = MissionRunner(prep, output=run_dir).run()
    except GuadalError as exc:
        return {**result, "status": "failed", "error": str(exc), "final_metrics": None}
    except Exception as exc:  # a plugin's bug fails this mission, never the sweep
        return {**result, "status": "failed", "error": f"{type(exc).__name__}: {exc}", "final_metrics": None}
    return {**result, "status": run.status, "final_metrics": run.final_metrics}


def _set_aside(run_dir: Path, attempt: int) -> None:
    """An unfinished earlier attempt is kept beside the new one, for its logs, not overwritten."""
    if not run_dir.exists():
        return
    n = max(attempt - 1, 1)
    while (aside := run_dir.with_name(f"{run_dir.name}.attempt{n}")).exists():
        n += 1
    run_dir.rename(aside)

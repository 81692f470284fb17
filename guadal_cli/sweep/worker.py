"""The one task a worker runs: a combination's mission, prepared from its dict and run.

It is a plain function of plain data, so a local process and a Dask worker on another host run
it alike (it only needs guadal installed there, and the maps at the same paths). It never
raises for a mission that fails: the failure comes back as a result, and the sweep goes on.
"""

from __future__ import annotations

import os
import signal
import socket
from pathlib import Path

from ..errors import GuadalError

#: set by SIGTERM in a local worker: the mission in hand stops, and no other starts
_terminated = False
_in_mission = False


def stop_on_terminate() -> None:
    """In a local worker process: SIGTERM stops the mission in hand as Ctrl-C would.

    Without it, a SIGTERM that came before the runner installed its own handler killed the
    worker outright and left that run directory saying 'running'.
    """
    signal.signal(signal.SIGTERM, _on_terminate)


def _on_terminate(signum, frame) -> None:
    global _terminated
    _terminated = True
    if _in_mission:  # between tasks the worker only waits for the pool to close it
        raise KeyboardInterrupt


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
    if _terminated:
        return {**result, "status": "interrupted", "error": "the sweep was stopped", "final_metrics": None}
    _set_aside(run_dir, task["attempt"])
    global _in_mission
    _in_mission = True
    try:
        with threadpool_limits(limits=1):  # one core per worker: workers, not BLAS threads, share the machine
            prep = prepare_dict(task["mission"], task["base_dir"], task["source"])
            run = MissionRunner(prep, output=run_dir).run()
    except KeyboardInterrupt:
        _close_unfinished(run_dir)
        raise
    except GuadalError as exc:
        return {**result, "status": "failed", "error": str(exc), "final_metrics": None}
    except Exception as exc:  # a plugin's bug fails this mission, never the sweep
        return {**result, "status": "failed", "error": f"{type(exc).__name__}: {exc}", "final_metrics": None}
    finally:
        _in_mission = False
    return {**result, "status": run.status, "final_metrics": run.final_metrics}


def _close_unfinished(run_dir: Path) -> None:
    """A stop that came before the runner could record it: the run directory says 'interrupted'."""
    from ..records import now_iso, read_manifest, write_manifest

    try:
        manifest = read_manifest(run_dir)
    except GuadalError:
        return  # stopped before the run directory existed: nothing to close
    if manifest.get("status") == "running":
        manifest.update(status="interrupted", ended_at=now_iso(), error="the sweep was stopped")
        write_manifest(run_dir, manifest)


def _set_aside(run_dir: Path, attempt: int) -> None:
    """An unfinished earlier attempt is kept beside the new one, for its logs, not overwritten."""
    if not run_dir.exists():
        return
    n = max(attempt - 1, 1)
    while (aside := run_dir.with_name(f"{run_dir.name}.attempt{n}")).exists():
        n += 1
    run_dir.rename(aside)

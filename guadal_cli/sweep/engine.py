"""The sweep loop: keep every worker busy, record each result, never let one mission stop it.

Which combinations run: those never tried, those interrupted, and failed ones that have not
used up their attempts (``1 + retries`` in all, counted across re-runs). Completed ones are
skipped. Each result is written to the sweep manifest as it arrives.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from pathlib import Path

from .manifest import SweepManifest
from .plan import Combination, Plan, task_for


def to_run(plan: Plan, manifest: SweepManifest) -> list[Combination]:
    """The combinations this invocation runs, in plan order."""
    allowed = 1 + plan.sweep.retries
    out = []
    for combo in plan.combinations:
        entry = manifest.entries[combo.id]
        status = entry["status"]
        if status in ("pending", "interrupted", "running") or (
            status == "failed" and entry["attempts"] < allowed
        ):
            out.append(combo)
    return out


def run_sweep(
    plan: Plan,
    manifest: SweepManifest,
    executor,
    combinations: list[Combination],
    on_change: Callable[[dict], None] = lambda counts: None,  # counts by status, and "finished"
) -> dict[str, int]:
    """Run ``combinations`` on ``executor``; returns the final counts by status.

    On Ctrl-C (KeyboardInterrupt) the running missions are stopped, the manifest says so, and
    the interrupt goes on to the caller.
    """
    queue = deque(combinations)
    inflight: dict = {}
    finished = 0  # results received by this invocation (what its progress bar counts)
    sweep_dir = Path(manifest.directory)
    manifest.save(force=True, status="running")
    try:
        while queue or inflight:
            while queue and len(inflight) < executor.slots:
                combo = queue.popleft()
                attempt = manifest.start(combo.id)
                inflight[executor.submit(task_for(plan, combo, sweep_dir, attempt))] = combo.id
                on_change({**manifest.counts(), "finished": finished})
            for handle, result in executor.wait(list(inflight), timeout=0.5):
                manifest.finish(inflight.pop(handle), result)
                finished += 1
                on_change({**manifest.counts(), "finished": finished})
    except KeyboardInterrupt:
        executor.stop(list(inflight))
        manifest.interrupt_running()
        manifest.save(force=True, status="interrupted")
        raise
    counts = manifest.counts()
    manifest.save(force=True, status="complete" if counts["complete"] == len(plan) else "incomplete")
    return counts

"""The database writer: a run recorder sink that never holds up the mission.

The mission thread only puts items on a bounded queue (or, if it is full, appends them to the
run's spool file); one background thread owns the database connection. It writes a batch at
most every ``flush_every_s`` (so a real boat's sample is in the database within a second), and
when the database is slow, locked or unreachable it appends the batch to
``RUN/database.spool.jsonl`` and retries every ``retry_every_s``. The spool is replayed in order
once the database answers, then removed. Keys are idempotent, so a batch delivered twice (the
connection died after the commit) is harmless. When the mission ends the writer keeps trying
for ``patience_s`` (a lock held by another process is usually gone in seconds); what is still
spooled after that stays on disk, and ``guadal db sync RUN`` delivers it from the CSVs.
"""

from __future__ import annotations

import atexit
import itertools
import json
import logging
import queue
import threading
import time
import weakref
from pathlib import Path

from ..records import RecordSink
from .engine import check_url, ensure_schema, make_engine, redact
from .ingest import SPOOL_NAME
from .store import RunRef, cell, notify

log = logging.getLogger(__name__)

#: writers whose thread may still be delivering; the process waits for them when it exits
_LIVE: weakref.WeakSet = weakref.WeakSet()

#: one lock per database URL in this process. A run's writer goes on after its mission returns,
#: so missions run back to back (a sweep worker) leave several writers on one SQLite file; left
#: to SQLite's busy handler they starve each other past any timeout. Taking turns here, they
#: queue fairly, and only other processes are left to the busy timeout.
_TURNS: dict[str, threading.Lock] = {}
_TURNS_GUARD = threading.Lock()


def _turn(url: str) -> threading.Lock:
    with _TURNS_GUARD:
        return _TURNS.setdefault(url, threading.Lock())


@atexit.register
def _drain_live_writers() -> None:
    for writer in list(_LIVE):
        writer.close()


#: items (one recorder call each) waiting for the database before the mission thread spools them
QUEUE_SIZE = 4096


class DatabaseWriter(RecordSink):
    """Writes a run to the database at ``url`` as the recorder produces it."""

    def __init__(
        self,
        url: str,
        *,
        queue_size: int | None = None,
        flush_every_s: float = 0.2,
        retry_every_s: float = 1.0,
        close_timeout_s: float = 15.0,
        patience_s: float = 10.0,
    ):
        check_url(url)
        self.url = url
        self.queue_size = queue_size or QUEUE_SIZE
        self.flush_every_s = flush_every_s
        self.retry_every_s = retry_every_s
        self.close_timeout_s = close_timeout_s
        self.patience_s = patience_s
        self.shown_url = redact(url)
        self._queue: queue.Queue = queue.Queue(maxsize=self.queue_size)
        self._spool_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._numbers = itertools.count()
        self._schema_checked = False
        self._directory: str | None = None
        self._mission: dict = {}
        self.spool_path_: Path | None = None
        self.engine_ = None
        self.run_: RunRef | None = None
        self.delivered_ = 0  # items committed
        self.outages_ = 0
        self.last_error_: str | None = None

    # --- the sink contract (called by the recorder on the mission thread) ---------------------
    def started(self, directory: Path, manifest: dict, mission: dict) -> None:
        self._start(directory, mission, {"op": "run", "manifest": _jsonable(manifest)})

    def resumed(self, directory: Path, manifest: dict, mission: dict) -> None:
        """First bring the database in line with the cut files (from the CSVs), then go on live.

        A spool left by the interrupted process is dropped: what it held that still counts is in
        the CSVs, and its rows past the cut must not be replayed over the new ones. A writer of the
        same run still delivering in this process (an in-process caller resuming at once) is
        waited for first, so none of its rows lands after the database is brought in line.
        """
        resolved = str(Path(directory).resolve())
        for other in list(_LIVE):  # an earlier attempt in this process may still be delivering
            if other is not self and other._directory == resolved:
                other.close()
        (Path(directory) / SPOOL_NAME).unlink(missing_ok=True)
        resume = _jsonable(manifest["resumes"][-1])
        self._start(directory, mission, {"op": "resync", "manifest": _jsonable(manifest), "resume": resume})

    def _start(self, directory: Path, mission: dict, first: dict) -> None:
        self.spool_path_ = Path(directory) / SPOOL_NAME
        self._directory = str(Path(directory).resolve())
        self._mission = _jsonable(mission)
        self._put(first)
        self._thread = threading.Thread(target=self._loop, name="guadal-db-writer", daemon=True)
        _LIVE.add(self)
        self._thread.start()

    def appended(self, table: str, first_row: int, rows: list, columns: list | None = None) -> None:
        self._put({"op": "rows", "table": table, "first": first_row, "rows": rows, "columns": columns})

    def finished(self, manifest: dict) -> None:
        """Hand over the final manifest and let the thread finish on its own: the run returns now.

        The process waits for it when it exits (``atexit``, bounded: a database still away gets
        one last try, then the rest stays in the spool for 'db sync').
        """
        self._put({"op": "run", "manifest": _jsonable(manifest)})
        self._stop.set()

    def close(self) -> None:
        """Wait (at most ``close_timeout_s``) until what is queued is delivered or spooled."""
        if self._thread is None:
            return
        self._stop.set()
        try:
            self._thread.join(self.close_timeout_s)
        except KeyboardInterrupt:
            # Ctrl-C (or SIGTERM) while the last rows go out: the run's files are complete, so the
            # interrupt only cuts this wait short; what is not delivered 'guadal db sync' delivers
            self.last_error_ = self.last_error_ or "interrupted while delivering the last rows"
        if self._thread.is_alive():
            log.warning(
                "database %s is still taking the run's last rows; if this process ends first, "
                "run 'guadal db sync %s'.",
                self.shown_url,
                self.spool_path_.parent if self.spool_path_ else "RUN",
            )
        if not self._thread.is_alive() and self.engine_ is not None:
            self.engine_.dispose()
        self._thread = None

    # --- mission thread side -----------------------------------------------------------------
    def _put(self, item: dict) -> None:
        item["n"] = next(self._numbers)  # the order to apply items in, wherever they waited
        try:
            self._queue.put_nowait(item)
        except queue.Full:  # the database is far behind: the mission does not wait for it
            self._spool([item])

    def _spool(self, items: list[dict]) -> None:
        lines = "".join(json.dumps(_spooled(item), separators=(",", ":")) + "\n" for item in items)
        with self._spool_lock, open(self.spool_path_, "a", encoding="utf-8") as fh:
            fh.write(lines)
            fh.flush()

    def _spool_size(self) -> int:
        try:
            return self.spool_path_.stat().st_size if self.spool_path_ else 0
        except FileNotFoundError:
            return 0

    # --- writer thread side ------------------------------------------------------------------
    def _loop(self) -> None:
        retry_at = 0.0
        give_up_at = None
        while True:
            stopping = self._stop.is_set()
            if stopping and give_up_at is None:
                give_up_at = time.monotonic() + self.patience_s
            batch = self._take(0.05 if stopping else self.flush_every_s)
            if batch and self._spool_size():
                self._spool(batch)  # keep the order: older rows are waiting in the spool
            elif batch and not self._deliver(batch):
                self._spool(batch)
                retry_at = time.monotonic() + self.retry_every_s
            last_call = stopping and self._queue.empty()
            if self._spool_size() and (time.monotonic() >= retry_at or last_call):
                if not self._replay_spool():
                    retry_at = time.monotonic() + self.retry_every_s
                    if last_call and time.monotonic() < give_up_at:
                        # a lock held by another process (a sweep's other worker, an import) is
                        # usually gone in seconds: keep trying a while before leaving it to the user
                        time.sleep(self.retry_every_s)
                        continue
                    if last_call:  # still away: the spool stays for 'db sync'
                        log.warning(
                            "database %s did not take every row of the run (%s); they are kept in the "
                            "run directory: run 'guadal db sync %s' when the database is back.",
                            self.shown_url,
                            self.last_error_,
                            self.spool_path_.parent,
                        )
                        return
            if last_call and not self._spool_size():
                if self.engine_ is not None:
                    self.engine_.dispose()
                return

    def _take(self, wait: float) -> list[dict]:
        try:
            batch = [self._queue.get(timeout=wait)]
        except queue.Empty:
            return []
        while True:
            try:
                batch.append(self._queue.get_nowait())
            except queue.Empty:
                return batch

    def _deliver(self, items: list[dict]) -> bool:
        """Write items in one transaction, in the order they were made; False (reason kept) if that failed.

        A full queue sends newer items to the spool while older ones still wait in the queue, so
        items are sorted by their number first (the run's row comes before its rows).
        """
        items = sorted(items, key=lambda item: item["n"])
        try:
            if self.engine_ is None:
                self.engine_ = make_engine(self.url, writer=True)
            if not self._schema_checked:
                ensure_schema(self.engine_)
                self._schema_checked = True
            with _turn(self.url), self.engine_.begin() as conn:
                self._apply(conn, items)
                if self.run_ is not None:
                    notify(conn, self.run_)
        except Exception as exc:  # whatever it was, the rows stay spooled, never lost
            if self.last_error_ is None:
                self.outages_ += 1
                # a SQLite file locked by another writer is a turn to wait, not an outage: only say
                # so if the rows are still not in when the mission ends (the warning in _loop)
                say = log.info if "database is locked" in str(exc) else log.warning
                say("database %s is unavailable, spooling rows: %s", self.shown_url, _first_line(exc))
            self.last_error_ = _first_line(exc)
            return False
        if self.last_error_ is not None:
            log.info("database %s is back", self.shown_url)
        self.last_error_ = None
        self.delivered_ += len(items)
        return True

    def _apply(self, conn, items: list[dict]) -> None:
        """Runs in order; between them, each table's row batches in one statement."""
        from .ingest import save_run_files
        from .store import forget_replaced_rows, save_batches, save_run

        pending: dict[str, list] = {}

        def flush():
            for table, batches in pending.items():
                save_batches(conn, self.run_, table, batches, columns_of.get(table))
            pending.clear()

        columns_of = {}
        for item in items:
            if item["op"] in ("run", "resync"):
                flush()
                self.run_ = save_run(conn, item["manifest"], self._mission, self._directory)
                if item["op"] == "resync":
                    forget_replaced_rows(conn, self.run_, item["resume"])
                    save_run_files(conn, self.run_, Path(self._directory))
            else:
                rows = [[cell(v) for v in row] for row in item["rows"]]
                pending.setdefault(item["table"], []).append((item["first"], rows))
                if item.get("columns"):
                    columns_of[item["table"]] = item["columns"]
        flush()

    def _replay_spool(self) -> bool:
        with self._spool_lock:
            try:
                data = self.spool_path_.read_bytes()
            except FileNotFoundError:
                return True
        complete = data[: data.rfind(b"\n") + 1]
        items = [json.loads(line) for line in complete.splitlines() if line.strip()]
        if items and not self._deliver(items):
            return False
        with self._spool_lock:  # keep whatever the mission thread appended meanwhile
            rest = self.spool_path_.read_bytes()[len(complete) :]
            if rest:
                self.spool_path_.write_bytes(rest)
            else:
                self.spool_path_.unlink()
        return True


def _jsonable(value):
    """A manifest or mission as plain JSON values (numpy scalars become Python ones)."""
    return json.loads(json.dumps(value, default=lambda v: v.item() if hasattr(v, "item") else str(v)))


def _spooled(item: dict) -> dict:
    """An item as a JSON line: row cells rounded as the CSV prints them."""
    if item["op"] == "rows":
        return {**item, "rows": [[cell(v) for v in row] for row in item["rows"]]}
    return item


def _first_line(exc: BaseException) -> str:
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]

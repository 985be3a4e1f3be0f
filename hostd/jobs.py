"""The job store: one SQLite file (WAL) in ``state_dir``, shared by the daemon and the CLI.

States: ``queued -> planning -> ready -> printing -> done | failed | cancelled |
interrupted``. Every change is an event (``events`` table) so ``hostd job ID`` can tell
the story. The ``control`` table is the terminal commands' door into a running
daemon: the CLI inserts a request, the daemon carries it out and writes the result.
"""

import contextlib
import json
import sqlite3
import time
import uuid
from pathlib import Path

from hostd.errors import HostdError
from hostd.outputs import disk_text

QUEUED, PLANNING, READY, PRINTING = "queued", "planning", "ready", "printing"
DONE, FAILED, CANCELLED, INTERRUPTED = "done", "failed", "cancelled", "interrupted"
STATES = (QUEUED, PLANNING, READY, PRINTING, DONE, FAILED, CANCELLED, INTERRUPTED)
ACTIVE = (QUEUED, PLANNING, READY, PRINTING)
FINISHED = (DONE, FAILED, CANCELLED, INTERRUPTED)

# One transaction, so a reader sees all of the tables or none of them.
_SCHEMA = """
BEGIN IMMEDIATE;
CREATE TABLE IF NOT EXISTS jobs (
    id TEXT PRIMARY KEY,
    name TEXT NOT NULL,            -- input file name as dropped
    rel_path TEXT NOT NULL,        -- path inside drop_dir as dropped (subfolder/name)
    input_path TEXT NOT NULL,      -- where the input is now (claimed, done or failed)
    sidecar_path TEXT,             -- where its sidecar is now, if any
    input_hash TEXT,
    target TEXT,                   -- subfolder: printer or profile name, or NULL
    profile TEXT,
    printer TEXT,                  -- printer chosen when printing starts
    priority INTEGER NOT NULL DEFAULT 0,
    copies INTEGER NOT NULL DEFAULT 1,
    copies_done INTEGER NOT NULL DEFAULT 0,
    state TEXT NOT NULL,
    progress REAL NOT NULL DEFAULT 0,
    last_line INTEGER NOT NULL DEFAULT 0,
    error TEXT,
    error_code TEXT,
    plan_key TEXT,
    outbox TEXT,
    node_id TEXT,
    created_at REAL NOT NULL,
    updated_at REAL NOT NULL,
    started_at REAL,
    finished_at REAL,
    seq INTEGER NOT NULL,
    decision TEXT,                 -- why a ready plan waits for a person (outside limits)
    stage TEXT                     -- while planning: the stage and the time so far
);
CREATE INDEX IF NOT EXISTS jobs_state ON jobs(state);
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    job_id TEXT NOT NULL,
    at REAL NOT NULL,
    kind TEXT NOT NULL,
    message TEXT
);
CREATE INDEX IF NOT EXISTS events_job ON events(job_id);
CREATE TABLE IF NOT EXISTS control (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    at REAL NOT NULL,
    action TEXT NOT NULL,
    target TEXT NOT NULL,
    done_at REAL,
    ok INTEGER,
    result TEXT
);
CREATE TABLE IF NOT EXISTS printers (
    name TEXT PRIMARY KEY,
    state TEXT,
    paused INTEGER NOT NULL DEFAULT 0,
    held TEXT,
    job_id TEXT,
    updated_at REAL
);
COMMIT;
"""

_FIELDS = ("name", "rel_path", "input_path", "sidecar_path", "input_hash", "target", "profile",
           "printer", "priority", "copies", "copies_done", "state", "progress", "last_line",
           "error", "error_code", "plan_key", "outbox", "node_id", "started_at", "finished_at",
           "decision", "stage")


_BUSY_TIMEOUT_S = 30.0
DISK_FULL = "jobs.disk_full"


def _retry_locked(call, timeout_s=_BUSY_TIMEOUT_S):
    """Run ``call()``, retrying while SQLite reports the file locked.

    SQLite's busy handler waits for ordinary locks, but where two connections
    would deadlock (both holding a read lock, both wanting to write, as when
    two processes switch the journal mode at once) it returns "database is
    locked" at once; backing off and trying again is the documented cure.
    """
    deadline = time.monotonic() + timeout_s
    delay = 0.01
    while True:
        try:
            return call()
        except sqlite3.OperationalError as exc:
            text = str(exc).lower()
            if ("locked" not in text and "busy" not in text) or time.monotonic() > deadline:
                raise
            time.sleep(delay)
            delay = min(2 * delay, 0.5)


DAMAGED = "jobs.damaged"


def is_damage(exc):
    """Whether a SQLite error says the file is damaged (SQLITE_CORRUPT, SQLITE_NOTADB),
    not merely busy or full."""
    code = getattr(exc, "sqlite_errorcode", None)   # Python 3.11+; extended codes
    if code is not None:
        return (code & 0xFF) in (11, 26)
    text = str(exc)
    return "malformed" in text or "not a database" in text


def open_checked(path):
    """The daemon's own store, checked first (``PRAGMA quick_check``).

    A file damaged (a power cut mid-write on an SD card that lies about flushing, a
    failing card) is moved aside with its WAL, never deleted, and a new one started.
    Returns (store, where the damaged file went or None, SQLite's verdict or None).
    """
    try:
        store = JobStore(path)
        verdict = store.db.execute("PRAGMA quick_check").fetchone()[0]
    except sqlite3.DatabaseError as exc:
        if not is_damage(exc):
            raise
        store, verdict = None, str(exc)
    if verdict == "ok":
        return store, None, None
    if store is not None:
        store.close()
    stamp, n = time.strftime("%Y%m%d-%H%M%S"), 1
    aside = Path("%s.damaged-%s" % (path, stamp))
    while aside.exists():              # never over an earlier one
        n += 1
        aside = Path("%s.damaged-%s-%d" % (path, stamp, n))
    for suffix in ("", "-wal", "-shm"):   # "-wal" stays beside its file, for .recover
        if Path(str(path) + suffix).exists():
            Path(str(path) + suffix).rename(str(aside) + suffix)
    return JobStore(path), aside, verdict


def new_job_id():
    """Sortable and safe in paths: ``YYYYmmdd-HHMMSS-`` and 12 hex digits. Ids made in
    one second differ by their random part alone: with 6 digits, a folder of a few
    hundred files taken at once collided now and then."""
    return time.strftime("%Y%m%d-%H%M%S", time.gmtime()) + "-" + uuid.uuid4().hex[:12]


class JobStore:
    """Jobs, their events, printer flags and control requests in one SQLite file.

    Each instance holds one connection; use one instance per thread.
    """

    def __init__(self, path, create=True):
        self.path = Path(path)
        if not create and not self.path.exists():
            raise HostdError("no job database here", code="jobs.missing", file=self.path,
                             fix="start the daemon once with `hostd run` (same --config)")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.db = sqlite3.connect(str(self.path), timeout=_BUSY_TIMEOUT_S, isolation_level=None)
        self.db.row_factory = sqlite3.Row
        self.db.execute("PRAGMA synchronous=NORMAL")
        if create:
            # WAL is a property of the file: set once by its owner, every later
            # connection (CLI, web) uses it without asking.
            _retry_locked(lambda: self.db.execute("PRAGMA journal_mode=WAL"))
            _retry_locked(self._create_tables)
        elif not self.db.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' "
                                 "AND name = 'jobs'").fetchone():
            # Readers never create or convert: a reader doing so while the daemon
            # did the same deadlocked them, and the daemon failed to start.
            self.db.close()
            raise HostdError("the job database is not set up yet", code="jobs.missing",
                             file=self.path, fix="start the daemon once with `hostd run` "
                             "(same --config) and wait until it is up")

    def _create_tables(self):
        try:
            self.db.executescript(_SCHEMA)
            # Stores made before printers could be held get the column that says why.
            cols = {r[1] for r in self.db.execute("PRAGMA table_info(printers)")}
            if "held" not in cols:
                self.db.execute("ALTER TABLE printers ADD COLUMN held TEXT")
            # ... and before a plan could wait for a person's decision.
            cols = {r[1] for r in self.db.execute("PRAGMA table_info(jobs)")}
            for col in ("decision", "stage"):
                if col not in cols:
                    self.db.execute("ALTER TABLE jobs ADD COLUMN %s TEXT" % col)
        except sqlite3.OperationalError:
            if self.db.in_transaction:
                self.db.rollback()
            raise

    def close(self):
        self.db.close()

    @contextlib.contextmanager
    def _writing(self):
        """Turn SQLite's "database or disk is full" (SQLITE_FULL, 13) into :data:`DISK_FULL`."""
        try:
            yield
        except sqlite3.OperationalError as exc:
            code = getattr(exc, "sqlite_errorcode", None)   # Python 3.11+
            if not (code == 13 if code is not None else "disk is full" in str(exc)):
                raise
            raise HostdError(
                "cannot record jobs: SQLite reports the database or its disk full (%s)"
                % disk_text(self.path.parent),
                code=DISK_FULL, file=self.path,
                fix="free space on that disk (old logs: `journalctl --vacuum-size=100M`; "
                    "finished jobs' folders in the outbox); hostd goes on by itself once "
                    "there is room") from exc

    def probe(self):
        """Raise :data:`DISK_FULL` unless the database can grow by a few pages now.

        The row spans overflow pages and is gone again before the commit, so nobody sees it,
        but the pages are allocated and written as for any growing write.
        """
        with self._writing(), self.db:
            self.db.execute("BEGIN IMMEDIATE")
            cur = self.db.execute("INSERT INTO control (at, action, target, done_at, ok, result) "
                                  "VALUES (0, 'probe', '', 0, 1, ?)", ("." * 16384,))
            self.db.execute("DELETE FROM control WHERE id = ?", (cur.lastrowid,))

    # -- jobs ------------------------------------------------------------------------------

    def add(self, name, rel_path, input_path, **values):
        """Insert a queued job; returns its id."""
        job_id = values.pop("id", None) or new_job_id()
        now = time.time()
        values = dict(values, name=name, rel_path=rel_path, input_path=str(input_path))
        values.setdefault("state", QUEUED)
        cols = ["id", "created_at", "updated_at", "seq"] + [k for k in values if k in _FIELDS]
        with self._writing(), self.db:
            self.db.execute("BEGIN IMMEDIATE")
            seq = self.db.execute("SELECT COALESCE(MAX(seq), 0) + 1 FROM jobs").fetchone()[0]
            row = [job_id, now, now, seq] + [values[k] for k in cols[4:]]
            self.db.execute("INSERT INTO jobs (%s) VALUES (%s)" % (", ".join(cols),
                                                                   ", ".join("?" * len(cols))), row)
            self._event(job_id, "created", "%s queued (%s)" % (name, rel_path), now)
        return job_id

    def get(self, job_id):
        row = self.db.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone()
        if row is None:
            row = self.db.execute("SELECT * FROM jobs WHERE id LIKE ? ORDER BY seq",
                                  (job_id + "%",)).fetchall()
            row = row[0] if len(row) == 1 else None
        return dict(row) if row else None

    def require(self, job_id):
        job = self.get(job_id)
        if job is None:
            raise HostdError("no job %r" % job_id, code="jobs.unknown",
                             fix="list the jobs with `hostd jobs`")
        return job

    def update(self, job_id, event=None, **values):
        """Set fields (and ``updated_at``); with ``event=(kind, message)`` log it too."""
        bad = [k for k in values if k not in _FIELDS]
        if bad:
            raise ValueError("unknown job fields %s" % bad)
        now = time.time()
        sets = ", ".join(["updated_at = ?"] + ["%s = ?" % k for k in values])
        with self._writing(), self.db:
            self.db.execute("BEGIN IMMEDIATE")
            self.db.execute("UPDATE jobs SET %s WHERE id = ?" % sets,
                            [now] + list(values.values()) + [job_id])
            if event:
                self._event(job_id, event[0], event[1], now)

    def set_state(self, job_id, state, message=None, **values):
        if state not in STATES:
            raise ValueError(state)
        if state in FINISHED:
            values.setdefault("finished_at", time.time())
        self.update(job_id, event=(state, message or state), state=state, **values)

    def list(self, state=None, limit=None):
        sql, args = "SELECT * FROM jobs", []
        if state:
            states = [state] if isinstance(state, str) else list(state)
            sql += " WHERE state IN (%s)" % ", ".join("?" * len(states))
            args += states
        sql += " ORDER BY seq"
        if limit:
            sql += " LIMIT %d" % int(limit)
        return [dict(r) for r in self.db.execute(sql, args)]

    def next_in_order(self, state):
        """Jobs in ``state`` by priority (high first), then arrival."""
        return [dict(r) for r in self.db.execute(
            "SELECT * FROM jobs WHERE state = ? ORDER BY priority DESC, seq", (state,))]

    def find_active(self, rel_path):
        row = self.db.execute("SELECT id FROM jobs WHERE rel_path = ? AND state IN (%s)"
                              % ", ".join("?" * len(ACTIVE)), (rel_path,) + ACTIVE).fetchone()
        return row[0] if row else None

    def recover(self):
        """After a restart: planning -> queued; printing -> interrupted. Returns changed ids."""
        changed = []
        for job in self.list(PLANNING):
            self.set_state(job["id"], QUEUED, "daemon restarted while planning: planning again")
            changed.append(job["id"])
        for job in self.list(PRINTING):
            self.set_state(job["id"], INTERRUPTED,
                           "daemon stopped while printing (line %d): check the bed, then "
                           "`hostd requeue %s`" % (job["last_line"], job["id"]),
                           error="the print was interrupted (daemon stopped or crashed)",
                           error_code="job.interrupted")
            changed.append(job["id"])
        return changed

    # -- events ------------------------------------------------------------------------------

    def _event(self, job_id, kind, message, at=None):
        self.db.execute("INSERT INTO events (job_id, at, kind, message) VALUES (?, ?, ?, ?)",
                        (job_id, at or time.time(), kind, message))

    def event(self, job_id, kind, message):
        with self._writing(), self.db:
            self._event(job_id, kind, message)

    def events(self, job_id):
        return [dict(r) for r in self.db.execute(
            "SELECT at, kind, message FROM events WHERE job_id = ? ORDER BY id", (job_id,))]

    # -- printers --------------------------------------------------------------------------

    def set_printer(self, name, **values):
        now = time.time()
        with self._writing(), self.db:
            self.db.execute("INSERT INTO printers (name, updated_at) VALUES (?, ?) "
                            "ON CONFLICT(name) DO UPDATE SET updated_at = excluded.updated_at",
                            (name, now))
            if values:
                sets = ", ".join("%s = ?" % k for k in values)
                self.db.execute("UPDATE printers SET %s WHERE name = ?" % sets,
                                list(values.values()) + [name])

    def printers(self):
        return {r["name"]: dict(r) for r in self.db.execute("SELECT * FROM printers")}

    # -- control requests (CLI -> daemon) --------------------------------------------------

    def request(self, action, target):
        with self._writing(), self.db:
            cur = self.db.execute("INSERT INTO control (at, action, target) VALUES (?, ?, ?)",
                                  (time.time(), action, target))
        return cur.lastrowid

    def pending_requests(self):
        return [dict(r) for r in self.db.execute(
            "SELECT * FROM control WHERE done_at IS NULL ORDER BY id")]

    def answer(self, request_id, ok, result):
        with self._writing():
            self.db.execute("UPDATE control SET done_at = ?, ok = ?, result = ? WHERE id = ?",
                            (time.time(), int(bool(ok)), result, request_id))

    def wait_answer(self, request_id, timeout_s=15.0, poll_s=0.05):
        """(ok, result) once the daemon answered, or None after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            row = self.db.execute("SELECT ok, result FROM control WHERE id = ? AND done_at IS "
                                  "NOT NULL", (request_id,)).fetchone()
            if row:
                return bool(row["ok"]), row["result"]
            time.sleep(poll_s)
        return None


def summary(job):
    """A JSON-ready subset of a job row for status files and the web page."""
    keys = ("id", "name", "state", "printer", "profile", "progress", "priority", "error")
    return json.loads(json.dumps({k: job.get(k) for k in keys}))

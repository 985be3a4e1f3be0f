"""What the page and the API show: cheap snapshots of the store and the running daemon.

Nothing here talks to a printer or waits for the run loop: rows come from the job store
(one SQLite connection per web thread, WAL readers never block the daemon's writer) and
live values (state, temperatures, line counters) are copies the driver thread keeps.
"""

import bisect
import concurrent.futures
import errno
import os
import stat
import threading
import time
from pathlib import Path

from hostd import jobs as J
from hostd import share
from hostd.errors import HostdError
from hostd.watcher import shown
from hostd.web.shape import shape_lines

PAGE_STATES = ("idle", "heating", "printing", "paused", "error", "disconnected")
_STATE_MAP = {"connecting": "disconnected", "stopped": "disconnected", None: "disconnected"}
HISTORY_POINTS = 120       # temperature samples per heater sent to a client
RECENT_JOBS = 20
QUEUE_STATES = (J.QUEUED, J.PLANNING, J.READY)


def page_state(driver_state, paused=False):
    """One of :data:`PAGE_STATES` for a driver/store printer state (``paused`` = operator flag)."""
    state = _STATE_MAP.get(driver_state, driver_state)
    if state not in PAGE_STATES:
        state = "error" if state else "disconnected"
    if paused and state == "idle":
        state = "paused"
    return state


def _downsample(samples, n=HISTORY_POINTS):
    if len(samples) <= n:
        return samples
    step = len(samples) / float(n)
    return [samples[int(i * step)] for i in range(n - 1)] + [samples[-1]]


SHARE_HUNG = object()   # what a share read returns when it did not answer in time
UPLOAD_WAIT_S = 30.0    # an upload to a slow share takes a while; one that hangs, no longer


class _ShareReads:
    """Calls on the share for the web threads (reads, uploads), given up after ``timeout_s``.

    A share that stops answering (an NFS server rebooting) blocks every call on it; a
    page that waited would hold a server thread per poll, and within seconds none
    would be left to answer anything, an emergency stop included. So a read runs on a
    helper thread; once one has not answered in time the page goes without the share's
    files (``default``) until that read returns.
    """

    def __init__(self, timeout_s=2.0):
        self.timeout_s = float(timeout_s)
        self._pool = concurrent.futures.ThreadPoolExecutor(2, "hostd-web-share")
        self._hung = None

    def call(self, default, fn, *args, timeout_s=None):
        """``fn(*args)``, or ``default`` when it has not returned within ``timeout_s``
        (default: the reads' 2 s) or an earlier call still hangs."""
        hung = self._hung
        if hung is not None and not hung.done():
            return default
        future = self._pool.submit(fn, *args)
        try:
            return future.result(self.timeout_s if timeout_s is None else timeout_s)
        except concurrent.futures.TimeoutError:
            self._hung = future
            return default


class ShareFile:
    """An outbox file read through :class:`_ShareReads`: a read that does not answer
    in time raises OSError, which ends the download, instead of holding the server
    thread until the share comes back."""

    # One hand-over to the helper thread per MB: servers ask for 32 kB at a time.
    READ_AHEAD = 1 << 20

    def __init__(self, share, f):
        self._share, self._f = share, f
        self._buf = memoryview(b"")

    def read(self, n=-1):
        if n is None or n < 0:
            n = 1 << 62
        if not self._buf:
            data = self._share.call(SHARE_HUNG, self._f.read, max(n, self.READ_AHEAD))
            if data is SHARE_HUNG:
                raise OSError(errno.ETIMEDOUT, "the share stopped answering during a download")
            self._buf = memoryview(data)
        out, self._buf = self._buf[:n], self._buf[n:]
        return bytes(out)

    def close(self):
        self._share.call(None, self._f.close)


def _open_confined(root, outbox, name):
    """(open binary file, os.stat_result) of ``name`` in ``outbox``, or None.

    None for anything but a regular file directly inside an outbox directly inside
    ``root``: no traversal, no symlinks (checked again on the open descriptor).
    """
    try:
        real_outbox = Path(outbox).resolve(strict=True)
        if real_outbox.parent != Path(root).resolve():
            return None
        path = real_outbox / name
        if not stat.S_ISREG(os.lstat(path).st_mode):
            return None
        f = open(path, "rb", opener=lambda p, flags: os.open(p, flags | os.O_NOFOLLOW))
    except OSError:
        return None
    st = os.fstat(f.fileno())
    if not stat.S_ISREG(st.st_mode):
        f.close()
        return None
    return f, st


class _FileCache:
    """Parsed small files keyed by (path, mtime, size): reports, G-code layer starts."""

    def __init__(self, size=64):
        self._lock = threading.Lock()
        self._data = {}
        self._size = size

    def get(self, path, parse):
        try:
            st = os.stat(path)
        except OSError:
            return None
        key = (str(path), st.st_mtime_ns, st.st_size)
        with self._lock:
            if key in self._data:
                return self._data[key]
        try:
            value = parse(path)
        except (OSError, ValueError, HostdError):
            value = None
        with self._lock:
            if len(self._data) >= self._size:
                self._data.pop(next(iter(self._data)))
            self._data[key] = value
        return value


def _read_json(path):
    return share.read_json(path, share.REPORT_BYTES)


def _layer_starts(path):
    """(file line numbers where each ``;LAYER:n`` starts, layer count) of a G-code file."""
    starts, count = [], 0
    with share.open_file(path) as f:
        for number, raw in enumerate(f, 1):
            if raw.startswith(b";LAYER:"):
                starts.append(number)
            elif raw.startswith(b";LAYER_COUNT:"):
                count = int(raw.split(b":", 1)[1] or 0)
    return starts, count or len(starts)


def outbox_files(outbox):
    """Names of the regular files (never symlinks, never hidden) in a job's outbox."""
    if not outbox:
        return []
    try:
        entries = list(os.scandir(outbox))
    except OSError:
        return []
    out = []
    for e in entries:
        try:
            if not e.name.startswith(".") and stat.S_ISREG(e.stat(follow_symlinks=False).st_mode):
                out.append(e.name)
        except OSError:
            continue
    return sorted(out)


class NodeView:
    """Read-only view of one node for the web threads."""

    def __init__(self, config, daemon=None, db_path=None):
        self.config = config
        self.daemon = daemon
        self.db_path = Path(db_path or config.db_path)
        self._local = threading.local()
        self._files = _FileCache()
        self._share = _ShareReads()
        # Uploads on helpers of their own: a slow one must not starve the page's reads.
        self._uploads = _ShareReads(timeout_s=UPLOAD_WAIT_S)

    # -- store -----------------------------------------------------------------------------

    @property
    def store(self):
        store = getattr(self._local, "store", None)
        if store is None:
            store = self._local.store = J.JobStore(self.db_path)
        return store

    def job(self, job_id):
        row = self.store.db.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone()
        return dict(row) if row else None

    def outbox_file(self, job_id, name):
        """Job ``job_id``'s outbox file ``name`` for a download: (:class:`ShareFile`,
        os.stat_result), None when there is no such file (or the name tries to leave
        the outbox), or :data:`SHARE_HUNG` when the outbox's share does not answer."""
        row = self.job(job_id)
        if row is None or not row.get("outbox"):
            return None
        if not name or name in (".", "..") or "/" in name or "\\" in name or "\0" in name \
                or name.startswith("."):
            return None
        opened = self._share.call(SHARE_HUNG, _open_confined, self.config.outbox_dir,
                                  row["outbox"], name)
        if opened is None or opened is SHARE_HUNG:
            return opened
        f, st = opened
        return ShareFile(self._share, f), st

    def share_write(self, fn, *args, timeout_s=None):
        """``fn(abandoned, *args)`` on the share helper: its result, or :data:`SHARE_HUNG`
        when it has not returned within ``timeout_s`` (default :data:`UPLOAD_WAIT_S`: one
        that stops answering must not hold the server thread). ``abandoned``
        (threading.Event) is set then, so a write that finishes later can undo itself
        instead of landing after the person was told it did not."""
        abandoned = threading.Event()
        result = self._uploads.call(SHARE_HUNG, fn, abandoned, *args, timeout_s=timeout_s)
        if result is SHARE_HUNG:
            abandoned.set()
        return result

    def outbox_stat(self, job, name):
        """os.stat_result of ``name`` in the job row's outbox, or None (missing, or the
        share does not answer)."""
        if not job.get("outbox"):
            return None

        def look():
            try:
                return os.stat(Path(job["outbox"]) / name)
            except OSError:
                return None
        return self._share.call(None, look)

    def counts(self):
        rows = self.store.db.execute("SELECT state, COUNT(*) FROM jobs GROUP BY state")
        out = {s: 0 for s in J.STATES}
        out.update({r[0]: r[1] for r in rows})
        return out

    def endings(self):
        """How many times jobs ended in each finished state, ever: a counter, read from
        the events (a requeued job leaves its state, never its history). A cancel counts
        only where a print had started (its job's state before it was printing)."""
        states = ", ".join("?" * len(J.STATES))
        rows = self.store.db.execute(
            "SELECT e.kind, COUNT(*) FROM events e WHERE e.kind IN (?, ?, ?, ?) AND (e.kind != ? "
            "OR (SELECT p.kind FROM events p WHERE p.job_id = e.job_id AND p.id < e.id AND "
            "p.kind IN (%s) ORDER BY p.id DESC LIMIT 1) = ?) GROUP BY e.kind" % states,
            J.FINISHED + (J.CANCELLED,) + tuple(J.STATES) + (J.PRINTING,))
        return {r[0]: r[1] for r in rows}

    def jobs(self, state=None, limit=200):
        sql, args = "SELECT * FROM jobs", []
        if state:
            states = [state] if isinstance(state, str) else list(state)
            sql += " WHERE state IN (%s)" % ", ".join("?" * len(states))
            args += states
        sql += " ORDER BY seq DESC LIMIT %d" % int(limit)
        return [dict(r) for r in self.store.db.execute(sql, args)]

    def queue(self):
        rows = self.store.db.execute(
            "SELECT * FROM jobs WHERE state IN (?, ?, ?) ORDER BY priority DESC, seq",
            QUEUE_STATES)
        return [dict(r) for r in rows]

    def recent(self, limit=RECENT_JOBS):
        rows = self.store.db.execute(
            "SELECT * FROM jobs WHERE state IN (?, ?, ?, ?) ORDER BY finished_at DESC, seq DESC "
            "LIMIT %d" % int(limit), J.FINISHED)
        return [dict(r) for r in rows]

    # -- jobs ------------------------------------------------------------------------------

    def report(self, job):
        for name in self._share.call([], outbox_files, job.get("outbox")):
            if name.endswith(".report.json"):
                return self._share.call(None, self._files.get, Path(job["outbox"]) / name,
                                        _read_json)
        return None

    def job_info(self, job, live=None, with_report=False):
        """A JSON-ready job: store fields, outputs, and (printing) layer, elapsed and ETA."""
        keys = ("id", "name", "state", "printer", "profile", "target", "priority", "copies",
                "copies_done", "progress", "error", "error_code", "created_at", "updated_at",
                "started_at", "finished_at", "decision")
        info = {k: job.get(k) for k in keys}
        info["stage"] = job.get("stage") if job["state"] == J.PLANNING else None
        files = self._share.call([], outbox_files, job.get("outbox"))
        info["files"] = files
        stem = next((f[:-len(".toolpath.png")] for f in files if f.endswith(".toolpath.png")),
                    None)
        info["images"] = {kind: "%s.%s.png" % (stem, kind)
                          for kind in ("input", "preview", "toolpath", "stress", "texture")
                          if stem and "%s.%s.png" % (stem, kind) in files}
        info["elapsed_s"] = info["eta_s"] = info["layer"] = info["layers"] = None
        if job["state"] == J.PRINTING:
            last_line = job.get("last_line") or 0
            elapsed = time.time() - job["started_at"] if job.get("started_at") else None
            if live:
                total = live.get("total") or 0
                info["progress"] = round(live["confirmed"] / total, 4) if total else 0.0
                last_line = live.get("last_confirmed_line", last_line)
                elapsed = live.get("seconds", elapsed)
            p = info["progress"] or 0.0
            info["elapsed_s"] = round(elapsed, 1) if elapsed is not None else None
            if elapsed and p > 0.001:
                info["eta_s"] = round(elapsed * (1.0 - p) / p, 1)
            gcode = next((f for f in files if f.endswith(".gcode")), None)
            if gcode:
                layers = self._share.call(None, self._files.get, Path(job["outbox"]) / gcode,
                                          _layer_starts)
                if layers:
                    starts, count = layers
                    info["layer"] = max(1, bisect.bisect_right(starts, last_line))
                    info["layers"] = count
        if with_report:
            info["report"] = self.report(job)
            info["shape"] = shape_lines(info["report"])
            info["events"] = self.store.events(job["id"])
        return info

    # -- printers ----------------------------------------------------------------------------

    def printers(self, history=False):
        rows = self.store.printers()
        out = []
        if self.daemon is None:
            names = [p.name for p in self.config.printers]
            for name in names:
                row = rows.get(name, {})
                out.append(self._printer_dict(name, row.get("state"), bool(row.get("paused")),
                                              row.get("job_id"), None, {}, {}, None, None,
                                              held=row.get("held")))
            return out
        for slot in self.daemon.slots:
            printer = slot.printer
            temps, hist, stats, starvation, live = {}, {}, {}, None, None
            if printer is not None:
                temps = printer.temperatures.current()
                if history:
                    hist = {h: _downsample(s) for h, s in printer.temperatures.history().items()}
                stats = {k: printer.stats.get(k, 0) for k in ("lines_sent", "resends",
                                                              "lines_resent", "timeouts")}
                sim = getattr(printer, "simulator", None)
                if sim is not None:
                    starvation = sim.firmware.stats.get("starvation_s")
                else:        # the link's own process reports its simulator's figure
                    starvation = printer.stats.get("starvation_s")
            link_job = slot.link_job
            if link_job is not None:
                live = link_job.snapshot()
            out.append(self._printer_dict(slot.name, slot.state, slot.paused,
                                          slot.job_id, live, temps, stats,
                                          starvation, slot.last_error, hist if history else None,
                                          slot.config.profile, held=slot.held))
        return out

    def _printer_dict(self, name, state, paused, job_id, live, temps, stats, starvation,
                      error, history=None, profile=None, held=None):
        cfg = self.config.printer(name)
        job = self.job(job_id) if job_id else None
        d = {"name": name, "profile": profile or (cfg.profile if cfg else None),
             "state": page_state(state, paused), "link_state": state, "paused": bool(paused),
             "temperatures": temps, "lines_sent": stats.get("lines_sent"),
             "resends": stats.get("resends"), "starvation_s": starvation, "error": error,
             "held": held,
             # The bed is not known clear: nothing starts here until a person says it is.
             "waiting_for_person": held is not None,
             # A printer that is not answering reports nothing new: its readings are old.
             "temperatures_stale": page_state(state, paused) in ("error", "disconnected"),
             "job": self.job_info(job, live) if job else None}
        if history is not None:
            d["history"] = history
        return d

    # -- node --------------------------------------------------------------------------------

    def status(self, history=False):
        from hostd import __version__
        printers = self.printers(history=history)
        queue = [self.job_info(j) for j in self.queue()]
        recent = [self.job_info(j) for j in self.recent()]
        # Changes when a job starts, ends or moves: the page reloads then, else it patches.
        sig = ";".join([",".join("%s=%s%s" % (p["name"], p["job"]["id"] if p["job"] else "",
                                              "!" if p["held"] else "")
                                 for p in printers),
                        ",".join("%s:%s" % (j["id"], j["state"]) for j in queue),
                        ",".join("%s:%s" % (j["id"], j["state"]) for j in recent[:5])])
        problem = self.daemon.problem if self.daemon is not None else None
        dropped = self.drop_folder()
        sig += ";" + (problem or "") + ";" + ",".join(
            "%s:%d" % (f["file"], f["complete"]) for f in dropped)
        return {"node_id": self.config.node_id, "version": __version__, "time": time.time(),
                "daemon": self.daemon is not None, "problem": problem, "printers": printers,
                "queue": queue, "recent": recent, "signature": sig, "drop_folder": dropped,
                "waiting_for_person": [p["name"] for p in printers if p["waiting_for_person"]],
                "counts": self.counts(), "token_configured": bool(self.config.web.token)}

    def drop_folder(self):
        """Inputs in the drop folder that are no job yet: still being copied, or left there
        for whichever node has a printer free (a node with live peers takes only what it
        can start soon). From the daemon's last scan, less what was claimed since."""
        if self.daemon is None:
            return []
        drop = Path(self.config.drop_dir)
        inputs = self.daemon.dropped()
        there = self._share.call([], lambda: [os.path.exists(drop / i["file"]) for i in inputs])
        return [dict(i, file=shown(i["file"])) for i, present in zip(inputs, there) if present]

    def nodes(self, stale_s=None):
        """Every node's status file on the share, with ``stale`` and ``age_s``."""
        from hostd.farm import Farm
        stale_s = stale_s or max(15.0, 3.0 * self.config.heartbeat_s)
        out = []
        farm = Farm(self.config.drop_dir, self.config.node_id)
        for node_id, (data, age) in self._share.call({}, farm.nodes).items():
            data = dict(data, node_id=node_id, age_s=round(max(age, 0.0), 1),
                        stale=age > stale_s or data.get("state") == "stopped",
                        printers=[dict(p, state=page_state(p.get("state"), p.get("paused")))
                                  for p in data.get("printers") or [] if isinstance(p, dict)])
            out.append(data)
        return out

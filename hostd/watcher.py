"""Watching the drop folder: which files are complete and may be taken.

A periodic scan every ``poll_s`` is the ground truth (NFS and SMB shares deliver no
inotify events); watchdog events, where they work, only make the next scan come
sooner and tell us a file arrived by rename (complete at once). Otherwise a file is
complete when its size and mtime have not changed for ``settle_s``; its sidecar
``NAME.yaml``, if present, must be complete too.

Layout: ``drop/NAME.ext`` (any printer) or ``drop/TARGET/NAME.ext`` where TARGET is a
printer or profile name. Hidden and partial names are ignored, symlinks are never
followed, deeper folders are not entered.
"""

import logging
import os
import re
import stat
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from hostd.names import hidden, visible

log = logging.getLogger("hostd.watcher")

INPUT_SUFFIXES = (".png", ".tif", ".tiff", ".npy", ".npz", ".stl", ".obj", ".ply", ".glb")
SIDECAR_SUFFIX = ".yaml"
_PARTIAL_SUFFIXES = (".part", ".tmp", ".crdownload", ".partial", ".download", ".swp")
MAX_NAME_BYTES = 200


class QuietShutdownRace(logging.Filter):
    """Drops watchdog's ERROR that its inotify thread read one last event while stopping.

    watchdog logs it when something in the folder changes in the instant the
    observer stops (seen when stopping the daemon mid-print); nothing is lost,
    since the next start scans the folder, and to a user it reads like a failure.
    """

    MESSAGE = "InotifyEmitter.queue_events() called when the thread is inactive"

    def filter(self, record):
        return record.getMessage() != self.MESSAGE


def ignored(name):
    """Hidden, temporary and partial-download names (``.*``, ``*.part``, ``~$*`` ...)."""
    low = name.lower()
    return (name.startswith(".") or name.startswith("~$") or name.startswith(".~lock.")
            or low.endswith(_PARTIAL_SUFFIXES) or name.endswith("~"))


def safe_stem(name, limit=60):
    """A file-system- and shell-safe stem for ``name`` (untrusted): ``[A-Za-z0-9._-]``."""
    stem = Path(name).stem
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", stem).strip("._-") or "input"
    return stem[:limit]


def shown(name):
    """``name`` as text any page, log or database can hold: bytes that are not UTF-8
    (carried by Python as surrogates) become U+FFFD, and characters that would change how
    it reads (a right-to-left override, controls) are written as escapes."""
    return visible(os.fsencode(name).decode("utf-8", "replace"))


def name_problem(name):
    """Why an untrusted file name cannot be taken as is (None when it is fine)."""
    try:
        raw = os.fsencode(name)
        raw.decode("utf-8")
    except UnicodeError:
        return "the name is not valid UTF-8"
    if len(raw) > MAX_NAME_BYTES:
        return "the name is longer than %d bytes" % MAX_NAME_BYTES
    if any(ord(c) < 32 or ord(c) == 127 for c in name):
        return "the name contains control characters"
    if any(hidden(c) for c in name):
        return "the name contains characters that change how it reads (%s)" % ", ".join(
            sorted({"U+%04X" % ord(c) for c in name if hidden(c)}))
    return None


@dataclass(frozen=True)
class Candidate:
    """A complete input in the drop folder, ready to be claimed."""
    path: Path            # drop/[TARGET/]NAME.ext
    rel_path: str         # "NAME.ext" or "TARGET/NAME.ext"
    target: str           # TARGET or None
    sidecar: Path         # drop/[TARGET/]NAME.yaml, or None
    # Other inputs of the same stem beside a sidecar ("t.png" with "t.npy" and "t.yaml"):
    # whose the sidecar is cannot be known, and both are refused naming each other.
    others: tuple = ()


class _Events:
    """watchdog handler: remember files that arrived by rename and wake the scanner."""

    def __init__(self, watcher):
        self.watcher = watcher

    def dispatch(self, event):
        if getattr(event, "is_directory", False):
            self.watcher.wake.set()
            return
        dest = getattr(event, "dest_path", None)
        if event.event_type == "moved" and dest:
            with self.watcher.lock:
                self.watcher.renamed.add(os.fsdecode(dest))
        self.watcher.wake.set()


class Watcher:
    """Scan ``drop_dir`` and report :class:`Candidate` files once complete.

    ``poll()`` returns each complete candidate once per appearance; after the daemon
    claims (renames) it, it is gone from the next scan.
    """

    def __init__(self, drop_dir, settle_s=2.0, poll_s=2.0, clock=time.monotonic):
        self.drop_dir = Path(drop_dir)
        self.settle_s = float(settle_s)
        self.poll_s = float(poll_s)
        self.clock = clock
        self.wake = threading.Event()
        self.lock = threading.Lock()
        self.renamed = set()
        self._seen = {}          # path -> ((size, mtime_ns, inode), stable since, by_rename)
        self._reported = set()
        self._next_scan = 0.0
        self._observer = None
        self.inputs = []         # (rel path, bytes, complete) of the inputs at the last scan

    def start(self):
        """Start watchdog if it can watch this folder; the scan works without it."""
        self.drop_dir.mkdir(parents=True, exist_ok=True)
        try:
            from watchdog.observers import Observer
            inotify_log = logging.getLogger("watchdog.observers.inotify")
            if not any(isinstance(f, QuietShutdownRace) for f in inotify_log.filters):
                inotify_log.addFilter(QuietShutdownRace())
            observer = Observer()
            observer.schedule(_Events(self), str(self.drop_dir), recursive=True)
            observer.daemon = True
            observer.start()
            self._observer = observer
        except Exception as exc:  # no inotify (share, container limits): scanning is enough
            log.info("drop folder events unavailable (%s); scanning every %.1f s", exc, self.poll_s)
            self._observer = None

    def stop(self):
        if self._observer is not None:
            self._observer.stop()
            self._observer.join(2)
            self._observer = None

    def due(self, now=None):
        now = self.clock() if now is None else now
        return now >= self._next_scan or self.wake.is_set()

    def _files(self):
        """(path, rel, target) of every visible regular file, one folder level deep."""
        out = []
        try:
            top = list(os.scandir(self.drop_dir))
        except OSError as exc:
            log.warning("cannot read the drop folder %s: %s", self.drop_dir, exc)
            return out
        for entry in top:
            if ignored(entry.name) or entry.is_symlink():
                continue
            if entry.is_dir(follow_symlinks=False):
                try:
                    inner = list(os.scandir(entry.path))
                except OSError:
                    continue
                for sub in inner:
                    if not ignored(sub.name) and not sub.is_symlink() \
                            and sub.is_file(follow_symlinks=False):
                        out.append((Path(sub.path), entry.name + "/" + sub.name, entry.name, sub))
            elif entry.is_file(follow_symlinks=False):
                out.append((Path(entry.path), entry.name, None, entry))
        return out

    def poll(self, now=None):
        """Scan if due; return the complete candidates not reported before."""
        now = self.clock() if now is None else now
        if not self.due(now):
            return []
        self.wake.clear()
        self._next_scan = now + self.poll_s
        with self.lock:
            renamed, self.renamed = self.renamed, set()
        files = self._files()
        present = set()
        states = {}
        for path, rel, target, entry in files:
            try:
                st = entry.stat(follow_symlinks=False)
            except OSError:
                continue
            if not stat.S_ISREG(st.st_mode):
                continue
            key = str(path)
            present.add(key)
            old = self._seen.get(key)
            # The inode tells a new file from the one reported before under the same name
            # (the first claimed and a second dropped or uploaded between two scans): a
            # new file is offered anew, never hidden behind the first's report.
            sig = (st.st_size, st.st_mtime_ns, st.st_ino)
            by_rename = key in renamed
            if old is None or old[0] != sig:
                self._seen[key] = (sig, now, by_rename)
                self._reported.discard(key)
            elif by_rename:
                self._seen[key] = old[:2] + (True,)
            complete = self._seen[key][2] or now - self._seen[key][1] >= self.settle_s
            states[key] = complete
        for key in list(self._seen):
            if key not in present:
                del self._seen[key]
                self._reported.discard(key)
        # What people see waiting in the drop folder (a file still being copied, or one
        # left for other nodes): replaced whole, read by the web threads.
        self.inputs = [(rel, self._seen[str(path)][0][0], states[str(path)])
                       for path, rel, _, _ in files
                       if path.suffix.lower() in INPUT_SUFFIXES and str(path) in states]
        out = []
        stems = {}
        for path, rel, _, _ in files:
            if path.suffix.lower() in INPUT_SUFFIXES:
                stems.setdefault(str(path.with_suffix("")), []).append(rel)
        for path, rel, target, _ in files:
            key = str(path)
            if path.suffix.lower() not in INPUT_SUFFIXES or not states.get(key):
                continue
            if key in self._reported:
                continue
            sidecar = path.with_name(path.stem + SIDECAR_SUFFIX)
            skey = str(sidecar)
            if skey in present and not states.get(skey):
                continue  # the sidecar is still being written: wait for both
            self._reported.add(key)
            others = tuple(r for r in stems[str(path.with_suffix(""))] if r != rel) \
                if skey in present else ()
            out.append(Candidate(path, rel, target, sidecar if skey in present else None,
                                 others))
        return out

    def forget(self, candidate):
        """Report ``candidate`` again at the next scan if it is still there (claim failed)."""
        self._reported.discard(str(candidate.path))

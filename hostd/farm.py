"""Several nodes, one share: claims, leases, node status files, archives and the plan cache.

- Claim: rename ``drop/[TARGET/]NAME.ext`` to ``drop/.claimed/<node>/<TARGET|@>/SAFE.ext``.
  Rename within one filesystem is atomic (local disks, NFS, SMB): one node wins, the
  others get ENOENT. The sidecar follows its file.
- Lease: each node rewrites ``drop/.claimed/<node>/.lease`` every heartbeat; a node
  whose lease is older than ``lease_s`` is dead and any node moves its claimed files
  back into the drop folder.
- Ages on the share are read on the share's clock: a file's modification time (set
  by the file server when written) against that of this node's own lease, renewed
  every heartbeat. The nodes' own clocks never enter: a Raspberry Pi without a
  battery-backed clock, or a NAS whose clock is off, would otherwise make a live
  node look dead (its files released and printed twice) or a dead one alive.
- Status: ``drop/.hostd/nodes/<node>.json`` (printers, state, current job, queue
  length, last seen), written atomically.
- Inputs are never deleted: ``done/YYYY-MM-DD/`` after success, ``failed/`` beside
  ``NAME.error.txt`` otherwise.
- Plan cache: ``outbox/.cache/<key>/`` with key = hash(input, sidecar, profile hash,
  pipeline version).
"""

import errno
import glob
import hashlib
import json
import logging
import os
import shutil
import socket
import time
import uuid
from pathlib import Path

from hostd import share
from hostd.errors import HostdError
from hostd.outputs import atomic_write, json_text
from hostd.status import status_fields
from hostd.watcher import safe_stem

log = logging.getLogger("hostd.farm")

ROOT_TARGET = "@"   # claimed-folder name for files dropped at the top of the drop folder


def unique_path(path):
    """``path``, or ``NAME-2.ext``, ``NAME-3.ext`` ... whichever does not exist yet."""
    path = Path(path)
    if not os.path.lexists(path):
        return path
    for i in range(2, 100000):
        other = path.with_name("%s-%d%s" % (path.stem, i, path.suffix))
        if not os.path.lexists(other):
            return other
    raise FileExistsError(path)


def file_hash(path):
    """sha256 hex digest of the regular file ``path`` (see :mod:`hostd.share`)."""
    return share.file_hash(path)


def plan_key(input_hash, sidecar_path, profile_hash, version):
    """Cache key of a plan: what goes in decides what comes out."""
    h = hashlib.sha256()
    h.update(input_hash.encode())
    h.update(b"\0")
    if sidecar_path and os.path.lexists(sidecar_path):
        from pipeline.input.sidecar import MAX_SIDECAR_BYTES
        h.update(share.read_bytes(sidecar_path, MAX_SIDECAR_BYTES))
    h.update(b"\0" + str(profile_hash).encode() + b"\0" + str(version).encode())
    return h.hexdigest()[:32]


def holder_text(holder):
    """A lease writer ("id host pid") as people read it."""
    words = (holder or "").split()
    if len(words) != 3:
        return "an older hostd" if not words else holder
    return "hostd pid %s on host %s (run %s)" % (words[2], words[1], words[0])


class Farm:
    """This node's view of the shared drop folder."""

    def __init__(self, drop_dir, node_id, lease_s=60.0):
        self.drop_dir = Path(drop_dir)
        self.node_id = node_id
        # Who writes the lease, this time round: a second hostd with the same node_id
        # (a cloned SD card keeps the hostname node_id comes from) writes another.
        self.holder = "%s %s %d" % (uuid.uuid4().hex[:12], socket.gethostname(), os.getpid())
        self._renewed = False
        self.lease_s = float(lease_s)
        self.claims_root = self.drop_dir / ".claimed"
        self.claim_dir = self.claims_root / node_id
        self.nodes_dir = self.drop_dir / ".hostd" / "nodes"

    def setup(self):
        for d in (self.claim_dir, self.nodes_dir):
            d.mkdir(parents=True, exist_ok=True)
        self.renew_lease()

    # -- claims ------------------------------------------------------------------------------

    def claim(self, candidate):
        """Rename the candidate (and its sidecar) into our claim folder.

        Returns ``(input_path, sidecar_path or None)``, or None when another node won.
        """
        folder = self.claim_dir / (candidate.target or ROOT_TARGET)
        folder.mkdir(parents=True, exist_ok=True)
        stem = safe_stem(candidate.path.name)
        dest = unique_path(folder / (stem + candidate.path.suffix.lower()))
        while os.path.lexists(dest.with_name(dest.stem + ".yaml")):
            dest = unique_path(dest.with_name(dest.stem + "-x" + dest.suffix))
        try:
            os.rename(candidate.path, dest)
        except FileNotFoundError:
            return None   # another node (or a person) took it first
        side = None
        if candidate.sidecar is not None:
            side = dest.with_name(dest.stem + ".yaml")
            try:
                os.rename(candidate.sidecar, side)
            except FileNotFoundError:
                side = None
        return dest, side

    def lease_holder(self):
        """The lease as last written: (its text after the time, mtime), or (None, None)."""
        try:
            with share.open_file(self.claim_dir / ".lease") as f:   # NFS revalidates on open
                words = f.read(share.SMALL_BYTES).decode("utf-8", "replace").split(None, 1)
                return (words[1].strip()[:200] if len(words) > 1 else ""), share.mtime(f)
        except (OSError, HostdError):
            return None, None

    def held_by_another(self, watch_s, poll_s=0.2):
        """At start-up, before the first renewal: whether another hostd still renews this
        node's lease. Unless its last writer stopped cleanly the lease is watched for
        ``watch_s``; returns the writer's "id host pid" if it is written meanwhile."""
        text, mtime = self.lease_holder()
        if text is None or text.startswith("stopped"):
            return None
        log.info("node %s's lease was last written by %s and not released (a crash, or "
                 "another hostd with this node_id): watching it for %.0f s",
                 self.node_id, holder_text(text), watch_s)
        deadline = time.monotonic() + watch_s
        while time.monotonic() < deadline:
            time.sleep(poll_s)
            now = self.lease_holder()
            if now != (text, mtime):
                return now[0] or text or "?"
        return None

    def renew_lease(self, state="running"):
        """Write the lease; returns who else wrote it since our last renewal (their
        "id host pid"), or None. ``state`` "stopped" tells the next start of this node
        that nobody holds it any more."""
        # Never the parents: a share that is not mounted must fail here, not be
        # recreated as empty folders on the local disk under its mount point.
        self.claim_dir.mkdir(exist_ok=True)
        other = None
        if self._renewed:
            text, _ = self.lease_holder()
            if text and not text.startswith(self.holder) and not text.startswith("stopped"):
                other = text
        atomic_write(self.claim_dir / ".lease", "%f %s\n" % (
            time.time(), self.holder if state != "stopped" else "stopped " + self.holder))
        self._renewed = True
        return other

    def share_now(self):
        """The share's time, within a heartbeat: when this node's lease was last renewed
        (this machine's clock only before the first renewal)."""
        try:
            return (self.claim_dir / ".lease").stat().st_mtime
        except OSError:
            return time.time()

    def release_dead(self, now=None):
        """Move claims of nodes whose lease expired back into the drop folder; returns count.

        ``now``: the share's time (default :meth:`share_now`).
        """
        now = self.share_now() if now is None else now
        moved = 0
        try:
            nodes = [d for d in os.scandir(self.claims_root) if d.is_dir(follow_symlinks=False)]
        except OSError:
            return 0
        for node in nodes:
            if node.name == self.node_id:
                continue
            lease = Path(node.path) / ".lease"
            try:
                age = now - lease.stat().st_mtime
            except FileNotFoundError:
                age = now - node.stat().st_mtime
            if age < self.lease_s:
                continue
            moved += self._release(Path(node.path))
        return moved

    def _release(self, node_dir):
        moved = 0
        for target_dir in node_dir.iterdir():
            if not target_dir.is_dir() or target_dir.is_symlink():
                continue
            dest_dir = self.drop_dir if target_dir.name == ROOT_TARGET else \
                self.drop_dir / target_dir.name
            dest_dir.mkdir(parents=True, exist_ok=True)
            # Sidecars first, so an input never reappears without its sidecar.
            entries = sorted(target_dir.iterdir(), key=lambda p: p.suffix.lower() != ".yaml")
            for path in entries:
                if path.name.startswith(".") or not path.is_file():
                    continue
                dest = dest_dir / path.name
                if os.path.lexists(dest):
                    continue
                try:
                    os.rename(path, dest)
                    moved += 1
                except OSError as exc:
                    if exc.errno != errno.ENOENT:
                        log.warning("cannot release %s: %s", path, exc)
        if moved:
            log.warning("released %d claimed files of dead node %s", moved, node_dir.name)
        return moved

    # -- node status --------------------------------------------------------------------------

    def publish_status(self, status):
        data = dict(status, node_id=self.node_id, last_seen=time.time(),
                    last_seen_utc=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))
        atomic_write(self.nodes_dir / (self.node_id + ".json"), json_text(data))

    def live_peers(self, now=None):
        """Other nodes whose status file is fresh (written within the lease) and not stopped."""
        return sorted(node for node, (data, age) in self.nodes(now).items()
                      if node != self.node_id and data.get("state") != "stopped"
                      and age < self.lease_s)

    def nodes(self, now=None):
        """Every node's status: {node: (data dict, seconds since written, share's clock)}."""
        now = self.share_now() if now is None else now
        out = {}
        for path in sorted(self.nodes_dir.glob("*.json")):
            try:
                with share.open_file(path) as f:   # an open, not a stat: NFS revalidates on open
                    raw = f.read(share.SMALL_BYTES + 1)
                    written = share.mtime(f)
                data = json.loads(raw) if len(raw) <= share.SMALL_BYTES else None
            except (OSError, ValueError, HostdError):
                continue
            if isinstance(data, dict):
                out[path.stem] = (status_fields(data), now - written)
        return out


# -- archives ----------------------------------------------------------------------------------

def _move(src, dest):
    dest.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.rename(src, dest)
    except OSError as exc:
        if exc.errno != errno.EXDEV:
            raise
        shutil.copy2(src, dest)      # another filesystem: copy, then remove the original
        os.unlink(src)


def archive(src, sidecar, dest_dir, name):
    """Move an input (and its sidecar) to ``dest_dir`` under its original ``name``.

    Returns (new input path, new sidecar path or None).
    """
    dest = unique_stem(Path(dest_dir) / name)
    _move(src, dest)
    side = None
    if sidecar and os.path.exists(sidecar):
        side = dest.with_name(dest.stem + ".yaml")
        _move(sidecar, side)
    return dest, side


def unique_stem(path):
    """``path``, or ``NAME-2.ext`` ..., whose stem no file in its folder has yet: an input
    filed there owns ``STEM.yaml`` and ``STEM.error.txt``, so ``part.npy`` and
    ``part.png`` must not share them."""
    path = Path(path)
    for i in range(1, 100000):
        stem = path.stem if i == 1 else "%s-%d" % (path.stem, i)
        if not any(True for _ in path.parent.glob(glob.escape(stem) + ".*")) \
                and not os.path.lexists(path.parent / stem):
            return path.with_name(stem + path.suffix)
    raise FileExistsError(path)


def archive_done(src, sidecar, done_dir, name, when=None):
    day = time.strftime("%Y-%m-%d", time.localtime(when))
    return archive(src, sidecar, Path(done_dir) / day, name)


def archive_failed(src, sidecar, failed_dir, name, reason):
    """Move to ``failed/`` and write ``NAME.error.txt`` beside it; returns the paths."""
    dest, side = archive(src, sidecar, failed_dir, name)
    atomic_write(dest.with_name(dest.stem + ".error.txt"), reason.rstrip() + "\n")
    return dest, side


# -- plan cache --------------------------------------------------------------------------------

class PlanCache:
    """Finished plans by key under ``root`` (shared between nodes through the outbox)."""

    def __init__(self, root):
        self.root = Path(root)

    def path(self, key):
        return self.root / key

    def get(self, key):
        d = self.path(key)
        return d if (d / "plan.json").is_file() else None

    def staging(self, job_id):
        d = self.root / (".tmp-" + job_id)
        shutil.rmtree(d, ignore_errors=True)
        d.mkdir(parents=True)
        return d

    def store(self, tmp, key, stem):
        """Publish a finished plan folder; if another node got there first, keep theirs."""
        atomic_write(Path(tmp) / "plan.json", json_text({"stem": stem, "key": key}))
        try:
            os.rename(tmp, self.path(key))
        except OSError:
            shutil.rmtree(tmp, ignore_errors=True)
        return self.path(key)

    def export(self, key, outdir, stem):
        """Copy a cached plan's files to ``outdir`` renamed to ``stem``; returns G-code path."""
        src = self.path(key)
        cached = share.read_json(src / "plan.json")["stem"]
        outdir = Path(outdir)
        outdir.mkdir(parents=True, exist_ok=True)
        gcode = None
        for f in src.iterdir():
            if f.name in ("plan.json", "result.json") or f.name.startswith("."):
                continue
            name = stem + f.name[len(cached):] if f.name.startswith(cached + ".") else f.name
            dest = outdir / name
            if os.path.lexists(dest):
                os.unlink(dest)      # requeued: the same plan exported again
            try:
                os.link(f, dest)
            except OSError:
                shutil.copy2(f, dest)
            if name.endswith(".gcode"):
                gcode = dest
        return gcode

"""Application keys, as OctoPrint's Application Keys plugin hands them out.

A client (Home Assistant, a farm dashboard) asks for a key under an app name; a person who
holds the web token approves or denies the request on the status page or with ``hostd keys``;
the client, polling with the app token it was given, then collects the key once. A key
authorises what OctoPrint clients do (job commands, uploads, connection commands), nothing
else: the web token stays the operator's credential.

Kept in ``STATE/appkeys.sqlite`` so the page (in the daemon) and the command (another
process) see the same requests. Nothing stored gives a key away: keys are kept as their
SHA-256 (they are 192 random bits, so a slow hash adds nothing). A key is drawn when it
is requested and waits for its client sealed with the client's app token (kept hashed):
approving it only lets its hash into the keys, and only that client can unseal it.
One key per app: approving a new request for an app replaces its old key.
"""

import base64
import hashlib
import secrets
import sqlite3
import time
from pathlib import Path

from hostd.errors import HostdError

FILE = "appkeys.sqlite"
# A request not decided (or an approved key not collected) within this long is dropped:
# the client has given up polling long before (Home Assistant waits a minute or two).
PENDING_S = 600.0
KEY_BYTES = 24
MAX_APP_CHARS = 64

SCHEMA = """
CREATE TABLE IF NOT EXISTS requests (
    id TEXT PRIMARY KEY, token_hash TEXT UNIQUE NOT NULL, app TEXT NOT NULL, user TEXT,
    remote TEXT, at REAL NOT NULL, state TEXT NOT NULL, sealed BLOB NOT NULL,
    key_hash TEXT NOT NULL, key_id TEXT);
CREATE TABLE IF NOT EXISTS keys (
    id TEXT PRIMARY KEY, app TEXT UNIQUE NOT NULL, key_hash TEXT UNIQUE NOT NULL,
    created REAL NOT NULL, last_used REAL, remote TEXT);
"""


def _hash(secret):
    return hashlib.sha256(secret.encode()).hexdigest()


def _pad(app_token):
    return hashlib.sha256(b"hostd appkey seal " + app_token.encode()).digest()[:KEY_BYTES]


def _text(raw):
    return base64.urlsafe_b64encode(raw).decode()


def _xor(a, b):
    return bytes(x ^ y for x, y in zip(a, b))


def clean_app(app):
    """The app name a client asked under, as text a page and a log can hold; HostdError
    ``appkeys.bad_app`` when it is missing or not a short line of text."""
    if not isinstance(app, str) or not app.strip():
        raise HostdError("the request names no app", code="appkeys.bad_app",
                         fix='send JSON {"app": "Home Assistant"}')
    app = app.strip()
    if len(app) > MAX_APP_CHARS or any(ord(c) < 32 or ord(c) == 127 for c in app):
        raise HostdError("the app name is longer than %d characters or holds control "
                         "characters" % MAX_APP_CHARS, code="appkeys.bad_app",
                         fix="send a short plain name")
    return app


class KeyStore:
    """Requests and keys of one node; a connection per call, so any thread may use it."""

    def __init__(self, state_dir):
        self.path = Path(state_dir) / FILE
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with self._db() as db:
            db.executescript(SCHEMA)
        try:
            self.path.chmod(0o600)
        except OSError:
            pass

    def _db(self):
        db = sqlite3.connect(self.path, timeout=10.0, isolation_level=None)
        db.row_factory = sqlite3.Row
        return _Closing(db)

    # -- the client's side -----------------------------------------------------------------

    def request(self, app, user=None, remote=None, now=None):
        """Record a request; returns the app token the client polls with (never stored)."""
        app = clean_app(app)
        app_token = secrets.token_urlsafe(24)
        raw = secrets.token_bytes(KEY_BYTES)
        with self._db() as db:
            self._prune(db, now)
            db.execute("INSERT INTO requests (id, token_hash, app, user, remote, at, state, "
                       "sealed, key_hash) VALUES (?, ?, ?, ?, ?, ?, 'pending', ?, ?)",
                       (secrets.token_hex(4), _hash(app_token), app,
                        str(user)[:MAX_APP_CHARS] if user else None, remote,
                        time.time() if now is None else now, _xor(raw, _pad(app_token)),
                        _hash(_text(raw))))
        return app_token

    def poll(self, app_token, now=None):
        """"pending", the key (once: the request is gone after), or None (denied, expired
        or unknown)."""
        with self._db() as db:
            self._prune(db, now)
            row = db.execute("SELECT * FROM requests WHERE token_hash = ?",
                             (_hash(app_token),)).fetchone()
            if row is None:
                return None
            if row["state"] == "pending":
                return "pending"
            db.execute("DELETE FROM requests WHERE id = ?", (row["id"],))
            return _text(_xor(row["sealed"], _pad(app_token)))

    def check(self, key, now=None):
        """The app a key belongs to (its last use noted), or None for a wrong or revoked key."""
        if not key:
            return None
        with self._db() as db:
            row = db.execute("SELECT id, app FROM keys WHERE key_hash = ?",
                             (_hash(key),)).fetchone()
            if row is None:
                return None
            db.execute("UPDATE keys SET last_used = ? WHERE id = ?",
                       (time.time() if now is None else now, row["id"]))
            return row["app"]

    # -- the operator's side -----------------------------------------------------------------

    def pending(self, now=None):
        """[{"id", "app", "user", "remote", "at" (epoch s)}] waiting for a decision."""
        with self._db() as db:
            self._prune(db, now)
            return [dict(r) for r in db.execute(
                "SELECT id, app, user, remote, at FROM requests WHERE state = 'pending' "
                "ORDER BY at")]

    def keys(self):
        """[{"id", "app", "created", "last_used", "remote"}]: never the keys themselves."""
        with self._db() as db:
            return [dict(r) for r in db.execute(
                "SELECT id, app, created, last_used, remote FROM keys ORDER BY created")]

    def approve(self, request_id, now=None):
        """Let the key of a pending request in (replacing the app's old key); returns a
        sentence. The key itself goes only to the client holding the app token."""
        with self._db() as db:
            row = self._pending_row(db, request_id, now)
            key_id = secrets.token_hex(4)
            db.execute("BEGIN IMMEDIATE")
            try:
                replaced = db.execute("DELETE FROM keys WHERE app = ?", (row["app"],)).rowcount
                db.execute("INSERT INTO keys (id, app, key_hash, created, remote) "
                           "VALUES (?, ?, ?, ?, ?)", (key_id, row["app"], row["key_hash"],
                                                      time.time(), row["remote"]))
                db.execute("UPDATE requests SET state = 'approved', key_id = ? WHERE id = ?",
                           (key_id, row["id"]))
                db.execute("COMMIT")
            except BaseException:
                db.execute("ROLLBACK")
                raise
        return "approved %s for %s%s; it collects its key at its next poll" % (
            row["id"], row["app"], " (its old key is revoked)" if replaced else "")

    def deny(self, request_id, now=None):
        with self._db() as db:
            row = self._pending_row(db, request_id, now)
            db.execute("DELETE FROM requests WHERE id = ?", (row["id"],))
        return "denied %s (%s)" % (row["id"], row["app"])

    def revoke(self, which):
        """Revoke a key by its id or its app's name; returns a sentence."""
        with self._db() as db:
            row = db.execute("SELECT id, app FROM keys WHERE id = ? OR app = ?",
                             (which, which)).fetchone()
            if row is None:
                raise HostdError("no key %r on this node" % which, code="appkeys.unknown",
                                 fix="`hostd keys list` shows the keys' ids and apps")
            db.execute("DELETE FROM keys WHERE id = ?", (row["id"],))
            db.execute("DELETE FROM requests WHERE key_id = ?", (row["id"],))
        return "revoked the key %s of %s" % (row["id"], row["app"])

    # -- internals ---------------------------------------------------------------------------

    def _pending_row(self, db, request_id, now):
        self._prune(db, now)
        row = db.execute("SELECT * FROM requests WHERE id = ?", (request_id,)).fetchone()
        if row is None or row["state"] != "pending":
            raise HostdError("no pending key request %r (expired after %.0f minutes, decided, "
                             "or never made)" % (request_id, PENDING_S / 60),
                             code="appkeys.no_request",
                             fix="`hostd keys list` shows the pending requests; ask the app to "
                                 "request a key again")
        return row

    def _prune(self, db, now):
        """Drop expired requests, and the keys approved for them that nobody collected."""
        cutoff = (time.time() if now is None else now) - PENDING_S
        for row in db.execute("SELECT id, key_id FROM requests WHERE at < ?",
                              (cutoff,)).fetchall():
            if row["key_id"]:
                db.execute("DELETE FROM keys WHERE id = ?", (row["key_id"],))
            db.execute("DELETE FROM requests WHERE id = ?", (row["id"],))


class _Closing:
    def __init__(self, db):
        self.db = db

    def __enter__(self):
        return self.db

    def __exit__(self, *exc):
        self.db.close()

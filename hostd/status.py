"""A node status file as read back from the share: only the fields hostd writes, each of
its type, strings bounded, links only to web pages.

Anyone who can write the share can plant ``drop/.hostd/nodes/NAME.json``, and every
node's farm page shows it: a field of the wrong type must not make the page fail, and
a ``javascript:`` address must not become a link. A field hostd starts writing is
added to :data:`FIELDS` (and :data:`PRINTER_FIELDS`) to be shown.
"""

import math
from urllib.parse import urlsplit

TEXT_CHARS = 200


def _text(value):
    return value[:TEXT_CHARS] if isinstance(value, str) else None


def _count(value):
    ok = isinstance(value, int) and not isinstance(value, bool) and 0 <= value < 2 ** 53
    return value if ok else None


def _number(value):
    ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    return float(value) if ok and math.isfinite(value) else None


def _fraction(value):
    value = _number(value)
    return value if value is not None and 0.0 <= value <= 1.0 else None


def _flag(value):
    return value if isinstance(value, bool) else False


def _names(value):
    return [v[:TEXT_CHARS] for v in value[:100] if isinstance(v, str)] \
        if isinstance(value, list) else []


def web_link(value):
    """``value`` if it is an http(s) address with a host, else None."""
    if not isinstance(value, str) or len(value) > 2000:
        return None
    try:
        parts = urlsplit(value)
    except ValueError:
        return None
    return value if parts.scheme in ("http", "https") and parts.netloc else None


PRINTER_FIELDS = {"name": _text, "profile": _text, "state": _text, "paused": _flag,
                  "job": _text, "job_name": _text, "error": _text, "progress": _fraction}


def _printers(value):
    if not isinstance(value, list):
        return []
    return [{k: check(p.get(k)) for k, check in PRINTER_FIELDS.items()}
            for p in value[:64] if isinstance(p, dict)]


FIELDS = {"state": _text, "pid": _count, "printers": _printers, "queue_length": _count,
          "planning": _names, "web_url": web_link, "problem": _text, "node_id": _text,
          "last_seen": _number, "last_seen_utc": _text}


def status_fields(data):
    """The fields of a status file's ``data`` (a dict) hostd knows, each checked: a
    value of the wrong type becomes None (an empty list, False)."""
    return {k: check(data.get(k)) for k, check in FIELDS.items()}

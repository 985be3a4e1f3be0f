"""What the daemon reads from a plan's report in the outbox: the figures a print needs
(its feed over the link) and whether a person must decide before it prints."""

import logging
from pathlib import Path

from hostd import share
from hostd.errors import HostdError

log = logging.getLogger("hostd.daemon")

# The plan's notes on what else would print it (another layout method, a smoothing).
ALTERNATIVES = ("plan.hold", "plan.other_method")


def report_in(outbox):
    """The ``NAME.report.json`` in a job's outbox folder as a dict ({} when absent)."""
    found = sorted(Path(outbox).glob("*.report.json")) if outbox else []
    if not found:
        return {}
    try:
        return share.read_json(found[0], share.REPORT_BYTES)
    except (OSError, ValueError, HostdError) as exc:
        log.warning("cannot read %s: %s", found[0], exc)
        return {}


def decision(report):
    """Why a ready plan must wait for a person (outside its profile's printable limits),
    as sentences; None when it may print by itself."""
    if not report.get("needs_decision"):
        return None
    outside = set(report.get("gate", {}).get("outside", []))
    warnings = report.get("warnings", [])
    said = ["%s." % w["message"] for w in warnings if w.get("code") in outside]
    # What the plan found would print it, so the person deciding sees the other way too.
    other = ["%s: %s." % (w["message"], w["fix"]) for w in warnings
             if w.get("code") in ALTERNATIVES]
    return ("Outside the profile's printable limits: " + _sentences(said)
            + (" Instead: " + _sentences(other) if other else ""))


def _sentences(parts):
    """Sentences one after another: each after the first begins with a capital (the
    messages begin in lower case, to follow a colon)."""
    return " ".join(p if k == 0 else p[:1].upper() + p[1:] for k, p in enumerate(parts))

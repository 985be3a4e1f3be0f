"""Logging to stderr in a journald-friendly form.

Under systemd (``$JOURNAL_STREAM`` or ``$INVOCATION_ID`` set) the journal stamps each
line itself, so lines carry no timestamp, and the level becomes a ``<N>`` syslog prefix
journald understands. In a terminal, lines start with the time.
"""

import logging
import os
import sys

_SYSLOG = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3,
           logging.CRITICAL: 2}


class _JournalFormatter(logging.Formatter):
    def format(self, record):
        prefix = "<%d>" % _SYSLOG.get(record.levelno, 6)
        return prefix + super().format(record)


def under_systemd(environ=None):
    environ = os.environ if environ is None else environ
    return bool(environ.get("JOURNAL_STREAM") or environ.get("INVOCATION_ID"))


def setup(level=logging.INFO, stream=None, environ=None):
    """Configure the ``hostd`` logger once; returns it."""
    logger = logging.getLogger("hostd")
    for handler in list(logger.handlers):
        logger.removeHandler(handler)
    handler = logging.StreamHandler(stream or sys.stderr)
    if under_systemd(environ):
        handler.setFormatter(_JournalFormatter("%(name)s: %(message)s"))
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)-7s %(name)s: %(message)s",
                                               "%Y-%m-%d %H:%M:%S"))
    logger.addHandler(handler)
    logger.setLevel(level)
    logger.propagate = False
    # waitress warns "Task queue depth is N" whenever a request waits for a thread: with
    # the page polling every 2 s that is routine, and alone in the log it reads as trouble.
    logging.getLogger("waitress.queue").setLevel(logging.ERROR)
    return logger

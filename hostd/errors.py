"""The daemon's one exception family; the edges (CLI, logs, web) turn it into messages.

``code`` is stable (tests and tools match on it), e.g. ``config.unknown_key``.
"""


class HostdError(Exception):
    """A daemon-side error a person can act on.

    Parameters
    ----------
    message : str
        What is wrong.
    code : str
        Stable machine-readable code.
    file : str, optional
        The file concerned (config, input, state database).
    key : str, optional
        The key inside that file (dotted path), for config errors.
    fix : str, optional
        How to fix it.
    """

    def __init__(self, message, *, code="hostd.error", file=None, key=None, fix=None):
        self.code = code
        self.message = message
        self.file = None if file is None else str(file)
        self.key = key
        self.fix = fix
        super().__init__(self.text())

    def text(self):
        parts = [self.file + ": " if self.file else "", self.message]
        if self.key:
            parts.append(" (key %s)" % self.key)
        if self.fix:
            parts.append(". Fix: " + self.fix)
        return "".join(parts)


# The longest reason a job's record, its NAME.error.txt or a log line carries: a reason
# quotes what people gave (a name, a sidecar's value), and that must never be unbounded.
MAX_REASON_CHARS = 4000


def bounded(text, limit=MAX_REASON_CHARS):
    """``text`` cut to ``limit`` characters, saying how much was left out."""
    text = str(text)
    if len(text) <= limit:
        return text
    return text[:limit] + " [... %d more characters not shown]" % (len(text) - limit)

"""The one exception family of the printer link.

``code`` is stable (the daemon and tests branch on it); the message is for people.
"""


class PrinterError(Exception):
    """A printer-link failure.

    Codes: ``port`` (cannot open/read/write the port), ``handshake`` (no sensible answer
    while connecting), ``timeout`` (printer stopped answering during a job), ``firmware``
    (the firmware reported an error such as thermal runaway; message is verbatim),
    ``resend`` (a resend request we cannot satisfy), ``state`` (call not valid in the
    current state), ``config`` (bad port URL or option), ``internal`` (a bug in the
    driver, reported instead of hanging the caller).
    """

    def __init__(self, code, message):
        super().__init__(message)
        self.code = code
        self.message = message

    def __str__(self):
        return "%s: %s" % (self.code, self.message)


class PortLost(Exception):
    """Internal to the driver: the port failed or the board reset; handled in its loop."""

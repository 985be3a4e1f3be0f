"""Settings of the printer link; the daemon fills them from the printer profile.

Scripts are plain G-code text (one command per line, ``;`` comments allowed). They are
sent as numbered lines like the job itself, so they are checksummed and resent too.
"""

from dataclasses import dataclass

from hostd.printer.protocol import clean

DEFAULT_PAUSE_GCODE = """\
M400            ; let the queued moves finish before parking
G91
G1 Z2 F600      ; lift off the print
G90
"""

DEFAULT_RESUME_GCODE = """\
G91
G1 Z-2 F600     ; back down to where the paused line left the nozzle
G90
"""

DEFAULT_CANCEL_GCODE = """\
M104 S0         ; hotend off
M140 S0         ; bed off
M107            ; fan off
G91
G1 Z5 F600      ; lift
G90
M84             ; motors off
"""

# After a firmware error that did not halt the printer (it still answers).
DEFAULT_ERROR_GCODE = """\
M104 S0
M140 S0
M84
"""


@dataclass
class LinkSettings:
    """Everything the driver needs from the profile; defaults suit a Marlin printer.

    Times are real seconds. ``send_ahead`` uses ADVANCED_OK when the firmware reports it
    (several lines in flight); otherwise, and when False, the link is ping-pong (one line
    in flight). ``rx_buffer_bytes`` is the firmware's serial receive buffer: never more
    unanswered bytes than that are in flight, so it cannot overrun.
    """

    baud: int = 115200
    send_ahead: bool = True
    rx_buffer_bytes: int = 127          # Marlin RX_BUFFER_SIZE 128, one slot kept free
    max_in_flight_lines: int = 0        # 0 = the firmware's command buffer (from ok B..)
    open_timeout_s: float = 5.0         # port must appear/open within this
    reset_wait_s: float = 2.5           # wait this long for 'start' after opening
    reopen_delay_s: float = 0.1         # closed->reopened gap, so the board sees the close
    banner_quiet_s: float = 0.2         # after 'start', the boot banner ends when quiet this long
    handshake_timeout_s: float = 2.0    # per probe (M110 / M115) while connecting
    handshake_attempts: int = 4
    ok_timeout_s: float = 10.0          # no answer (ok, busy, error...) -> recovery
    max_timeouts: int = 4               # consecutive recoveries before the job stops
    resend_quiet_s: float = 0.03        # quiet period before replaying after a resend
    history_lines: int = 4096           # sent lines kept for resend requests
    autoreport_s: int = 2               # M155 interval when AUTOREPORT_TEMP is present
    temp_poll_s: float = 2.0            # M105 interval otherwise
    temp_history: int = 600             # samples kept per heater
    reconnect: bool = True              # reopen the port when it returns after a loss
    reconnect_interval_s: float = 0.5
    progress_interval_s: float = 0.25   # progress events at most this often
    pause_gcode: str = DEFAULT_PAUSE_GCODE
    resume_gcode: str = DEFAULT_RESUME_GCODE
    cancel_gcode: str = DEFAULT_CANCEL_GCODE
    error_gcode: str = DEFAULT_ERROR_GCODE


def script_lines(text):
    """The commands of a script, comments and blank lines removed."""
    return [line for line in (clean(raw) for raw in (text or "").splitlines()) if line]

"""Printer link: a Marlin host-protocol driver and a Marlin-like simulator.

Public entry points:

- :class:`hostd.printer.link.Printer` -- the driver (own thread, flow control, resends,
  pause/resume/cancel/estop, temperatures, events).
- :class:`hostd.printer.process.PrinterProcess` -- the same driver in a child process, for
  callers that do CPU-heavy Python work (the GIL would otherwise stall the stream).
- :class:`hostd.printer.settings.LinkSettings` -- baud, timeouts and the profile's scripts.
- :class:`hostd.printer.sim.Simulator` / :class:`hostd.printer.simconfig.SimConfig` -- the
  simulated printer behind a real pseudo-terminal (``sim://`` ports, ``hostd sim-printer``).
- :class:`hostd.printer.errors.PrinterError` -- the one exception family, with a stable ``code``.
"""

from hostd.printer.errors import PrinterError
from hostd.printer.settings import LinkSettings
from hostd.printer.link import Printer
from hostd.printer.process import PrinterProcess

__all__ = ["Printer", "PrinterProcess", "LinkSettings", "PrinterError"]

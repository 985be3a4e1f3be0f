"""Shared helpers for the printer-link tests: move generators and a sim+driver pair."""

import contextlib
import math
import os
import shutil
import tempfile

from hostd.printer import LinkSettings, Printer
from hostd.printer.sim import Simulator
from hostd.printer.simconfig import SimConfig

# Commands the host adds on its own (handshake, temperature polling, recovery probes,
# M108 to break a heating wait on cancel).
HOUSEKEEPING = ("M105", "M108", "M110", "M115", "M155")


def moves(count, feed_mm_min=3000, step_mm=0.2):
    """Short G1 moves along a wavy path with varying Z and extrusion (like a 4D path)."""
    lines = []
    e = 0.0
    for i in range(count):
        x = 20 + (i * step_mm) % 150
        y = 20 + 10 * math.sin(i / 15.0)
        z = 0.2 + 0.05 * math.sin(i / 40.0)
        e += 0.01 + 0.005 * math.cos(i / 7.0)
        lines.append("G1 X%.3f Y%.3f Z%.3f E%.5f F%d" % (x, y, z, e, feed_mm_min))
    return lines


def job_commands(sim):
    """What the firmware executed, without the host's housekeeping commands."""
    return [c for c in sim.commands() if c.split()[0] not in HOUSEKEEPING]


def script(text):
    from hostd.printer.settings import script_lines
    return script_lines(text)


@contextlib.contextmanager
def sim_and_printer(baud=250000, settings=None, **options):
    """A Simulator on a real pty and a connected Printer opened on its device path.

    The pty is published under a symlink, like /dev/serial/by-id/..., so that the
    port keeps its name when the simulated device disappears and comes back.
    """
    options.setdefault("boot_s", 0.05)      # quick boots keep the test set short
    config = SimConfig(**options)
    folder = tempfile.mkdtemp(prefix="hostd-sim-")
    sim = Simulator(config, baud=baud, link_path=os.path.join(folder, "printer"))
    path = sim.start()
    settings = settings or LinkSettings()
    settings.baud = baud
    settings.banner_quiet_s = 0.05
    printer = Printer(path, settings)
    try:
        printer.connect()
        yield sim, printer
    finally:
        printer.close()
        sim.stop()
        shutil.rmtree(folder, ignore_errors=True)

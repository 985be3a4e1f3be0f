"""The simulated printer: a :class:`~hostd.printer.firmware.Firmware` behind a real pty.

One thread runs the wire and the firmware. The wire is modelled at the configured byte
rate (baud/10 bytes/s each way) on a virtual clock: bytes the host writes reach the
firmware's receive buffer one byte-time after another, replies reach the host only when
their last byte would have been transmitted. That keeps link utilisation and round-trip
figures meaningful although a pty itself has no speed.

Use::

    sim = Simulator(SimConfig(advanced_ok=True, time_scale=0.01), baud=250000)
    path = sim.start()          # open ``path`` with pyserial like a real printer
    ...
    sim.commands()              # every command the firmware executed, in order
    sim.stats                   # overruns, line errors, starvation, ...
    sim.stop()
"""

import queue
import random
import threading
import time
from collections import deque

from hostd.printer.errors import PrinterError
from hostd.printer.firmware import Firmware
from hostd.printer.pty import PtyEndpoint
from hostd.printer.simconfig import SimConfig

_IDLE_POLL_S = 0.01   # how often to look for a host while none has the port open
_MAX_WAIT_S = 0.05


class Simulator:
    """A Marlin-like printer on a pseudo-terminal, served by a background thread."""

    def __init__(self, config=None, baud=115200, link_path=None, clock=time.monotonic):
        self.config = config or SimConfig()
        self.baud = self.config.baud or baud
        self.byte_s = 10.0 / self.baud if self.baud else 0.0
        self.clock = clock
        self.rng = random.Random(self.config.seed)
        self.firmware = Firmware(self.config, self.rng)
        self.endpoint = PtyEndpoint(link_path)
        self.connections = 0          # times a host opened the port
        self.dropped_out_bytes = 0    # replies the host never read (its buffer was full)
        self.bytes_in = 0
        self.bytes_out = 0
        self._stop = threading.Event()
        self._pressed = queue.SimpleQueue()   # actions from the printer's own controls
        self._thread = None
        self._ready = threading.Event()
        self._host = False
        self._boot_at = None
        self._reopen_at = None
        self._stalled_until = 0.0
        self._in = bytearray()        # bytes read from the pty, not yet "arrived"
        self._in_start = 0.0          # when the first byte of _in starts arriving
        self._out = deque()           # (release time, bytes)
        self._out_busy = 0.0
        self.error = None

    # -- public ------------------------------------------------------------------------

    @property
    def path(self):
        """The device path a host should open (the symlink when one was requested)."""
        return self.endpoint.link_path or self.endpoint.path

    @property
    def stats(self):
        stats = dict(self.firmware.stats, connections=self.connections, bytes_in=self.bytes_in,
                     bytes_out=self.bytes_out, dropped_out_bytes=self.dropped_out_bytes)
        return stats

    def commands(self):
        """Every command the firmware executed, in order (without N/checksum)."""
        return [text for _, text in list(self.firmware.executed)]

    def start(self):
        """Open the pty, start serving, return the path to open."""
        self.endpoint.open()
        self._thread = threading.Thread(target=self._serve, name="hostd-sim", daemon=True)
        self._thread.start()
        return self.path

    def stop(self):
        self._stop.set()
        if self._thread:
            self._thread.join(5)
        self.endpoint.close()

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.stop()

    def press(self, action):
        """The printer's own controls: Marlin tells the host ``//action:<action>``
        (``cancel``, ``pause``, ``resume``; ``paused``/``resumed`` when it paused itself)."""
        self._pressed.put(action)

    def wait_port(self, timeout_s=5.0):
        """Block until the port exists (after a simulated disconnect)."""
        deadline = time.monotonic() + timeout_s
        while self.endpoint.master is None:
            if time.monotonic() > deadline:
                raise PrinterError("port", "simulated port did not come back")
            time.sleep(0.01)
        return self.path

    # -- thread ------------------------------------------------------------------------

    def _serve(self):
        try:
            while not self._stop.is_set():
                self._cycle()
        except Exception as exc:  # reported to whoever looks at sim.error; never silent
            self.error = exc
            raise

    def _cycle(self):
        now = self.clock()
        while not self._pressed.empty():
            self.firmware.out.append("//action:" + self._pressed.get())
        if self.endpoint.master is None:
            if now >= self._reopen_at:
                self.endpoint.open()
            else:
                time.sleep(min(_IDLE_POLL_S, self._reopen_at - now))
            return
        if now < self._stalled_until:
            time.sleep(min(_IDLE_POLL_S, self._stalled_until - now))
            return
        wait_s = self._next_deadline(now) - now
        host, readable = self.endpoint.poll(max(0.0, min(wait_s, _MAX_WAIT_S)))
        now = self.clock()
        if not host:
            if self._host:
                self._host = False        # host closed the port
                self._in.clear()
                self._out.clear()
            time.sleep(_IDLE_POLL_S)
            return
        if not self._host:
            self._host = True             # opening the port resets the board
            self.connections += 1
            self._reset(now)
        if readable:
            data = self.endpoint.read()
            if data:
                self.bytes_in += len(data)
                if not self._in:
                    self._in_start = max(now, self._in_start)
                self._in += data
        self._deliver(now)
        firmware = self.firmware
        if self._boot_at is not None and now >= self._boot_at:
            self._boot_at = None
            firmware.banner()
        if self._boot_at is None:
            firmware.step(now)
        if firmware.fault:
            self._fault(firmware.fault, now)
            if self.endpoint.master is None:
                return
        self._queue_output(now)
        self._flush_output(now)

    def _reset(self, now):
        self.firmware.reset(now)
        self._boot_at = now + self.config.boot_s
        self._in.clear()
        self._out.clear()
        self._in_start = now
        self._out_busy = now

    def _fault(self, kind, now):
        self.firmware.fault = None
        if kind == "reset":
            self._reset(now)
        elif kind == "stall":
            # Nothing is read, run or answered until it recovers; the host's bytes wait in
            # the port's buffer meanwhile, as they would for a hung board.
            self._stalled_until = now + self.config.stall_s
        elif kind == "disconnect":
            # The device vanishes (USB unplugged) and comes back later under the same link.
            self.endpoint.close(unlink=True)
            self.firmware.out.clear()
            self._out.clear()
            self._in.clear()
            self._host = False
            self._reopen_at = now + self.config.reconnect_s
            self.firmware.reset(now)

    def _deliver(self, now):
        """Hand the firmware the bytes whose last bit has arrived by ``now``."""
        if not self._in:
            self._in_start = max(self._in_start, now)
            return
        if self._boot_at is not None:
            self._in.clear()              # the bootloader ignores the host
            return
        if self.byte_s:
            count = min(len(self._in), int((now - self._in_start) / self.byte_s + 1e-9))
        else:
            count = len(self._in)
        if count <= 0:
            return
        chunk = bytes(self._in[:count])
        del self._in[:count]
        start = 0
        # Feed line by line so each line carries its own arrival time.
        while start < len(chunk):
            end = chunk.find(b"\n", start)
            end = len(chunk) if end < 0 else end + 1
            arrival = self._in_start + end * self.byte_s if self.byte_s else now
            self.firmware.feed(chunk[start:end], arrival)
            start = end
        self._in_start += count * self.byte_s

    def _queue_output(self, now):
        firmware = self.firmware
        if not firmware.out:
            return
        for line in firmware.out:
            data = line.encode("ascii", "replace") + b"\n"
            if self.config.fault_noise and self.rng.random() < self.config.fault_noise:
                data = bytes(self.rng.randrange(1, 256) for _ in range(self.rng.randrange(1, 12))) + b"\n" + data
            begin = max(now, self._out_busy)
            self._out_busy = begin + len(data) * self.byte_s
            self._out.append((self._out_busy, data))
        firmware.out.clear()

    def _flush_output(self, now):
        batch = bytearray()
        while self._out and self._out[0][0] <= now:
            batch += self._out.popleft()[1]
        if batch:
            self.bytes_out += len(batch)
            self.dropped_out_bytes += self.endpoint.write(bytes(batch))

    def _next_deadline(self, now):
        times = [now + _MAX_WAIT_S]
        if self._boot_at is not None:
            times.append(self._boot_at)
        if self._out:
            times.append(self._out[0][0])
        if self._in and self.byte_s:
            newline = self._in.find(b"\n")
            if newline >= 0:
                times.append(self._in_start + (newline + 1) * self.byte_s)
        wake = self.firmware.next_wakeup(now)
        if wake is not None:
            times.append(wake)
        return min(times)

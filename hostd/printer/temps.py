"""Temperature state of the printer as the host sees it: current/target and a short history."""

import threading
from collections import deque


class TemperatureLog:
    """Latest reading per heater (``T``, ``T0``, ``B``, ...) plus a bounded history.

    Updated by the driver thread, read from any thread (snapshots are copies).
    """

    def __init__(self, history=600):
        self._lock = threading.Lock()
        self._latest = {}
        self._history = {}
        self._size = history

    def update(self, temps, at_s):
        """Record a parsed report ``{heater: (current, target or None)}`` taken at ``at_s``."""
        with self._lock:
            for heater, (current, target) in temps.items():
                if target is None and heater in self._latest:
                    target = self._latest[heater][1]  # reports without /target keep the last one
                self._latest[heater] = (current, target)
                self._history.setdefault(heater, deque(maxlen=self._size)).append((at_s, current, target))

    def current(self):
        """``{heater: {"current": C, "target": C or None}}``."""
        with self._lock:
            return {h: {"current": c, "target": t} for h, (c, t) in self._latest.items()}

    def history(self, heater=None):
        """``{heater: [(time_s, current, target), ...]}`` (oldest first)."""
        with self._lock:
            items = self._history.items() if heater is None else [(heater, self._history.get(heater, ()))]
            return {h: list(samples) for h, samples in items}

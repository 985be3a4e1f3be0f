"""waitress with a bound on request heads and a reserve of connections for the page.

waitress closes a connection only after ``channel_timeout`` without any activity, and stops
accepting at ``connection_limit``: a client sending one header line every few seconds never
goes idle, so a few hundred of them hold every connection and the page, the API, /healthz
and the emergency stop go unanswered for as long as they like. Here:

- a request head (request line and headers) must arrive whole within ``head_timeout_s`` of
  its first byte (of the connection, for its first request), or the connection is closed;
- past ``waiting_limit`` open connections, the ones that have waited longest for a request
  of theirs -- a head or body still arriving, or idle between requests -- are closed to
  make room, so a new connection (a person's page, a monitor's /healthz) is always taken
  and answered, while connections being answered are never touched.
"""

import time

from waitress.adjustments import Adjustments
from waitress.channel import HTTPChannel
from waitress.server import MultiSocketServer, TcpWSGIServer
from waitress.task import ThreadedTaskDispatcher


class HeadChannel(HTTPChannel):
    """An HTTP connection that knows since when its current request has been arriving."""

    def __init__(self, server, sock, addr, adj, map=None):
        super().__init__(server, sock, addr, adj, map)
        # Nothing received yet: the first head is due from the moment we accepted it.
        self.request_started = self.creation_time

    def received(self, data):
        started = self.request_started
        if started is None and self.request is None and data:
            started = time.time()
        done = super().received(data)
        self.request_started = started if self.request is not None else None
        return done

    def head_overdue(self, now, limit_s):
        request = self.request
        return (self.request_started is not None and now - self.request_started > limit_s
                and (request is None or not request.headers_finished))

    def waiting_since(self):
        """When this connection began waiting for a request of its own; None while one is
        being answered (never to be closed for room)."""
        if self.requests or self.will_close or self.close_when_flushed or self.total_outbufs_len:
            return None
        return self.request_started if self.request_started is not None else self.last_activity


class HeadServer(TcpWSGIServer):
    """TcpWSGIServer using :class:`HeadChannel`, enforcing the head bound and the reserve."""

    channel_class = HeadChannel
    head_timeout_s = 10.0
    waiting_limit = 400

    def readable(self):
        # Called by the loop before each wait: room is made before the next accept.
        if len(self._map) >= self.waiting_limit and self.accepting:
            channels = self.active_channels.values()
            excess = sum(1 for c in channels if not c.will_close) - self.waiting_limit
            if excess >= 0:
                self._make_room(excess + 1)
        return super().readable()

    def maintenance(self, now):
        super().maintenance(now)
        for channel in list(self.active_channels.values()):
            if channel.head_overdue(now, self.head_timeout_s):
                channel.will_close = True

    def _make_room(self, count):
        waiting = []
        for channel in self.active_channels.values():
            since = channel.waiting_since()
            if since is not None:
                waiting.append((since, id(channel), channel))
        waiting.sort()
        for _, _, channel in waiting[:count]:
            channel.will_close = True          # closed by the loop in this same pass


def create_server(app, head_timeout_s, waiting_limit, **kw):
    """Like ``waitress.create_server`` for TCP listeners, with :class:`HeadServer`s.

    Returns (server to run and close, the port it listens on).
    """
    adj = Adjustments(**kw)
    map_ = {}
    dispatcher = ThreadedTaskDispatcher()
    dispatcher.set_thread_count(adj.threads)
    servers = []
    for sockinfo in adj.listen:
        server = HeadServer(app, map_, dispatcher=dispatcher, adj=adj, sockinfo=sockinfo)
        server.head_timeout_s, server.waiting_limit = head_timeout_s, waiting_limit
        servers.append(server)
    port = int(servers[0].effective_port)
    if len(servers) == 1:
        return servers[0], port
    multi = MultiSocketServer(map_, adj=adj, dispatcher=dispatcher, log_info=servers[0].log_info,
                              effective_listen=[(s.effective_host, s.effective_port)
                                                for s in servers])
    return multi, port

"""waitress inside the daemon process: its own small thread pool, never the run loop's thread.

The request path only reads the store (its own SQLite connection per thread) and copies
of the driver's counters, so serving pages cannot hold up the serial stream. ``web.port``
0 takes any free port (tests, several nodes on one machine); the address is logged and
published in the node's status file as ``web_url`` for the farm view.
"""

import logging
import socket
import threading

log = logging.getLogger("hostd.web")
THREADS = 6
# A farm's page must stay up for the people who need it while slow or stuck clients hold
# connections: room for many idle sockets (cheap), and an idle one is closed after
# CHANNEL_TIMEOUT_S (checked every CLEANUP_S). A request head must arrive whole within
# HEAD_TIMEOUT_S, and past WAITING_LIMIT connections the one waiting longest for a request
# of its own is closed for a new one: the rest up to CONNECTION_LIMIT is a reserve that
# clients trickling headers cannot take (see hostd.web.heads).
CONNECTION_LIMIT = 500
WAITING_LIMIT = 400
HEAD_TIMEOUT_S = 10.0
CHANNEL_TIMEOUT_S = 30
CLEANUP_S = 1
# A response larger than this makes its thread wait for the client to read it: above any
# outbox file (the largest G-code is ~70 MB), a slow reader's download is left to the
# server's buffer (on disk past 1 MB) and never holds one of the few threads.
OUTPUT_BUFFER_BYTES = 256 << 20


class WebServer:
    """A running waitress server; :meth:`stop` closes it."""

    def __init__(self, server, url):
        self.server = server
        self.url = url
        self.thread = threading.Thread(target=self._serve, name="hostd-web", daemon=True)
        self.announcer = None     # zeroconf, while the node is announced

    def _serve(self):
        try:
            self.server.run()
        except Exception:        # closed under its feet at shutdown, or a real failure
            if self.server is not None:
                log.exception("web server stopped")

    def stop(self):
        announcer, self.announcer = self.announcer, None
        if announcer is not None:
            announcer.close()
        server, self.server = self.server, None
        if server is None:
            self.thread.join(2.0)
            return
        closed = threading.Event()

        def close():
            server.close()
            closed.set()
        trigger = getattr(server, "trigger", None)
        if trigger is not None and self.thread.is_alive():
            # Closed in the loop's own thread, which the trigger wakes at once: closed from
            # here, the loop slept on until its poll timed out (1 s) before it saw it.
            try:
                trigger.pull_trigger(close)
            except OSError:
                pass
            else:
                self.thread.join(2.0)
        if not closed.is_set():
            close()
            self.thread.join(2.0)


def public_url(host, port):
    if host in ("0.0.0.0", "::", ""):
        host = socket.gethostname()
    if ":" in host:
        host = "[%s]" % host
    return "http://%s:%d/" % (host, port)


def start(config, store=None, daemon=None, threads=THREADS):
    """Serve the app for ``config.web`` in background threads; None if it cannot bind.

    A busy port must not keep the printers from working: it is logged, not raised.
    """
    try:
        return _start(config, store, daemon, threads)
    except Exception:
        log.exception("web page not started")
        return None


def _start(config, store, daemon, threads):
    from hostd import announce
    from hostd.web.app import create_app
    from hostd.web.heads import create_server
    app = create_app(config, store=store, daemon=daemon)
    try:
        server, port = create_server(
            app, HEAD_TIMEOUT_S, WAITING_LIMIT, host=config.web.host, port=config.web.port,
            threads=threads, ident="hostd", clear_untrusted_proxy_headers=True,
            connection_limit=CONNECTION_LIMIT, asyncore_use_poll=True,
            channel_timeout=CHANNEL_TIMEOUT_S, cleanup_interval=CLEANUP_S,
            outbuf_high_watermark=OUTPUT_BUFFER_BYTES,
            max_request_body_size=app.config["MAX_CONTENT_LENGTH"] + 65536)
    except OSError as exc:
        log.warning("web page not started: cannot listen on %s:%s (%s); set web.port in "
                    "hostd.yaml to a free port", config.web.host, config.web.port, exc.strerror)
        return None
    url = public_url(config.web.host, port)
    web = WebServer(server, url)
    web.thread.start()
    web.announcer = announce.start(config, port)
    log.info("status page on %s%s", url, "" if config.web.token else
             " (actions off: no web.token configured)")
    return web

"""sd_notify over a real AF_UNIX datagram socket; journald-friendly log lines."""

import io
import logging
import socket

import pytest

from hostd import logs
from hostd.notify import Notifier, watchdog_interval_s


@pytest.fixture
def listener(tmp_path):
    path = str(tmp_path / "notify.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(2)
    yield path, sock
    sock.close()


def test_messages_reach_the_socket(listener, monkeypatch):
    path, sock = listener
    monkeypatch.setenv("NOTIFY_SOCKET", path)
    n = Notifier()
    assert n.ready("watching /drop")
    assert sock.recv(4096) == b"READY=1\nSTATUS=watching /drop"
    assert n.status("2 printing\n1 queued")
    assert sock.recv(4096) == b"STATUS=2 printing 1 queued"
    assert n.watchdog()
    assert sock.recv(4096) == b"WATCHDOG=1"
    assert n.stopping()
    assert sock.recv(4096) == b"STOPPING=1"


def test_abstract_namespace_socket(monkeypatch):
    name = "hostd-test-%d" % id(monkeypatch)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.settimeout(2)
    try:
        monkeypatch.setenv("NOTIFY_SOCKET", "@" + name)
        assert Notifier().watchdog()
        assert sock.recv(100) == b"WATCHDOG=1"
    finally:
        sock.close()


def test_without_systemd_nothing_is_sent(monkeypatch, tmp_path):
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    assert not Notifier().ready()
    # A socket that went away must not raise (the print goes on).
    assert not Notifier(str(tmp_path / "gone.sock")).watchdog()


def test_watchdog_interval(monkeypatch):
    monkeypatch.setenv("WATCHDOG_USEC", "30000000")
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    assert watchdog_interval_s() == 15.0
    monkeypatch.setenv("WATCHDOG_PID", "1")   # meant for another process
    assert watchdog_interval_s() is None


def test_journald_lines_carry_no_timestamp():
    out = io.StringIO()
    log = logs.setup(stream=out, environ={"JOURNAL_STREAM": "8:123"})
    log.warning("printer lost")
    assert out.getvalue() == "<4>hostd: printer lost\n"
    out = io.StringIO()
    log = logs.setup(stream=out, environ={})
    log.info("hello")
    line = out.getvalue()
    assert line[:2] == "20" and line.rstrip().endswith("hostd: hello")
    logs.setup(level=logging.WARNING)

"""A real browser on a real daemon: headless Debian chromium over the DevTools protocol.

`hostd run` on the simulator with a token, a file dropped, the page opened: the progress
bar advances by itself (JS polling), pause with the token changes the printer's state,
and a screenshot is kept in test-artifacts/.
"""

import os
import shutil
import time
import urllib.request
from pathlib import Path

import pytest

from daemon_helpers import SIM, DaemonProcess, write_config, write_dome
from web_helpers import CHROMIUM, Chromium, free_port, get_json, wait_http

ROOT = Path(__file__).resolve().parents[1]
ARTIFACTS = ROOT / "test-artifacts"
TOKEN = "browser-test-token"
# Slow enough (moves at 1/5 of real time) for a person, or a test, to see the bar move;
# heaters quick, since the test watches the bar, not the heating (0.7 s of it; 2.9 s with
# time constants of 2 and 4 s, 40 s of the test's 56 with the defaults).
SLOW_SIM = "sim://?time_scale=0.2&advanced_ok=1&boot_s=0&hotend_tau_s=0.5&bed_tau_s=1"

pytestmark = pytest.mark.slow


def _requirements():
    if not os.path.exists(CHROMIUM):
        pytest.skip("Debian's chromium is not installed at %s (apt-get install chromium)"
                    % CHROMIUM)
    pytest.importorskip("websocket", reason="pip package websocket-client is not installed")


def test_page_in_headless_chromium(tmp_path):
    _requirements()
    port = free_port()
    config = write_config(tmp_path, printers=[{"name": "p1", "profile": "generic-0.5mm",
                                               "port": SLOW_SIM, "baud": 2000000}],
                          web={"host": "127.0.0.1", "port": port, "token": TOKEN})
    base = "http://127.0.0.1:%d" % port
    d = DaemonProcess(config)
    browser = None
    try:
        wait_http(base + "/healthz")
        write_dome(tmp_path / "in" / "dome.npy", diameter_mm=25, height_mm=4)
        drop = tmp_path / "share" / "drop"
        for f in ("dome.yaml", "dome.npy"):       # sidecar first, as a person would copy
            shutil.copy(tmp_path / "in" / f, drop / (f + ".tmp"))
            os.rename(drop / (f + ".tmp"), drop / f)

        def printing():
            _, s = get_json(base + "/api/status")
            p = s["printers"][0]
            return p["job"] and p["state"] in ("heating", "printing") and \
                (p["job"]["progress"] or 0) > 0.01
        deadline = time.monotonic() + 120
        while not printing():
            assert time.monotonic() < deadline, "no print started:\n" + d.output()[-3000:]
            assert d.proc.poll() is None, d.output()[-3000:]
            time.sleep(0.05)

        browser = Chromium()
        browser.goto(base + "/")
        assert browser.js("document.querySelector('.printer h2').textContent").startswith("p1")
        bar = "document.querySelector('[data-field=progress]').value"
        first = browser.wait_js(bar, what="a progress bar")
        # No reload: hostd.js polls the API and moves the bar.
        browser.js("window.__same_page = true")
        browser.wait_js("%s > %r" % (bar, first + 0.005), timeout=30, what="the bar to advance")
        assert browser.js("window.__same_page === true")

        browser.js("document.getElementById('token-input').value = %r;"
                   "document.getElementById('token-keep').click()" % TOKEN)
        assert browser.js("sessionStorage.getItem('hostd-token')") == TOKEN
        assert TOKEN not in browser.js("document.documentElement.outerHTML")
        browser.js("document.querySelector('form.pause button').click()")
        browser.wait_js("document.querySelector('[data-field=state]').textContent === 'paused'",
                        timeout=30, what="the state to read paused")
        _, s = get_json(base + "/api/status")
        assert s["printers"][0]["state"] == "paused" and s["printers"][0]["paused"] is True
        browser.screenshot(ARTIFACTS / "web_page_paused.png")
        assert (ARTIFACTS / "web_page_paused.png").stat().st_size > 10000

        # Cancel asks for confirmation: dismissed, nothing happens.
        browser.js("window.confirm = function () { return false; };"
                   "document.querySelector('form.action[data-confirm] button').click()")
        time.sleep(0.5)
        _, s = get_json(base + "/api/status")
        assert s["printers"][0]["job"] is not None
    finally:
        if browser is not None:
            browser.close()
        assert d.stop() == 0, d.output()[-3000:]


def test_print_anyway_in_headless_chromium(tmp_path):
    """A plan outside its profile's printable limits waits on its page; "Print anyway",
    confirmed, with the token, prints it."""
    _requirements()
    profiles = tmp_path / "profiles"
    profiles.mkdir()
    text = (ROOT / "profiles" / "generic-0.5mm.yaml").read_text()
    (profiles / "strict-0.5mm.yaml").write_text(
        text.replace("name: generic-0.5mm", "name: strict-0.5mm")
            .replace("min_coverage: 0.90", "min_coverage: 1.0"))
    port = free_port()
    config = write_config(tmp_path, printers=[{"name": "p1", "profile": "strict-0.5mm",
                                               "port": SIM, "baud": 2000000}],
                          web={"host": "127.0.0.1", "port": port, "token": TOKEN})
    base = "http://127.0.0.1:%d" % port
    d = DaemonProcess(config, env={"HOSTD_PROFILES": str(profiles)})
    browser = None
    try:
        wait_http(base + "/healthz")
        write_dome(tmp_path / "share" / "drop" / "dome.npy")

        def job():
            _, body = get_json(base + "/api/jobs")
            jobs = body["jobs"] if isinstance(body, dict) else body
            return jobs[0] if jobs else {}
        deadline = time.monotonic() + 120
        while not job().get("decision"):
            assert time.monotonic() < deadline, "no job waits:\n" + d.output()[-3000:]
            time.sleep(0.05)
        assert job()["state"] == "ready"
        browser = Chromium()
        browser.goto(base + "/jobs/" + job()["id"])
        assert "tool paths cover" in browser.js("document.body.textContent")
        browser.js("document.getElementById('token-input').value = %r;"
                   "document.getElementById('token-keep').click()" % TOKEN)
        browser.js("window.confirm = function () { return true; };"
                   "document.querySelector('form.approve button').click()")
        deadline = time.monotonic() + 60
        while job()["state"] == "ready":
            assert time.monotonic() < deadline, "not approved:\n" + d.output()[-3000:]
            time.sleep(0.05)
        assert job()["decision"] is None and job()["state"] in ("printing", "done")
    finally:
        if browser is not None:
            browser.close()
        assert d.stop() == 0, d.output()[-3000:]


def test_bed_is_clear_in_headless_chromium(tmp_path):
    """After a print the printer waits: its card says why and has Bed is clear; a person
    clicks it (token kept in the tab) and the next job prints; after that one it waits
    again, and `hostd clear` from the terminal releases it."""
    from daemon_helpers import hostd
    _requirements()
    port = free_port()
    config = write_config(tmp_path, printers=[{"name": "p1", "profile": "generic-0.5mm",
                                               "port": SIM, "baud": 2000000}],
                          web={"host": "127.0.0.1", "port": port, "token": TOKEN})
    base = "http://127.0.0.1:%d" % port
    d = DaemonProcess(config)
    browser = None

    def states():
        _, body = get_json(base + "/api/jobs")
        return sorted(j["state"] for j in body["jobs"])

    def wait(predicate, what, timeout=120):
        deadline = time.monotonic() + timeout
        while not predicate():
            assert time.monotonic() < deadline, "%s:\n%s" % (what, d.output()[-3000:])
            assert d.proc.poll() is None, d.output()[-3000:]
            time.sleep(0.05)

    def waiting():
        return get_json(base + "/api/status")[1]["waiting_for_person"]
    try:
        wait_http(base + "/healthz")
        for name in ("first.npy", "second.npy"):
            write_dome(tmp_path / "share" / "drop" / name)
        wait(lambda: states() == ["done", "ready"], "one printed, one ready")
        time.sleep(2.0)
        assert states() == ["done", "ready"], "the next job started on the finished sheet"
        assert waiting() == ["p1"]
        with urllib.request.urlopen(base + "/metrics", timeout=5) as r:
            assert "hostd_printers_waiting_for_person 1.0" in r.read().decode()

        browser = Chromium()
        browser.goto(base + "/")
        card = browser.js("document.querySelector('.printer .waiting').textContent")
        assert "Waits for a person" in card and "finished" in card and "hostd clear p1" in card
        browser.js("document.getElementById('token-input').value = %r;"
                   "document.getElementById('token-keep').click()" % TOKEN)
        browser.js("document.querySelector('form.clear button').click()")
        wait(lambda: states() == ["done", "done"], "the second print after Bed is clear")
        wait(lambda: waiting() == ["p1"], "the wait after the second print")
        r = hostd("clear", "p1", "-c", config)
        assert r.returncode == 0 and "bed of p1 is clear" in r.stdout, r.stderr
        assert waiting() == []
    finally:
        if browser is not None:
            browser.close()
        assert d.stop() == 0, d.output()[-3000:]

"""Real OctoPrint clients against a real node (`hostd run` on the simulator, loopback only).

Home Assistant's library (pyoctoprintapi) runs the integration's set-up flow: probe, ask
for a key, a person approves it with `hostd keys approve`, the client collects it, then
reads discovery, server, printer and job info while a print runs, and what it reads is what
the node's own /api/status says. octorest uploads a height field that then prints. A
zeroconf browser (python-zeroconf on 127.0.0.1) finds the node's announcement.
"""

import asyncio
import json
import shutil
import time

import pytest
import yaml

from daemon_helpers import SIM, DaemonProcess, hostd, jobs, wait_for, write_config, write_dome
from web_helpers import free_port, get_json, wait_http

pytestmark = pytest.mark.slow
TOKEN = "octoprint-clients-token"
# Moves at 1/5 of real time, so a print runs while the clients look; heating, which no
# client here watches, over in 0.7 s.
SLOW_SIM = "sim://?time_scale=0.2&advanced_ok=1&boot_s=0&hotend_tau_s=0.5&bed_tau_s=1"


def start_node(tmp_path, port, sim=SLOW_SIM, profile="generic-0.5mm", **web):
    config = write_config(tmp_path, printers=[{"name": "p1", "profile": profile, "port": sim,
                                               "baud": 2000000}],
                          web=dict({"host": "127.0.0.1", "port": port, "token": TOKEN}, **web))
    d = DaemonProcess(config)
    wait_http("http://127.0.0.1:%d/healthz" % port)
    return config, d


def drop_dome(tmp_path, name="dome"):
    # At 1/5 of real time its moves take 12 s: the clients look, pause, resume and cancel
    # within the first 2 of them.
    write_dome(tmp_path / "in" / (name + ".npy"))
    drop = tmp_path / "share" / "drop"
    for f in (name + ".yaml", name + ".npy"):
        shutil.copy(tmp_path / "in" / f, drop / (f + ".tmp"))
        (drop / (f + ".tmp")).rename(drop / f)


def approve_when_asked(config, app):
    """What a person does: `hostd keys list`, then `hostd keys approve ID`."""
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        r = hostd("keys", "list", "--json", "-c", config)
        assert r.returncode == 0, r.stderr
        pending = [p for p in json.loads(r.stdout)["pending"] if p["app"] == app]
        if pending:
            assert pending[0]["remote"] == "127.0.0.1"
            r = hostd("keys", "approve", pending[0]["id"], "-c", config)
            assert r.returncode == 0, r.stderr
            return r.stdout
        time.sleep(0.2)
    raise AssertionError("no key request from %s" % app)


async def home_assistant_setup(port, config, app="Home Assistant"):
    """The integration's config flow (homeassistant/components/octoprint/config_flow.py)."""
    import aiohttp
    from pyoctoprintapi import OctoprintClient
    async with aiohttp.ClientSession() as session:
        client = OctoprintClient("127.0.0.1", session, port, False, "/")
        approved = asyncio.get_running_loop().run_in_executor(None, approve_when_asked,
                                                              config, app)
        key = await client.request_app_key(app, "admin", 60)
        assert "approved" in await approved
        client.set_api_key(key)
        discovery = await client.get_discovery_info()
        server = await client.get_server_info()
        tracking = await client.get_tracking_info()
        webcam = await client.get_webcam_info()
        return key, discovery.upnp_uuid, server.version, tracking, webcam


async def poll_printer(port, key):
    import aiohttp
    from pyoctoprintapi import OctoprintClient
    async with aiohttp.ClientSession() as session:
        client = OctoprintClient("127.0.0.1", session, port, False, "/")
        client.set_api_key(key)
        return await client.get_printer_info(), await client.get_job_info()


async def act(port, key, what):
    import aiohttp
    from pyoctoprintapi import OctoprintClient
    async with aiohttp.ClientSession() as session:
        client = OctoprintClient("127.0.0.1", session, port, False, "/")
        client.set_api_key(key)
        await getattr(client, what)()


def test_home_assistant_adds_the_node_and_follows_a_print(tmp_path):
    pytest.importorskip("pyoctoprintapi")
    from pyoctoprintapi.exceptions import UnauthorizedException
    port = free_port()
    base = "http://127.0.0.1:%d" % port
    config, d = start_node(tmp_path, port)
    try:
        key, uid, version, tracking, webcam = asyncio.run(home_assistant_setup(port, config))
        _, settings = get_json(base + "/api/settings")
        assert uid == settings["plugins"]["discovery"]["upnpUuid"]
        assert uid == (tmp_path / "state" / "upnp_uuid").read_text().strip()
        assert version == "1.10.0" and tracking.enabled is False
        assert webcam is not None and webcam.enabled is False

        drop_dome(tmp_path)

        def printing():
            _, s = get_json(base + "/api/status")
            p = s["printers"][0]
            return p["job"] and p["state"] == "printing" and (p["job"]["progress"] or 0) > 0.01
        wait_for(printing, 180, "a print to run", proc=d)
        printer, job = asyncio.run(poll_printer(port, key))
        _, s = get_json(base + "/api/status")
        p = s["printers"][0]
        assert printer.state.text == "Printing" and printer.state.flags.printing
        assert not printer.state.flags.paused and printer.state.flags.operational
        temps = {t.name: t for t in printer.temperatures}
        for heater, name in (("T", "tool0"), ("B", "bed")):
            assert temps[name].target_temp == p["temperatures"][heater]["target"]
            assert abs(temps[name].actual_temp - p["temperatures"][heater]["current"]) < 3.0
        assert job.state == "Printing"
        assert job.job.file.name.endswith(".gcode") and job.job.file.origin == "local"
        assert job.job.file.name in p["job"]["files"]
        assert abs(job.progress.completion - 100 * p["job"]["progress"]) < 5.0
        assert job.progress.print_time is not None and job.progress.print_time_left is not None
        assert abs(job.progress.print_time_left - p["job"]["eta_s"]) < \
            max(30.0, 0.25 * p["job"]["eta_s"])

        asyncio.run(act(port, key, "pause_job"))
        wait_for(lambda: get_json(base + "/api/status")[1]["printers"][0]["state"] == "paused",
                 30, "paused", proc=d)
        assert asyncio.run(poll_printer(port, key))[0].state.flags.paused
        asyncio.run(act(port, key, "resume_job"))
        wait_for(lambda: get_json(base + "/api/status")[1]["printers"][0]["state"] == "printing",
                 30, "printing again", proc=d)
        asyncio.run(act(port, key, "cancel_job"))
        wait_for(lambda: [j["state"] for j in jobs(config)] == ["cancelled"], 60,
                 "the job cancelled", proc=d)

        _, page = 200, get_page(base + "/")
        assert "Home Assistant" in page and key not in page
        r = hostd("keys", "revoke", "Home Assistant", "-c", config)
        assert r.returncode == 0, r.stderr
        with pytest.raises(UnauthorizedException):
            asyncio.run(poll_printer(port, key))
    finally:
        d.stop()
    assert key not in d.output()


def get_page(url):
    import urllib.request
    with urllib.request.urlopen(url, timeout=10) as r:
        return r.read().decode()


def small_dome_profile(tmp_path):
    """generic-0.5mm planning an input without a sidecar as a 15 mm dome by the paper's
    method: what the sidecar of write_dome says, for a client that sends no sidecar."""
    from pipeline.profiles.profile import find_profile
    data = yaml.safe_load(find_profile("generic-0.5mm").read_text())
    data["defaults"]["size_mm"] = 15.0
    data["flatten"]["method"] = "isoline"
    path = tmp_path / "small-dome.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def test_octorest_upload_becomes_a_job_and_prints(tmp_path):
    octorest = pytest.importorskip("octorest")
    port = free_port()
    config, d = start_node(tmp_path, port, sim=SIM, profile=small_dome_profile(tmp_path))
    key = None
    try:
        base = "http://127.0.0.1:%d" % port
        r = get_json(base + "/plugin/appkeys/request", method="POST",
                     data=json.dumps({"app": "octorest"}).encode(),
                     headers={"Content-Type": "application/json"})
        assert r[0] == 201
        approve_when_asked(config, "octorest")
        status, answer = get_json(base + "/plugin/appkeys/request/" + r[1]["app_token"])
        assert status == 200
        key = answer["api_key"]
        client = octorest.OctoRest(url=base, apikey=key)
        write_dome(tmp_path / "in" / "dome.npy")
        result = client.upload(str(tmp_path / "in" / "dome.npy"), select=True, print=True)
        assert result["done"] is True and result["files"]["local"]["name"] == "dome.npy"
        with pytest.raises(RuntimeError):
            (tmp_path / "in" / "bad.npy").write_bytes(b"not an array")
            client.upload(str(tmp_path / "in" / "bad.npy"))
        wait_for(lambda: [j["state"] for j in jobs(config)] == ["done"], 240,
                 "the upload to print", proc=d)
        [job] = jobs(config)
        assert job["name"] == "dome.npy"
        listed = {f["name"]: f for f in client.files()["files"]}
        assert listed["dome.npy"]["prints"]["success"] == 1
        assert not list((tmp_path / "share" / "failed").glob("bad*"))
        with pytest.raises(RuntimeError):
            octorest.OctoRest(url=base, apikey=key[:-2] + "xx").upload(
                str(tmp_path / "in" / "dome.npy"))
    finally:
        d.stop()
    assert key and key not in d.output() and r[1]["app_token"] not in d.output()
    assert "octorest" in d.output()          # the request is logged, without its secrets


def browse(service, seconds):
    from zeroconf import IPVersion, ServiceBrowser, Zeroconf
    zc = Zeroconf(interfaces=["127.0.0.1"], ip_version=IPVersion.V4Only)
    found = []

    class Listener:
        def add_service(self, zc_, type_, name):
            found.append(name)

        def update_service(self, *args):
            pass

        def remove_service(self, *args):
            pass

    browser = ServiceBrowser(zc, service, Listener())
    try:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline and not found:
            time.sleep(0.05)
        infos = [zc.get_service_info(service, n, timeout=3000) for n in found]
        return infos
    finally:
        browser.cancel()
        zc.close()


def test_zeroconf_browse_finds_the_node(tmp_path):
    pytest.importorskip("zeroconf")
    port = free_port()
    _, d = start_node(tmp_path, port, sim=SIM, announce=True)
    try:
        infos = [i for i in browse("_octoprint._tcp.local.", 10) if i and i.port == port]
        assert infos, d.output()[-2000:]
        info = infos[0]
        _, settings = get_json("http://127.0.0.1:%d/api/settings" % port)
        txt = {k.decode(): v.decode() for k, v in info.properties.items()}
        assert txt["uuid"] == settings["plugins"]["discovery"]["upnpUuid"]
        assert txt["path"] == "/" and txt["api"] == "0.1" and txt["version"] == "1.10.0"
        assert "127.0.0.1" in info.parsed_addresses()
        assert any(i and i.port == port for i in browse("_http._tcp.local.", 10))
    finally:
        d.stop()


def test_no_announcement_when_turned_off(tmp_path):
    pytest.importorskip("zeroconf")
    port = free_port()
    _, d = start_node(tmp_path / "off", port, sim=SIM, announce=False)
    try:
        assert not [i for i in browse("_octoprint._tcp.local.", 4) if i and i.port == port]
    finally:
        d.stop()

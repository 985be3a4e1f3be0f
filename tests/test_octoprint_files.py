"""OctoPrint's upload, files, settings, server, connection and discovery endpoints."""

import io
import os
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from hostd.web.app import create_app
from test_appkeys import approved_key
from test_web_api import Node, answerer, node  # noqa: F401 (fixtures)


def npy_bytes(z):
    b = io.BytesIO()
    np.save(b, z)
    return b.getvalue()


def upload(node, name, content, key, **fields):
    data = dict(fields, file=(io.BytesIO(content), name))
    return node.client.post("/api/files/local", data=data, headers={"X-Api-Key": key},
                            content_type="multipart/form-data")


def tree(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def test_upload_lands_in_the_drop_folder_with_its_sidecar(node):
    key = approved_key(node)
    r = upload(node, "dome.npy", npy_bytes(np.ones((8, 8))), key, select="true",
               print="true", sidecar="pixel_mm: 0.5\nmethod: isoline\n")
    assert r.status_code == 201, r.json
    assert r.json["done"] is True and r.json["files"]["local"]["name"] == "dome.npy"
    assert r.json["files"]["local"]["origin"] == "local"
    assert r.headers["Location"].endswith("/api/files/local/dome.npy")
    drop = node.config.drop_dir
    assert tree(drop) == ["dome.npy", "dome.yaml"]
    assert (drop / "dome.yaml").read_text() == "pixel_mm: 0.5\nmethod: isoline\n"
    again = upload(node, "dome.npy", npy_bytes(np.ones((8, 8))), key)
    assert again.json["files"]["local"]["name"] != "dome.npy"     # never over another
    r = upload(node, "d.npy", npy_bytes(np.ones((8, 8))), key, printer="nope")
    assert r.status_code == 400 and "no printer or profile" in r.json["error"]
    r = upload(node, "d.npy", npy_bytes(np.ones((8, 8))), key, printer="generic-0.5mm")
    assert r.status_code == 201 and (drop / "generic-0.5mm" / "d.npy").exists()


@pytest.mark.parametrize("name,content,code,status", [
    ("junk.npy", b"not numpy at all", "heightfield.content_mismatch", 400),
    ("empty.png", b"", "heightfield.empty", 400),
    ("notes.txt", b"hello", "heightfield.unsupported_type", 415)])
def test_a_bad_file_gets_the_intakes_coded_reason_and_never_lands(node, tmp_path, name,
                                                                  content, code, status):
    from pipeline.errors import PipelineError
    from pipeline.input.heightfield import check_file
    dropped = tmp_path / "as-dropped" / name
    dropped.parent.mkdir()
    dropped.write_bytes(content)
    with pytest.raises(PipelineError) as exc:        # what the intake says of it dropped
        check_file(dropped)
    assert exc.value.code == code
    r = upload(node, name, content, approved_key(node))
    assert r.status_code == status and r.json["code"] == code
    assert set(r.json) == {"error", "code"} and name in r.json["error"]
    assert ".upload-" not in r.json["error"]
    assert tree(node.config.drop_dir) == []


def test_a_bad_sidecar_gets_its_code_and_nothing_lands(node):
    r = upload(node, "dome.npy", npy_bytes(np.ones((8, 8))), approved_key(node),
               sidecar="pixel_mm: lots\n")
    assert r.status_code == 400 and r.json["code"].startswith("sidecar.")
    assert "dome.yaml" in r.json["error"]
    assert tree(node.config.drop_dir) == []


def test_nothing_is_written_outside_the_drop_folder(node, tmp_path):
    before = set(tree(tmp_path))
    key = approved_key(node)
    for name in ("../../evil.npy", "..\\..\\evil2.npy", "/etc/evil3.npy", "../drop2/e.npy"):
        r = upload(node, name, npy_bytes(np.ones((4, 4))), key)
        assert r.status_code in (201, 400), r.json     # the name taken plain, or refused
    new = set(tree(tmp_path)) - before
    assert all(p.startswith("drop/") or p.startswith("state/") for p in new), new
    assert {"evil.npy", "evil3.npy", "e.npy"} <= set(tree(node.config.drop_dir))


def test_files_lists_jobs_in_octoprints_shape(node):
    key = approved_key(node)
    files = node.client.get("/api/files", headers={"X-Api-Key": key}).json
    assert files["free"] > 0 and files["total"] >= files["free"]
    by_name = {f["name"]: f for f in files["files"]}
    dome = by_name["dome.npy"]
    assert dome["origin"] == "local" and dome["hostd"]["state"] == "printing"
    assert dome["hostd"]["job"] == node.printing
    assert by_name["<script>alert(1)</script>.png"]["prints"] == {"success": 0, "failure": 1}
    one = node.client.get("/api/files/local/dome.npy").json
    assert one["hostd"]["job"] == node.printing
    assert node.client.get("/api/files/local/none.npy").status_code == 404


def test_settings_server_and_discovery_share_one_stable_uuid(node, tmp_path):
    s = node.client.get("/api/settings").json
    uid = s["plugins"]["discovery"]["upnpUuid"]
    assert len(uid) == 36 and s["plugins"]["tracking"]["enabled"] is False
    assert s["webcam"]["webcamEnabled"] is False
    assert (node.config.state_dir / "upnp_uuid").read_text().strip() == uid
    again = create_app(node.config, store=node.store).test_client()      # a restart
    assert again.get("/api/settings").json["plugins"]["discovery"]["upnpUuid"] == uid
    assert node.client.get("/api/server").json == {"version": "1.10.0", "safemode": None}
    r = node.client.get("/plugin/discovery/discovery.xml")
    assert r.mimetype == "text/xml"
    ns = {"u": "urn:schemas-upnp-org:device-1-0"}
    root = ET.fromstring(r.data)
    assert root.find("u:device/u:UDN", ns).text == "uuid:" + uid
    assert root.find("u:device/u:deviceType", ns).text == "urn:schemas-upnp-org:device:Basic:1"
    other = Node(tmp_path / "other")
    assert other.client.get("/api/settings").json["plugins"]["discovery"]["upnpUuid"] != uid
    other.store.close()


def test_connection_state_and_commands(node, answerer):
    c = node.client.get("/api/connection").json
    assert c["current"]["state"] == "Printing"
    cfg = node.config.printers[0]
    assert c["current"]["port"] == cfg.port and c["current"]["baudrate"] == cfg.baud
    assert c["current"]["printerProfile"] == cfg.profile
    h = {"X-Api-Key": approved_key(node)}
    r = node.client.post("/api/connection", headers=h, json={"command": "disconnect"})
    assert r.status_code == 409 and "cancel the job first" in r.json["error"]
    r = node.client.post("/api/connection", headers=h, json={"command": "connect"})
    assert r.status_code == 204                       # connected already: nothing asked
    r = node.client.post("/api/connection", headers=h, json={"command": "explode"})
    assert r.status_code == 400
    node.store.set_printer("sim", state="idle", job_id=None)
    r = node.client.post("/api/connection", headers=h, json={"command": "disconnect"})
    assert r.status_code == 204
    node.store.set_printer("sim", paused=1)
    assert node.client.post("/api/connection", headers=h,
                            json={"command": "connect"}).status_code == 204
    assert answerer.seen == [("pause", "sim"), ("resume", "sim")]


def test_job_commands_follow_octoprints_preconditions(node, answerer):
    h = {"X-Api-Key": approved_key(node)}
    r = node.client.post("/api/job", headers=h, json={"command": "start"})
    assert r.status_code == 409 and r.json["error"] == "Printer is already printing"
    r = node.client.post("/api/job", headers=h, json={"command": "pause", "action": "resume"})
    assert r.status_code == 204                       # not paused: nothing to resume
    r = node.client.post("/api/job", headers=h, json={"command": "pause"})     # toggle
    assert r.status_code == 204
    assert node.client.post("/api/job", headers=h, json={"command": "restart"}).status_code == 409
    assert node.client.post("/api/job", headers=h, json={"command": "x"}).status_code == 400
    node.store.set_printer("sim", state="idle", job_id=None)
    r = node.client.post("/api/job", headers=h, json={"command": "cancel"})
    assert r.status_code == 409 and r.json["error"] == "Printer is neither printing nor paused"
    r = node.client.post("/api/job", headers=h, json={"command": "start"})
    assert r.status_code == 409 and "by itself" in r.json["error"]
    node.store.set_printer("sim", paused=1)            # held by a person: start releases it
    assert node.client.post("/api/job", headers=h, json={"command": "start"}).status_code == 204
    assert answerer.seen == [("pause", "sim"), ("resume", "sim")]


def test_announce_setting(tmp_path):
    import yaml

    from hostd.announce import wanted
    from hostd.config import load_config
    from hostd.errors import HostdError
    path = tmp_path / "hostd.yaml"
    for web, expected in (({"host": "127.0.0.1"}, False), ({"host": "0.0.0.0"}, True),
                          ({"host": "192.168.1.4"}, True), ({"host": "localhost"}, False),
                          ({"host": "0.0.0.0", "announce": False}, False),
                          ({"host": "127.0.0.1", "announce": True}, True)):
        path.write_text(yaml.safe_dump({"web": web}))
        assert wanted(load_config(path).web) is expected, web
    path.write_text(yaml.safe_dump({"web": {"announce": "no"}}))
    with pytest.raises(HostdError) as exc:
        load_config(path)
    assert exc.value.code == "config.type" and "true or false" in str(exc.value)
    assert os.path.exists(path)

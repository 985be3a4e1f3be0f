"""hostd.yaml: the embedded default works, overrides merge, mistakes name key and file."""

import subprocess
import sys

import pytest

from hostd.config import check_profiles, load_config
from hostd.errors import HostdError


def test_default_config_just_works(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    c = load_config()
    assert c.drop_dir == tmp_path / "hostd-data" / "drop"
    for key in ("state_dir", "outbox_dir", "done_dir", "failed_dir"):
        assert getattr(c, key).parent == tmp_path / "hostd-data"
    assert len(c.printers) == 1 and c.printers[0].port.startswith("sim://")
    assert (c.web.host, c.web.port) == ("127.0.0.1", 8080)
    assert c.planning.workers >= 1 and c.planning.time_limit_s > 0 and c.planning.memory_mb > 0
    assert c.node_id


def test_file_merges_over_default_and_resolves_relative_to_itself(tmp_path):
    cfg = tmp_path / "etc" / "hostd.yaml"
    cfg.parent.mkdir()
    cfg.write_text("node_id: n1\ndrop_dir: ../share/drop\npoll_s: 0.5\n"
                   "planning: {workers: 3}\n"
                   "printers: [{name: left, port: /dev/ttyACM0, profile: prusa-mk3s-0.4mm}]\n")
    c = load_config(cfg)
    assert c.node_id == "n1" and c.poll_s == 0.5
    assert c.drop_dir == tmp_path / "share" / "drop"
    assert c.planning.workers == 3 and c.planning.time_limit_s == 600.0   # merged section
    assert [p.name for p in c.printers] == ["left"] and c.printers[0].baud == 115200


@pytest.mark.parametrize("text, key, code", [
    ("pol_s: 2\n", "pol_s", "config.unknown_key"),
    ("poll_s: fast\n", "poll_s", "config.type"),
    ("planning: {workers: 0}\n", "planning.workers", "config.value"),
    ("planning: {threads: 2}\n", "planning.threads", "config.unknown_key"),
    ("web: {port: '80'}\n", "web.port", "config.type"),
    ("printers: [{name: a, port: sim://, speed: 3}]\n", "printers[0].speed", "config.unknown_key"),
    ("printers: [{port: sim://}]\n", "printers[0]", "config.missing"),
    ("printers: [{name: a}, {name: a}]\n", "printers[1].name", "config.value"),
    ("printers: [{name: a, port: /dev/ttyACM0}, {name: b, port: /dev/ttyACM0}]\n",
     "printers[1].port", "config.value"),
    ("printers: [{name: '../x'}]\n", "printers[0].name", "config.value"),
    ("printers: []\n", "printers", "config.type"),
])
def test_mistakes_name_the_key_and_the_file(tmp_path, text, key, code):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text(text)
    with pytest.raises(HostdError) as err:
        load_config(cfg)
    assert err.value.code == code
    assert err.value.key == key
    assert str(cfg) in err.value.text() and key in err.value.text()


def test_one_device_under_two_names_is_one_port(tmp_path):
    device = tmp_path / "ttyACM0"
    device.touch()
    (tmp_path / "by-id").mkdir()
    (tmp_path / "by-id" / "usb-Prusa_MK3").symlink_to(device)
    cfg = tmp_path / "hostd.yaml"
    cfg.write_text("printers: [{name: a, port: %s}, {name: b, port: %s}]\n"
                   % (device, tmp_path / "by-id" / "usb-Prusa_MK3"))
    with pytest.raises(HostdError) as err:
        load_config(cfg)
    assert err.value.key == "printers[1].port" and "the same port" in err.value.text()
    # Simulated printers are each their own.
    cfg.write_text("printers: [{name: a, port: 'sim://'}, {name: b, port: 'sim://'}]\n")
    assert len(load_config(cfg).printers) == 2


def test_a_printer_whose_profile_does_not_load_is_a_config_error(tmp_path):
    broken = tmp_path / "mine.yaml"
    broken.write_text("name: mine\n")
    for profile, says in (("prusa-mk3s", "no profile named 'prusa-mk3s'"),
                          (str(broken), "profile %s: missing required key" % broken)):
        cfg = tmp_path / "hostd.yaml"
        cfg.write_text("printers: [{name: p1, port: 'sim://'}, {name: left, port: 'sim://', "
                       "profile: '%s'}]\n" % profile)
        config = load_config(cfg)
        with pytest.raises(HostdError) as err:
            check_profiles(config)
        assert err.value.code == "config.profile" and err.value.key == "printers[1].profile"
        assert "printer 'left'" in err.value.text() and says in err.value.text()
        assert str(cfg) in err.value.text()
    # and `hostd run` refuses to start on it, before touching any folder
    r = subprocess.run([sys.executable, "-m", "hostd", "run", "--config", str(cfg)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "config.profile" in r.stderr
    assert not (tmp_path / "hostd-data").exists()
    check_profiles(load_config())       # the embedded default's profile loads


def test_unreadable_and_broken_yaml(tmp_path):
    with pytest.raises(HostdError) as err:
        load_config(tmp_path / "missing.yaml")
    assert err.value.code == "config.unreadable"
    bad = tmp_path / "broken.yaml"
    bad.write_text("poll_s: [1,\n")
    with pytest.raises(HostdError) as err:
        load_config(bad)
    assert err.value.code == "config.yaml" and "line" in err.value.text()

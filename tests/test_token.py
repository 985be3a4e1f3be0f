"""Without a token the page draws its actions disabled and says how to turn them on;
``hostd token`` writes one that a daemon started with that file accepts."""

import dataclasses
import os
import re
import stat
from pathlib import Path

import pytest

from hostd.cli import main
from hostd.config import load_config
from hostd.web.app import create_app


def _client(tmp_path, token):
    base = load_config()
    config = dataclasses.replace(base, node_id="n1", drop_dir=tmp_path / "drop",
                                 state_dir=tmp_path / "state", outbox_dir=tmp_path / "outbox",
                                 web=dataclasses.replace(base.web, token=token))
    for d in ("drop_dir", "state_dir", "outbox_dir"):
        getattr(config, d).mkdir(parents=True, exist_ok=True)
    from hostd import jobs as J
    J.JobStore(config.db_path).close()
    return create_app(config).test_client()


def test_without_a_token_every_button_is_drawn_disabled_with_the_way_out(tmp_path):
    html = _client(tmp_path, None).get("/").get_data(as_text=True)
    buttons = [b for b in re.findall(r"<button type=\"submit\"[^>]*>", html)
               if "token-keep" not in b]
    assert len(buttons) >= 3 and all("disabled" in b for b in buttons)
    assert "hostd token" in html and "hostd run -c hostd.yaml" in html
    on = _client(tmp_path / "on", "secret").get("/").get_data(as_text=True)
    assert not any("disabled" in b for b in re.findall(r"<button type=\"submit\"[^>]*>", on))


def test_hostd_token_writes_a_token_the_daemon_reads(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["token"]) == 0
    token = capsys.readouterr().out.strip()
    assert len(token) >= 24
    config = load_config(tmp_path / "hostd.yaml")
    assert config.web.token == token
    assert (tmp_path / "hostd.yaml").stat().st_mode & 0o077 == 0
    # The embedded default fills in the rest: the same folders as `hostd run` alone.
    assert config.drop_dir == load_config().drop_dir
    assert main(["token"]) == 0                  # a new one replaces it
    assert load_config(tmp_path / "hostd.yaml").web.token == capsys.readouterr().out.strip()


def test_hostd_token_never_follows_a_planted_part_file(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me\n")
    (tmp_path / "hostd.yaml.part").symlink_to(victim)
    assert main(["token"]) == 0
    token = capsys.readouterr().out.strip()
    assert victim.read_text() == "keep me\n"
    assert load_config(tmp_path / "hostd.yaml").web.token == token
    assert not (tmp_path / "hostd.yaml.part").exists()


def test_the_new_token_is_private_from_its_creation(tmp_path, monkeypatch, capsys):
    # Whatever the umask, and with no chmod after the fact, no one else could read it.
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(os, "chmod", lambda *a, **k: None)
    monkeypatch.setattr(Path, "chmod", lambda *a, **k: None)
    old = os.umask(0)
    try:
        assert main(["token"]) == 0
    finally:
        os.umask(old)
    assert (tmp_path / "hostd.yaml").stat().st_mode & 0o077 == 0


def test_a_symlinked_config_stays_a_link_and_gets_the_token(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "etc").mkdir()
    real = tmp_path / "etc" / "hostd.yaml"
    real.write_text("poll_s: 3.0\n")
    (tmp_path / "hostd.yaml").symlink_to(real)
    assert main(["token"]) == 0
    token = capsys.readouterr().out.strip()
    assert (tmp_path / "hostd.yaml").is_symlink()
    config = load_config(real)
    assert config.web.token == token and config.poll_s == 3.0


@pytest.mark.skipif(os.geteuid() != 0, reason="giving a file to another owner needs root")
def test_a_token_written_as_root_keeps_the_files_owner_and_group(tmp_path, capsys):
    conf = tmp_path / "hostd.yaml"
    conf.write_text("poll_s: 3.0\n")
    os.chown(conf, 4321, 4322)
    conf.chmod(0o640)
    assert main(["token", "-c", str(conf)]) == 0
    st = conf.stat()
    assert (st.st_uid, st.st_gid) == (4321, 4322)
    assert stat.S_IMODE(st.st_mode) == 0o640       # the service's group still reads it
    assert load_config(conf).web.token == capsys.readouterr().out.strip()


def test_a_world_readable_config_loses_its_world_bits_and_keeps_its_group(tmp_path, capsys):
    conf = tmp_path / "hostd.yaml"
    conf.write_text("poll_s: 3.0\n")
    conf.chmod(0o644)
    assert main(["token", "-c", str(conf)]) == 0
    assert stat.S_IMODE(conf.stat().st_mode) == 0o640

"""Without a token the page draws its actions disabled and says how to turn them on;
``hostd token`` writes one that a daemon started with that file accepts."""

import dataclasses
import re

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

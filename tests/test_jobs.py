"""The SQLite job store: states, order, events, restart recovery, control requests."""

import sqlite3

import pytest

from hostd import jobs as J
from hostd.errors import HostdError


@pytest.fixture
def store(tmp_path):
    s = J.JobStore(tmp_path / "jobs.sqlite")
    yield s
    s.close()


def test_wal_and_lifecycle(store, tmp_path):
    assert store.db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    jid = store.add("a.png", "a.png", tmp_path / "a.png", profile="p")
    assert store.get(jid)["state"] == J.QUEUED
    for state in (J.PLANNING, J.READY, J.PRINTING):
        store.set_state(jid, state)
    store.update(jid, progress=0.5, last_line=120)
    store.set_state(jid, J.DONE, "printed")
    job = store.get(jid)
    assert job["state"] == J.DONE and job["finished_at"] and job["progress"] == 0.5
    kinds = [e["kind"] for e in store.events(jid)]
    assert kinds == ["created", "planning", "ready", "printing", "done"]
    assert store.get(jid[:-2])["id"] == jid      # a unique prefix finds it
    with pytest.raises(HostdError):
        store.require("nope")


def test_priority_then_arrival(store, tmp_path):
    ids = [store.add(n, n, tmp_path / n, priority=p)
           for n, p in (("a", 0), ("b", 5), ("c", 0), ("d", 5))]
    order = [j["name"] for j in store.next_in_order(J.QUEUED)]
    assert order == ["b", "d", "a", "c"]
    assert len(set(ids)) == 4


def test_recovery_after_a_crash(tmp_path):
    path = tmp_path / "jobs.sqlite"
    s = J.JobStore(path)
    q = s.add("q", "q", "q")
    p = s.add("p", "p", "p")
    s.set_state(p, J.PLANNING)
    r = s.add("r", "r", "r")
    s.set_state(r, J.PRINTING)
    s.update(r, last_line=77)
    # kill -9: no close, a second connection takes over
    s2 = J.JobStore(path)
    changed = s2.recover()
    assert set(changed) == {p, r}
    assert s2.get(q)["state"] == J.QUEUED
    assert s2.get(p)["state"] == J.QUEUED
    job = s2.get(r)
    assert job["state"] == J.INTERRUPTED and job["error_code"] == "job.interrupted"
    assert "requeue" in s2.events(r)[-1]["message"]


def test_control_requests_round_trip(tmp_path):
    daemon = J.JobStore(tmp_path / "jobs.sqlite")
    cli = J.JobStore(tmp_path / "jobs.sqlite")
    req = cli.request("pause", "p1")
    assert cli.wait_answer(req, timeout_s=0.1) is None
    [pending] = daemon.pending_requests()
    assert (pending["action"], pending["target"]) == ("pause", "p1")
    daemon.answer(pending["id"], True, "paused p1")
    assert cli.wait_answer(req) == (True, "paused p1")
    assert daemon.pending_requests() == []


def test_missing_database_is_a_clear_error(tmp_path):
    with pytest.raises(HostdError) as err:
        J.JobStore(tmp_path / "none.sqlite", create=False)
    assert "hostd run" in err.value.text()


def test_a_reader_never_sets_up_the_store(tmp_path):
    # The daemon creates the file and its tables; a CLI reader arriving first must
    # neither create tables nor switch the journal mode (the two processes doing
    # both at once deadlocked, and the daemon exited at start).
    path = tmp_path / "jobs.sqlite"
    db = sqlite3.connect(str(path))
    db.execute("CREATE TABLE unrelated (x)")
    db.commit()
    with pytest.raises(HostdError) as err:
        J.JobStore(path, create=False)
    assert err.value.code == "jobs.missing"
    tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    assert tables == {"unrelated"}
    assert db.execute("PRAGMA journal_mode").fetchone()[0] == "delete"
    db.close()
    J.JobStore(path).close()
    reader = J.JobStore(path, create=False)
    assert reader.db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    reader.close()


def test_setup_retries_while_the_file_is_locked(monkeypatch):
    calls = []

    def flaky():
        calls.append(1)
        if len(calls) < 3:
            raise sqlite3.OperationalError("database is locked")
        return "ok"

    monkeypatch.setattr(J.time, "sleep", lambda s: None)
    assert J._retry_locked(flaky) == "ok"
    assert len(calls) == 3
    with pytest.raises(sqlite3.OperationalError):
        J._retry_locked(lambda: (_ for _ in ()).throw(sqlite3.OperationalError("no such table")))


def test_unknown_fields_and_states_are_refused(store):
    jid = store.add("a", "a", "a")
    with pytest.raises(ValueError):
        store.update(jid, colour="red")
    with pytest.raises(ValueError):
        store.set_state(jid, "exploded")
    with pytest.raises(sqlite3.Error):
        store.db.execute("SELECT nope FROM jobs")


def test_a_terminal_command_on_a_full_job_database_says_so(tmp_path, monkeypatch, capsys):
    """``hostd cancel`` etc. insert a request: on a full database that is the error shown."""
    import argparse

    from daemon_helpers import fill_store
    from hostd.commands import jobs as cli
    store = J.JobStore(tmp_path / "jobs.sqlite")
    jid = store.add("a.png", "a.png", tmp_path / "a.png", profile="p")
    fill_store(store)
    monkeypatch.setattr(cli, "_open", lambda args, need_daemon: (None, store, 1234))
    rc = cli.cmd_action(argparse.Namespace(action="cancel", target=jid, config=None))
    err = capsys.readouterr().err
    assert rc == 2 and "error jobs.disk_full" in err and "Fix: free space" in err


def damage(path):
    """What a power cut mid-write does to an SD card's pages: all after the first garbled."""
    size = path.stat().st_size
    with open(path, "r+b") as f:
        f.seek(4096)
        f.write(b"\xde\xad" * ((size - 4096) // 2))


def test_a_damaged_job_database_is_kept_aside_and_a_new_one_started(tmp_path):
    path = tmp_path / "jobs.sqlite"
    store = J.JobStore(path)
    store.add("a.png", "a.png", tmp_path / "a.png")
    store.close()
    store, aside, verdict = J.open_checked(path)
    assert aside is None and verdict is None and len(store.list()) == 1
    store.close()

    damage(path)
    kept = path.read_bytes()
    store, aside, verdict = J.open_checked(path)
    assert aside.name.startswith("jobs.sqlite.damaged-") and aside.read_bytes() == kept
    assert "malformed" in verdict or "corrupt" in verdict, verdict
    assert store.list() == [] and store.add("b.png", "b.png", tmp_path / "b.png")
    store.close()

    path.write_bytes(b"this is no database, but a file put in its place" * 100)
    store, aside2, verdict = J.open_checked(path)
    assert aside2 != aside and aside2.exists() and "not a database" in verdict
    store.close()


def test_a_terminal_command_on_a_damaged_job_database_says_so(tmp_path, capsys):
    from daemon_helpers import write_config
    from hostd.cli import main
    from hostd.config import load_config
    cfg = write_config(tmp_path)
    path = load_config(cfg).db_path
    store = J.JobStore(path)
    store.add("a.png", "a.png", tmp_path / "a.png")
    store.close()
    damage(path)
    assert main(["jobs", "--config", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert "error jobs.damaged" in err and "restart the daemon" in err


def test_job_ids_made_in_one_burst_do_not_collide():
    """A drop folder of thousands of files is taken within a second or two; with six
    random hex digits twenty thousand ids would hold about a dozen duplicates."""
    ids = [J.new_job_id() for _ in range(20000)]
    assert len(set(ids)) == len(ids)

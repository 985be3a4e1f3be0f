"""The daemon's rooms are objects it wires and looks up by name, each handed what it uses."""

import ast
from pathlib import Path

import pytest

from daemon_helpers import in_process_daemon
from hostd.errors import HostdError

ROOT = Path(__file__).resolve().parents[1]
PARTS = ("routes", "farm", "watcher", "store", "endings", "outages", "plans", "printing",
         "intake", "control", "recovery")


def test_parts_are_looked_up_by_name(tmp_path):
    d = in_process_daemon(tmp_path, 0)
    try:
        for name in PARTS:
            assert d.lookup(name) is getattr(d, name)
        # each room is handed the same store and printers, not a daemon to reach into
        for name in ("intake", "control", "recovery", "printing", "outages"):
            room = d.lookup(name)
            assert room.store is d.store and room.slots is d.slots
            assert not any(v is d for v in vars(room).values())
        assert d.lookup("nope", None) is None
        with pytest.raises(HostdError) as err:
            d.lookup("nope")
        assert err.value.code == "daemon.no_part" and "control" in err.value.text()
    finally:
        d.shutdown()


def test_no_mixins_in_hostd():
    names = [node.name for path in (ROOT / "hostd").rglob("*.py")
             for node in ast.walk(ast.parse(path.read_text()))
             if isinstance(node, ast.ClassDef) and node.name.endswith("Mixin")]
    assert names == []

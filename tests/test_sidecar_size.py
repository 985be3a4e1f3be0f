"""A sidecar holds a few keys: a huge one is refused before it is parsed (parsing megabytes
of YAML stalled the daemon's intake for tens of seconds)."""

import pytest

from pipeline.errors import InvalidSidecar
from pipeline.input.sidecar import MAX_SIDECAR_BYTES, load_sidecar


def _sidecar(path, size):
    line = "# " + "x" * 77 + "\n"
    path.write_text(line * (size // len(line)) + "size_mm: 150\n")
    return path


def test_a_huge_sidecar_is_refused_unparsed(tmp_path, monkeypatch):
    import yaml
    parsed = []
    monkeypatch.setattr(yaml, "safe_load", lambda text: parsed.append(text) or {})
    path = _sidecar(tmp_path / "big.yaml", 4 * MAX_SIDECAR_BYTES)
    with pytest.raises(InvalidSidecar) as err:
        load_sidecar(path)
    assert err.value.code == "sidecar.too_large" and parsed == []
    assert str(path.stat().st_size) in str(err.value)


def test_a_sidecar_under_the_limit_is_read(tmp_path):
    assert load_sidecar(_sidecar(tmp_path / "ok.yaml", MAX_SIDECAR_BYTES - 200)).size_mm == 150

"""A sidecar holds a few keys: a huge one is refused before it is parsed (parsing megabytes
of YAML stalled the daemon's intake for tens of seconds)."""

import errno
import io

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


def test_a_huge_sidecar_is_refused_before_it_is_opened(tmp_path, monkeypatch):
    from pipeline.input import sidecar as sidecar_mod
    monkeypatch.setattr(sidecar_mod, "open", lambda *a, **kw: pytest.fail("opened"),
                        raising=False)
    path = _sidecar(tmp_path / "big.yaml", 4 * MAX_SIDECAR_BYTES)
    with pytest.raises(InvalidSidecar) as err:
        load_sidecar(path)
    text = str(err.value)
    assert err.value.code == "sidecar.too_large" and err.value.fix
    assert str(path.stat().st_size) in text and str(MAX_SIDECAR_BYTES) in text


def test_a_sidecar_that_grows_while_it_is_read_is_read_no_further_than_the_limit(
        tmp_path, monkeypatch):
    from pipeline.input import sidecar as sidecar_mod
    path = _sidecar(tmp_path / "growing.yaml", 100)
    asked = []

    class Growing(io.BytesIO):
        def read(self, n=-1):
            asked.append(n)
            return super().read(n)
    monkeypatch.setattr(sidecar_mod, "open", lambda *a, **kw: Growing(b"#" * 10**7),
                        raising=False)
    with pytest.raises(InvalidSidecar) as err:
        load_sidecar(path)
    assert err.value.code == "sidecar.too_large"
    assert asked and all(0 <= n <= MAX_SIDECAR_BYTES + 1 for n in asked)


def test_a_sidecar_that_cannot_be_read_is_refused_with_its_own_code(tmp_path, monkeypatch):
    from pipeline.input import sidecar as sidecar_mod

    def denied(*args, **kw):
        raise PermissionError(errno.EACCES, "Permission denied")
    monkeypatch.setattr(sidecar_mod, "open", denied, raising=False)
    with pytest.raises(InvalidSidecar) as err:
        load_sidecar(_sidecar(tmp_path / "locked.yaml", 100))
    assert err.value.code == "sidecar.unreadable" and "Permission denied" in str(err.value)

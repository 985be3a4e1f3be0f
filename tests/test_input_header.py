"""The checks of an input's first bytes that the daemon runs on every file it takes
(heightfield.check_file): cheap, and never refusing a file of the right type."""

import io

import numpy as np
import pytest

from pipeline.errors import InvalidHeightField
from pipeline.input import heightfield as H

GOOD = {"a.npy": b"\x93NUMPY\x01\x00", "a.png": b"\x89PNG\r\n\x1a\n\x00\x00",
        "a.tif": b"II*\x00\x08\x00", "a.tiff": b"MM\x00*\x00\x08", "a.npz": b"PK\x03\x04\x14",
        "a.ply": b"ply\nformat ascii 1.0\n", "a.glb": b"glTF\x02\x00", "a.obj": b"v 0 0 0\n",
        "a.stl": b"solid part\n"}


@pytest.mark.parametrize("name", sorted(GOOD))
def test_a_file_that_starts_as_its_type_passes(tmp_path, name):
    (tmp_path / name).write_bytes(GOOD[name] + b"\n" * 64)
    assert H.check_file(tmp_path / name) == "." + name.split(".")[1]


def test_a_binary_stl_passes_by_its_face_count(tmp_path):
    path = tmp_path / "b.stl"
    path.write_bytes(b"\x00" * 80 + (1).to_bytes(4, "little") + b"\x00" * 50)
    H.check_file(path)


def test_only_the_first_bytes_are_read(tmp_path, monkeypatch):
    path = tmp_path / "big.npy"
    np.save(path, np.zeros((1000, 1000)))
    asked = []

    class Recording(io.BytesIO):
        def read(self, n=-1):
            asked.append(n)
            return super().read(n)
    monkeypatch.setattr(H, "open", lambda *a, **kw: Recording(path.read_bytes()), raising=False)
    H.check_file(path)
    assert asked and all(0 <= n <= 512 for n in asked)


def test_a_file_that_cannot_be_read_is_refused_as_unreadable(tmp_path, monkeypatch):
    path = tmp_path / "locked.png"
    path.write_bytes(GOOD["a.png"])

    def denied(*args, **kw):
        raise PermissionError(13, "Permission denied")
    monkeypatch.setattr(H, "open", denied, raising=False)
    with pytest.raises(InvalidHeightField) as err:
        H.check_file(path)
    assert err.value.code == "heightfield.unreadable" and "Permission denied" in str(err.value)

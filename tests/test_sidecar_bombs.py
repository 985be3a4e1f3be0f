"""A sidecar is a few `key: value` lines: YAML anchors and aliases (a few hundred bytes that
stand for gigabytes), deep nesting and huge numbers are refused with a coded sidecar error,
as it is parsed, and no message ever quotes more than a few dozen characters of a value."""

import resource
import time

import pytest

from daemon_helpers import in_process_daemon, tick_until, write_dome
from hostd import jobs as J
from pipeline.errors import InvalidSidecar
from pipeline.input.sidecar import MAX_COPIES, brief, load_sidecar


def alias_bomb(levels):
    """``smooth_mm:`` over ``levels`` lists of nine aliases of the level below: 9**levels
    values (eight levels: 358 bytes, 43 million values)."""
    lines = ["smooth_mm:", "  - &z [1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    below = "z"
    for level in range(levels):
        name = "a%d" % level
        lines.append("  - &%s [%s]" % (name, ", ".join(["*" + below] * 9)))
        below = name
    return "\n".join(lines) + "\n"


def _refused(tmp_path, text):
    path = tmp_path / "t.yaml"
    path.write_text(text)
    with pytest.raises(InvalidSidecar) as err:
        load_sidecar(path)
    assert len(str(err.value)) < 400, str(err.value)[:400]
    return err.value


@pytest.mark.parametrize("levels", [4, 8])
def test_aliases_are_refused_before_any_value_is_built(tmp_path, levels):
    t0, rss0 = time.process_time(), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    err = _refused(tmp_path, alias_bomb(levels))
    assert err.code == "sidecar.alias" and err.where == "line 2" and err.fix
    assert time.process_time() - t0 < 5
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0 < 50_000   # kB


def test_an_anchor_alone_is_refused_too(tmp_path):
    assert _refused(tmp_path, "size_mm: &s 150\n").code == "sidecar.alias"


@pytest.mark.parametrize("text, code", [
    ("smooth_mm: " + "[" * 5000 + "]" * 5000 + "\n", "sidecar.nested"),
    ("smooth_mm: " + "{a: " * 3000 + "1" + "}" * 3000 + "\n", "sidecar.nested"),
    ("copies: " + "9" * 5000 + "\n", "sidecar.value"),
    ("size_mm: " + "9" * 200 + "\n", "sidecar.value"),
    ("copies: 100000\n", "sidecar.value"),
    ("priority: 99999999999999999999999\n", "sidecar.value"),
    ("smooth_mm: [" + ", ".join(["1.5"] * 5000) + "]\n", "sidecar.type"),
])
def test_deep_huge_and_excessive_values_are_clear_sidecar_errors(tmp_path, text, code):
    err = _refused(tmp_path, text)
    assert err.code == code and err.fix


def test_copies_up_to_the_bound_are_taken(tmp_path):
    path = tmp_path / "t.yaml"
    path.write_text("copies: %d\npriority: -5\n" % MAX_COPIES)
    side = load_sidecar(path)
    assert (side.copies, side.priority) == (MAX_COPIES, -5)
    path.write_text("copies: %d\n" % (MAX_COPIES + 1))
    with pytest.raises(InvalidSidecar) as err:
        load_sidecar(path)
    assert "from 1 to %d" % MAX_COPIES in err.value.fix


def test_brief_never_formats_a_value_whole():
    big = [[list(range(100))] * 100] * 100
    assert brief(big) == "a list of 100 items"
    assert brief({"a": big}) == "a mapping of 1 keys"
    assert len(brief("x" * 10000)) == 40 and brief(1.5) == "1.5"
    assert brief(10 ** 100) == "an integer of 101 digits"


@pytest.mark.parametrize("text, code", [
    (alias_bomb(5), "sidecar.alias"),
    ("smooth_mm: " + "[" * 5000 + "]" * 5000 + "\n", "sidecar.nested"),
    ("copies: " + "9" * 5000 + "\n", "sidecar.value"),
])
def test_the_daemon_fails_the_job_with_the_sidecar_error_and_a_short_reason(tmp_path, text,
                                                                            code):
    d = in_process_daemon(tmp_path, 0)
    try:
        drop = d.config.drop_dir
        write_dome(drop / "t.npy")
        (drop / "t.yaml").write_text(text)
        tick_until(d, lambda: [j["state"] for j in d.store.list()] == [J.FAILED])
        job = d.store.list()[0]
        assert job["error_code"] == code, job["error"][:500]
        assert len(job["error"]) < 1000
        error_txt = d.config.failed_dir / "t.error.txt"
        assert error_txt.stat().st_size < 2000
        assert (d.config.failed_dir / "t.yaml").read_text() == text    # nothing is lost
    finally:
        d.shutdown()


def test_a_reason_of_any_length_is_bounded_in_the_record_and_the_error_file(tmp_path):
    from hostd.errors import MAX_REASON_CHARS
    d = in_process_daemon(tmp_path, 0)
    try:
        write_dome(d.config.drop_dir / "t.npy")
        tick_until(d, lambda: len(d.store.list()) == 1)
        d.endings.fail(d.store.list()[0], "x" * 10 ** 6, "test.long")
        job = d.store.list()[0]
        assert len(job["error"]) < MAX_REASON_CHARS + 100
        assert "more characters not shown" in job["error"]
        assert (d.config.failed_dir / "t.error.txt").stat().st_size < MAX_REASON_CHARS + 2000
    finally:
        d.shutdown()

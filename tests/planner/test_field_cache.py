"""The on-disk cache of the finger search's lookahead fields: a file is used only when it was built for the
same inputs and code and is intact; a stale, corrupt or tampered file is reported and rebuilt."""
import logging

import numpy as np
import pytest

from planner.optimize import field_cache

pytestmark = pytest.mark.fast


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTBLOCK_CACHE", str(tmp_path))
    return tmp_path


def counting_build(builds):
    def build():
        builds.append(1)
        return {"values": np.arange(6.0).reshape(2, 3), "layout": np.ones(3)}
    return build


def only_file(cache):
    files = list(cache.glob("fields-*.npz"))
    assert len(files) == 1, files
    return files[0]


def test_built_once_then_loaded(cache):
    builds, digest = [], field_cache.key_digest((np.zeros(3), 1.5, (1, 2)))
    first = field_cache.load_or_build("fields", digest, counting_build(builds))
    second = field_cache.load_or_build("fields", digest, counting_build(builds))
    assert len(builds) == 1
    assert np.array_equal(first["values"], second["values"]) and set(second) == {"values", "layout"}


def test_key_covers_inputs_code_and_libraries():
    base = field_cache.key_digest((np.zeros(3), 1.5))
    assert field_cache.key_digest((np.zeros(3), 1.5)) == base
    assert field_cache.key_digest((np.zeros(3) + 1e-12, 1.5)) != base  # table contents / geometry
    assert field_cache.key_digest((np.zeros(3, np.float32), 1.5)) != base
    assert field_cache.key_digest((np.zeros(3), 1.5), modules=("planner.optimize.lookahead",)) != base  # code


@pytest.mark.parametrize("damage", ["truncated", "garbage", "other inputs", "tampered array"])
def test_stale_or_corrupt_file_is_reported_and_rebuilt(cache, caplog, damage):
    builds, digest = [], field_cache.key_digest(("inputs",))
    field_cache.load_or_build("fields", digest, counting_build(builds))
    path = only_file(cache)
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[:200])
    elif damage == "garbage":
        path.write_bytes(b"not a zip file at all")
    elif damage == "other inputs":  # a file built for another key, under this key's name
        other = field_cache.key_digest(("other inputs",))
        field_cache.load_or_build("other", other, counting_build(builds))
        next(cache.glob("other-*.npz")).replace(path)
        builds.pop()
    else:
        with np.load(path) as stored:
            arrays = {key: stored[key] for key in stored.files}
        arrays["values"][0, 0] = 99.0
        np.savez(path, **arrays)
    with caplog.at_level(logging.WARNING, logger=field_cache.__name__):
        arrays = field_cache.load_or_build("fields", digest, counting_build(builds))
    assert len(builds) == 2, "the damaged file was used"
    assert arrays["values"][0, 0] == 0.0
    assert str(path) in caplog.text and "rebuilding" in caplog.text
    field_cache.load_or_build("fields", digest, counting_build(builds))
    assert len(builds) == 2, "the rebuilt file replaced the damaged one"


def test_unwritable_cache_still_returns_the_arrays(tmp_path, monkeypatch, caplog):
    blocked = tmp_path / "file"
    blocked.write_text("a file where the directory should be")
    monkeypatch.setenv("SOFTBLOCK_CACHE", str(blocked / "cache"))
    builds = []
    with caplog.at_level(logging.WARNING, logger=field_cache.__name__):
        arrays = field_cache.load_or_build("fields", field_cache.key_digest(("x",)), counting_build(builds))
    assert len(builds) == 1 and arrays["values"].shape == (2, 3)
    assert "cannot store" in caplog.text

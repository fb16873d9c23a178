"""The on-disk array cache: built once, read after, rebuilt when damaged, harmless when it cannot be written."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruction.cache import cache_dir, cached_arrays, cached_decoded
from reconstruction.core import energy


def test_arrays_are_built_once_read_after_and_a_damaged_file_is_rebuilt(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    calls = []

    def build():
        calls.append(1)
        return np.arange(3.0), np.eye(2)

    a = cached_arrays("t", "key 1", build)
    b = cached_arrays("t", "key 1", build)
    assert len(calls) == 1 and all(np.array_equal(x, y) for x, y in zip(a, b, strict=True)) and len(b) == 2
    cached_arrays("t", "key 2", build)  # another key: its own file
    assert len(calls) == 2 and len(list(cache_dir().glob("t-*.npz"))) == 2
    for p in cache_dir().glob("t-*.npz"):
        p.write_bytes(b"not an npz")
    c = cached_arrays("t", "key 1", build)
    assert len(calls) == 3 and np.array_equal(c[1], np.eye(2))
    assert len(cached_arrays("t", "key 1", build)) == 2 and len(calls) == 3  # the rebuilt file is read again
    for p in cache_dir().glob("t-*.npz"):  # cut short (a full disk, a killed writer elsewhere): a broken zip
        p.write_bytes(p.read_bytes()[:40])
    assert np.array_equal(cached_arrays("t", "key 1", build)[0], np.arange(3.0)) and len(calls) == 4


def test_decoded_arrays_are_what_later_reads_give_and_a_refused_file_is_built_again(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    calls = []

    def build():
        calls.append(1)
        return (np.arange(4, dtype=np.int16),)

    def decode(arrays):
        if arrays[0].dtype != np.int16:
            raise ValueError("another coding")
        return arrays[0].astype(np.float64) / 2

    first = cached_decoded("d", "k", build, decode)  # built, saved, decoded like a later read
    again = cached_decoded("d", "k", build, decode)
    assert len(calls) == 1 and np.array_equal(first, again) and np.array_equal(again, [0, 0.5, 1, 1.5])
    (path,) = cache_dir().glob("d-*.npz")
    np.savez(path, a0=np.zeros(3))  # a file of another coding: refused by decode, built again
    assert np.array_equal(cached_decoded("d", "k", build, decode), first) and len(calls) == 2


def test_a_cache_that_cannot_be_written_costs_only_the_build(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))  # a file where the folder should be
    out = cached_arrays("t", "k", lambda: (np.ones(4),))
    assert np.array_equal(out[0], np.ones(4))


@pytest.mark.parametrize("distribution", ["ggx", "beckmann"])
def test_the_albedo_tables_come_from_the_cache_with_the_values_of_a_fresh_build(tmp_path, monkeypatch,
                                                                              distribution):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    energy._microfacet_tables.cache_clear()
    try:
        first = energy._microfacet_tables(distribution)
        assert len(list(cache_dir().glob(f"albedo-{distribution}-*.npz"))) == 1
        energy._microfacet_tables.cache_clear()
        monkeypatch.setattr(energy, "_build_microfacet", lambda d: pytest.fail("built again"))
        again = energy._microfacet_tables(distribution)
    finally:
        energy._microfacet_tables.cache_clear()
    monkeypatch.undo()
    built = energy._build_microfacet(distribution)
    for x, y, z in zip(first, again, built, strict=True):
        np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(x, z)

"""The prepared-observation cache of ``jaxnav ppp`` (jaxnav.apps.prep_cache), data-free."""

from __future__ import annotations

from jaxnav.apps import prep_cache


def test_key_roles_damage_and_no_leftovers(tmp_path, monkeypatch):
    monkeypatch.setenv("JAXNAV_CACHE_DIR", str(tmp_path / "cache"))
    a, b = tmp_path / "a.sp3", tmp_path / "b.clk"
    a.write_text("orbits")
    b.write_text("clocks")
    # the same files in other roles are another preparation
    k1 = prep_cache.key([("--sp3", a), ("--clk", b)], {})
    assert k1 != prep_cache.key([("--sp3", a), ("--sp3", b)], {})
    assert k1 != prep_cache.key([("--sp3", a), ("--clk", b)], {"freq": "dual"})
    b.write_text("clocks, edited")  # an edited file is never served stale
    assert k1 != prep_cache.key([("--sp3", a), ("--clk", b)], {})

    calls = []

    def build():
        calls.append(1)
        return {"n": len(calls)}

    files = [("--obs", a)]
    assert prep_cache.cached(files, {}, build)[:2] == ({"n": 1}, False)
    assert prep_cache.cached(files, {}, build)[:2] == ({"n": 1}, True)
    entry = next(prep_cache.cache_dir().glob("*.pkl"))
    entry.write_bytes(b"\x80\x05 damaged")  # a damaged entry is rebuilt, never an error
    assert prep_cache.cached(files, {}, build)[:2] == ({"n": 2}, False)
    assert prep_cache.cached(files, {}, build, read=False)[:2] == ({"n": 3}, False)  # renewed
    assert prep_cache.cached(files, {}, build)[:2] == ({"n": 3}, True)
    assert not list(prep_cache.cache_dir().glob("*.tmp"))

"""The cache checks a module before importing it and repairs itself (issue 11, class 3):
truncated, garbage or missing modules are rebuilt with a CacheWarning instead of killing
the interpreter (SIGBUS) or failing forever; builds killed with `kill -9` leave litter that
a later build removes; an unwritable cache falls back to a private temporary folder."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import textwrap
import time
import warnings

import pytest

import gagen
from gagen.building import builder, cache
from gagen.building.builder import (
    CacheWarning,
    cached_module_is_intact,
    clean_abandoned_builds,
    compiler_command,
    usable_cache_dir,
)

LOAD_IN_A_FRESH_PROCESS = textwrap.dedent("""
    import sys, warnings
    import numpy as np, gagen
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        dyn = gagen.load("chain:1", cache_dir=sys.argv[1], verbose=False)
    print(dyn.mass_matrix(np.array([0.3])).item())
    print("|".join(type(w.message).__name__ + ": " + str(w.message) for w in caught))
""")


def load_in_a_fresh_process(cache):
    return subprocess.run([sys.executable, "-c", LOAD_IN_A_FRESH_PROCESS, str(cache)],
                          capture_output=True, text=True, timeout=600, check=False)


@pytest.fixture(scope="module")
def built_entry(tmp_path_factory):
    """A cache holding chain:1, and the path of its module."""
    cache = tmp_path_factory.mktemp("cache")
    path, _report = builder.build(gagen.resolve_model("chain:1"), cache_dir=cache)
    return cache, path


def corrupt(path, how: str) -> None:
    data = path.read_bytes()
    if how == "truncated":
        path.write_bytes(data[: len(data) // 3])
    elif how == "garbage":
        path.write_bytes(os.urandom(len(data)))
    elif how == "missing":
        path.unlink()
    elif how == "one flipped byte":
        path.write_bytes(data[:1000] + bytes([data[1000] ^ 1]) + data[1001:])


@pytest.mark.parametrize("how", ["truncated", "garbage", "missing", "one flipped byte"])
def test_every_kind_of_damage_fails_the_check(tmp_path, built_entry, how):
    _cache, path = built_entry
    entry = tmp_path / path.parent.name
    subprocess.run(["cp", "-r", str(path.parent), str(entry)], check=True)
    assert cached_module_is_intact(entry, path.name)
    corrupt(entry / path.name, how)
    assert not cached_module_is_intact(entry, path.name)
    (entry / "module.sha256").unlink(missing_ok=True)
    assert not cached_module_is_intact(entry, path.name)


def test_a_truncated_module_is_rebuilt_with_a_warning_not_a_crash(built_entry):
    """In a fresh process, as a user meets it: importing the truncated library would be
    SIGBUS (exit -7); instead the entry is rebuilt, and the next load is silent."""
    cache, path = built_entry
    expected = load_in_a_fresh_process(cache)
    assert expected.returncode == 0, expected.stderr
    corrupt(path, "truncated")
    repaired = load_in_a_fresh_process(cache)
    assert repaired.returncode == 0, repaired.stderr
    value, caught = repaired.stdout.splitlines()
    assert value == expected.stdout.splitlines()[0]
    assert "CacheWarning" in caught and "corrupt or incomplete" in caught, repaired
    assert cached_module_is_intact(path.parent, path.name)
    again = load_in_a_fresh_process(cache)
    assert again.stdout.splitlines()[1:] in ([], [""]), again


def litter(cache, name: str, owner: str | None, age: float = 0.0):
    folder = cache / name
    folder.mkdir()
    (folder / "rhs.c").write_text("half written")
    if owner is not None:
        (folder / "building.pid").write_text(owner)
    if age:
        os.utime(folder, (time.time() - age, time.time() - age))
    return folder


def test_builds_killed_midway_are_cleaned_up_later(tmp_path):
    host = socket.gethostname()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    gone = [litter(tmp_path, ".gagen_a_1-x1", f"{host} {dead.pid}"),
            litter(tmp_path, ".gagen_a_1-x2", None, age=2 * 86400)]
    kept = [litter(tmp_path, ".gagen_a_1-x3", f"{host} {os.getpid()}"),  # still running
            litter(tmp_path, ".gagen_a_1-x4", f"another-host {dead.pid}"),
            litter(tmp_path, ".gagen_a_1-x5", None),  # young: maybe starting right now
            litter(tmp_path, "unrelated", f"{host} {dead.pid}")]
    clean_abandoned_builds(tmp_path)
    assert not any(f.exists() for f in gone)
    assert all(f.exists() for f in kept)


@pytest.mark.parametrize("kind", ["a file", "read-only", "under a file"])
def test_an_unwritable_cache_falls_back_to_a_private_folder(tmp_path, monkeypatch, kind):
    if kind == "read-only" and os.geteuid() == 0:
        monkeypatch.setattr(cache.tempfile, "mkdtemp", _refuse_in(tmp_path / "ro"))
    target = {"a file": tmp_path / "cachefile", "read-only": tmp_path / "ro",
              "under a file": tmp_path / "cachefile" / "sub"}[kind]
    (tmp_path / "cachefile").write_text("not a folder")
    (tmp_path / "ro").mkdir()
    (tmp_path / "ro").chmod(0o500)
    monkeypatch.setattr(cache, "_fallback_cache", None)
    with pytest.warns(CacheWarning, match="cannot write the cache folder"):
        fallback = usable_cache_dir(target)
    assert fallback != target and fallback.is_dir() and os.access(fallback, os.W_OK)
    assert str(target) in _last_warning_text(target)


def _refuse_in(folder):
    real = cache.tempfile.mkdtemp

    def mkdtemp(*args, dir=None, **kwargs):
        if dir is not None and str(dir).startswith(str(folder)):
            raise PermissionError(13, "Permission denied")
        return real(*args, dir=dir, **kwargs)
    return mkdtemp


def _last_warning_text(target) -> str:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        usable_cache_dir(target)
    return str(caught[-1].message)


@pytest.mark.parametrize("cc", ["", "   ", "''"])
def test_a_blank_cc_means_the_default_compiler(monkeypatch, cc):
    monkeypatch.setenv("CC", cc)
    command = compiler_command()
    assert command and command[0].strip()


def test_cc_with_arguments_is_split_like_a_shell(monkeypatch):
    monkeypatch.setenv("CC", "ccache 'gcc' -m64")
    assert compiler_command() == ["ccache", "gcc", "-m64"]


def test_a_missing_compiler_is_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setenv("CC", "no-such-compiler-gagen")
    with pytest.raises(gagen.BuildError, match="no C compiler found"):
        builder.check_compiler()


# ------------------------------------------------------------------ where the cache is


def test_gagen_cache_dir_overrides_the_platform_folder(monkeypatch, tmp_path):
    monkeypatch.setenv("GAGEN_CACHE_DIR", str(tmp_path / "mine"))
    assert builder.default_cache_dir() == tmp_path / "mine"


@pytest.mark.skipif(sys.platform != "linux", reason="XDG_CACHE_HOME is the Linux convention")
@pytest.mark.parametrize("xdg", ["", "  ", "relative/cache", "."])
def test_the_cache_never_lands_relative_to_the_working_directory(monkeypatch, tmp_path, xdg):
    monkeypatch.delenv("GAGEN_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", xdg)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.chdir(tmp_path)
    assert builder.default_cache_dir() == tmp_path / "home" / ".cache" / "gagen"


@pytest.mark.skipif(sys.platform != "linux", reason="XDG_CACHE_HOME is the Linux convention")
def test_the_platform_folder_follows_xdg_cache_home(monkeypatch, tmp_path):
    monkeypatch.delenv("GAGEN_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert builder.default_cache_dir() == tmp_path / "xdg" / "gagen"

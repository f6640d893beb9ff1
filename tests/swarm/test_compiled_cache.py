"""Where Numba's cache goes: the user's cache folder for an installed copy, else beside the sources."""

from __future__ import annotations

from pathlib import Path

import pytest
from numba.core import config

from swarm.compiled_cache import use_user_cache_when_installed

INSTALLED = Path("/venv/lib/python3.11/site-packages/swarm/compiled_cache.py")


@pytest.fixture
def numba_env(monkeypatch, tmp_path):
    """No NUMBA_CACHE_DIR, XDG_CACHE_HOME in tmp_path; Numba's config read again afterwards."""
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    yield tmp_path
    monkeypatch.undo()
    config.reload_config()


def test_an_installed_copy_compiles_into_the_users_cache(numba_env) -> None:
    import os

    want = str(numba_env / "swarm-mapping" / "numba")
    assert use_user_cache_when_installed(INSTALLED) == want
    assert os.environ["NUMBA_CACHE_DIR"] == want
    assert config.CACHE_DIR == want  # Numba was imported before: it read the setting again


def test_a_checkout_keeps_numbas_default_and_a_users_setting_is_kept(numba_env, monkeypatch) -> None:
    import os

    assert use_user_cache_when_installed(Path("/home/me/swarm/swarm/compiled_cache.py")) is None
    assert "NUMBA_CACHE_DIR" not in os.environ
    monkeypatch.setenv("NUMBA_CACHE_DIR", "/mine")
    assert use_user_cache_when_installed(INSTALLED) is None
    assert os.environ["NUMBA_CACHE_DIR"] == "/mine"

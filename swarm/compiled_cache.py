"""Where Numba keeps the compiled kernels: beside the sources in a checkout, in the user's cache
for an installed copy.

Numba writes its cache (``cache=True``) into ``__pycache__`` beside each module. In an installed
copy that is ``site-packages/swarm/...``: files pip does not know of, which ``pip uninstall`` (and
so a later ``pip install -e .``) leaves behind, and whose folders then hide the package an
editable install provides (``swarm --help``: ``ImportError: cannot import name '__version__'
from 'swarm'``). So an installed copy sets ``NUMBA_CACHE_DIR`` to
``$XDG_CACHE_HOME/swarm-mapping/numba`` (``~/.cache/swarm-mapping/numba``) unless the user has
set it. Numba checks each cached kernel against its source file's time stamp and size, so
another installed version never loads a stale kernel.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path


def use_user_cache_when_installed(package_dir: Path | None = None) -> str | None:
    """Set ``NUMBA_CACHE_DIR`` for an installed copy (``package_dir`` below a ``site-packages``
    or ``dist-packages`` folder; default: this package's); return the folder set, else None."""
    if "NUMBA_CACHE_DIR" in os.environ:
        return None
    here = (package_dir or Path(__file__)).resolve()
    if not {"site-packages", "dist-packages"} & set(here.parts):
        return None
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    folder = str(base / "swarm-mapping" / "numba")
    os.environ["NUMBA_CACHE_DIR"] = folder
    if "numba" in sys.modules:  # imported before us: have it read the setting again
        from numba.core import config

        config.reload_config()
    return folder

"""Numba's own cache statistics of compiled functions, as a fresh interpreter sees them."""

import json
import os
import subprocess
import sys

from tests.support.paths import ROOT


def second_run_cache_statistics(setup: str, functions: str) -> dict[str, list[int]]:
    """Run ``setup`` in two fresh interpreters; the second's {function name: [cache hits, misses]}.

    ``functions`` is a Python expression (in ``setup``'s namespace) for a tuple of compiled
    functions. The first run may compile and write the cache; the second must load it.
    """
    script = (
        f"import json\n{setup}\n"
        f"print(json.dumps({{f.__name__: [sum(f.stats.cache_hits.values()), "
        f"sum(f.stats.cache_misses.values())] for f in {functions}}}))\n"
    )
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    runs = []
    for _ in range(2):
        out = subprocess.run(
            [sys.executable, "-c", script], cwd=ROOT, env=env, capture_output=True, text=True, timeout=600
        )
        assert out.returncode == 0, out.stderr
        runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
    return runs[1]

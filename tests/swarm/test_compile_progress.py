"""A role that compiles Numba kernels on a first run says so, kernel by kernel (n of m), and says
nothing when they all load from the cache; each warm-up names the kernels it compiles."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from tests.support.paths import ROOT

KERNELS = """
import numba

@numba.njit(cache=True)
def helper(x):
    return 2.0 * x

@numba.njit(cache=True)
def double_all(a):
    out = a.copy()
    for i in range(len(a)):
        out[i] = helper(a[i])
    return out

@numba.njit(cache=True)
def total(a):
    return a.sum()
"""

WARM_UP = """
import sys
import numpy as np
sys.path.insert(0, sys.argv[1])
import kernels
from swarm.compile_progress import compile_progress

with compile_progress([kernels.double_all, kernels.total], print, "r9"):
    kernels.total(kernels.double_all(np.ones(3)))
"""


def _run(code: str, *args: str, env: dict | None = None) -> str:
    proc = subprocess.run(
        [sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=300,
        env={**os.environ, **(env or {})}, cwd=ROOT,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc.stdout


@pytest.mark.slow
def test_a_first_run_says_which_kernel_compiles_and_a_second_says_nothing(tmp_path) -> None:
    (tmp_path / "kernels.py").write_text(KERNELS)
    cache = {"NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    first = _run(WARM_UP, str(tmp_path), env=cache).splitlines()
    assert first[0].startswith("r9: compiling kernels (first run): 2 are not in Numba's cache"), first
    assert str(tmp_path / "cache") in first[0]
    # the kernel double_all calls (helper) compiles inside it: two kernels, not three
    assert first[1:3] == [
        "r9: compiling kernel 1 of 2: kernels.double_all",
        "r9: compiling kernel 2 of 2: kernels.total",
    ]
    assert first[3].startswith("r9: compiled 2 kernel(s) in ") and len(first) == 4, first
    assert _run(WARM_UP, str(tmp_path), env=cache) == ""  # loaded from the cache: not a word


TWO_SIGNATURES = """
import sys
import numpy as np
sys.path.insert(0, sys.argv[1])
import kernels
from swarm.compile_progress import compile_progress

with compile_progress([kernels.total], print):
    kernels.total(np.ones(3))
    kernels.total(np.ones(3, np.int32))  # the same kernel compiled again, for int32
"""


@pytest.mark.slow
def test_a_kernel_compiled_for_two_argument_types_counts_once(tmp_path) -> None:
    (tmp_path / "kernels.py").write_text(KERNELS)
    lines = _run(TWO_SIGNATURES, str(tmp_path), env={"NUMBA_CACHE_DIR": str(tmp_path / "cache")}).splitlines()
    assert lines[0].startswith("compiling kernels (first run): 1 is not in Numba's cache"), lines
    assert lines[1:3] == [
        "compiling kernel 1 of 1: kernels.total",
        "compiling kernel 1 of 1 again, for other argument types: kernels.total",
    ], lines
    assert lines[3].startswith("compiled 1 kernel(s) in ") and len(lines) == 4, lines


WHAT_COMPILES = """
import json, sys
from numba.core.registry import CPUDispatcher

def compiled():
    out = set()
    for name, module in list(sys.modules.items()):
        if name.split(".")[0] in ("swarm", "robot_agent", "sim2d", "coordinator", "map_server"):
            for value in vars(module).values():
                if isinstance(value, CPUDispatcher) and value.signatures:
                    out.add(value.py_func.__module__ + "." + value.py_func.__qualname__)
    return out

def names(kernels):
    return sorted(k.py_func.__module__ + "." + k.py_func.__qualname__ for k in kernels)

if sys.argv[1] == "agent":
    from robot_agent.kernels import agent_kernels, load_kernels
    load_kernels()
    declared = names(agent_kernels())
else:
    import math
    import numpy as np
    from sim2d.render import Renderer, camera_pose, warm_up_kernels
    from swarm.config import load_mission
    mission = load_mission("configs/office.yaml")
    rig = mission.rig_for("r1")
    renderer = Renderer(mission.load_floor_plan(), rig.camera(), seed=0)
    pose = camera_pose(1.0, 5.0, 0.0, rig.camera_height, math.radians(rig.pitch_deg))
    renderer.stereo_pair(pose, rig.noise_std, np.random.default_rng(0))
    renderer.depth_image(pose, 0.01, 5.0, np.random.default_rng(0))
    declared = names(warm_up_kernels())
print(json.dumps({"declared": declared, "compiled": sorted(compiled())}))
"""


@pytest.mark.slow
def test_the_agents_warm_up_names_every_kernel_it_compiles_and_no_other() -> None:
    out = json.loads(_run(WHAT_COMPILES, "agent"))
    assert out["declared"] == out["compiled"], out


@pytest.mark.slow
def test_the_worlds_warm_up_names_the_kernels_a_frame_compiles() -> None:
    out = json.loads(_run(WHAT_COMPILES, "world"))
    assert out["declared"] == out["compiled"], out

"""``swarm bench agent-memory``: where one robot agent's memory goes, step by step.

Builds one :class:`robot_agent.agent.Agent` of a mission (default: the campus floor) on a
loopback Zenoh router session of its own (no map server: the agent starts from an empty map),
then feeds it frames rendered by sim2d and drives its robot in a pymunk world, as ``swarm sim``
does, one frame per period. After each step it prints the process's memory from
``/proc/self/status`` (VmRSS, VmHWM: the peak RSS so far) and ``/proc/self/smaps_rollup`` (PSS,
split into private and shared pages: the shared ones are mostly the libraries' code), the
time, the explorer's state, and (``--arrays``) the largest numpy arrays the agent holds, found
by walking its objects' attributes. ``--trace`` also runs tracemalloc (numpy reports its buffers
to it): the peak of traced memory within each step and the top allocation sites; it slows the
agent down several times.

Linux only (``/proc``). Figures are MB (10^6 bytes)."""

from __future__ import annotations

import gc
import hashlib
import math
import os
import time
import tracemalloc
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from swarm.bench.proc_memory import memory_kb

KB = 1024
MB = 1e6
PAGE = os.sysconf("SC_PAGE_SIZE")


def memory() -> dict[str, float]:
    """This process's memory (MB): ``rss``, ``hwm`` (peak RSS), ``pss``, ``private``, ``shared``,
    ``pss_anon`` (the heap's and arrays' share of PSS). Raises OSError off Linux."""
    mb = {name: kb * KB / MB for name, kb in memory_kb().items()}  # swarm.bench.proc_memory
    out = {"rss": mb.get("VmRSS", math.nan), "hwm": mb.get("VmHWM", math.nan)}
    out["pss"] = mb.get("Pss", math.nan)
    out["private"] = mb.get("Private_Clean", 0.0) + mb.get("Private_Dirty", 0.0)
    out["shared"] = mb.get("Shared_Clean", 0.0) + mb.get("Shared_Dirty", 0.0)
    out["pss_anon"] = mb.get("Pss_Anon", math.nan)
    return out


def reset_peak() -> None:
    """Reset VmHWM to the current RSS (``/proc/self/clear_refs``, 5), so that the next step's peak
    is its own; ignored where the kernel does not allow it."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass


def resident_bytes(array: np.ndarray) -> int:
    """Bytes of ``array``'s buffer in RAM now (its pages present, from /proc/self/pagemap): an
    array from np.zeros holds only the pages written so far. -1 when pagemap cannot be read."""
    page = PAGE
    start = array.__array_interface__["data"][0]
    first, last = start // page, (start + max(array.nbytes, 1) - 1) // page
    try:
        with open("/proc/self/pagemap", "rb") as f:
            f.seek(first * 8)
            entries = np.frombuffer(f.read((last - first + 1) * 8), dtype=np.uint64)
    except OSError:
        return -1
    present = int(np.count_nonzero(entries >> np.uint64(63)))
    return min(present * page, array.nbytes)


def arrays_held(roots: dict[str, object], min_bytes: int = 1_000_000) -> list[tuple[str, int, int, str]]:
    """The numpy arrays of at least ``min_bytes`` reachable from ``roots`` (name: object) through
    attributes, dict values, list/tuple items: (path, bytes of its own buffer, bytes of it
    resident, dtype and shape), largest first; a view is counted once, at its base's path, and
    each buffer only once."""
    seen_objects: set[int] = set()
    seen_buffers: set[int] = set()
    found = []
    walks = (_walk(root, name, seen_objects) for name, root in roots.items())
    for path, obj in (item for walk in walks for item in walk):
        if not isinstance(obj, np.ndarray):
            continue
        base = obj
        while isinstance(base.base, np.ndarray):
            base = base.base
        if id(base) in seen_buffers or base.nbytes < min_bytes:
            continue
        seen_buffers.add(id(base))
        found.append((path, base.nbytes, resident_bytes(base), f"{base.dtype} {base.shape}"))
    return sorted(found, key=lambda f: -f[1])


def _walk(obj: object, path: str, seen: set[int], depth: int = 0) -> Iterator[tuple[str, object]]:
    if id(obj) in seen or depth > 12:
        return
    seen.add(id(obj))
    yield path, obj
    if isinstance(obj, np.ndarray) or isinstance(obj, (str, bytes, int, float, type)) or callable(obj):
        if not hasattr(obj, "__self__"):  # a bound method: walk its object
            return
        yield from _walk(obj.__self__, f"{path}.__self__", seen, depth + 1)
        return
    if isinstance(obj, dict):
        for k, v in list(obj.items())[:200]:
            yield from _walk(v, f"{path}[{k!r}]", seen, depth + 1)
        return
    if isinstance(obj, (list, tuple, set, frozenset)):
        for i, v in enumerate(list(obj)[:200]):
            yield from _walk(v, f"{path}[{i}]", seen, depth + 1)
        return
    if type(obj).__module__.split(".")[0] not in ("robot_agent", "swarm", "sim2d", "collections", "_thread"):
        return
    attrs = getattr(obj, "__dict__", None)
    if attrs is None and hasattr(obj, "__slots__"):
        attrs = {s: getattr(obj, s) for s in obj.__slots__ if hasattr(obj, s)}
    for k, v in (attrs or {}).items():
        yield from _walk(v, f"{path}.{k}", seen, depth + 1)


def _site(frame: tracemalloc.Frame) -> str:
    """``package/module.py:line`` of a traceback frame."""
    return f"{'/'.join(Path(frame.filename).parts[-2:])}:{frame.lineno}"


class Steps:
    """Prints one line per step: its name, seconds, memory after it and the peak RSS within it."""

    def __init__(self, trace: bool, out: Callable[[str], None] = print) -> None:
        self.trace = trace
        self.out = out
        self.rows: list[dict] = []
        out(
            f"{'step':<34} {'s':>6} {'RSS':>7} {'peakRSS':>8} {'PSS':>7} {'private':>8} {'shared':>7}"
            + (f" {'traced':>7} {'peak traced':>11}" if trace else "")
            + "  (MB)"
        )

    def run(self, name: str, fn: Callable[[], object]) -> object:
        reset_peak()
        if self.trace:
            tracemalloc.reset_peak()
        t0 = time.perf_counter()
        result = fn()
        seconds = time.perf_counter() - t0
        gc.collect()
        mem = memory()
        row = {"step": name, "s": seconds, **mem}
        line = (
            f"{name:<34} {seconds:6.2f} {mem['rss']:7.1f} {mem['hwm']:8.1f} {mem['pss']:7.1f} "
            f"{mem['private']:8.1f} {mem['shared']:7.1f}"
        )
        if self.trace:
            now, peak = tracemalloc.get_traced_memory()
            row["traced"], row["peak_traced"] = now / MB, peak / MB
            line += f" {now / MB:7.1f} {peak / MB:11.1f}"
        self.rows.append(row)
        self.out(line)
        return result


def world_process(conn, config: Path, rid: str) -> None:
    """The simulator's side, in a process of its own (so that its memory is not the agent's):
    sends robot ``rid``'s encoded frame, then for each (v, omega, tilt) received drives the
    pymunk world one frame period and sends the next frame; None ends it."""
    from sim2d.render import Renderer, camera_pose
    from sim2d.world import World
    from swarm.config import load_mission
    from swarm.protocol.wire import Frame

    mission = load_mission(config)
    rig, body, sim = mission.rig_for(rid), mission.robot, mission.sim
    world = World(mission.load_floor_plan(), body.radius, body.max_speed, body.max_turn_rate)
    start = mission.start_of(rid)
    world.add_robot(rid, start.x, start.y, start.yaw)
    renderer = Renderer(mission.load_floor_plan(), rig.camera(), seed=sim.seed)
    rng = np.random.default_rng([sim.seed, mission.robot_ids.index(rid)])
    tilt, seq = 0.0, 0
    while True:
        seq += 1
        x, y, yaw = world.pose(rid)
        pose = camera_pose(x, y, yaw, rig.camera_height, math.radians(rig.pitch_deg) + tilt)
        frame = Frame(rid, seq, world.time, pose, renderer.camera, "raw8")
        if rig.mode == "range":
            frame.depth = renderer.depth_image(pose, rig.range_noise, rig.max_range, rng)
        else:
            frame.left, frame.right = renderer.stereo_pair(pose, rig.noise_std, rng)
        conn.send_bytes(frame.encode())
        command = conn.recv()
        if command is None:
            return
        v, omega, new_tilt = command
        world.command(rid, v, omega)
        tilt = tilt if new_tilt is None else new_tilt
        n = max(1, round(sim.frame_period_s / sim.dt))
        for _ in range(n):
            world.step(sim.frame_period_s / n)


def start_server(config: Path, store: Path, endpoint: str):
    """``swarm server`` of ``config`` on ``endpoint`` (a process of its own, its log discarded)."""
    import subprocess
    import sys

    command = [sys.executable, "-m", "swarm.cli", "server", "--config", str(config), "--store", str(store)]
    return subprocess.Popen(
        [*command, "--listen", endpoint], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )


def run(
    config: Path,
    robot: str | None,
    frames: int,
    arrays: bool,
    trace: bool,
    top: int = 12,
    server: bool = False,
) -> list[dict]:
    """Build one agent of ``config`` (``robot``: its id; default the first) and drive it ``frames``
    frames rendered by a world process; prints as it goes and returns the steps' rows (MB, s).
    ``server``: against a map server (``swarm server`` in a process of its own, a fresh store):
    the agent starts from its snapshot, shares its deltas, and resyncs from it at the end."""
    import multiprocessing
    import tempfile

    steps = Steps(trace)
    if trace:
        tracemalloc.start(8)
    steps.run("imports (before)", lambda: None)

    def imports():
        import robot_agent.agent  # noqa: F401

    steps.run("import robot_agent.agent", imports)
    from robot_agent.agent import Agent
    from swarm.config import load_mission
    from swarm.protocol import bus
    from swarm.protocol.wire import Snapshot

    mission = load_mission(config)
    rid = robot or mission.robot_ids[0]
    ours, theirs = multiprocessing.Pipe()
    world = multiprocessing.get_context("spawn").Process(target=world_process, args=(theirs, config, rid))
    world.start()
    endpoint = bus.tcp_endpoint(bus.free_port())
    store = tempfile.TemporaryDirectory(prefix="agent-memory-")
    serving = start_server(config, Path(store.name), endpoint) if server else None
    if serving is None:
        session = steps.run("zenoh router session", lambda: bus.open_session([endpoint]))
    else:
        session = steps.run("zenoh session to the map server", lambda: bus.open_session(connect=[endpoint]))
    agent = steps.run("Agent()", lambda: Agent(mission, rid, session, seed=0, coordination=False))
    if serving is not None:
        steps.run("catch_up (map/snapshot)", lambda: agent.catch_up(timeout=30.0))
        agent.sharing.start()
    commands = hashlib.sha256()
    try:
        for seq in range(1, frames + 1):
            payload = ours.recv_bytes()
            state = agent.explorer.state.value
            cmd = steps.run(f"frame {seq:3d} ({state})", lambda p=payload: agent.handle(p))
            if cmd is None:
                raise RuntimeError(f"the agent did not answer frame {seq}")
            commands.update(np.array([cmd.v, cmd.omega, cmd.tilt or 0.0]).tobytes())
            ours.send((cmd.v, cmd.omega, cmd.tilt))
        from swarm.map import heap

        # not what the agent does: how much of RSS is free heap pages the frames left behind
        steps.run("heap.trim (diagnostic)", heap.trim)
        cmap = agent.explorer.map
        # what a catch-up or a resync from the map server does: this map's own state as a snapshot
        snap = Snapshot(agent.explorer.grid, cmap.lam.copy(), cmap.eta.copy())
        steps.run("team.load_snapshot (of this map)", lambda: agent.team.load_snapshot(snap))
        del snap
        if serving is not None:
            steps.run("team.resync (map/snapshot)", lambda: agent.team.resync(force=True))
        maps = hashlib.sha256(cmap.lam.tobytes() + cmap.eta.tobytes()).hexdigest()[:16]
        print(
            f"\nresults: map sha256 {maps}, commands sha256 {commands.hexdigest()[:16]}, "
            f"entropy {agent.explorer.map_entropy:,.3f} bits"
        )
        if arrays:
            from swarm.map import fusion

            print(f"\nthe largest numpy arrays the agent holds (>= 1 MB; top {top}): size, resident")
            held = arrays_held({"agent": agent, "fusion._local": fusion._local.__dict__})
            for path, nbytes, resident, what in held[:top]:
                print(f"  {nbytes / MB:8.1f} {resident / MB:8.1f} MB  {what:<28} {path}")
            total, in_ram = sum(h[1] for h in held) / MB, sum(h[2] for h in held) / MB
            print(f"  {total:8.1f} {in_ram:8.1f} MB  in all ({len(held)} arrays)")
        if trace:
            snap = tracemalloc.take_snapshot()
            print(f"\ntracemalloc: the top {top} allocation sites alive now")
            for stat in snap.statistics("traceback")[:top]:
                where = " < ".join(_site(f) for f in reversed(stat.traceback[-4:]))
                print(f"  {stat.size / MB:8.1f} MB  {where}")
    finally:
        if world.is_alive():
            ours.send(None)
        world.join(timeout=30)
        agent.shutdown(ack_wait_s=0.0 if serving is None else 5.0)
        session.close()
        if serving is not None:
            serving.terminate()
            serving.wait(timeout=60)
        store.cleanup()
    return steps.rows

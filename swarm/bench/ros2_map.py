"""``swarm bench ros2-map``: what publishing the team map as ROS 2 topics costs, in time and bytes.

Two maps: the office of ``configs/office.yaml`` (16 m x 10 m x 2.2 m at 0.1 m: 352,000 voxels,
16,000 grid cells) and a large one, the office repeated ``tiles`` x ``tiles`` times (default 4:
64 m x 40 m, 5.6 million voxels, 256,000 cells, over ``incremental_above``: updates between whole
grids). Each holds what a finished mission would: the true coverage (``sim2d.ground_truth``) as
the belief mean with sigma 0.05 over the voxels below 1.2 m, the prior above.

The exploration is replayed through the ``swarm map ros2`` code (``ros2_map``): one merged delta
per 1 m x 1 m tile of columns, tiles in a boustrophedon sweep, ``rate`` deltas per simulated
second (default 20: four robots sharing five times a second). Every 50 ms of simulated time
the deltas due are applied and the messages due go out as the role sends them (default options:
grid at most 1 Hz, cloud at most every 2 s and 2 MB/s), on a Zenoh session that a second one
subscribes to. Printed per map: the start from a snapshot, the cost of applying a delta, per kind
of message its count, wall time (build, serialise, put; p50 and max) and bytes (mean, max), the
bytes a subscriber received per simulated second, and the share of simulated time the work took.
"""

from __future__ import annotations

import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from ros2_map.options import Ros2MapOptions
from ros2_map.outputs import MapOutputs
from ros2_map.replica import FollowedMap
from ros2_map.role import TYPES, UPDATES_QOS
from swarm.map.coverage_map import prior_information
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.protocol import bus
from swarm.protocol.wire import DeltaMessage, Snapshot
from swarm.ros2.graph import LATCHED_QOS
from swarm.ros2.map_messages import register_map_msgs
from swarm.ros2.node import Ros2Context

SEEN_BELOW_M = 1.2
SIGMA = 0.05
TICK_S = 0.05
TILE_M = 1.0


def finished_map(config: Path, tiles: int) -> tuple[Grid, SensorModel, np.ndarray, np.ndarray]:
    """(grid, sensor, lam, eta) of the module doc's finished map, the office ``tiles`` x ``tiles``."""
    from sim2d.ground_truth import coverage
    from swarm.config import load_mission

    mission = load_mission(config)
    grid = mission.workspace.grid()
    truth = coverage(mission.load_floor_plan(), grid)
    truth = np.tile(truth, (tiles, tiles, 1))
    grid = Grid(grid.origin, grid.voxel, truth.shape)
    sensor = mission.sensor.model()
    lam0, eta0 = prior_information(sensor)
    lam = np.full(grid.shape, lam0, np.float32)
    eta = np.full(grid.shape, eta0, np.float32)
    z = grid.lo[2] + (np.arange(grid.shape[2]) + 0.5) * grid.voxel
    seen = z < SEEN_BELOW_M
    lam[:, :, seen] = 1.0 / SIGMA**2
    eta[:, :, seen] = truth[:, :, seen] / SIGMA**2
    return grid, sensor, lam.reshape(-1), eta.reshape(-1)


def tile_deltas(grid: Grid, sensor: SensorModel, lam: np.ndarray, eta: np.ndarray) -> list[bytes]:
    """One merged payload per tile of columns holding what the map knows beyond the prior there."""
    lam0, eta0 = prior_information(sensor)
    n = max(1, round(TILE_M / grid.voxel))
    nx, ny, nz = grid.shape
    payloads = []
    for ti in range(0, nx, n):
        rows = range(0, ny, n) if (ti // n) % 2 == 0 else reversed(range(0, ny, n))
        for tj in rows:
            block = np.zeros(grid.shape, bool)
            block[ti : ti + n, tj : tj + n, :] = True
            idx = np.flatnonzero(block.reshape(-1) & (lam > lam0 * 1.001))
            if idx.size == 0:
                continue
            dlam = (lam[idx] - np.float32(lam0)).astype(np.float32)
            deta = (eta[idx] - np.float32(eta0)).astype(np.float32)
            seq = len(payloads) + 1
            payloads.append(DeltaMessage("r1", 1, seq, 0.0, grid, idx.astype(np.uint32), dlam, deta).encode())
    return payloads


def replay(name: str, config: Path, tiles: int, rate: float, options: Ros2MapOptions) -> dict:
    """Figures of one map (module doc)."""
    grid, sensor, lam, eta = finished_map(config, tiles)
    payloads = tile_deltas(grid, sensor, lam, eta)
    lam0, eta0 = prior_information(sensor)
    prior = Snapshot(grid, np.full(grid.size, lam0, np.float32), np.full(grid.size, eta0, np.float32))
    endpoint = bus.tcp_endpoint(bus.free_port())
    pub_session = bus.open_session(listen=[endpoint], timestamping=True)
    sub_session = bus.open_session(connect=[endpoint])
    received: dict[str, list[int]] = defaultdict(list)
    kinds = {"OccupancyGrid_": "full", "OccupancyGridUpdate_": "update", "PointCloud2_": "cloud"}

    def on_sample(sample) -> None:
        kind = next(k for t, k in kinds.items() if f"::{t}/" in str(sample.key_expr))
        received[kind].append(len(sample.payload))

    try:
        subscriber = sub_session.declare_subscriber(f"{options.domain_id}/**", on_sample)
        context = Ros2Context(pub_session, options.domain_id, options.distro)
        register_map_msgs(context.types)
        node = context.node(options.node_name)
        pubs = {
            "full": node.publisher(options.map_topic, TYPES["full"], LATCHED_QOS),
            "update": node.publisher(options.updates, TYPES["update"], UPDATES_QOS),
            "cloud": node.publisher(options.cloud_topic, TYPES["cloud"], LATCHED_QOS),
        }
        time.sleep(0.5)  # the subscriber reaches the publishers
        tiny = Snapshot(Grid((0, 0, 0), 1.0, (2, 2, 2)), prior.lam[:8], prior.eta[:8])
        FollowedMap(tiny, sensor)  # the entropy table and the compiled kernels, once
        started = time.perf_counter()
        fmap = FollowedMap(prior, sensor)
        outputs = MapOutputs(fmap, options, context.types)
        catch_up_s = time.perf_counter() - started
        apply_s: list[float] = []
        sent_s: dict[str, list[float]] = defaultdict(list)
        busy = 0.0
        now, next_delta = 0.0, 0
        duration = len(payloads) / rate
        while now <= duration + options.full_period_s or not outputs.idle():
            while next_delta < len(payloads) and next_delta / rate <= now:
                t0 = time.perf_counter()
                fmap.apply_payload(payloads[next_delta])
                apply_s.append(time.perf_counter() - t0)
                next_delta += 1
            t0 = time.perf_counter()
            for kind, message, build_s in outputs.due(now, time.time()):
                t1 = time.perf_counter()
                pubs[kind].publish_cdr(context.types.serialize(message, TYPES[kind]))
                sent_s[kind].append(build_s + time.perf_counter() - t1)
            busy += time.perf_counter() - t0
            now += TICK_S
        busy += sum(apply_s)
        sent = sum(len(v) for v in sent_s.values())
        deadline = time.monotonic() + 5.0  # the last messages arrive (those not dropped on the way)
        while sum(len(v) for v in received.values()) < sent and time.monotonic() < deadline:
            time.sleep(0.1)
        subscriber.undeclare()
        node.close()
    finally:
        sub_session.close()
        pub_session.close()
    return {
        "name": name,
        "voxels": grid.size,
        "cells": grid.shape[0] * grid.shape[1],
        "deltas": len(payloads),
        "delta_bytes": float(np.mean([len(p) for p in payloads])),
        "occupied": outputs.cloud.points,
        "sim_s": now,
        "catch_up_s": catch_up_s,
        "apply_ms": 1e3 * float(np.median(apply_s)),
        "sent_s": dict(sent_s),
        "received": dict(received),
        "busy_share": busy / now,
    }


def run(config: Path, tiles: int = 4, rate: float = 20.0) -> list[dict]:
    options = Ros2MapOptions()
    return [
        replay("office", config, 1, rate, options),
        replay(f"office x {tiles}x{tiles}", config, tiles, rate, options),
    ]


def format_figures(results: list[dict]) -> str:
    lines = []
    for r in results:
        lines.append(
            f"{r['name']}: {r['voxels']:,} voxels, {r['cells']:,} grid cells, {r['occupied']:,} occupied "
            f"voxels; {r['deltas']} merged deltas of {r['delta_bytes'] / 1e3:.1f} kB over {r['sim_s']:.0f} s"
        )
        lines.append(
            f"  start from a snapshot {r['catch_up_s'] * 1e3:7.1f} ms; "
            f"apply a delta {r['apply_ms']:.2f} ms (median)"
        )
        total = 0
        for kind, label in (("full", "whole grid"), ("update", "grid update"), ("cloud", "cloud")):
            times = np.array(r["sent_s"].get(kind, [])) * 1e3
            sizes = np.array(r["received"].get(kind, []))
            total += int(sizes.sum())
            if times.size == 0:
                lines.append(f"  {label:12s}    0 sent")
                continue
            lines.append(
                f"  {label:12s} {times.size:4d} sent ({sizes.size} received): "
                f"{np.median(times):7.2f} ms p50, {times.max():7.2f} ms max; "
                f"{sizes.mean() / 1e3 if sizes.size else 0:9.1f} kB mean, "
                f"{sizes.max() / 1e3 if sizes.size else 0:9.1f} kB max"
            )
        lines.append(
            f"  received {total / r['sim_s'] / 1e3:.1f} kB per simulated s; the work took "
            f"{100 * r['busy_share']:.1f}% of the simulated time"
        )
    return "\n".join(lines)

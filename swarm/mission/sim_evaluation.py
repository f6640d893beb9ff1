"""After a simulated mission (``swarm sim run``): evaluate it against the floor plan's ground
truth, write its run folder and print its last lines, as :func:`evaluate_and_write` does with
what :func:`swarm.mission.runner.run_mission` returns."""

from __future__ import annotations

import json
import time

import numpy as np

from sim2d.ground_truth import coverage as true_coverage_of
from swarm.formats.map_file import save_map
from swarm.map.entropy_cache import EntropyCache
from swarm.map.entropy_table import default_table
from swarm.mission import evaluation
from swarm.mission.interrupts import INTERRUPTED_EXIT, say
from swarm.mission.role_processes import stop_roles
from swarm.mission.run_report import RunRecord, compute_metrics, write_run_folder
from swarm.mission.runner import INTERRUPTED_STOP_S
from swarm.mission.team_monitor import NEVER


def evaluate_and_write(args, default_config, mission, monitor, facts, interrupts, out, settings) -> int:
    """Evaluate the run against the floor plan's ground truth, write the run folder, print the
    last lines; the exit status (130 when the run was interrupted).

    ``args``: the ``swarm sim run`` arguments; ``monitor``, ``facts``: what ``run_mission``
    returned; ``settings``: (coordination, threshold parts, sensor-observable mask). An
    interrupted run is evaluated on the map server's map as the interrupt found it
    (``facts["server_map"]``, else the monitor's replica); the roles it left stopping
    (``facts["stopping"]``) are ended here, after the run folder is written."""
    interrupted = facts["reason"].startswith("interrupted")
    try:
        if facts["reason"] == "interrupted while starting" or (interrupted and monitor.sim_time == 0.0):
            say(f"swarm: interrupted before the first frame: the roles stopped; {out}/ has no metrics.json")
            return INTERRUPTED_EXIT
        return _write_run(args, default_config, mission, monitor, facts, interrupts, out, settings)
    finally:  # the roles an interrupt left stopping have had the evaluation's time to end
        stop_roles(facts["stopping"], INTERRUPTED_STOP_S)


def _write_run(args, default_config, mission, monitor, facts, interrupts, out, settings) -> int:
    coordination, threshold_parts, sensor_observable = settings
    interrupted = facts["reason"].startswith("interrupted")
    # interrupted: the map server's map (or its store's) as it stood, else the monitor's replica
    cmap = facts["server_map"] if interrupted and facts["server_map"] is not None else monitor.cmap
    t0, cpu0 = time.monotonic(), time.process_time()
    grid = mission.workspace.grid()
    plan = mission.load_floor_plan()
    truth = true_coverage_of(plan, grid) if plan is not None else None
    workspace = (mission.workspace.lo, mission.workspace.hi)
    record = RunRecord(
        config=str(args.config or args.map or default_config),
        robots=mission.robot_ids,
        strategy=args.strategy,
        coordination=coordination,
        seed=args.seed,
        threshold_bits=facts["threshold_bits"],
        initial_entropy_bits=monitor.curve[0][1],
        entropy_curve=[[t, h] for t, h in monitor.curve],
        trajectories={r: [list(p) for p in pts] for r, pts in monitor.trajectories.items()},
        bytes_shared=dict(monitor.bytes_shared),
        sim_time_s=monitor.sim_time,
        wall_time_s=facts["wall_time_s"],
        workspace=workspace,
        floor_plan=plan,
        height_band=(0.1, mission.rig.camera_height + 0.1),
    )
    first_delta = monitor.first_delta_copy()  # one snapshot for the overlaps and observed_by.npz
    observed_by = {r: n != NEVER for r, n in first_delta.items()}
    metrics = compute_metrics(record, cmap, truth, observed_by, sensor_observable)
    metrics["threshold_parts"] = None if threshold_parts is None else threshold_parts.as_dict()
    metrics["stop_reason"] = facts["reason"]
    metrics["robot_link"] = "ros2" if getattr(args, "ros2", False) else "swarm"
    metrics["interrupted"] = interrupted
    metrics["max_time_s"] = mission.stop.max_time_s if args.max_time is None else float(args.max_time)
    metrics["share_min_bits"] = mission.sharing.share_min_bits
    metrics["max_held_bits"] = mission.sharing.max_held_bits
    coordinator_stats = facts.get("coordinator_stats")
    metrics["coordinator_answer_ms"] = (
        None if coordinator_stats is None else coordinator_stats.get("answer_ms")
    )
    metrics.update(
        evaluation.overlaps_during_mission(first_delta, metrics["entropy_curve"], metrics["threshold_bits"])
    )
    server_map = facts["server_map"]
    if server_map is not None:
        # The server merged the same deltas the monitor saw: its map must be the same.
        diff = float(np.max(np.abs(server_map.lam - monitor.cmap.lam) / monitor.cmap.lam))
        metrics["server_map_max_rel_diff"] = diff
        metrics["server_final_entropy_bits"] = float(EntropyCache.from_information(
            server_map.lam, server_map.eta, table=default_table()).total)  # fmt: skip
    try:
        write_run_folder(out, metrics, cmap, mission.to_yaml(), record)
        if server_map is not None:
            save_map(out / "server_map.npz", server_map)
        curve_t = np.array([t for t, _h in monitor.curve])
        arrays = {}
        for r, n in first_delta.items():
            arrays[f"first_delta_{r}"] = n
            arrays[f"first_seen_{r}"] = evaluation.first_seen_times(n, curve_t, never=NEVER)
        np.savez_compressed(out / "observed_by.npz", **arrays)
    except BaseException:  # a run folder cut short is not a finished run
        (out / "metrics.json").unlink(missing_ok=True)
        raise
    keys = (
        "reached_threshold",
        "mission_time_s",
        "sim_time_s",
        "final_entropy_bits",
        "occupancy_f1",
        "explored_fraction",
        "distance_m",
    )
    print(final_line(metrics, facts), flush=True)
    answers = metrics["coordinator_answer_ms"]
    if answers:
        print(
            f"coordinator: {answers['count']} answers, {answers['mean']:.1f} ms mean, "
            f"{answers['p95']:.1f} ms p95, {answers['max']:.1f} ms max (coord/stats)",
            flush=True,
        )
    print(json.dumps({k: _rounded(metrics.get(k)) for k in keys}, default=str))
    took = f"{time.monotonic() - t0:.1f} s (CPU {time.process_time() - cpu0:.1f} s)"
    print(f"stopped: {facts['reason']}; evaluation {took}; wrote {out}/")
    if interrupted:  # on stderr too: after Ctrl-C, a pipe's reader (tee) has gone with it
        source = facts["map_source"] or "the runner's replica of the team map (the map server gave none)"
        say(
            f"swarm: interrupted ({facts['signal'] or 'stopped'}) at sim t={monitor.sim_time:.1f} s: wrote "
            f"metrics.json (stop_reason interrupted), map.npz, top_view.png, map_3d.png, slices/ and "
            f"entropy.png from {source} to {out}/{interrupts.since()}"
        )
    elif interrupts.interrupted:
        say(f"swarm: interrupted while the run folder was written; it is complete: {out}/")
    return INTERRUPTED_EXIT if interrupts.interrupted else 0


def final_line(metrics: dict, facts: dict) -> str:
    """The run's last figures, after the agents' shutdown flush, as metrics.json holds them,
    and what the flush did since the last progress line."""
    stop = facts["at_stop"]
    flushed = stop["deltas_after_flush"] - stop["deltas"]
    h, h_stop = metrics["final_entropy_bits"], stop["entropy_bits"]
    server = metrics.get("server_final_entropy_bits")
    return (
        f"final, after the shutdown flush: H={h:,.0f} bits (H_th {metrics['threshold_bits']:,.0f}), "
        f"sim t={metrics['sim_time_s']:.1f} s; the flush brought {flushed} more delta(s) "
        f"({h - h_stop:+,.0f} bits since the last progress line, H={h_stop:,.0f}); "
        + (f"the map server's map: H={server:,.0f} bits" if server is not None else "no map from the server")
    )


def _rounded(value):
    """Floats to 6 decimals, in dicts too: the summary line shows 306.0, not the sum of 612 frame
    periods (306.0000000000011)."""
    if isinstance(value, float):
        return round(value, 6)
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    return value

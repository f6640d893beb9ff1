"""The study's grid: mission sources x robots x strategies x coordination x seeds, as cells."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from swarm.navigation.strategies import Strategy

Coordination = Literal["coordinator", "none"]
COORDINATIONS: tuple[str, ...] = ("coordinator", "none")


#: The command-line option behind each field of :class:`StudySpec` (for error messages).
OPTION_OF = {
    "configs": "CONFIG",
    "maps": "--map",
    "robots": "--robots",
    "strategies": "--strategies",
    "coordination": "--coordination",
    "seeds": "--seeds",
    "max_time_s": "--max-time",
    "observable_threshold": "--observable-threshold",
    "jobs": "--jobs",
    "out": "--out",
    "resume": "--resume",
}
#: Seconds a mission gets to stop its processes after Ctrl-C before its process group is killed.


class StudyError(ValueError):
    """An invalid study: the message names the option and the problem."""


# -- the grid ----------------------------------------------------------------------------------


def unique(values: Iterable[Any]) -> tuple:
    out: list[Any] = []
    for v in values:
        if v not in out:
            out.append(v)
    return tuple(out)


class StudySpec(BaseModel):
    """A study: the grid of missions to run and where to write it."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    configs: tuple[Path, ...] = ()
    maps: tuple[Path, ...] = ()
    robots: tuple[int, ...] = (1, 2, 4)
    strategies: tuple[Strategy, ...] = ("entropy",)
    coordination: tuple[Coordination, ...] = ("coordinator", "none")
    seeds: tuple[int, ...] = (0, 1, 2)
    max_time_s: float | None = None
    observable_threshold: float | None = Field(default=None, ge=0, le=1)
    jobs: int = 1
    out: Path
    resume: bool = False

    @field_validator("configs", "maps")
    @classmethod
    def _files_exist(cls, paths: tuple[Path, ...]) -> tuple[Path, ...]:
        for p in paths:
            if not p.is_file():
                raise ValueError(f"{p}: no such file")
        return unique(paths)

    @field_validator("robots")
    @classmethod
    def _robots_positive(cls, robots: tuple[int, ...]) -> tuple[int, ...]:
        if not robots:
            raise ValueError("give at least one robot count")
        bad = [n for n in robots if n < 1]
        if bad:
            raise ValueError(f"every robot count must be >= 1 (got {bad[0]})")
        return unique(robots)

    @field_validator("seeds")
    @classmethod
    def _seeds_valid(cls, seeds: tuple[int, ...]) -> tuple[int, ...]:
        if not seeds:
            raise ValueError("give at least one seed")
        bad = [s for s in seeds if s < 0]
        if bad:
            raise ValueError(f"seeds must be >= 0 (got {bad[0]})")
        return unique(seeds)

    @field_validator("strategies", "coordination")
    @classmethod
    def _not_empty(cls, values: tuple[str, ...]) -> tuple[str, ...]:
        if not values:
            raise ValueError("give at least one value")
        return unique(values)

    @field_validator("max_time_s")
    @classmethod
    def _max_time_positive(cls, t: float | None) -> float | None:
        if t is not None and not (math.isfinite(t) and t > 0):
            raise ValueError(f"must be a positive number of sim seconds (got {t})")
        return t

    @field_validator("jobs")
    @classmethod
    def _jobs_positive(cls, jobs: int) -> int:
        if jobs < 1:
            raise ValueError(f"must be >= 1 (got {jobs})")
        return jobs

    @model_validator(mode="after")
    def _sources(self) -> StudySpec:
        if not self.configs and not self.maps:
            raise ValueError("give at least one mission CONFIG or --map MAP.yaml")
        labels: dict[str, Path] = {}
        for path, kind in self.sources:
            label = source_label(path, kind)
            if label in labels:
                raise ValueError(f"{labels[label]} and {path} would both be named {label!r}; rename one")
            labels[label] = path
        return self

    @property
    def sources(self) -> list[tuple[Path, str]]:
        """(path, kind) of every mission source, kind "config" or "map"."""
        return [(p, "config") for p in self.configs] + [(p, "map") for p in self.maps]


def source_label(path: Path, kind: str) -> str:
    """The name of a mission source in run names and tables: the file stem, ``-map`` for ROS maps."""
    return Path(path).stem + ("-map" if kind == "map" else "")


def effective_coordination(robots: int, strategy: str, coordination: str) -> str:
    """The coordination a mission really uses: only entropy teams of 2+ robots have a coordinator."""
    return coordination if robots > 1 and strategy == "entropy" else "none"


@dataclass(frozen=True)
class Cell:
    """One mission of the study: a point of the grid, run once."""

    source: Path
    kind: str  # "config" or "map"
    robots: int
    strategy: str
    coordination: str
    seed: int

    @property
    def label(self) -> str:
        return source_label(self.source, self.kind)

    @property
    def name(self) -> str:
        return f"{self.label}-{self.robots}r-{self.strategy}-{self.coordination}-s{self.seed}"

    @property
    def setting(self) -> tuple[str, int, str, str]:
        """The cell without its seed: (label, robots, strategy, coordination)."""
        return (self.label, self.robots, self.strategy, self.coordination)

    def sim_args(
        self, out: Path, max_time_s: float | None, observable_threshold: float | None = None
    ) -> list[str]:
        """Arguments of ``swarm`` that run this cell into run folder ``out``."""
        where = [str(self.source)] if self.kind == "config" else ["--map", str(self.source)]
        args = ["sim", "run", *where, "--robots", str(self.robots), "--strategy", self.strategy]
        args += ["--coordination", self.coordination, "--seed", str(self.seed), "--quiet", "--out", str(out)]
        if max_time_s is not None:
            args += ["--max-time", f"{max_time_s:g}"]
        if observable_threshold is not None:
            args += ["--observable-threshold", f"{observable_threshold:g}"]
        return args


@dataclass(frozen=True)
class Skipped:
    """Cells of a source and robot count that were not run, and why."""

    label: str
    robots: int
    reason: str


def expand_grid(spec: StudySpec, capacity: Mapping[Path, int]) -> tuple[list[Cell], list[Skipped]]:
    """The cells of ``spec``, seeds outermost, and the skipped (source, robots) pairs.

    ``capacity`` maps each source path to the most robots its mission places. Cells whose
    coordination makes no difference (one robot, or a strategy other than entropy) are run
    once as coordination ``none``; duplicates are dropped.
    """
    cells: list[Cell] = []
    skipped: list[Skipped] = []
    for path, kind in spec.sources:
        cap = capacity[path]
        for n in spec.robots:
            if n > cap:
                reason = f"asks for {n} robots; the mission places {cap}"
                skipped.append(Skipped(source_label(path, kind), n, reason))
    too_many = {(s.label, s.robots) for s in skipped}
    for seed in spec.seeds:
        for path, kind in spec.sources:
            for n in spec.robots:
                if (source_label(path, kind), n) in too_many:
                    continue
                for strategy in spec.strategies:
                    for coordination in spec.coordination:
                        coord = effective_coordination(n, strategy, coordination)
                        cell = Cell(path, kind, n, strategy, coord, seed)
                        if cell not in cells:
                            cells.append(cell)
    return cells, skipped


def mission_capacity(spec: StudySpec) -> dict[Path, int]:
    """The most robots each source's mission places (for a ROS map: the most of those asked for).
    StudyError when a mission's robot has no start pose (the simulator needs every one)."""
    from swarm.config import ConfigError, load_mission, mission_from_map

    capacity: dict[Path, int] = {}
    for path in spec.configs:
        try:
            capacity[path] = len(load_mission(path).start_poses())
        except ConfigError as exc:
            raise StudyError(f"CONFIG: {exc}") from exc
    for path in spec.maps:
        error: ConfigError | None = None
        for n in sorted(spec.robots, reverse=True):
            try:
                mission_from_map(path, robots=n)
            except ConfigError as exc:
                error = exc
                continue
            capacity[path] = n
            break
        else:
            raise StudyError(f"--map: {error}")
    return capacity

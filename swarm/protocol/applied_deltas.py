"""Which deltas a replica of the team map holds: each (robot, epoch, seq) at most once.

docs/design.md section 5: the server applies every (robot, epoch, seq) once and acks the
contiguous prefix per (robot, epoch). Every holder of a copy of the team map (agents, the
coordinator, the mission runner) keeps the same record for the ``merged`` stream, so a
repeated message changes nothing and a snapshot's acks count as already applied.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping


class SeqSet:
    """Sequence numbers seen for one (robot, epoch): a contiguous prefix and those above it."""

    def __init__(self, prefix: int = 0) -> None:
        self.prefix = prefix
        self.above: set[int] = set()

    def add(self, seq: int) -> bool:
        """Record ``seq``; False when it was seen already."""
        if seq <= self.prefix or seq in self.above:
            return False
        self.above.add(seq)
        while self.prefix + 1 in self.above:
            self.prefix += 1
            self.above.discard(self.prefix)
        return True

    def __contains__(self, seq: int) -> bool:
        return seq <= self.prefix or seq in self.above

    def cover(self, prefix: int) -> None:
        """Count every seq up to ``prefix`` as seen (e.g. the acks of a snapshot)."""
        if prefix > self.prefix:
            self.prefix = prefix
            self.above = {s for s in self.above if s > prefix}
            while self.prefix + 1 in self.above:
                self.prefix += 1
                self.above.discard(self.prefix)


class AppliedDeltas:
    """A ``SeqSet`` per (robot, epoch)."""

    def __init__(self) -> None:
        self._sets: dict[tuple[str, int], SeqSet] = {}

    def add(self, robot: str, epoch: int, seq: int) -> bool:
        """Record a delta; False when it was applied already (a duplicate)."""
        return self._sets.setdefault((robot, int(epoch)), SeqSet()).add(int(seq))

    def __contains__(self, delta_id: tuple[str, int, int]) -> bool:
        robot, epoch, seq = delta_id
        seqs = self._sets.get((robot, int(epoch)))
        return seqs is not None and int(seq) in seqs

    def cover(
        self,
        acks: Mapping[str, Mapping[int, int]],
        above: Mapping[str, Mapping[int, Iterable[int]]] | None = None,
    ) -> None:
        """Count the deltas a snapshot holds as applied: its ``acks`` ({robot: {epoch: last
        contiguous seq}}) and the seqs ``above`` them ({robot: {epoch: [seq, ...]}})."""
        for robot, by_epoch in acks.items():
            for epoch, seq in by_epoch.items():
                self._sets.setdefault((robot, int(epoch)), SeqSet()).cover(int(seq))
        for robot, by_epoch in (above or {}).items():
            for epoch, seqs in by_epoch.items():
                for seq in seqs:
                    self.add(robot, epoch, seq)

    def acks(self) -> dict[str, dict[int, int]]:
        """The contiguous prefix per (robot, epoch), in the shape of ``map/acks``."""
        out: dict[str, dict[int, int]] = {}
        for (robot, epoch), seqs in sorted(self._sets.items()):
            out.setdefault(robot, {})[epoch] = seqs.prefix
        return out

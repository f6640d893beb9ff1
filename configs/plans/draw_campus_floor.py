"""Draw ``campus_floor.yaml``: ``python configs/plans/draw_campus_floor.py`` rewrites it.

One floor of a campus building, 80 m x 48 m, for missions of 16 robots and more
(``configs/campus_floor.yaml``): three east-west and three north-south corridors, 2 m wide,
cut the floor into 4 x 4 blocks of 18-19 m x 10-11 m; each block is two rooms behind a
partition, and every room has a 1.2 m door onto each east-west corridor along it. Each room
holds a desk and a cabinet. Walls are 0.2 m thick, centred on lines of the 0.1 m voxel grid,
and every box face lies on a voxel boundary (as in ``office.yaml``).
"""

from __future__ import annotations

from pathlib import Path

WIDTH, DEPTH = 80.0, 48.0
#: the corridors' (from, to) in metres: east-west ones in y, north-south ones in x
EAST_WEST = ((11.0, 13.0), (23.0, 25.0), (35.0, 37.0))
NORTH_SOUTH = ((19.0, 21.0), (39.0, 41.0), (59.0, 61.0))
DOOR = 1.2  # m


def _spans(lo: float, hi: float, gaps) -> list[tuple[float, float]]:
    """[lo, hi] without the (a, b) gaps, as (from, to) pieces."""
    out, at = [], lo
    for a, b in sorted(gaps):
        if a > at:
            out.append((at, a))
        at = max(at, b)
    if at < hi:
        out.append((at, hi))
    return out


def _blocks(corridors, size: float) -> list[tuple[float, float]]:
    """The (from, to) between the corridors and the shell, along one axis."""
    edges = [0.0, *[v for c in corridors for v in c], size]
    return [(edges[i], edges[i + 1]) for i in range(0, len(edges), 2)]


def campus_floor() -> str:
    """The plan's YAML text."""
    cols, rows = _blocks(NORTH_SOUTH, WIDTH), _blocks(EAST_WEST, DEPTH)
    shell = f"[[0, 0], [{WIDTH:g}, 0], [{WIDTH:g}, {DEPTH:g}], [0, {DEPTH:g}]]"
    walls = [f"  - points: {shell}\n    closed: true"]
    boxes = []
    doors_at: dict[float, list[tuple[float, float]]] = {y: [] for c in EAST_WEST for y in c}
    for x0, x1 in cols:
        mid = round((x0 + x1) / 2)
        for y0, y1 in rows:
            walls.append(f"  - points: [[{mid:g}, {y0:g}], [{mid:g}, {y1:g}]]  # partition")
            for r0, r1 in ((x0, mid), (mid, x1)):
                centre = round((r0 + r1) / 2)
                for y in (y0, y1):
                    if y in doors_at:  # a wall onto an east-west corridor: a door in it
                        doors_at[y].append((centre - DOOR / 2, centre + DOOR / 2))
                for (x, y), size, height in (
                    ((r0 + 1.3, y0 + 0.8), "[1.6, 0.8]", 0.8),  # a desk
                    ((r1 - 0.7, y1 - 1.2), "[0.6, 1.2]", 1.8),  # a cabinet
                ):
                    boxes.append(f"  - {{centre: [{x:.1f}, {y:.1f}], size: {size}, height: {height}}}")
    for y, doors in doors_at.items():  # the east-west corridors' walls, open at the crossings
        for a, b in _spans(0.0, WIDTH, [*NORTH_SOUTH, *doors]):
            walls.append(f"  - points: [[{a:g}, {y:g}], [{b:g}, {y:g}]]")
    for x in (v for c in NORTH_SOUTH for v in c):  # the north-south corridors' walls
        for a, b in _spans(0.0, DEPTH, EAST_WEST):
            walls.append(f"  - points: [[{x:g}, {a:g}], [{x:g}, {b:g}]]")
    head = (
        "# One floor of a campus building, 80 m x 48 m (drawn by draw_campus_floor.py: edit that,\n"
        "# not this file): three east-west and three north-south corridors 2 m wide, 4 x 4 blocks\n"
        "# of two rooms, a 1.2 m door from each room onto each east-west corridor along it.\n"
        "name: campus_floor\nwall_height: 2.5\nwall_thickness: 0.2\n"
    )
    return head + "walls:\n" + "\n".join(walls) + "\nboxes:\n" + "\n".join(boxes) + "\n"


if __name__ == "__main__":
    (Path(__file__).resolve().parent / "campus_floor.yaml").write_text(campus_floor())

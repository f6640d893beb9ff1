"""Draw the project's own ROS map_server maps: ``python configs/maps/own_maps.py`` rewrites them.

Three buildings with different layouts for the exploration studies (docs/study.md), each a
``NAME.pgm`` (0.05 m per cell; 0 = occupied, 254 = free, 205 = unknown outside the building)
and a ``NAME.yaml``. The origins are off the 0.1 m voxel grid on purpose, so no wall sits on
voxel boundaries:

- ``offices_corridor``: 22 m x 11 m, a 1.6 m corridor along the middle, eight offices off it
  behind 0.10 m walls with 0.8 m doors, desks and cupboards, a wider lobby at one end.
- ``thick_hall``: 16 m x 12 m, an open hall with 0.35 m walls and four 0.6 m pillars, a long
  L-shaped corridor (1.2 m) to two store rooms with 0.9 m doors, and a diagonal partition.
- ``narrow_rooms``: 14 m x 10 m, nine rooms in a 3 x 3 block linked by 0.7 m doors in 0.15 m
  walls (a robot of radius 0.18 m clears them by 0.17 m), with boxes in the corners, never
  within 0.6 m of a door.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

RES = 0.05
FREE, OCCUPIED, UNKNOWN = 254, 0, 205
HERE = Path(__file__).resolve().parent


class Drawing:
    """A floor of ``w`` x ``h`` metres; walls and boxes in metres, drawn as occupied cells."""

    def __init__(self, w: float, h: float) -> None:
        self.occ = np.zeros((round(h / RES), round(w / RES)), dtype=bool)  # rows from the bottom

    def box(self, x0: float, y0: float, x1: float, y1: float) -> None:
        c0, c1 = sorted((round(x0 / RES), round(x1 / RES)))
        r0, r1 = sorted((round(y0 / RES), round(y1 / RES)))
        self.occ[r0 : max(r1, r0 + 1), c0 : max(c1, c0 + 1)] = True

    def hwall(self, y: float, x0: float, x1: float, t: float, doors: list[tuple[float, float]] = ()) -> None:
        """A wall along x at height y (centre line), thickness t, with door gaps (x from, x to)."""
        self.box(x0, y - t / 2, x1, y + t / 2)
        for a, b in doors:
            self.clear(a, y - t, b, y + t)

    def vwall(self, x: float, y0: float, y1: float, t: float, doors: list[tuple[float, float]] = ()) -> None:
        self.box(x - t / 2, y0, x + t / 2, y1)
        for a, b in doors:
            self.clear(x - t, a, x + t, b)

    def clear(self, x0: float, y0: float, x1: float, y1: float) -> None:
        c0, c1 = sorted((round(x0 / RES), round(x1 / RES)))
        r0, r1 = sorted((round(y0 / RES), round(y1 / RES)))
        self.occ[r0:r1, c0:c1] = False

    def line(self, a: tuple[float, float], b: tuple[float, float], t: float) -> None:
        """A straight wall of thickness t from a to b at any angle."""
        img = self.occ.astype(np.uint8)
        pa = (round(a[0] / RES), round(a[1] / RES))
        pb = (round(b[0] / RES), round(b[1] / RES))
        cv2.line(img, pa, pb, 1, thickness=max(round(t / RES), 1))
        self.occ = img.astype(bool)

    def save(self, name: str, origin: tuple[float, float]) -> None:
        pad = 4  # unknown cells round the building
        img = np.full((self.occ.shape[0] + 2 * pad, self.occ.shape[1] + 2 * pad), UNKNOWN, np.uint8)
        img[pad:-pad, pad:-pad] = np.where(self.occ, OCCUPIED, FREE)
        cv2.imwrite(str(HERE / f"{name}.pgm"), img[::-1])  # the image's first row is the top
        ox, oy = origin[0] - pad * RES, origin[1] - pad * RES
        (HERE / f"{name}.yaml").write_text(
            f"image: {name}.pgm\nmode: trinary\nresolution: {RES}\norigin: [{ox:.3f}, {oy:.3f}, 0.0]\n"
            "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
        )


def offices_corridor() -> None:
    d = Drawing(22.0, 11.0)
    t = 0.10
    d.hwall(0.05, 0, 22, t)
    d.hwall(10.95, 0, 22, t)
    d.vwall(0.05, 0, 11, t)
    d.vwall(21.95, 0, 11, t)
    # corridor y 4.7-6.3 from x 4 to 22; lobby x 0-4 open full height
    south_doors = [(x + 1.6, x + 2.4) for x in (4.0, 8.5, 13.0, 17.5)]
    d.hwall(4.7, 4.0, 22, t, south_doors)
    d.hwall(6.3, 4.0, 22, t, [(x + 2.0, x + 2.8) for x in (4.0, 8.5, 13.0, 17.5)])
    for x in (8.5, 13.0, 17.5):
        d.vwall(x, 0, 4.7, t)
        d.vwall(x, 6.3, 11, t)
    d.vwall(4.0, 0, 4.7, t, [(2.0, 3.0)])  # the first south office also opens on the lobby
    d.vwall(4.0, 6.3, 11, t)
    # desks (0.8 x 1.4) and cupboards (0.5 x 1.2) in the offices
    for x in (4.0, 8.5, 13.0, 17.5):
        d.box(x + 0.6, 0.6, x + 2.0, 1.4)
        d.box(x + 3.6, 2.5, x + 4.1, 3.7)
        d.box(x + 0.6, 9.6, x + 2.0, 10.4)
        d.box(x + 3.7, 7.2, x + 4.2, 8.4)
    d.box(1.2, 8.5, 2.8, 9.3)  # a lobby bench and a counter
    d.box(0.6, 1.0, 1.4, 3.0)
    d.save("offices_corridor", origin=(0.03, 0.07))


def thick_hall() -> None:
    d = Drawing(16.0, 12.0)
    t = 0.35
    d.hwall(t / 2, 0, 16, t)
    d.hwall(12 - t / 2, 0, 16, t)
    d.vwall(t / 2, 0, 12, t)
    d.vwall(16 - t / 2, 0, 12, t)
    # the hall: x 0-10, y 0-12; pillars
    for x, y in ((3.0, 3.5), (7.0, 3.5), (3.0, 8.5), (7.0, 8.5)):
        d.box(x - 0.3, y - 0.3, x + 0.3, y + 0.3)
    d.vwall(10.0, 0, 12, t, [(5.4, 6.6)])  # the hall's east wall, one wide opening
    # the L corridor: east from the opening, then north, 1.2 m wide
    d.hwall(5.4 - t / 2, 10.0, 14.6, t)
    d.hwall(6.6 + t / 2, 10.0, 13.4, t)
    d.vwall(14.6 + t / 2, 0.0, 6.6, t)
    d.vwall(13.4 - t / 2, 6.6, 12.0, t, [(9.0, 9.9)])
    # two store rooms south of the corridor (x 10-14.6, y 0-5.2) split in two, 0.9 m doors
    d.vwall(12.3, 0, 5.2, t)
    d.hwall(5.4 - t / 2, 10.0, 14.6, t, [(10.8, 11.7), (13.2, 14.1)])
    d.box(10.6, 0.6, 11.4, 2.0)
    d.box(13.0, 0.6, 14.0, 1.4)
    # a diagonal partition in the hall, shelves along the west wall
    d.line((1.5, 10.8), (4.5, 6.5), 0.12)
    d.box(0.4, 5.0, 0.9, 7.5)
    d.save("thick_hall", origin=(0.02, 0.04))


def narrow_rooms() -> None:
    d = Drawing(14.0, 10.0)
    t = 0.15
    w, h = 14 / 3, 10 / 3  # a room, wall centre to wall centre
    d.hwall(t / 2, 0, 14, t)
    d.hwall(10 - t / 2, 0, 14, t)
    d.vwall(t / 2, 0, 10, t)
    d.vwall(14 - t / 2, 0, 10, t)
    doors = []  # (x0, y0, x1, y1) of each door's gap
    for i, x in enumerate((w, 2 * w)):  # walls between columns of rooms, a 0.7 m door per room
        d.vwall(x, 0, 10, t)
        for k in range(3):
            yc = (k + 0.5) * h + (0.7 if (i + k) % 2 else -0.7)
            doors.append((x - t, yc - 0.35, x + t, yc + 0.35))
    for j, y in enumerate((h, 2 * h)):
        d.hwall(y, 0, 14, t)
        for k in range(3):
            xc = (k + 0.5) * w + (0.9 if (j + k) % 2 else -0.9)
            doors.append((xc - 0.35, y - t, xc + 0.35, y + t))
    for door in doors:
        d.clear(*door)
    for k in range(3):  # two boxes per room, in corners whose doors they leave clear
        for j in range(3):
            for box in _corner_boxes(k * w, j * h, w, h, doors):
                d.box(*box)
    d.save("narrow_rooms", origin=(0.04, 0.01))


def _corner_boxes(x0: float, y0: float, w: float, h: float, doors: list) -> list[tuple]:
    """A 0.6 x 0.5 m and a 0.75 x 0.55 m box in two corners of the room (x0, y0, w, h), each at
    least 0.6 m from every door gap (a robot of radius 0.18 m passes with room to turn); the
    first two such corners, lower-left and upper-right first."""
    sizes = ((0.6, 0.5), (0.75, 0.55))
    corners = ((0, 0), (1, 1), (0, 1), (1, 0))  # (right?, top?)
    gap = 0.3  # from the wall's centre line

    def place(size, corner):
        bx = x0 + gap if corner[0] == 0 else x0 + w - gap - size[0]
        by = y0 + gap if corner[1] == 0 else y0 + h - gap - size[1]
        return (bx, by, bx + size[0], by + size[1])

    def clear(box):
        for a in doors:
            dx = max(0.0, a[0] - box[2], box[0] - a[2])
            dy = max(0.0, a[1] - box[3], box[1] - a[3])
            if np.hypot(dx, dy) < 0.6:
                return False
        return True

    out, free = [], list(corners)
    for size in sizes:
        for corner in free:
            if clear(place(size, corner)):
                out.append(place(size, corner))
                free.remove(corner)
                break
    return out


if __name__ == "__main__":
    offices_corridor()
    thick_hall()
    narrow_rooms()

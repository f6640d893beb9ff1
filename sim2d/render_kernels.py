"""Compiled per-pixel steps of the renderer (Numba): nearest hit of each ray, then its grey level.

``cast_rays`` takes floor-plane rays sorted by azimuth (one per image column for a level
camera, one per pixel otherwise), each with the slopes of its pixels. For each block of
neighbouring rays it keeps the quads whose azimuth wedge meets the block's; for each ray it
clips the ray against those quads (Cyrus-Beck) once and sorts the crossings by entry
distance; for each pixel of the ray it walks the crossings nearest first and stops as soon
as no later crossing can be nearer than the best hit found (a hit is never nearer than its
crossing's entry). Ties between quads go to the lower quad index, as numpy's ``argmin``
over the quads in index order would; a quad hit must be strictly nearer than the floor.

``shade_pixels`` turns each pixel's hit into a grey level: texture x albedo x light, the
texture sampled trilinearly for the pixel's footprint on the surface.

Every step is IEEE arithmetic in the same order as the vectorised numpy renderer it replaced
(kept in the tests as the oracle), so distances, faces and images are the same. The kernels
use Numba's ``error_model="numpy"``: a division is the plain IEEE one, as in numpy, without
Python's zero-divisor check (no divisor here can be zero). Without that check's branch the
compiler turns branch-free loops (the footprints of a batch of pixels) into vector
instructions, whose lanes round exactly as the scalar instructions do.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sim2d.texture_sampling import trilinear

FACE_NONE, FACE_FLOOR, FACE_SIDE, FACE_TOP = 0, 1, 2, 3
TWO_PI = 2 * np.pi
BATCH = 64  # pixels per batch of ``shade_pixels``


@numba.njit(cache=True, nogil=True, error_model="numpy")
def cast_rays(
    origin, cam_z, unit, slope, perm, angle, block, q_lo, q_hi, in_range,
    edge_a, edge_n, heights, max_distance, distance, face, obstacle, edge,
):  # fmt: skip
    """Nearest hit of every pixel; writes ``distance``, ``face``, ``obstacle``, ``edge`` (R, rows).

    ``origin`` (2,) and ``cam_z``: camera (m); ``unit`` (R, 2): floor-plane ray directions;
    ``slope`` (R, rows): d_z / |d_xy| of each pixel (ray-major, so that a ray's pixels are
    adjacent in memory); ``perm``: the rays in azimuth order and
    ``angle`` their sorted azimuths (rad, relative to the view's middle); ``block``: rays per
    culling block; ``q_lo``, ``q_hi``, ``in_range`` (Q,): each quad's azimuth interval and
    whether it is within ``max_distance``; ``edge_a``, ``edge_n`` (Q, 4, 2): a point and the
    outward normal of each quad side; ``heights`` (Q,) m.
    """
    n_rays = len(perm)
    n_rows = slope.shape[1]
    n_quads = len(heights)
    ox, oy = origin[0], origin[1]
    # n . (origin - a) of every quad side (> 0: the camera is outside that side), once per view.
    side_num = np.empty((n_quads, 4))
    for q in range(n_quads):
        for e in range(4):
            nx, ny = edge_n[q, e, 0], edge_n[q, e, 1]
            side_num[q, e] = nx * (ox - edge_a[q, e, 0]) + ny * (oy - edge_a[q, e, 1])
    cand = np.empty(n_quads, dtype=np.int64)
    c_in, c_out, c_h = np.empty(n_quads), np.empty(n_quads), np.empty(n_quads)
    c_quad, c_enter = np.empty(n_quads, dtype=np.int64), np.empty(n_quads, dtype=np.int64)
    for r0 in range(0, n_rays, block):
        r1 = min(r0 + block, n_rays)
        a_lo, a_hi = angle[r0] - 1e-9, angle[r1 - 1] + 1e-9
        n_cand = 0
        for q in range(n_quads):
            if not in_range[q]:
                continue
            for shift in (-TWO_PI, 0.0, TWO_PI):
                if q_lo[q] + shift <= a_hi and q_hi[q] + shift >= a_lo:
                    cand[n_cand] = q
                    n_cand += 1
                    break
        for j in range(r0, r1):
            ray = perm[j]
            u0, u1 = unit[ray, 0], unit[ray, 1]
            # Cyrus-Beck: crossings of this ray, kept sorted by entry distance (stable).
            n_cross = 0
            for k in range(n_cand):
                q = cand[k]
                r_in, enter, r_out, parallel_out = -np.inf, 0, np.inf, False
                for e in range(4):
                    num = side_num[q, e]
                    den = u0 * edge_n[q, e, 0] + u1 * edge_n[q, e, 1]
                    if den < 0:
                        t = -num / den
                        if t > r_in:
                            r_in, enter = t, e
                    elif den > 0:
                        r_out = min(r_out, -num / den)
                    elif den == 0 and num > 0:
                        parallel_out = True
                if not (r_in < r_out and r_out > 0) or parallel_out:
                    continue
                r_in = max(r_in, 0.0)
                if not r_in < max_distance:
                    continue
                at = n_cross
                while at > 0 and c_in[at - 1] > r_in:
                    c_in[at], c_out[at], c_h[at] = c_in[at - 1], c_out[at - 1], c_h[at - 1]
                    c_quad[at], c_enter[at] = c_quad[at - 1], c_enter[at - 1]
                    at -= 1
                c_in[at], c_out[at], c_h[at], c_quad[at], c_enter[at] = r_in, r_out, heights[q], q, enter
                n_cross += 1
            for row in range(n_rows):
                m = slope[ray, row]
                floor_r = -cam_z / m if m < 0 else np.inf
                best_r, best_c, best_side = np.inf, -1, False
                for c in range(n_cross):
                    r_in = c_in[c]
                    if r_in > best_r or r_in >= floor_r:
                        break  # every later hit is at least this far
                    h = c_h[c]
                    z_in = cam_z + m * r_in
                    if z_in >= 0 and z_in <= h:
                        hit_r, side = r_in, True
                    elif z_in > h and m < 0 and (h - cam_z) / m <= c_out[c]:
                        hit_r, side = (h - cam_z) / m, False
                    else:
                        continue
                    if hit_r < best_r or (hit_r == best_r and c_quad[c] < c_quad[best_c]):
                        best_r, best_c, best_side = hit_r, c, side
                if best_c >= 0 and best_r < floor_r:
                    r, f, o = best_r, FACE_SIDE if best_side else FACE_TOP, c_quad[best_c]
                    s = c_enter[best_c] if best_side else -1
                elif m < 0:
                    r, f, o, s = floor_r, FACE_FLOOR, -1, -1
                else:
                    r, f, o, s = np.inf, FACE_NONE, -1, -1
                if r > max_distance:
                    r, f, o, s = np.inf, FACE_NONE, -1, -1
                distance[ray, row], face[ray, row], obstacle[ray, row], edge[ray, row] = r, f, o, s


@numba.njit(cache=True, nogil=True, error_model="numpy")
def shade_pixels(
    distance, face, obstacle, edge, unit, slope, origin, cam_z, fx, edge_n, albedo, offsets,
    side_light, flat_light, sky, texels, starts, sizes, shrink, texel, grey,
):  # fmt: skip
    """Grey level (0-255) of every pixel from its hit (R, rows); writes the image ``grey`` (rows, R).

    Hits and rays as ``cast_rays`` gives them; ``fx``: focal length (px); per quad
    ``albedo`` (Q,), texture ``offsets`` (Q, 5, 2) m (4 sides, top) and ``side_light``
    (Q, 4); ``flat_light``: light on the floor and tops; ``sky``: grey of no return; the
    rest: a ``TexturePyramid``'s arrays. Pixels go in batches: surface coordinates of the
    batch, then its footprints, then its texture lookups, then its grey levels.
    """
    ox, oy = origin[0], origin[1]
    n_rays, n_rows = distance.shape
    n_pixels = distance.size
    flat_grey = grey.ravel()
    flat_distance, flat_face, flat_slope = distance.ravel(), face.ravel(), slope.ravel()
    flat_obstacle, flat_edge = obstacle.ravel(), edge.ravel()
    index = np.empty(BATCH, dtype=np.int64)
    su, sv, footprint = np.empty(BATCH), np.empty(BATCH), np.empty(BATCH)
    hit_r, hit_m, along_normal = np.empty(BATCH), np.empty(BATCH), np.empty(BATCH)
    lit, tex, scratch = np.empty(BATCH), np.empty(BATCH), np.empty((3, BATCH))
    ray, row = 0, 0  # divmod(pixel, n_rows), kept without a division
    for start in range(0, n_pixels, BATCH):
        count = 0
        for pixel in range(start, min(start + BATCH, n_pixels)):
            at = row * n_rays + ray  # the pixel in the image (rows, R)
            this_ray = ray
            row += 1
            if row == n_rows:
                ray, row = ray + 1, 0
            f = flat_face[pixel]
            if f == FACE_NONE:
                flat_grey[at] = sky
                continue
            r, m = flat_distance[pixel], flat_slope[pixel]
            u0, u1 = unit[this_ray, 0], unit[this_ray, 1]
            px, py, pz = ox + r * u0, oy + r * u1, cam_z + r * m
            o = flat_obstacle[pixel]
            if f == FACE_SIDE:
                e = flat_edge[pixel]
                nx, ny = edge_n[o, e, 0], edge_n[o, e, 1]
                along_normal[count] = abs(nx * u0 + ny * u1)
                su[count] = px * -ny + py * nx + offsets[o, e, 0]
                sv[count] = pz + offsets[o, e, 1]
                alb, light = albedo[o], side_light[o, e]
            else:
                along_normal[count] = abs(m)
                light = flat_light
                if f == FACE_FLOOR:
                    su[count], sv[count], alb = px * 0.8, py * 0.8, 0.8
                else:
                    su[count], sv[count], alb = px + offsets[o, 4, 0], py + offsets[o, 4, 1], albedo[o]
            hit_r[count], hit_m[count] = r, m
            lit[count] = 255.0 * alb * light
            index[count] = at
            count += 1
        # Footprints in a branch-free loop: the square roots and divisions of several pixels go in
        # one vector instruction.
        for k in range(count):
            norm = math.sqrt(1 + hit_m[k] * hit_m[k])
            cos_inc = along_normal[k] / norm
            footprint[k] = hit_r[k] * norm / fx / max(cos_inc, 0.2)  # range / f, widened when grazing
        trilinear(texels, starts, sizes, shrink, texel, su, sv, footprint, count, scratch, tex)
        for k in range(count):
            flat_grey[index[k]] = lit[k] * (0.25 + 0.75 * tex[k])


@numba.njit(cache=True, nogil=True, error_model="numpy")
def grey_levels(grey, normal, noise_std, out):
    """``out`` (uint8) = clip(rint(grey + (0 + noise_std normal)), 0, 255), rounding half to even.

    ``grey``, ``normal`` (standard normal draws) and ``out`` of one shape; an empty ``normal``
    adds no noise. 0 + s z is what numpy's ``Generator.normal(0, s)`` returns for the draw z.
    """
    flat_grey, flat_out = grey.ravel(), out.ravel()
    if normal.size == 0:
        for k in range(len(flat_out)):
            flat_out[k] = np.uint8(min(max(np.rint(flat_grey[k]), 0.0), 255.0))
        return
    flat_normal = normal.ravel()
    for k in range(len(flat_out)):
        noise = 0.0 + noise_std * flat_normal[k]
        flat_out[k] = np.uint8(min(max(np.rint(flat_grey[k] + noise), 0.0), 255.0))

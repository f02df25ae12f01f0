"""First-person rendering of a :class:`~cmal_lcd.data.world.world.World` into a G-buffer.

Backends implement the :class:`Renderer` protocol: ``render(x, y, heading, sun_direction=)``
returns a :class:`GBuffer` (albedo, normal, depth, material, sun visibility, view direction).
Lighting and weather are applied afterwards (:mod:`cmal_lcd.data.world.weather`), so geometry
(depth, normals, materials) never depends on the condition.

The one backend so far, :class:`HeightmapRenderer`, is a numba-compiled heightmap ray-caster:
per image column a 2-D DDA walks the grid front to back and fills rows bottom-up (walls and tops
of cells, so buildings and fences have vertical faces), then billboards (trees, bushes, poles,
signs) are drawn with a depth test, then sun visibility is found by marching each hit point
towards the sun. It runs headless on a CPU, needs no system packages and is bit-identical across
runs and thread counts (each frame is computed by one thread, in a fixed order; see
:mod:`.threads`). A mesh backend
(e.g. OpenGL via moderngl/EGL) can be added by implementing :class:`Renderer` and registering it
in :data:`RENDERERS`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Protocol

import numba
import numpy as np

from cmal_lcd.data.world import materials as M
from cmal_lcd.data.world.config import CameraSpec
from cmal_lcd.data.world.threads import run_frame_chunks
from cmal_lcd.data.world.world import World

#: Range assigned to the far skyline, metres (fogs it like distant mountains).
FAR_DISTANCE_M = 3000.0
#: Tile sizes (cells) of the two max-height maps that let the shadow march skip empty space.
_COARSE = 8
_COARSE2 = 64


@dataclass(frozen=True)
class GBuffer:
    """Per-pixel geometry and surface of a batch of frames.

    Attributes
    ----------
    albedo : ndarray, float32 (N, H, W, 3)
        Linear surface albedo (0 for sky).
    normal : ndarray, float32 (N, H, W, 3)
        Unit world normal (0 for sky).
    depth : ndarray, float32 (N, H, W)
        Range along the view ray, metres; ``inf`` for sky.
    material : ndarray, uint8 (N, H, W)
        Material id (:mod:`~cmal_lcd.data.world.materials`), ``SKY`` = 0.
    sun_visibility : ndarray, float32 (N, H, W)
        Fraction of the sun seen from the surface point (0 in shadow); 1 without a sun.
    view : ndarray, float32 (N, H, W, 3)
        Unit view direction (world frame, ``z`` up).
    puddle : ndarray, float32 (N, H, W)
        Depth of the hollow under the pixel where rain water collects (0 off the road).
    horizon : float
        Image row (in pixels from the top, fractional) of the horizon: the mirror axis of
        reflections on level ground.
    """

    albedo: np.ndarray
    normal: np.ndarray
    depth: np.ndarray
    material: np.ndarray
    sun_visibility: np.ndarray
    view: np.ndarray
    puddle: np.ndarray
    horizon: float

    def __len__(self) -> int:
        return self.depth.shape[0]


class Renderer(Protocol):
    """A renderer backend: poses in, G-buffers out."""

    name: str
    image_size: tuple[int, int]

    def render(self, x: np.ndarray, y: np.ndarray, heading: np.ndarray, *,
               sun_direction: np.ndarray | None = None) -> GBuffer:
        """Render frames at ground positions ``x, y`` (metres) and ``heading`` (radians).

        Parameters
        ----------
        x, y, heading : ndarray, float (N,)
        sun_direction : ndarray, float (N, 3), optional
            Unit vector towards the sun per frame; rows with ``z <= 0`` (or ``None``) cast no
            shadows (visibility 1).
        """
        ...


# ---------------------------------------------------------------------------- numba kernels

@numba.njit(cache=False)
def _hash01(seed: np.int64, a: np.int64, b: np.int64) -> float:
    h = (seed * 0x27D4EB2F + a * 0x165667B1 + b * 0x9E3779B1) & 0xFFFFFFFF
    h ^= h >> 15
    h = (h * 0x2C1B3C6D) & 0xFFFFFFFF
    h ^= h >> 12
    h = (h * 0x297A2D39) & 0xFFFFFFFF
    h ^= h >> 15
    return (h & 0xFFFFFF) / 16777216.0


@numba.njit(cache=False)
def _block_exit(qx, qy, ux, uy, bx, by, block):
    """Distance along the horizontal direction ``(ux, uy)`` to leave tile ``(bx, by)``."""
    tx = np.inf
    if ux > 1e-12:
        tx = ((bx + 1) * block - qx) / ux
    elif ux < -1e-12:
        tx = (bx * block - qx) / ux
    ty = np.inf
    if uy > 1e-12:
        ty = ((by + 1) * block - qy) / uy
    elif uy < -1e-12:
        ty = (by * block - qy) / uy
    return max(min(tx, ty), 0.0) + 1e-3


@numba.njit(cache=False)
def _sun_visibility(px, py, pz, sx, sy, sz, height, canopy_lo, canopy_hi, coarse, coarse2, cell,
                    max_dist):
    """Fraction of sunlight reaching ``(px, py, pz)``: march towards the sun over the grid.

    Samples every cell; tiles whose highest point (``coarse``: 8 x 8 cells, ``coarse2``:
    64 x 64) lies below the ray are skipped whole (the ray only rises, so they cannot shadow
    the point). Canopies let half the light through per cell.
    """
    if sz <= 0.0:
        return 0.0
    hor = math.sqrt(sx * sx + sy * sy)
    if hor < 1e-6 or max_dist <= 0.0:
        return 1.0
    ux = sx / hor
    uy = sy / hor
    tan_e = sz / hor
    ny = height.shape[0]
    nx = height.shape[1]
    vis = 1.0
    z0 = pz + 0.05
    d = cell
    while d <= max_dist:
        qx = px + ux * d
        qy = py + uy * d
        qz = z0 + tan_e * d
        ix = int(math.floor(qx / cell))
        iy = int(math.floor(qy / cell))
        if ix < 0 or iy < 0 or ix >= nx or iy >= ny:
            break
        bx = ix // _COARSE2
        by = iy // _COARSE2
        if qz >= coarse2[by, bx]:
            d += _block_exit(qx, qy, ux, uy, bx, by, _COARSE2 * cell)
            continue
        bx = ix // _COARSE
        by = iy // _COARSE
        if qz >= coarse[by, bx]:
            d += _block_exit(qx, qy, ux, uy, bx, by, _COARSE * cell)
            continue
        if height[iy, ix] > qz:
            return 0.0
        if canopy_lo[iy, ix] < qz < canopy_hi[iy, ix]:
            vis *= 0.5
            if vis < 0.05:
                return 0.0
        d += cell
    return vis


@numba.njit(cache=False)
def _sprite_texel(kind, u, v, seed, r, g, b):
    """Shape test and surface of a billboard at local ``u`` in [-1, 1], ``v`` in [0, 1].

    Returns (inside, material, r, g, b, nu, nv, nf): the normal in the billboard frame
    (right, up, towards the camera).
    """
    au = abs(u)
    if kind == M.CONIFER:
        if v < 0.18 and au < 0.09:
            nu = u / 0.09
            return True, M.BARK, 0.20, 0.14, 0.09, nu, 0.0, math.sqrt(max(0.0, 1 - nu * nu))
        if v >= 0.12:
            tier = (v - 0.12) / 0.88
            saw = (tier * 6.0) % 1.0
            w = (1.0 - tier) * (0.72 + 0.28 * (1.0 - saw))
            n = _hash01(seed, int(math.floor((u + 1.0) * 8.0)), int(math.floor(v * 24.0)))
            if au < w * (0.82 + 0.3 * n):
                shade = 0.7 + 0.6 * _hash01(seed + 7, int(math.floor((u + 1.0) * 12.0)),
                                            int(math.floor(v * 36.0)))
                nf = math.sqrt(max(0.0, 1 - u * u))
                return True, M.FOLIAGE, r * shade, g * shade, b * shade, u, 0.45, nf
        return False, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if kind == M.BROADLEAF or kind == M.BUSH:
        if kind == M.BROADLEAF:
            if v < 0.42 and au < 0.1:
                nu = u / 0.1
                return True, M.BARK, 0.22, 0.17, 0.11, nu, 0.0, math.sqrt(max(0.0, 1 - nu * nu))
            cv, rv = 0.64, 0.36
        else:
            cv, rv = 0.5, 0.5
        dv = (v - cv) / rv
        rr = u * u + dv * dv
        n = _hash01(seed, int(math.floor((u + 1.0) * 6.0)), int(math.floor(v * 12.0)))
        if rr < 0.72 + 0.35 * n:
            shade = 0.7 + 0.6 * _hash01(seed + 3, int(math.floor((u + 1.0) * 10.0)),
                                        int(math.floor(v * 20.0)))
            nf = math.sqrt(max(0.0, 1 - min(rr, 1.0)))
            return True, M.FOLIAGE, r * shade, g * shade, b * shade, u, dv, nf
        return False, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if kind == M.LAMP_POLE:
        if au < 0.1:
            return True, M.POLE, r, g, b, u / 0.1, 0.0, math.sqrt(max(0.0, 1 - (u / 0.1) ** 2))
        if 0.93 < v < 0.98 and au < 0.55:
            return True, M.POLE, r * 0.6, g * 0.6, b * 0.6, 0.0, 0.3, 0.95
        return False, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if kind == M.SIGN_BOARD:
        if v >= 0.5:
            band = int(math.floor((v - 0.5) * 8.0))
            cell_u = int(math.floor((u + 1.0) * 4.0))
            inner = au < 0.8 and 0.56 < v < 0.94
            if inner and band % 2 == 1 and _hash01(seed, cell_u, band) > 0.45:
                return True, M.SIGN, 0.85, 0.85, 0.85, 0.0, 0.0, 1.0
            return True, M.SIGN, r, g, b, 0.0, 0.0, 1.0
        if abs(au - 0.6) < 0.07:
            return True, M.POLE, 0.35, 0.35, 0.36, 0.0, 0.0, 1.0
        return False, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    return False, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0


@numba.njit(cache=False)
def _bilinear(grid, gx, gy):
    """Bilinear sample of ``grid[iy, ix]`` at cell coordinates (cell centres at ``i + 0.5``)."""
    ny = grid.shape[0]
    nx = grid.shape[1]
    bx = min(max(gx - 0.5, 0.0), nx - 1.001)
    by = min(max(gy - 0.5, 0.0), ny - 1.001)
    jx = int(bx)
    jy = int(by)
    wx = bx - jx
    wy = by - jy
    return ((grid[jy, jx] * (1 - wx) + grid[jy, jx + 1] * wx) * (1 - wy)
            + (grid[jy + 1, jx] * (1 - wx) + grid[jy + 1, jx + 1] * wx) * wy)


@numba.njit(cache=False)
def _surface_texel(m, solid_wall, side, stepx, stepy, ix, iy, hc, px, py, pz, height, ground,
                   albedo, style, palette, road_lat, road_s, cell, lane):
    """Material, albedo and normal where a view ray hits cell ``(ix, iy)`` at ``(px, py, pz)``.

    Buildings and fences have vertical walls (windows and planks from the palette); the faces
    of the small steps of the terrain heightmap are shaded as the terrain (smooth normal from
    the height gradient, bilinear albedo); road markings are drawn from the road coordinates.

    Returns (material, r, g, b, nx, ny, nz).
    """
    nx = height.shape[1]
    ny = height.shape[0]
    mat = m
    if solid_wall:
        if side == 0:
            nxx, nyy, nzz = -float(stepx), 0.0, 0.0
            u = py
        else:
            nxx, nyy, nzz = 0.0, -float(stepy), 0.0
            u = px
        st = style[iy, ix]
        ar = float(palette[st, 0])
        ag = float(palette[st, 1])
        ab = float(palette[st, 2])
        spacing = palette[st, 3]
        if m == M.BUILDING:
            wz = pz - ground[iy, ix]
            top = hc - ground[iy, ix]
            fu = (u % spacing) / spacing
            fz = wz % 3.0
            if wz > 0.8 and wz < top - 0.5 and 1.0 < fz < 2.2 and 0.25 < fu < 0.75:
                ar, ag, ab = 0.05, 0.06, 0.075
                mat = M.WINDOW
        elif (u % spacing) / spacing < 0.2:
            ar, ag, ab = ar * 0.55, ag * 0.55, ab * 0.55
        return mat, ar, ag, ab, nxx, nyy, nzz
    if m == M.BUILDING or m == M.FENCE:
        return (mat, albedo[iy, ix, 0] / 255.0, albedo[iy, ix, 1] / 255.0,
                albedo[iy, ix, 2] / 255.0, 0.0, 0.0, 1.0)
    grid = height if m == M.ROCK else ground
    x0 = max(ix - 1, 0)
    x1 = min(ix + 1, nx - 1)
    y0 = max(iy - 1, 0)
    y1 = min(iy + 1, ny - 1)
    hx = (grid[iy, x1] - grid[iy, x0]) / ((x1 - x0) * cell)
    hy = (grid[y1, ix] - grid[y0, ix]) / ((y1 - y0) * cell)
    ln = math.sqrt(hx * hx + hy * hy + 1.0)
    nxx, nyy, nzz = -hx / ln, -hy / ln, 1.0 / ln
    if m == M.ROCK:
        return (mat, albedo[iy, ix, 0] / 255.0, albedo[iy, ix, 1] / 255.0,
                albedo[iy, ix, 2] / 255.0, nxx, nyy, nzz)
    gx = px / cell
    gy = py / cell
    ar = _bilinear(albedo[:, :, 0], gx, gy) / 255.0
    ag = _bilinear(albedo[:, :, 1], gx, gy) / 255.0
    ab = _bilinear(albedo[:, :, 2], gx, gy) / 255.0
    if m == M.ROAD:
        lat = abs(_bilinear(road_lat, gx, gy))
        along = _bilinear(road_s, gx, gy)
        if (lat < 0.08 and along % 10.0 < 4.0) or abs(lat - (lane - 0.25)) < 0.08:
            mat = M.MARKING
            ar, ag, ab = 0.70, 0.68, 0.60
    return mat, ar, ag, ab, nxx, nyy, nzz


@numba.njit(cache=False)
def _column_ray(c, width, focal, fx, fy, rx, ry):
    """Horizontal direction of the view rays of image column ``c`` (of ``width``).

    ``(fx, fy)`` and ``(rx, ry)`` are the camera's unit forward and right vectors. Returns
    (xc, dx, dy): ``xc`` the column's offset from the image centre in focal lengths, and
    ``(dx, dy) = forward + xc * right``, the ray per metre of forward distance.
    """
    xc = (c + 0.5 - 0.5 * width) / focal
    return xc, fx + xc * rx, fy + xc * ry


@numba.njit(cache=False)
def _dda_axis(g, i, d, cell):
    """Grid-walk set-up along one axis for a ray at cell coordinate ``g`` (in cell ``i``) with
    direction component ``d``.

    Returns (step, t_delta, t_max): the cell step (-1, 0 or 1), the forward distance between
    two cell borders, and the distance to the first one (``inf`` for a ray along the border).
    """
    if d > 0:
        t_delta = cell / d
        return 1, t_delta, (i + 1 - g) * t_delta
    if d < 0:
        t_delta = -cell / d
        return -1, t_delta, (g - i) * t_delta
    return 0, np.inf, np.inf


@numba.njit(cache=False)
def _cell_top_row(hc, cz, z_enter, z_exit, focal, horizon):
    """Topmost image row (clipped at 0) covered by a cell of top ``hc`` that the column's ray
    crosses between forward distances ``z_enter`` and ``z_exit``, seen from height ``cz``."""
    if hc >= cz:
        r_top = horizon - focal * (hc - cz) / z_enter
    else:
        r_top = horizon - focal * (hc - cz) / z_exit
    return max(int(math.ceil(r_top - 0.5)), 0)


@numba.njit(cache=False)
def _cell_hit(k, cz, hc, z_enter, z_exit):
    """Where the view ray of slope ``k`` (rise per metre forward) from height ``cz`` meets a cell
    of top ``hc`` that it crosses between forward distances ``z_enter`` and ``z_exit``.

    Returns (wall, zf, pz): whether it hits the cell's wall (at ``z_enter``) rather than its top,
    the forward distance and the height of the hit point.
    """
    wall = cz + k * z_enter <= hc or k >= 0.0
    if wall:
        zf = z_enter
    else:
        zf = (hc - cz) / k
        zf = min(max(zf, z_enter), z_exit)
    pz = hc if not wall else cz + k * zf
    return wall, zf, pz


@numba.njit(cache=False)
def _march_column(n, c, xc, dx, dy, cx, cy, cz, sx, sy, sz, height, ground, material, albedo,
                  style, palette, canopy_lo, canopy_hi, coarse, coarse2, road_lat, road_s, puddle,
                  lane, cell, focal, horizon, max_dist, shadow_dist, out_albedo, out_normal,
                  out_depth, out_mat, out_vis, out_view, out_puddle):
    """Column ``c`` of frame ``n``: a front-to-back DDA over the grid (``height`` etc.,
    (ny, nx)) from the camera ``(cx, cy, cz)`` along ``(dx, dy)`` (see :func:`_column_ray`),
    filling rows bottom-up with the wall or top of each cell that rises above the rows filled
    so far, until the image top or ``max_dist``. Writes the outputs ``out_*`` (N, H, W[, 3]).

    Returns the topmost filled row (``H`` when none): the rows above it see the sky.
    """
    ny = height.shape[0]
    nx = height.shape[1]
    gx = cx / cell
    gy = cy / cell
    ix = int(math.floor(gx))
    iy = int(math.floor(gy))
    stepx, tdx, tmx = _dda_axis(gx, ix, dx, cell)
    stepy, tdy, tmy = _dda_axis(gy, iy, dy, cell)
    z_enter = 0.0
    side = 0
    ymin = out_depth.shape[1]
    while ymin > 0:
        if ix < 0 or iy < 0 or ix >= nx or iy >= ny or z_enter > max_dist:
            break
        z_exit = min(tmx, tmy)
        hc = height[iy, ix]
        rs = _cell_top_row(hc, cz, z_enter, z_exit, focal, horizon) if z_enter > 1e-3 else ymin
        if rs < ymin:
            m = material[iy, ix]
            solid = m == M.BUILDING or m == M.FENCE
            for r in range(rs, ymin):
                k = (horizon - (r + 0.5)) / focal
                wall, zf, pz = _cell_hit(k, cz, hc, z_enter, z_exit)
                px = cx + zf * dx
                py = cy + zf * dy
                norm = math.sqrt(1.0 + xc * xc + k * k)
                out_depth[n, r, c] = zf * norm
                out_view[n, r, c, 0] = dx / norm
                out_view[n, r, c, 1] = dy / norm
                out_view[n, r, c, 2] = k / norm
                mat, ar, ag, ab, nxx, nyy, nzz = _surface_texel(
                    m, wall and solid, side, stepx, stepy, ix, iy, hc, px, py, pz,
                    height, ground, albedo, style, palette, road_lat, road_s, cell, lane)
                out_albedo[n, r, c, 0] = ar
                out_albedo[n, r, c, 1] = ag
                out_albedo[n, r, c, 2] = ab
                out_normal[n, r, c, 0] = nxx
                out_normal[n, r, c, 1] = nyy
                out_normal[n, r, c, 2] = nzz
                out_mat[n, r, c] = mat
                if m == M.ROAD or m == M.GRAVEL:
                    out_puddle[n, r, c] = _bilinear(puddle, px / cell, py / cell) / 255.0
                vis = 1.0
                if sz > 0.0:
                    if nxx * sx + nyy * sy + nzz * sz <= 0.0:
                        vis = 0.0
                    else:
                        vis = _sun_visibility(px + 0.02 * nxx, py + 0.02 * nyy, pz, sx, sy, sz,
                                              height, canopy_lo, canopy_hi, coarse, coarse2, cell,
                                              shadow_dist)
                out_vis[n, r, c] = vis
            ymin = rs
        if tmx < tmy:
            z_enter = tmx
            tmx += tdx
            ix += stepx
            side = 0
        else:
            z_enter = tmy
            tmy += tdy
            iy += stepy
            side = 1
    return ymin


@numba.njit(cache=False)
def _fill_sky_column(n, c, ymin, xc, dx, dy, skyline, focal, horizon, out_albedo, out_normal,
                     out_depth, out_mat, out_vis, out_view):
    """Rows ``0 .. ymin - 1`` of column ``c`` of frame ``n``: the far skyline (``skyline``,
    (B,): elevation, radians, per azimuth bin) where the ray passes below it, else the sky.

    Writes the G-buffer outputs (``out_*``, (N, H, W[, 3])) of those pixels.
    """
    n_sky = skyline.shape[0]
    az = math.atan2(dy, dx)
    if az < 0:
        az += 2 * math.pi
    b = int(az / (2 * math.pi) * n_sky) % n_sky
    for r in range(ymin):
        k = (horizon - (r + 0.5)) / focal
        norm = math.sqrt(1.0 + xc * xc + k * k)
        out_view[n, r, c, 0] = dx / norm
        out_view[n, r, c, 1] = dy / norm
        out_view[n, r, c, 2] = k / norm
        elevation = math.atan2(k, math.sqrt(1.0 + xc * xc))
        out_vis[n, r, c] = 1.0
        if elevation < skyline[b]:
            out_depth[n, r, c] = FAR_DISTANCE_M
            out_mat[n, r, c] = M.FAR
            out_albedo[n, r, c, 0] = 0.22
            out_albedo[n, r, c, 1] = 0.25
            out_albedo[n, r, c, 2] = 0.28
            hn = math.sqrt(dx * dx + dy * dy)
            out_normal[n, r, c, 0] = -dx / hn * 0.6
            out_normal[n, r, c, 1] = -dy / hn * 0.6
            out_normal[n, r, c, 2] = 0.8
        else:
            out_depth[n, r, c] = np.inf
            out_mat[n, r, c] = M.SKY
            for j in range(3):
                out_albedo[n, r, c, j] = 0.0
                out_normal[n, r, c, j] = 0.0


@numba.njit(cache=False)
def _billboard_box(x, y, base, tall, radius, cx, cy, cz, fx, fy, rx, ry, width, height, focal,
                   horizon, max_dist):
    """Screen placement of a billboard standing at ``(x, y, base)``, ``tall`` high and
    ``2 * radius`` wide, in a ``height x width`` image.

    Returns (visible, zf, colc, halfw, rowb, rowt): whether any of it is in view, its forward
    distance, centre column and half width, and its bottom and top rows (fractional pixels).
    """
    ddx = x - cx
    ddy = y - cy
    zf = ddx * fx + ddy * fy
    if zf < 0.5 or zf > max_dist:
        return False, zf, 0.0, 0.0, 0.0, 0.0
    lat = ddx * rx + ddy * ry
    colc = 0.5 * width + focal * lat / zf
    halfw = focal * radius / zf
    rowb = horizon - focal * (base - cz) / zf
    rowt = horizon - focal * (base + tall - cz) / zf
    visible = not (colc + halfw < 0.0 or colc - halfw > width or rowb < 0.0 or rowt > height)
    return visible, zf, colc, halfw, rowb, rowt


@numba.njit(cache=False)
def _draw_billboards(n, cx, cy, cz, fx, fy, rx, ry, sx, sy, sz, sprites, height, canopy_lo,
                     canopy_hi, coarse, coarse2, cell, focal, horizon, max_dist, shadow_dist,
                     out_albedo, out_normal, out_depth, out_mat, out_vis, out_puddle):
    """Billboards (``sprites``, (S, 10), columns
    :data:`~cmal_lcd.data.world.materials.SPRITE_FIELDS`) of frame ``n`` seen from
    ``(cx, cy, cz)`` (forward ``(fx, fy)``, right ``(rx, ry)``), drawn where nearer than
    ``out_depth`` (N, H, W). Writes the outputs ``out_*`` (N, H, W[, 3])."""
    H = out_depth.shape[1]
    W = out_depth.shape[2]
    for si in range(sprites.shape[0]):
        visible, zf, colc, halfw, rowb, rowt = _billboard_box(
            sprites[si, 0], sprites[si, 1], sprites[si, 2], sprites[si, 3], sprites[si, 4], cx, cy,
            cz, fx, fy, rx, ry, W, H, focal, horizon, max_dist)
        if not visible:
            continue
        kind = int(sprites[si, 5])
        seed = np.int64(sprites[si, 9])
        c0 = max(0, int(math.ceil(colc - halfw - 0.5)))
        c1 = min(W - 1, int(math.floor(colc + halfw - 0.5)))
        r0 = max(0, int(math.ceil(rowt - 0.5)))
        r1 = min(H - 1, int(math.floor(rowb - 0.5)))
        for r in range(r0, r1 + 1):
            v = (rowb - (r + 0.5)) / (rowb - rowt)
            k = (horizon - (r + 0.5)) / focal
            for c in range(c0, c1 + 1):
                xc = (c + 0.5 - 0.5 * W) / focal
                depth = zf * math.sqrt(1.0 + xc * xc + k * k)
                if depth >= out_depth[n, r, c]:
                    continue
                u = (c + 0.5 - colc) / halfw
                inside, mat, ar, ag, ab, nu, nv, nf = _sprite_texel(
                    kind, u, v, seed, sprites[si, 6], sprites[si, 7], sprites[si, 8])
                if not inside:
                    continue
                ln = math.sqrt(nu * nu + nv * nv + nf * nf)
                nxx = (nu * rx - nf * fx) / ln
                nyy = (nu * ry - nf * fy) / ln
                nzz = nv / ln
                out_depth[n, r, c] = depth
                out_mat[n, r, c] = mat
                out_puddle[n, r, c] = 0.0
                out_albedo[n, r, c, 0] = ar
                out_albedo[n, r, c, 1] = ag
                out_albedo[n, r, c, 2] = ab
                out_normal[n, r, c, 0] = nxx
                out_normal[n, r, c, 1] = nyy
                out_normal[n, r, c, 2] = nzz
                vis = 1.0
                if sz > 0.0:
                    px = cx + zf * (fx + xc * rx)
                    py = cy + zf * (fy + xc * ry)
                    pz = cz + k * zf
                    # foliage is lit through its own leaves: wrap the normal term
                    if nxx * sx + nyy * sy + nzz * sz <= -0.3:
                        vis = 0.0
                    else:
                        vis = _sun_visibility(px, py, pz, sx, sy, sz, height, canopy_lo,
                                              canopy_hi, coarse, coarse2, cell, shadow_dist)
                out_vis[n, r, c] = vis


@numba.njit(cache=False)
def _render_frame(n, cam, sun, height, ground, material, albedo, style, palette, canopy_lo,
                  canopy_hi, coarse, coarse2, sprites, skyline, road_lat, road_s, puddle, lane,
                  cell, focal, horizon, max_dist, shadow_dist, out_albedo, out_normal, out_depth,
                  out_mat, out_vis, out_view, out_puddle):
    """Frame ``n``: per column a front-to-back DDA over the grid filling rows bottom-up (walls
    and tops of cells), the sky and far skyline above, then the billboards, depth-tested.

    ``cam`` (N, 4): camera ``x, y, z, heading``; ``sun`` (N, 3): unit vector towards the sun;
    the outputs ``out_*`` are (N, H, W[, 3]) (see :class:`GBuffer`).
    """
    W = out_depth.shape[2]
    cx = cam[n, 0]
    cy = cam[n, 1]
    cz = cam[n, 2]
    hd = cam[n, 3]
    sx = sun[n, 0]
    sy = sun[n, 1]
    sz = sun[n, 2]
    fx = math.cos(hd)
    fy = math.sin(hd)
    rx = math.sin(hd)
    ry = -math.cos(hd)
    for c in range(W):
        xc, dx, dy = _column_ray(c, W, focal, fx, fy, rx, ry)
        ymin = _march_column(n, c, xc, dx, dy, cx, cy, cz, sx, sy, sz, height, ground, material,
                             albedo, style, palette, canopy_lo, canopy_hi, coarse, coarse2,
                             road_lat, road_s, puddle, lane, cell, focal, horizon, max_dist,
                             shadow_dist, out_albedo, out_normal, out_depth, out_mat, out_vis,
                             out_view, out_puddle)
        _fill_sky_column(n, c, ymin, xc, dx, dy, skyline, focal, horizon, out_albedo, out_normal,
                         out_depth, out_mat, out_vis, out_view)
    _draw_billboards(n, cx, cy, cz, fx, fy, rx, ry, sx, sy, sz, sprites, height, canopy_lo,
                     canopy_hi, coarse, coarse2, cell, focal, horizon, max_dist, shadow_dist,
                     out_albedo, out_normal, out_depth, out_mat, out_vis, out_puddle)


@numba.njit(nogil=True, cache=False)
def _render_batch(start, stop, cam, sun, height, ground, material, albedo, style, palette,
                  canopy_lo, canopy_hi, coarse, coarse2, sprites, skyline, road_lat, road_s,
                  puddle, lane, cell, focal, horizon, max_dist, shadow_dist, out_albedo,
                  out_normal, out_depth, out_mat, out_vis, out_view, out_puddle):
    """Render frames ``start .. stop - 1`` (see :func:`_render_frame`)."""
    for n in range(start, stop):
        _render_frame(n, cam, sun, height, ground, material, albedo, style, palette, canopy_lo,
                      canopy_hi, coarse, coarse2, sprites, skyline, road_lat, road_s, puddle, lane,
                      cell, focal, horizon, max_dist, shadow_dist, out_albedo, out_normal,
                      out_depth, out_mat, out_vis, out_view, out_puddle)


def coarse_max_height(world: World, block: int) -> np.ndarray:
    """Highest surface or canopy top in each ``block x block`` tile, float32 (n/block, n/block)."""
    top = np.maximum(world.height, world.canopy_hi)
    n = top.shape[0]
    m = -(-n // block)
    padded = np.full((m * block, m * block), -np.inf, np.float32)
    padded[:n, :n] = top
    return padded.reshape(m, block, m, block).max(axis=(1, 3))


class HeightmapRenderer:
    """The numba heightmap ray-caster (see the module docstring).

    Parameters
    ----------
    world : World
    camera : CameraSpec
        Mounting height, field of view, pitch, draw and shadow distances.
    image_size : (int, int)
        ``(H, W)`` of the G-buffer.
    """

    name = "heightmap"

    def __init__(self, world: World, camera: CameraSpec, *, image_size: tuple[int, int]):
        height, width = (int(v) for v in image_size)
        if height < 1 or width < 1:
            raise ValueError(f"image_size: expected positive (H, W), got {image_size}")
        self.world = world
        self.camera = camera
        self.image_size = (height, width)
        self.focal = 0.5 * width / math.tan(math.radians(camera.hfov_deg) / 2)
        self.horizon = 0.5 * height + self.focal * math.tan(math.radians(camera.pitch_deg))
        self._coarse = coarse_max_height(world, _COARSE)
        self._coarse2 = coarse_max_height(world, _COARSE2)

    def camera_poses(self, x: np.ndarray, y: np.ndarray, heading: np.ndarray) -> np.ndarray:
        """``(x, y, z, heading)`` per frame, float64 (N, 4); ``z`` = ground + camera height."""
        x = np.asarray(x, np.float64).reshape(-1)
        y = np.asarray(y, np.float64).reshape(-1)
        heading = np.asarray(heading, np.float64).reshape(-1)
        if not (len(x) == len(y) == len(heading)):
            raise ValueError(f"x, y, heading: lengths differ ({len(x)}, {len(y)}, {len(heading)})")
        z = self.world.ground_height(x, y) + self.camera.height_m
        return np.stack([x, y, z, heading], axis=1)

    def render(self, x: np.ndarray, y: np.ndarray, heading: np.ndarray, *,
               sun_direction: np.ndarray | None = None) -> GBuffer:
        """See :meth:`Renderer.render`."""
        cam = self.camera_poses(x, y, heading)
        n = len(cam)
        if sun_direction is None:
            sun = np.zeros((n, 3), np.float64)
        else:
            sun = np.asarray(sun_direction, np.float64).reshape(n, 3)
        h, w = self.image_size
        out = GBuffer(albedo=np.zeros((n, h, w, 3), np.float32),
                      normal=np.zeros((n, h, w, 3), np.float32),
                      depth=np.full((n, h, w), np.inf, np.float32),
                      material=np.zeros((n, h, w), np.uint8),
                      sun_visibility=np.ones((n, h, w), np.float32),
                      view=np.zeros((n, h, w, 3), np.float32),
                      puddle=np.zeros((n, h, w), np.float32), horizon=float(self.horizon))
        world = self.world
        if n:
            run_frame_chunks(
                _render_batch, n, cam, sun, world.height, world.ground, world.material,
                world.albedo, world.style, world.palette, world.canopy_lo, world.canopy_hi,
                self._coarse, self._coarse2, world.sprites, world.skyline, world.road_lateral,
                world.road_s, world.puddle, float(world.spec.lane_width_m), float(world.cell_m),
                float(self.focal), float(self.horizon), float(self.camera.max_distance_m),
                float(self.camera.shadow_distance_m), out.albedo, out.normal, out.depth,
                out.material, out.sun_visibility, out.view, out.puddle)
        return out


#: Renderer backends by name: ``factory(world, camera, *, image_size) -> Renderer``.
RENDERERS: dict[str, Callable[..., Renderer]] = {"heightmap": HeightmapRenderer}


def make_renderer(name: str, world: World, camera: CameraSpec, *,
                  image_size: tuple[int, int]) -> Renderer:
    """Build the renderer backend ``name`` (see :data:`RENDERERS`)."""
    if name not in RENDERERS:
        raise ValueError(f"name: unknown renderer {name!r}; known: {sorted(RENDERERS)}")
    return RENDERERS[name](world, camera, image_size=image_size)

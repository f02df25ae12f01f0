"""Weather: per-frame parameter draws and the physical image model applied to a G-buffer.

The model, in linear light, per pixel with albedo ``rho``, normal ``n``, sun direction ``l``,
sun visibility ``v`` and range ``d``:

1. surfaces: wetness ``w`` darkens (``rho (1 - 0.6 w)``), water in the road's hollows darkens
   further, snow covers upward-facing ground;
2. light: ``J = rho (E_sun max(n.l, 0) v + E_amb (0.6 + 0.4 n_z))`` (direct sun with cast
   shadows, hemisphere sky light); the sky is a horizon-to-zenith gradient with the sun's disc
   and glow;
3. atmosphere (Koschmieder): ``I = J t + A (1 - t)``, ``t = exp(-beta d)``; the sky is treated
   as lying at the draw distance, so dense fog turns it into airlight. Wet level ground then
   mirrors the scene (screen space, about the horizon row) with Schlick's Fresnel reflectance
   (``F0 = 0.02``), strongest in puddles;
4. camera: exposure, gamma 2.2, contrast and saturation, rain streaks (unfogged, near the
   lens), water drops on the lens (each a tiny inverting lens), lens blur, box down-sampling
   of the super-sampled image, sensor noise, 8-bit rounding.

Every scalar is drawn per frame from the condition's range (:mod:`.condition`), so a condition
is a distribution of appearances. Draws are deterministic given the generator.
"""

from __future__ import annotations

from dataclasses import dataclass

import math

import numba
import numpy as np
from scipy import ndimage

from cmal_lcd.data.world import materials as M
from cmal_lcd.data.world.condition import COLOR_PARAMS, RANGE_PARAMS, ConditionParams
from cmal_lcd.data.world.noise import smooth_wander
from cmal_lcd.data.world.render import GBuffer
from cmal_lcd.data.world.threads import run_frame_chunks

#: Parameters that stay fixed within a drive (the sun does not move in a minute).
FIXED_WITHIN_DRIVE = ("sun_elevation_deg", "sun_azimuth_deg")


@dataclass(frozen=True)
class WeatherParams:
    """Weather of a batch of frames under one condition.

    Attributes
    ----------
    condition : str
    values : dict of str -> ndarray, float64 (N,)
        One value per frame for every name in :data:`~.condition.RANGE_PARAMS`.
    colors : dict of str -> ndarray, float64 (3,)
        The condition's colours.
    noise_seed : ndarray, uint64 (N,)
        Seeds of each frame's rain streaks and sensor noise.
    """

    condition: str
    values: dict[str, np.ndarray]
    colors: dict[str, np.ndarray]
    noise_seed: np.ndarray

    def __len__(self) -> int:
        return len(self.noise_seed)

    def subset(self, index: np.ndarray | slice) -> "WeatherParams":
        """The frames ``index`` of this batch."""
        return WeatherParams(self.condition, {k: v[index] for k, v in self.values.items()},
                             self.colors, self.noise_seed[index])

    def sun_direction(self) -> np.ndarray:
        """Unit vector towards the sun per frame, float64 (N, 3); zero where there is no
        direct sun (``sun_intensity == 0`` or the sun below the horizon)."""
        el = np.deg2rad(self.values["sun_elevation_deg"])
        az = np.deg2rad(self.values["sun_azimuth_deg"])
        sun = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
        off = (self.values["sun_intensity"] <= 0) | (el <= 0)
        sun[off] = 0.0
        return sun


def _colors(condition: ConditionParams) -> dict[str, np.ndarray]:
    return {k: np.asarray(v, np.float64) for k, v in condition.colors.items()}


def sample_frame_weather(condition: ConditionParams, rngs: list[np.random.Generator]
                         ) -> WeatherParams:
    """Independent weather per frame (training frames): every scalar uniform in its range.

    Parameters
    ----------
    condition : ConditionParams
    rngs : list of numpy.random.Generator
        One generator per frame (its own stream, so frames are independent of batch size).

    Returns
    -------
    WeatherParams
        ``N = len(rngs)`` frames.
    """
    names = list(RANGE_PARAMS)
    draws = np.array([rng.uniform(size=len(names) + 1) for rng in rngs]).reshape(len(rngs), -1)
    values = {}
    for j, name in enumerate(names):
        lo, hi = condition.ranges[name]
        values[name] = lo + (hi - lo) * draws[:, j]
    seeds = np.floor(draws[:, -1] * 2.0 ** 63).astype(np.uint64)
    return WeatherParams(condition.name, values, _colors(condition), seeds)


def sample_drive_weather(condition: ConditionParams, *, n: int, rng: np.random.Generator,
                         jitter: float, period_frames: tuple[float, float] = (40.0, 200.0)
                         ) -> WeatherParams:
    """Weather of a drive: one draw per drive, drifting smoothly by ``jitter`` of each range.

    The sun (:data:`FIXED_WITHIN_DRIVE`) stays fixed within the drive.

    Parameters
    ----------
    condition : ConditionParams
    n : int
        Frames in the drive.
    rng : numpy.random.Generator
        The drive's weather stream.
    jitter : float
        Drift amplitude as a fraction of each range (0 = constant weather in the drive).

    Returns
    -------
    WeatherParams
    """
    values = {}
    for name in RANGE_PARAMS:
        lo, hi = condition.ranges[name]
        base = rng.uniform()
        drift = smooth_wander(n, rng=rng, period_frames=period_frames)
        amount = 0.0 if name in FIXED_WITHIN_DRIVE else jitter
        values[name] = lo + (hi - lo) * np.clip(base + amount * drift, 0.0, 1.0)
    seeds = rng.integers(0, 2 ** 63, size=n, dtype=np.uint64)
    return WeatherParams(condition.name, values, _colors(condition), seeds)


#: Order of the scalar parameters in the kernels' per-frame rows.
_P = {name: i for i, name in enumerate(RANGE_PARAMS)}
#: Order of the colours in the kernels' colour table.
_C = {name: i for i, name in enumerate(COLOR_PARAMS)}
_SUN_I, _AMB, _SKY_B = _P["sun_intensity"], _P["ambient"], _P["sky_brightness"]
_BETA = _P["fog_beta"]
_AIR, _WET, _SNOW, _EXPO = _P["airlight"], _P["wetness"], _P["snow_cover"], _P["exposure"]
_PUDDLES = _P["puddles"]
_CONTRAST, _SAT = _P["contrast"], _P["saturation"]
_ZENITH, _HORIZON, _SUN_C = _C["sky_zenith"], _C["sky_horizon"], _C["sun_color"]
_AMB_C, _AIR_C = _C["ambient_color"], _C["airlight_color"]


@numba.njit(cache=False)
def _shade_frame(n, albedo, normal, depth, mat, vis, view, puddle, horizon, params, colors, sun,
                 wet_gain, sky_distance, out):
    """Linear radiance of frame ``n`` (steps 1-3 of the module docstring) into ``out[n]``."""
    h, w = depth.shape[1], depth.shape[2]
    p = params[n]
    sx, sy, sz = sun[n, 0], sun[n, 1], sun[n, 2]
    has_sun = sz > 0.0
    beta = p[_BETA]
    reflectance = np.zeros((h, w))
    for r in range(h):
        for c in range(w):
            m = mat[n, r, c]
            vx, vy, vz = view[n, r, c, 0], view[n, r, c, 1], view[n, r, c, 2]
            if m == M.SKY:
                up = math.sqrt(min(max(vz, 0.0), 1.0))
                glow = 0.0
                if has_sun:
                    cs = vx * sx + vy * sy + vz * sz
                    glow = p[_SUN_I] * (0.08 * math.exp((cs - 1.0) * 25.0)
                                        + (2.0 if cs > 0.9997 else 0.0))
                for j in range(3):
                    rad = (colors[_HORIZON, j] * (1.0 - up) + colors[_ZENITH, j] * up) * p[_SKY_B]
                    rad += glow * colors[_SUN_C, j]
                    t = math.exp(-beta * sky_distance)
                    out[n, r, c, j] = rad * t + p[_AIR] * colors[_AIR_C, j] * (1.0 - t)
                continue
            nx, ny, nz = normal[n, r, c, 0], normal[n, r, c, 1], normal[n, r, c, 2]
            snow = 0.0
            if p[_SNOW] > 0.0 and m != M.FAR and m != M.WINDOW:
                e = min(max((nz - 0.6) / 0.3, 0.0), 1.0)
                snow = p[_SNOW] * e * e * (3.0 - 2.0 * e)
            wet = p[_WET] * wet_gain[m]
            ndotl = 0.0
            if has_sun:
                ndotl = nx * sx + ny * sy + nz * sz
                if m == M.FOLIAGE:
                    ndotl = (ndotl + 0.3) / 1.3  # light through leaves
                ndotl = max(ndotl, 0.0) * vis[n, r, c] * p[_SUN_I]
            hemi = p[_AMB] * (0.6 + 0.4 * nz)
            water = p[_PUDDLES] * puddle[n, r, c]
            if (wet > 0.0 or water > 0.0) and nz > 0.5:
                # wet ground and puddles are mirrors: Schlick's Fresnel term, F0 = 0.02 (water)
                cv = min(max(-(vx * nx + vy * ny + vz * nz), 0.0), 1.0)
                fresnel = 0.02 + 0.98 * (1.0 - cv) ** 5
                reflectance[r, c] = min(0.5 * wet * fresnel + water * (0.3 + 0.7 * fresnel), 0.9)
            t = math.exp(-beta * depth[n, r, c])
            for j in range(3):
                a = albedo[n, r, c, j] * (1.0 - snow) + 0.85 * snow
                a *= (1.0 - 0.6 * wet) * (1.0 - 0.8 * water)  # water darkens the surface
                rad = a * (ndotl * colors[_SUN_C, j] + hemi * colors[_AMB_C, j])
                out[n, r, c, j] = rad * t + p[_AIR] * colors[_AIR_C, j] * (1.0 - t)
    # reflections: a level wet road mirrors the scene about the horizon row (screen space,
    # exact for distant objects); above the image top it reflects the horizon sky
    frame = out[n].copy()
    for r in range(h):
        for c in range(w):
            refl = reflectance[r, c]
            if refl <= 0.0:
                continue
            rm = int(math.floor(2.0 * horizon - (r + 0.5)))
            for j in range(3):
                if 0 <= rm < h and rm < r:
                    mirrored = frame[rm, c, j]
                else:
                    mirrored = colors[_HORIZON, j] * p[_SKY_B]
                out[n, r, c, j] = out[n, r, c, j] * (1.0 - refl) + mirrored * refl


@numba.njit(nogil=True, cache=False)
def _shade_batch(start, stop, albedo, normal, depth, mat, vis, view, puddle, horizon, params,
                 colors, sun, wet_gain, sky_distance, out):
    for n in range(start, stop):
        _shade_frame(n, albedo, normal, depth, mat, vis, view, puddle, horizon, params, colors,
                     sun, wet_gain, sky_distance, out)


@numba.njit(nogil=True, cache=False)
def _tone_batch(start, stop, radiance, params, out):
    """Exposure, gamma 2.2, contrast about the frame mean, saturation; clipped to [0, 1]."""
    gamma = 1.0 / 2.2
    for n in range(start, stop):
        p = params[n]
        h, w = radiance.shape[1], radiance.shape[2]
        total = 0.0
        for r in range(h):
            for c in range(w):
                for j in range(3):
                    v = min(max(radiance[n, r, c, j] * p[_EXPO], 0.0), 1.0) ** gamma
                    out[n, r, c, j] = v
                    total += v
        mean = total / (h * w * 3)
        for r in range(h):
            for c in range(w):
                for j in range(3):
                    out[n, r, c, j] = mean + (out[n, r, c, j] - mean) * p[_CONTRAST]
                grey = 0.299 * out[n, r, c, 0] + 0.587 * out[n, r, c, 1] + 0.114 * out[n, r, c, 2]
                for j in range(3):
                    v = grey + (out[n, r, c, j] - grey) * p[_SAT]
                    out[n, r, c, j] = min(max(v, 0.0), 1.0)


def _param_table(weather: WeatherParams) -> np.ndarray:
    """Per-frame parameters as rows, float64 (N, P), columns in RANGE_PARAMS order."""
    return np.stack([np.asarray(weather.values[k], np.float64) for k in RANGE_PARAMS], axis=1)


def _color_table(weather: WeatherParams) -> np.ndarray:
    """Colours as rows, float64 (C, 3), in COLOR_PARAMS order."""
    return np.stack([np.asarray(weather.colors[k], np.float64) for k in COLOR_PARAMS])


def shade_radiance(gbuf: GBuffer, weather: WeatherParams, *, sky_distance_m: float) -> np.ndarray:
    """Scene radiance after lighting and the atmosphere (steps 1-3 of the module docstring).

    Parameters
    ----------
    gbuf : GBuffer
        ``N`` frames at the render resolution.
    weather : WeatherParams
        ``N`` frames.
    sky_distance_m : float
        Range at which the sky is fogged (the draw distance).

    Returns
    -------
    ndarray, float32 (N, H, W, 3)
        Linear radiance.
    """
    if len(gbuf) != len(weather):
        raise ValueError(f"weather: {len(weather)} frames for a G-buffer of {len(gbuf)}")
    out = np.empty(gbuf.albedo.shape, np.float32)
    if len(gbuf):
        run_frame_chunks(_shade_batch, len(gbuf), gbuf.albedo, gbuf.normal, gbuf.depth,
                         gbuf.material, gbuf.sun_visibility, gbuf.view, gbuf.puddle,
                         float(gbuf.horizon), _param_table(weather), _color_table(weather),
                         weather.sun_direction(), M.WETNESS_GAIN.astype(np.float64),
                         float(sky_distance_m), out)
    return out


@numba.njit(cache=False)
def _draw_streaks(image, streaks, color):
    """Alpha-blend line streaks ``(x0, y0, dx, dy, length, alpha)`` into ``image (H, W, 3)``."""
    h, w = image.shape[0], image.shape[1]
    for k in range(streaks.shape[0]):
        x0, y0, dx, dy, length, alpha = streaks[k]
        steps = int(length * 2.0) + 1
        for i in range(steps):
            t = i * 0.5
            x = int(x0 + dx * t)
            y = int(y0 + dy * t)
            if 0 <= x < w and 0 <= y < h:
                # fade in and out along the streak
                a = alpha * (1.0 - abs(2.0 * i / max(steps - 1, 1) - 1.0) * 0.6)
                for j in range(3):
                    image[y, x, j] = image[y, x, j] * (1.0 - a) + color[j] * a


@numba.njit(cache=False)
def _draw_drops(image, drops):
    """Water drops on the lens: each disc ``(x, y, radius)`` shows a blurred, inverted and
    magnified view of its surroundings (a drop is a small lens), with a slightly darker rim."""
    h, w = image.shape[0], image.shape[1]
    source = image.copy()
    for k in range(drops.shape[0]):
        x0, y0, radius = drops[k, 0], drops[k, 1], drops[k, 2]
        for y in range(max(0, int(y0 - radius)), min(h, int(y0 + radius) + 1)):
            for x in range(max(0, int(x0 - radius)), min(w, int(x0 + radius) + 1)):
                dx = x + 0.5 - x0
                dy = y + 0.5 - y0
                rr = (dx * dx + dy * dy) / (radius * radius)
                if rr >= 1.0:
                    continue
                # inverted image of a region 2.5 times the drop's size, averaged over 3x3 taps
                sx = x0 - 2.5 * dx
                sy = y0 - 2.5 * dy
                for j in range(3):
                    total = 0.0
                    for oy in (-1, 0, 1):
                        for ox in (-1, 0, 1):
                            ix = min(max(int(sx) + ox * 2, 0), w - 1)
                            iy = min(max(int(sy) + oy * 2, 0), h - 1)
                            total += source[iy, ix, j]
                    rim = 0.92 if rr > 0.75 else 1.0
                    image[y, x, j] = total / 9.0 * rim


def drop_table(rng: np.random.Generator, *, density: float, radius_px: float,
               out_size: tuple[int, int], scale: int) -> np.ndarray:
    """Random lens drops of one frame, in render pixels.

    Returns
    -------
    ndarray, float64 (K, 3)
        ``x, y, radius`` per drop.
    """
    h, w = out_size
    count = int(rng.poisson(density * h * w / 1000.0)) if radius_px > 0 else 0
    table = np.empty((count, 3))
    table[:, 0] = rng.uniform(0, w * scale, size=count)
    table[:, 1] = rng.uniform(0, h * scale, size=count)
    table[:, 2] = radius_px * scale * rng.uniform(0.5, 1.0, size=count)
    return table


def streak_table(rng: np.random.Generator, *, density: float, length_px: float, alpha: float,
                 angle_deg: float, out_size: tuple[int, int], scale: int) -> np.ndarray:
    """Random rain streaks of one frame, in render pixels.

    Returns
    -------
    ndarray, float64 (K, 6)
        ``x0, y0, dx, dy, length, alpha`` per streak (``dx, dy`` unit direction).
    """
    h, w = out_size
    count = int(rng.poisson(density * h * w / 1000.0)) if alpha > 0 else 0
    angle = np.deg2rad(angle_deg + rng.normal(0.0, 3.0, size=count))
    length = length_px * rng.uniform(0.6, 1.4, size=count) * scale
    table = np.empty((count, 6))
    table[:, 0] = rng.uniform(0, w * scale, size=count)
    table[:, 1] = rng.uniform(-length, h * scale, size=count)
    table[:, 2] = np.sin(angle)
    table[:, 3] = np.cos(angle)
    table[:, 4] = length
    table[:, 5] = alpha * rng.uniform(0.5, 1.0, size=count)
    return table


def camera_image(radiance: np.ndarray, weather: WeatherParams, *, supersample: int
                 ) -> np.ndarray:
    """Camera response of linear radiance (step 4 of the module docstring).

    Parameters
    ----------
    radiance : ndarray, float32 (N, H * supersample, W * supersample, 3)
    weather : WeatherParams
    supersample : int

    Returns
    -------
    ndarray, uint8 (N, H, W, 3)
    """
    n, hs, ws, _ = radiance.shape
    s = int(supersample)
    if hs % s or ws % s:
        raise ValueError(f"supersample: {s} does not divide the render size {(hs, ws)}")
    h, w = hs // s, ws // s
    p = weather.values
    image = np.empty_like(radiance)
    if n:
        run_frame_chunks(_tone_batch, n, radiance, _param_table(weather), image)
    rain_color = np.clip(weather.colors["rain_color"], 0, 1) ** (1 / 2.2)
    out = np.empty((n, h, w, 3), np.float32)
    for i in range(n):
        rng = np.random.default_rng(int(weather.noise_seed[i]))
        frame = np.ascontiguousarray(image[i])
        streaks = streak_table(rng, density=p["rain_density"][i], length_px=p["rain_length_px"][i],
                               alpha=p["rain_alpha"][i], angle_deg=p["rain_angle_deg"][i],
                               out_size=(h, w), scale=s)
        if len(streaks):
            _draw_streaks(frame, streaks, rain_color)
        drops = drop_table(rng, density=p["drop_density"][i], radius_px=p["drop_radius_px"][i],
                           out_size=(h, w), scale=s)
        if len(drops):
            _draw_drops(frame, drops)
        sigma = p["blur_px"][i] * s
        if sigma > 0:
            frame = ndimage.gaussian_filter(frame, sigma=(sigma, sigma, 0), mode="nearest")
        small = frame.reshape(h, s, w, s, 3).mean(axis=(1, 3))
        small = small + rng.normal(0.0, p["noise_std"][i], size=small.shape)
        out[i] = small
    return np.clip(np.round(out * 255.0), 0, 255).astype(np.uint8)


def apply_weather(gbuf: GBuffer, weather: WeatherParams, *, supersample: int,
                  sky_distance_m: float) -> np.ndarray:
    """G-buffer (at ``supersample`` times the output size) to 8-bit RGB frames.

    Returns
    -------
    ndarray, uint8 (N, H, W, 3)
    """
    radiance = shade_radiance(gbuf, weather, sky_distance_m=sky_distance_m)
    return camera_image(radiance, weather, supersample=supersample)

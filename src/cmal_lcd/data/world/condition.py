"""A weather condition as configuration: ranges that each frame's parameters are drawn from.

A condition file (``conf/condition/<name>.yaml``) sets some of the fields below; the others
keep the neutral defaults given here. Scalar parameters are ranges ``[low, high]`` (a frame
draws a value in the range, so a condition is a distribution of appearances, not one fixed
transform); colours are linear RGB triples. The physical model that uses them is in
:mod:`cmal_lcd.data.world.weather`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

#: Scalar parameters (ranges): name -> (default range, allowed minimum, allowed maximum, doc).
RANGE_PARAMS: dict[str, tuple[tuple[float, float], float, float, str]] = {
    "sun_elevation_deg": ((35.0, 55.0), -90.0, 90.0, "sun elevation above the horizon"),
    "sun_azimuth_deg": ((0.0, 360.0), -720.0, 720.0, "sun azimuth, counter-clockwise from +x"),
    "sun_intensity": ((0.0, 0.0), 0.0, math.inf, "direct sunlight (0 = overcast)"),
    "ambient": ((1.0, 1.0), 0.0, math.inf, "sky (hemisphere) light"),
    "sky_brightness": ((1.0, 1.0), 0.0, math.inf, "multiplier on the sky colours"),
    "fog_beta": ((0.001, 0.001), 0.0, math.inf, "Koschmieder extinction coefficient, 1/m"),
    "airlight": ((0.8, 0.8), 0.0, math.inf, "airlight A brightness (times airlight_color)"),
    "wetness": ((0.0, 0.0), 0.0, 1.0, "wet surfaces: darker albedo, sky reflections"),
    "puddles": ((0.0, 0.0), 0.0, 1.0, "water in the road's hollows: mirror-like reflections"),
    "rain_density": ((0.0, 0.0), 0.0, math.inf, "rain streaks per 1000 output pixels"),
    "rain_length_px": ((6.0, 10.0), 0.0, math.inf, "streak length, output pixels"),
    "rain_alpha": ((0.0, 0.0), 0.0, 1.0, "streak opacity"),
    "rain_angle_deg": ((-10.0, 10.0), -80.0, 80.0, "streak slant from vertical"),
    "drop_density": ((0.0, 0.0), 0.0, math.inf, "water drops on the lens per 1000 output pixels"),
    "drop_radius_px": ((2.0, 4.0), 0.0, math.inf, "largest drop radius, output pixels"),
    "snow_cover": ((0.0, 0.0), 0.0, 1.0, "snow on upward-facing ground"),
    "exposure": ((1.0, 1.0), 0.0, math.inf, "camera exposure multiplier"),
    "contrast": ((1.0, 1.0), 0.0, math.inf, "contrast about the image mean"),
    "saturation": ((1.0, 1.0), 0.0, math.inf, "colour saturation"),
    "blur_px": ((0.0, 0.0), 0.0, 8.0, "Gaussian blur sigma, output pixels (rain on the lens)"),
    "noise_std": ((0.005, 0.005), 0.0, 1.0, "sensor noise std (0..1 intensity)"),
}

#: Colour parameters (linear RGB): name -> (default, doc).
COLOR_PARAMS: dict[str, tuple[tuple[float, float, float], str]] = {
    "sky_zenith": ((0.35, 0.45, 0.65), "sky colour overhead"),
    "sky_horizon": ((0.70, 0.75, 0.82), "sky colour at the horizon"),
    "sun_color": ((1.0, 0.95, 0.85), "direct light colour"),
    "ambient_color": ((0.55, 0.60, 0.70), "sky light colour"),
    "airlight_color": ((0.85, 0.88, 0.92), "fog/haze colour"),
    "rain_color": ((0.80, 0.82, 0.85), "rain streak colour"),
}


@dataclass(frozen=True)
class ConditionParams:
    """One weather condition: ranges per scalar parameter and fixed colours.

    Attributes
    ----------
    name : str
        Condition name (the key under ``data.conditions``).
    ranges : dict of str -> (float, float)
        ``[low, high]`` of every name in :data:`RANGE_PARAMS`.
    colors : dict of str -> (float, float, float)
        Linear RGB of every name in :data:`COLOR_PARAMS`.
    """

    name: str
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)
    colors: dict[str, tuple[float, float, float]] = field(default_factory=dict)

    @classmethod
    def from_config(cls, name: str, conf: Mapping[str, Any] | None, *,
                    where: str = "data.conditions") -> "ConditionParams":
        """Parse and validate a condition mapping; unset fields take neutral defaults.

        Raises
        ------
        ValueError
            Naming the key (``data.conditions.<name>.<key>``) of an unknown key, a range that is
            not two numbers with ``low <= high``, a value outside its allowed interval (e.g. a
            negative ``fog_beta``), or a colour that is not three non-negative numbers.
        """
        prefix = f"{where}.{name}"
        if not isinstance(name, str) or not name or "/" in name or "-" in name:
            raise ValueError(f"{where}: condition names must be non-empty and contain no '/' "
                             f"or '-' (they build drive and pair names), got {name!r}")
        conf = dict(conf or {})
        unknown = sorted(set(conf) - set(RANGE_PARAMS) - set(COLOR_PARAMS))
        if unknown:
            raise ValueError(f"{prefix}: unknown keys {unknown}; known: "
                             f"{sorted(RANGE_PARAMS) + sorted(COLOR_PARAMS)}")
        ranges: dict[str, tuple[float, float]] = {}
        for key, (default, lo_allowed, hi_allowed, _doc) in RANGE_PARAMS.items():
            value = conf.get(key, default)
            low, high = _pair(value, f"{prefix}.{key}")
            if not (lo_allowed <= low <= high <= hi_allowed):
                raise ValueError(f"{prefix}.{key}: need {lo_allowed} <= low <= high <= "
                                 f"{hi_allowed}, got [{low}, {high}]")
            ranges[key] = (low, high)
        colors: dict[str, tuple[float, float, float]] = {}
        for key, (default, _doc) in COLOR_PARAMS.items():
            value = conf.get(key, default)
            try:
                rgb = tuple(float(v) for v in value)
            except (TypeError, ValueError):
                raise ValueError(f"{prefix}.{key}: expected three numbers, got {value!r}") from None
            if len(rgb) != 3 or not all(math.isfinite(v) and v >= 0 for v in rgb):
                raise ValueError(f"{prefix}.{key}: expected three finite numbers >= 0, "
                                 f"got {value!r}")
            colors[key] = rgb  # type: ignore[assignment]
        return cls(name=name, ranges=ranges, colors=colors)

    def as_dict(self) -> dict[str, Any]:
        """Plain mapping (ranges and colours as lists), as stored in ``dataset.json``."""
        out: dict[str, Any] = {k: list(v) for k, v in self.ranges.items()}
        out.update({k: list(v) for k, v in self.colors.items()})
        return out


def _pair(value: Any, where: str) -> tuple[float, float]:
    """``[low, high]`` from a two-number sequence (a single number means a fixed value)."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value, value]
    try:
        low, high = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: expected a range [low, high] of two numbers, "
                         f"got {value!r}") from None
    if not (math.isfinite(low) and math.isfinite(high)):
        raise ValueError(f"{where}: range bounds must be finite, got [{low}, {high}]")
    return low, high


__all__ = ["COLOR_PARAMS", "RANGE_PARAMS", "ConditionParams"]

"""Material ids of the G-buffer and the fixed palettes of walls, fences and sprites."""

from __future__ import annotations

import numpy as np

SKY = 0
GRASS = 1
ROAD = 2
MARKING = 3
GRAVEL = 4
BUILDING = 5
WINDOW = 6
ROCK = 7
FENCE = 8
FOLIAGE = 9
BARK = 10
POLE = 11
SIGN = 12
SNOW = 13
FAR = 14  # the distant mountain skyline

#: How wet each material gets in rain (road surfaces most; foliage sheds water).
WETNESS_GAIN = np.zeros(16, np.float32)
WETNESS_GAIN[[ROAD, MARKING, GRAVEL]] = 1.0
WETNESS_GAIN[[GRASS, ROCK, BUILDING, FENCE, POLE, SIGN, BARK]] = 0.5
WETNESS_GAIN[[WINDOW]] = 0.3
WETNESS_GAIN[[FOLIAGE]] = 0.25

#: Sprite kinds.
CONIFER = 0
BROADLEAF = 1
BUSH = 2
LAMP_POLE = 3
SIGN_BOARD = 4

#: Sprite record fields (columns of ``World.sprites``).
SPRITE_FIELDS = ("x", "y", "z", "height", "radius", "kind", "r", "g", "b", "seed")

_WALLS = np.array([
    [0.62, 0.58, 0.52], [0.70, 0.68, 0.64], [0.45, 0.22, 0.16], [0.55, 0.30, 0.20],
    [0.40, 0.40, 0.42], [0.60, 0.55, 0.38], [0.35, 0.42, 0.50], [0.72, 0.62, 0.45],
    [0.50, 0.47, 0.44], [0.30, 0.32, 0.30], [0.66, 0.45, 0.35], [0.55, 0.58, 0.52],
], np.float32)
_FENCES = np.array([
    [0.35, 0.24, 0.15], [0.70, 0.70, 0.68], [0.42, 0.40, 0.37], [0.25, 0.27, 0.28],
], np.float32)
#: First palette entry of fences (walls take ``0 .. 2 * len(_WALLS) - 1``).
FENCE_PALETTE_START = 64


def palette() -> np.ndarray:
    """Wall and fence colours with their pattern spacing.

    Returns
    -------
    ndarray, float32 (256, 4)
        ``r, g, b`` (linear albedo) and the window (walls) or plank (fences) spacing in metres.
        Wall styles ``2 k`` and ``2 k + 1`` share colour ``k`` with 2.5 m and 3.5 m windows.
    """
    table = np.zeros((256, 4), np.float32)
    table[:, :3] = 0.5
    table[:, 3] = 3.0
    for k, rgb in enumerate(_WALLS):
        for j, spacing in enumerate((2.5, 3.5)):
            table[2 * k + j, :3] = rgb
            table[2 * k + j, 3] = spacing
    for k, rgb in enumerate(_FENCES):
        table[FENCE_PALETTE_START + k, :3] = rgb
        table[FENCE_PALETTE_START + k, 3] = 0.25 + 0.1 * k
    return table


N_WALL_STYLES = 2 * len(_WALLS)
N_FENCE_STYLES = len(_FENCES)

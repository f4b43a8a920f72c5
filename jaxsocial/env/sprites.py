"""Tile sprites and the observation atlas, built once in numpy (docs/environment.md 4.5, 4.6, 5).

Sprites are 3x3 RGB tiles. Agents are triangles rasterised with 3x supersampling and the original's
two-stage mean; their colour comes either from the prestige value (a white sprite recoloured with
`(alpha * colour) >> 8`) or from a fixed colour drawn directly.
"""

from __future__ import annotations

import functools

import numpy as np

from jaxsocial.env.types import AGENT_COLOR_NAMES, BONUS, COLORS, GOAL, NUM_TILE_TYPES, SHADOW, TILE_COLORS

TILE = 3
SUPER = 3 * TILE
TRIANGLE_RIGHT = np.array([(0.12, 0.19), (0.87, 0.50), (0.12, 0.81)])
"""Agent triangle vertices (x right, y down, unit tile) pointing right."""


@functools.cache
def triangle_masks() -> np.ndarray:
    """bool[4, 9, 9] supersampled triangle per sprite direction (0 right, 1 down, 2 left, 3 up)."""
    a, b, c = TRIANGLE_RIGHT
    centres = (np.arange(SUPER) + 0.5) / SUPER
    px, py = np.meshgrid(centres, centres)  # [row=y, col=x]
    # Barycentric coordinates of each subpixel centre with respect to (a, b, c).
    v0, v1 = c - a, b - a
    p = np.stack([px - a[0], py - a[1]], -1)
    d00, d01, d11 = v0 @ v0, v0 @ v1, v1 @ v1
    d20, d21 = p @ v0, p @ v1
    denom = d00 * d11 - d01 * d01
    u = (d11 * d20 - d01 * d21) / denom
    v = (d00 * d21 - d01 * d20) / denom
    right = (u >= 0) & (v >= 0) & (u + v < 1)
    # Rotating by 90 degrees clockwise on screen (y down) turns right into down, etc.
    return np.stack([np.rot90(right, k=-d) for d in range(4)])


def downsample(image: np.ndarray) -> np.ndarray:
    """float64[9, 9, C] -> uint8[3, 3, C] by the original's two-stage mean (columns, then rows), floored."""
    cols = image.reshape(SUPER, TILE, 3, -1).mean(axis=2)
    return cols.reshape(TILE, 3, TILE, -1).mean(axis=1).astype(np.uint8)


@functools.cache
def white_alpha() -> np.ndarray:
    """uint8[4, 3, 3]: the white agent sprite's channel value per direction (0, 56, 170, 198 or 255)."""
    masks = triangle_masks().astype(np.float64) * 255.0
    return np.stack([downsample(m[..., None])[..., 0] for m in masks])


def agent_sprite(direction: int, color: tuple[int, int, int], mode: str) -> np.ndarray:
    """uint8[3, 3, 3] agent sprite pointing `direction` in `color`.

    mode 'prestige': the white sprite recoloured per pixel as `(alpha * colour) >> 8` (docs/environment.md
    section 5); mode 'fixed': the triangle drawn directly in `color` and downsampled.
    """
    if mode == "prestige":
        alpha = white_alpha()[direction].astype(np.int64)[..., None]
        return ((alpha * np.asarray(color, np.int64)) >> 8).astype(np.uint8)
    mask = triangle_masks()[direction].astype(np.float64)[..., None]
    return downsample(mask * np.asarray(color, np.float64))


def blend(base: np.ndarray, sprite: np.ndarray) -> np.ndarray:
    """Draw an agent sprite over a tile (docs/environment.md 4.6): `floor((base (m - a) + sprite a) / m)`
    with `a = R + G + B` of the sprite pixel and `m` its maximum over the tile. uint8[3, 3, 3] each."""
    alpha = sprite.astype(np.int64).sum(-1, keepdims=True)
    m = alpha.max()
    if m == 0:
        return base.copy()
    out = (base.astype(np.int64) * (m - alpha) + sprite.astype(np.int64) * alpha) // m
    return out.astype(np.uint8)


def tile_sprite(tile_type: int) -> np.ndarray:
    """uint8[3, 3, 3] flat fill of a tile type."""
    return np.broadcast_to(TILE_COLORS[tile_type], (TILE, TILE, 3)).copy()


def cell_sprite(tile_type: int, direction: int, color: tuple[int, int, int], mode: str) -> np.ndarray:
    """uint8[3, 3, 3] a cell holding an agent: the sprite alone on an empty cell, blended over a tile
    (bonus tile or goal) otherwise."""
    sprite = agent_sprite(direction, color, mode)
    if tile_type in (BONUS, GOAL):
        return blend(tile_sprite(tile_type), sprite)
    return sprite


def prestige_palette() -> list[tuple[int, int, int]]:
    """Every colour `int(s * blue + (1 - s) * red)` can take: index `2 B + (R + B - 254)`."""
    return [(max(254 - b + parity, 0), 0, b) for b in range(256) for parity in range(2)]


def fixed_palette() -> list[tuple[int, int, int]]:
    return [COLORS[name] for name in AGENT_COLOR_NAMES]


# Atlas layout: 0 shadow, 1 + t a bare tile of type t, then agents by (tile type, direction, colour).
FIRST_AGENT_TILE = 1 + NUM_TILE_TYPES


@functools.cache
def atlas(mode: str) -> np.ndarray:
    """uint8[T, 3, 3, 3] every cell picture an observation can contain, for agent colour `mode`."""
    palette = prestige_palette() if mode == "prestige" else fixed_palette()
    tiles = [np.broadcast_to(np.array(SHADOW, np.uint8), (TILE, TILE, 3))]
    tiles += [tile_sprite(t) for t in range(NUM_TILE_TYPES)]
    for t in range(NUM_TILE_TYPES):
        for d in range(4):
            tiles += [cell_sprite(t, d, color, mode) for color in palette]
    return np.stack(tiles).astype(np.uint8)


def palette_size(mode: str) -> int:
    return 512 if mode == "prestige" else len(AGENT_COLOR_NAMES)

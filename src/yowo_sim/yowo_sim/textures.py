"""Procedural textures of the simulated scenes (RGB uint8): walls, floors,
ceilings, furniture fronts, posters and decals. Tiling textures wrap seamlessly.

Every function draws from the ``rng`` it is given, in a fixed order, so a seed
gives the same pixels.
"""

from __future__ import annotations

import cv2
import numpy as np

_LETTERS = np.array(list("ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789"))


def _noise(rng, h: int, w: int, beta: float) -> np.ndarray:
    """Tileable 1/f^beta noise with unit standard deviation (via FFT, so it wraps)."""
    ky = np.fft.fftfreq(h)[:, None]
    kx = np.fft.rfftfreq(w)[None, :]
    k = np.sqrt(kx * kx + ky * ky)
    k[0, 0] = 1.0
    amp = k ** (-beta / 2.0)
    amp[0, 0] = 0.0
    spectrum = amp * (rng.standard_normal(amp.shape) + 1j * rng.standard_normal(amp.shape))
    n = np.fft.irfft2(spectrum, s=(h, w))
    return (n / (n.std() + 1e-12)).astype(np.float32)


def _colour(rng, hue=(0, 180), sat=(40, 200), val=(80, 220)) -> np.ndarray:
    hsv = np.array([[[rng.uniform(*hue), rng.uniform(*sat), rng.uniform(*val)]]], np.uint8)
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0].astype(np.float32)


def _shade(base: np.ndarray, factor: np.ndarray) -> np.ndarray:
    return np.clip(base[None, None, :] * factor[..., None], 0, 255).astype(np.uint8)


def _wrapped(img: np.ndarray, draw) -> None:
    """Draw a shape and its 8 periodic copies, so the texture still tiles."""
    h, w = img.shape[:2]
    for dy in (-h, 0, h):
        for dx in (-w, 0, w):
            draw(dx, dy)


def _random_shapes(rng, img: np.ndarray, count: int, size: tuple[int, int], wrap: bool) -> None:
    h, w = img.shape[:2]
    for _ in range(count):
        col = tuple(int(c) for c in _colour(rng, val=(20, 250)))
        kind = int(rng.integers(5))
        cx, cy = int(rng.integers(w)), int(rng.integers(h))
        s = int(rng.integers(*size))
        thick = -1 if rng.random() < 0.6 else int(rng.integers(1, 5))
        pts = (rng.uniform(-s, s, (int(rng.integers(3, 7)), 2))).astype(np.int32)
        angle = float(rng.uniform(0, 180))
        text = "".join(rng.choice(_LETTERS, int(rng.integers(2, 6))))
        scale = s / 30.0

        def draw(dx, dy, kind=kind, col=col, cx=cx, cy=cy, s=s, thick=thick, pts=pts):
            c = (cx + dx, cy + dy)
            if kind == 0:
                cv2.circle(img, c, s, col, thick, cv2.LINE_AA)
            elif kind == 1:
                cv2.rectangle(img, (c[0] - s, c[1] - s // 2), (c[0] + s, c[1] + s // 2), col, thick, cv2.LINE_AA)
            elif kind == 2:
                cv2.fillPoly(img, [pts + np.array(c)], col, cv2.LINE_AA)
            elif kind == 3:
                cv2.ellipse(img, c, (s, max(2, s // 3)), angle, 0, 360, col, thick, cv2.LINE_AA)
            else:
                cv2.putText(
                    img, text, (c[0] - s, c[1]), cv2.FONT_HERSHEY_SIMPLEX, scale, col, max(1, s // 12), cv2.LINE_AA
                )

        if wrap:
            _wrapped(img, draw)
        else:
            draw(0, 0)


def flat(rng, size: int, colour: np.ndarray, amplitude: float) -> np.ndarray:
    """Nearly uniform surface: only a faint, smooth variation (texture-poor case)."""
    return _shade(colour, 1.0 + amplitude * _noise(rng, size, size, 4.0))


def plaster(rng, h: int, w: int) -> np.ndarray:
    img = _shade(
        _colour(rng, sat=(10, 70), val=(170, 225)), 1.0 + 0.05 * _noise(rng, h, w, 3.0) + 0.03 * _noise(rng, h, w, 1.0)
    )
    for _ in range(h * w // 15000):  # stains and scuffs
        col = tuple(int(c) for c in _colour(rng, sat=(0, 90), val=(60, 200)))
        c = rng.integers(0, (w, h))
        ax = tuple(int(a) for a in rng.integers(3, 25, 2))
        ang = float(rng.uniform(0, 180))
        _wrapped(
            img,
            lambda dx, dy: cv2.ellipse(img, (int(c[0]) + dx, int(c[1]) + dy), ax, ang, 0, 360, col, -1, cv2.LINE_AA),
        )
    for _ in range(h * w // 30000):  # cracks and scribbles
        pts = np.cumsum(rng.normal(0, 12, (int(rng.integers(4, 12)), 2)), axis=0) + rng.integers(0, (w, h))
        col = tuple(int(c) for c in _colour(rng, val=(30, 120)))
        _wrapped(
            img, lambda dx, dy: cv2.polylines(img, [(pts + [dx, dy]).astype(np.int32)], False, col, 1, cv2.LINE_AA)
        )
    return img


def brick(rng, h: int, w: int) -> np.ndarray:
    rows, per_row = max(2, 2 * round(h / 43)), max(1, round(w / 64))  # ~0.08 x 0.25 m bricks
    y = np.arange(h)[:, None] * rows / h
    x = np.arange(w)[None, :] * per_row / w
    row = np.floor(y).astype(int)
    xs = x + 0.5 * (row % 2)
    brick_id = row * per_row + np.floor(xs).astype(int) % per_row
    tint = rng.uniform(0.75, 1.2, rows * per_row)[brick_id]
    mortar = ((y - row) < 0.12) | ((xs - np.floor(xs)) < 0.04)
    base = _colour(rng, hue=(0, 15), sat=(120, 200), val=(120, 190))
    img = _shade(base, tint * (1.0 + 0.08 * _noise(rng, h, w, 1.5)))
    img[mortar] = _shade(np.array([190.0, 185.0, 175.0]), 1.0 + 0.05 * _noise(rng, h, w, 2.0))[mortar]
    return img


def wallpaper(rng, h: int, w: int) -> np.ndarray:
    img = _shade(_colour(rng, sat=(20, 120), val=(150, 220)), 1.0 + 0.04 * _noise(rng, h, w, 2.5))
    _random_shapes(rng, img, h * w // 6000, (5, 22), wrap=True)
    return img


def planks(rng, h: int, w: int, plank_px: int, vertical: bool) -> np.ndarray:
    """Wood boards ``plank_px`` wide with grain; ``vertical``: boards run top to bottom."""
    # Grain: noise stretched along the boards.
    ky = np.fft.fftfreq(h)[:, None]
    kx = np.fft.rfftfreq(w)[None, :]
    k = np.sqrt(kx**2 + (ky * 12.0) ** 2) if vertical else np.sqrt((kx * 12.0) ** 2 + ky**2)
    k[0, 0] = 1.0
    amp = k**-1.2
    amp[0, 0] = 0.0
    grain = np.fft.irfft2(amp * (rng.standard_normal(amp.shape) + 1j * rng.standard_normal(amp.shape)), s=(h, w))
    grain = (grain / grain.std()).astype(np.float32)
    if vertical:
        tint = rng.uniform(0.75, 1.2, w // plank_px + 1)[np.arange(w) // plank_px][None, :]
        gap = np.broadcast_to(((np.arange(w) % plank_px) < 2)[None, :], (h, w))
    else:  # rows of 1/4-width boards, with the board ends staggered per row
        rows = np.arange(h) // plank_px
        along = (np.arange(w)[None, :] + rng.integers(0, w, rows.max() + 1)[rows][:, None]) % w
        board = rows[:, None] * 4 + along // (w // 4)
        tint = rng.uniform(0.75, 1.2, board.max() + 1)[board]
        gap = ((np.arange(h) % plank_px) < 2)[:, None] | ((along % (w // 4)) < 2)
    base = _colour(rng, hue=(8, 22), sat=(90, 170), val=(110, 200))
    img = _shade(base, tint * (1.0 + 0.12 * grain))
    img[gap] //= 2
    for _ in range(h * w // 40000):  # knots
        c = rng.integers(0, (w, h))
        ax = (int(rng.integers(3, 8)), int(rng.integers(6, 14)))
        angle = 0.0 if vertical else 90.0
        _wrapped(
            img,
            lambda dx, dy: cv2.ellipse(
                img, (int(c[0]) + dx, int(c[1]) + dy), ax, angle, 0, 360, (70, 45, 25), -1, cv2.LINE_AA
            ),
        )
    return img


def tiles(rng, h: int, w: int, cell: int, decorated: bool) -> np.ndarray:
    ny, nx = h // cell, w // cell
    iy, ix = np.arange(h) // cell, np.arange(w) // cell
    tile_id = iy[:, None] * nx + ix[None, :]
    base = _colour(rng, sat=(10, 150), val=(140, 230))
    img = _shade(base, rng.uniform(0.85, 1.12, ny * nx)[tile_id] * (1.0 + 0.03 * _noise(rng, h, w, 2.0)))
    img[(np.arange(h) % cell) < 3, :] = (110, 105, 100)  # grout
    img[:, (np.arange(w) % cell) < 3] = (110, 105, 100)
    if decorated:  # some tiles carry a motif
        for tile in rng.choice(ny * nx, ny * nx // 4, replace=False):
            ty, tx = divmod(int(tile), nx)
            sub = img[ty * cell + 3 : (ty + 1) * cell, tx * cell + 3 : (tx + 1) * cell]
            _random_shapes(rng, sub, 3, (3, max(4, cell // 4)), wrap=False)
    return img


def concrete(rng, h: int, w: int) -> np.ndarray:
    grey = float(rng.uniform(120, 175))
    img = _shade(
        np.array([grey, grey * 0.98, grey * 0.95]), 1.0 + 0.10 * _noise(rng, h, w, 2.2) + 0.05 * _noise(rng, h, w, 0.8)
    )
    step = 128  # form-tie holes every 0.5 m
    for y in range(step // 2, h, step):
        for x in range(step // 2, w, step):
            cv2.circle(img, (x, y), 5, (50, 50, 50), -1, cv2.LINE_AA)
    for _ in range(h * w // 25000):  # pores and stains
        c = rng.integers(0, (w, h))
        r = int(rng.integers(2, 14))
        v = int(rng.uniform(60, 200))
        _wrapped(img, lambda dx, dy: cv2.circle(img, (int(c[0]) + dx, int(c[1]) + dy), r, (v, v, v), -1, cv2.LINE_AA))
    return img


def carpet(rng, h: int, w: int) -> np.ndarray:
    a, b = _colour(rng, val=(70, 160)), _colour(rng, val=(70, 160))
    mix = (np.tanh(1.5 * _noise(rng, h, w, 2.5)) + 1.0) / 2.0
    fibres = 1.0 + 0.15 * _noise(rng, h, w, 0.3)
    img = (a[None, None] * mix[..., None] + b[None, None] * (1.0 - mix[..., None])) * fibres[..., None]
    return np.clip(img, 0, 255).astype(np.uint8)


def ceiling(rng, size: int) -> np.ndarray:
    """Acoustic ceiling tiles (0.5 m grid) with speckles."""
    img = _shade(np.array([225.0, 225.0, 220.0]), 1.0 + 0.06 * _noise(rng, size, size, 0.5))
    cell = size // 4
    grid = (np.arange(size) % cell) < 3
    img[grid, :] = (170, 170, 170)
    img[:, grid] = (170, 170, 170)
    return img


def books(rng, size: int) -> np.ndarray:
    """Bookshelf front: boards every ~0.4 m with rows of books."""
    img = np.zeros((size, size, 3), np.uint8)
    wood = planks(rng, size, size, size // 4, vertical=False)
    shelves = 5
    gap = size // shelves
    for s in range(shelves):
        top = s * gap
        img[top : top + gap] = (wood[top : top + gap] * 0.35).astype(np.uint8)  # dark shelf interior
        img[top + gap - 10 : top + gap] = wood[top + gap - 10 : top + gap]  # the board
        x = 0
        while x < size:
            bw = int(rng.integers(6, 22))
            bh = int(rng.integers(gap // 2, gap - 14))
            col = tuple(int(c) for c in _colour(rng, val=(40, 230)))
            y1 = top + gap - 10
            cv2.rectangle(img, (x, y1 - bh), (x + bw - 2, y1 - 1), col, -1)
            if rng.random() < 0.7:  # title band
                band = tuple(int(255 - c) for c in col)
                yb = y1 - bh + int(rng.integers(5, max(6, bh // 2)))
                cv2.rectangle(img, (x + 1, yb), (x + bw - 3, yb + 3), band, -1)
            x += bw + int(rng.integers(0, 3)) + (int(rng.integers(10, 40)) if rng.random() < 0.1 else 0)
    return img


def cardboard(rng, size: int) -> np.ndarray:
    img = _shade(np.array([170.0, 130.0, 85.0]) * rng.uniform(0.8, 1.1), 1.0 + 0.06 * _noise(rng, size, size, 1.2))
    tape = int(rng.integers(size // 3, 2 * size // 3))
    img[:, tape - 12 : tape + 12] = (200, 180, 140)
    x, y = int(rng.integers(20, size // 2)), int(rng.integers(20, size // 2))
    cv2.rectangle(img, (x, y), (x + size // 3, y + size // 5), (235, 235, 230), -1)
    for k in range(3):
        text = "".join(rng.choice(_LETTERS, int(rng.integers(4, 8))))
        cv2.putText(img, text, (x + 4, y + 14 + 14 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (20, 20, 20), 1, cv2.LINE_AA)
    _random_shapes(rng, img, 4, (8, 30), wrap=False)
    return img


def poster(rng, w: int, h: int) -> np.ndarray:
    """A unique picture: gradient or cloudy background, random shapes and text, a frame."""
    c0, c1 = _colour(rng), _colour(rng)
    if rng.random() < 0.5:
        ramp = np.linspace(0.0, 1.0, h, dtype=np.float32)[:, None, None]
        img = (c0 * (1 - ramp) + c1 * ramp) * np.ones((1, w, 1), np.float32)
    else:
        mix = (np.tanh(_noise(rng, h, w, 3.0)) + 1.0)[..., None] / 2.0
        img = c0 * mix + c1 * (1.0 - mix)
    img = np.clip(img, 0, 255).astype(np.uint8)
    _random_shapes(rng, img, int(rng.integers(8, 20)), (max(4, min(w, h) // 20), max(6, min(w, h) // 5)), wrap=False)
    frame = max(3, min(w, h) // 25)
    cv2.rectangle(img, (0, 0), (w - 1, h - 1), tuple(int(c) for c in _colour(rng, val=(10, 90))), 2 * frame)
    return img


def decal(rng, w: int, h: int) -> np.ndarray:
    """Small wall item: a sign, a note, a switch plate or a little picture."""
    kind = int(rng.integers(4))
    if kind == 3:
        return poster(rng, w, h)
    bg = _colour(rng, val=(60, 230)) if kind == 0 else np.array([235.0, 232.0, 220.0]) * rng.uniform(0.85, 1.0)
    img = np.empty((h, w, 3), np.uint8)
    img[:] = bg.astype(np.uint8)
    ink = tuple(int(c) for c in (_colour(rng, val=(0, 90)) if bg.mean() > 120 else _colour(rng, val=(200, 255))))
    if kind == 2:  # switch / socket plate
        for _ in range(int(rng.integers(1, 3))):
            x0, y0 = int(rng.integers(0, w // 2)), int(rng.integers(0, h // 2))
            cv2.rectangle(img, (x0 + w // 8, y0 + h // 8), (x0 + w // 2, y0 + h // 2), (150, 150, 150), -1, cv2.LINE_AA)
            cv2.circle(img, (x0 + w // 4, y0 + h // 4), max(2, min(w, h) // 12), (40, 40, 40), -1, cv2.LINE_AA)
    else:  # sign or note: lines of text
        line_h = max(8, h // int(rng.integers(2, 6)))
        for y in range(line_h, h - 2, line_h):
            text = "".join(rng.choice(_LETTERS, max(2, w // max(6, line_h // 2))))
            cv2.putText(
                img, text, (3, y - 2), cv2.FONT_HERSHEY_SIMPLEX, line_h / 40.0, ink, max(1, line_h // 16), cv2.LINE_AA
            )
    cv2.rectangle(img, (0, 0), (w - 1, h - 1), ink, max(1, min(w, h) // 30))
    return img


def motif_tiled(rng, size: int, repeats: int) -> np.ndarray:
    """One motif repeated on a regular grid: locally rich, globally ambiguous."""
    cell = size // repeats
    motif = poster(rng, cell, cell)
    return np.tile(motif, (repeats, repeats, 1))

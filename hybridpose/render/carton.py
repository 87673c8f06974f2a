"""A carton's print: a light sheet with picture panels and lines of lettering on it, the print a packaged
part (a tea box, a printed cube) carries — drawn for the part's faces (:mod:`~hybridpose.render.face_print`).

A photo crop laid over a whole face has no straight border inside the face. A real carton's panels end in
straight lines parallel to the face's edges, and its lettering runs in rows, with white card around both.
A network fitted without them took a panel's border on ViSP's tea box for an edge of the box and placed
the box end-on, 20–80° off, although it placed a plain box rendered at the same pose within 1°.
"""
from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

CARD_GREY = (170, 255)      # the card's grey level (uint8): white to light grey board
TINTED_SHARE = 0.25         # share of the sheets on a coloured card instead of a white one
PANELS = (1, 5)             # picture panels per sheet (low, high exclusive)
PANEL_SIDE = (0.15, 0.75)   # a panel's side over the sheet's side
TEXT_LINES = (2, 14)        # lines of lettering per sheet (low, high exclusive)
# the lettering's height over the sheet's width: a face spans 0.7–3.3 sheet widths (face_print.SPAN_RANGE),
# so this puts 1–20 rows of letters on a face, as a carton's name and small print do
LETTER_SHARE = (0.03, 0.25)
FONTS = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX,
         cv2.FONT_HERSHEY_TRIPLEX, cv2.FONT_HERSHEY_SCRIPT_SIMPLEX)  # OpenCV's stroke fonts
MIN_PICTURE_PX = 32         # a panel narrower than this is a flat colour (a picture needs room)
_LETTERS = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789  "


def carton_sheet(width: int, height: int, rng: np.random.Generator,
                 panel_fill: Callable[[int, int, np.random.Generator], np.ndarray]) -> np.ndarray:
    """(height, width, 3) uint8 RGB print sheet, seeded by ``rng``: a white (or, ``TINTED_SHARE`` of the
    draws, coloured) card, ``PANELS`` rectangles filled by ``panel_fill(w, h, rng)`` ((h, w, 3) uint8 RGB:
    a photo crop, clutter) or a flat colour, some framed, and ``TEXT_LINES`` rows of random lettering."""
    if width < 16 or height < 16:
        raise ValueError(f"width, height: expected a sheet of at least 16 × 16 pixels, got {width} × {height}")
    if not callable(panel_fill):
        raise TypeError(f"panel_fill: expected a function (w, h, rng) -> (h, w, 3) uint8 image, got {type(panel_fill).__name__}")
    if rng.random() < TINTED_SHARE:
        card = rng.uniform(60, 255, 3)
    else:
        card = np.full(3, rng.uniform(*CARD_GREY)) + rng.normal(0, 4, 3)
    sheet = np.empty((height, width, 3), np.uint8)
    sheet[:] = np.clip(card, 0, 255).astype(np.uint8)
    for _ in range(int(rng.integers(*PANELS))):
        w = int(width * rng.uniform(*PANEL_SIDE))
        h = int(height * rng.uniform(*PANEL_SIDE))
        x, y = int(rng.integers(0, width - w + 1)), int(rng.integers(0, height - h + 1))
        if rng.random() < 0.7 and min(w, h) >= MIN_PICTURE_PX:
            sheet[y:y + h, x:x + w] = panel_fill(w, h, rng)
        else:
            sheet[y:y + h, x:x + w] = rng.integers(0, 256, 3).astype(np.uint8)
        if rng.random() < 0.3:
            cv2.rectangle(sheet, (x, y), (x + w - 1, y + h - 1), _ink(rng), int(rng.integers(1, 6)))
    for _ in range(int(rng.integers(*TEXT_LINES))):
        _lettering(sheet, rng)
    return sheet


def _ink(rng: np.random.Generator) -> tuple[int, int, int]:
    """A print colour: mostly dark (black, navy, brown), else any."""
    if rng.random() < 0.7:
        return tuple(int(v) for v in rng.integers(0, 90, 3))
    return tuple(int(v) for v in rng.integers(0, 256, 3))


def _lettering(sheet: np.ndarray, rng: np.random.Generator) -> None:
    """One row of random letters drawn into ``sheet`` in place, at a random place, size and font."""
    height, width = sheet.shape[:2]
    font = FONTS[int(rng.integers(len(FONTS)))]
    letter_px = width * rng.uniform(*LETTER_SHARE)
    scale = letter_px / cv2.getTextSize("H", font, 1.0, 1)[0][1]
    thickness = max(1, int(round(scale * rng.uniform(1.0, 3.0))))
    text = "".join(rng.choice(list(_LETTERS), int(rng.integers(2, 16))))
    x = int(rng.integers(-width // 4, width))
    y = int(rng.integers(int(letter_px), height + int(letter_px)))
    cv2.putText(sheet, text, (x, y), font, scale, _ink(rng), thickness, cv2.LINE_AA)

"""A carton's print sheet (hybridpose.render.carton): white card, picture panels, rows of lettering; drawn
for a share of the face prints, from a stream of its own."""
import numpy as np
import pytest

from hybridpose.render import AppearanceSpec
from hybridpose.render.carton import MIN_PICTURE_PX, carton_sheet

W, H = 160, 120


def _chequer(width, height, rng):
    """A panel's picture that cannot be mistaken for card or lettering: a 1-px chequer of red and green."""
    out = np.zeros((height, width, 3), np.uint8)
    out[..., 0] = 255 * ((np.add.outer(np.arange(height), np.arange(width)) % 2) == 0)
    out[..., 1] = 255 - out[..., 0]
    return out


def test_a_sheet_is_card_with_panels_and_lettering_and_repeats_for_its_seed():
    calls = []

    def fill(width, height, rng):
        calls.append((width, height))
        return _chequer(width, height, rng)

    sheets = [carton_sheet(W, H, np.random.default_rng(seed), fill) for seed in range(30)]
    assert all(s.shape == (H, W, 3) and s.dtype == np.uint8 for s in sheets)
    assert np.array_equal(sheets[4], carton_sheet(W, H, np.random.default_rng(4), _chequer))
    assert calls and all(min(w, h) >= MIN_PICTURE_PX for w, h in calls)
    # every sheet shows card (its commonest colour, mostly light) and dark ink beside it
    commonest = [np.unique(s.reshape(-1, 3), axis=0, return_counts=True) for s in sheets]
    card = np.array([colours[np.argmax(counts)] for colours, counts in commonest])
    assert np.mean(card.min(1) >= 150) > 0.5
    assert np.mean([(s.max(2) < 90).mean() > 0.002 for s in sheets]) > 0.8
    # pictures sit in straight-edged panels: some sheet carries the chequer over a whole axis-aligned box
    red = [(s[..., 0] == 255) & (s[..., 1] == 0) for s in sheets]
    assert any(r.sum() > 200 for r in red)


def test_a_carton_share_draws_cartons_for_that_share_of_the_prints_and_nothing_else_changes():
    plain = AppearanceSpec("random", texture_share=1.0, print_on="faces")
    cartons = AppearanceSpec("random", texture_share=1.0, print_on="faces", carton_share=0.5)
    looks = [(plain.draw(W, H, 7, i), cartons.draw(W, H, 7, i)) for i in range(40)]
    same = [np.array_equal(a.object_texture, b.object_texture) for a, b in looks]
    assert 8 <= same.count(False) <= 32  # about half the prints are cartons …
    for a, b in looks:  # … and the background, lights and colour stay as they were drawn
        assert np.array_equal(a.background, b.background) and a.object_rgb == b.object_rgb and a.ambient == b.ambient
    assert cartons.record()["carton_share"] == 0.5 and "carton_share" not in plain.record()


def test_bad_carton_input_names_the_argument():
    with pytest.raises(ValueError, match="carton_share: a carton's print is laid on the faces"):
        AppearanceSpec("random", texture_share=0.5, carton_share=0.5)
    with pytest.raises(ValueError, match=r"carton_share: expected a share of the prints in \[0, 1\]"):
        AppearanceSpec("random", print_on="faces", carton_share=1.5)
    with pytest.raises(ValueError, match="width, height: expected a sheet of at least 16"):
        carton_sheet(8, 100, np.random.default_rng(0), _chequer)
    with pytest.raises(TypeError, match="panel_fill: expected a function"):
        carton_sheet(W, H, np.random.default_rng(0), None)

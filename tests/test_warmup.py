"""The kernels are compiled (or loaded from numba's cache) before a first frame, not in it."""
import pytest

from hybridpose import warm_up
from hybridpose.registry import available


def test_every_backend_warms_up_on_the_drawn_cube():
    from hybridpose.geometry.raster import zbuffer_front_faces

    seconds = warm_up(trackers=tuple(available("tracker", baselines=True)), fusions=tuple(available("fusion")))
    assert seconds > 0 and zbuffer_front_faces.signatures


def test_an_unknown_backend_is_named():
    with pytest.raises(ValueError, match="unknown tracker 'nope'"):
        warm_up(trackers=("nope",))

"""Plug your own backend into the hybrid: here a tracker that wraps the built-in edge tracker and
refuses to trust any frame darker than a threshold (e.g. an eclipse your sensor cannot see through).

A backend derives from its role's base class (``hybridpose.trackers.base.Tracker``,
``hybridpose.regressors.base.PoseRegressor``, ``hybridpose.fusion.base.Fusion``), or gives every member
of the role's contract itself (``hybridpose.contracts``: a tracker's ``init / track / reset`` and
``object``, ``lost_quality``, ``tells_covered``; ``track`` takes the keywords ``search_px``,
``lost_quality`` and ``covered_lost_quality`` and may ignore them), as this one does: the estimator
names what is missing when it is built. To make it available by name to
``HybridEstimator.from_names`` and ``hybridpose track --tracker``, register it — in your package's
``pyproject.toml``::

    [project.entry-points."hybridpose.tracker"]
    dark-aware-edges = "my_package.trackers:DarkAwareTracker"

or, in the same process, with ``hybridpose.registry.register("tracker", "dark-aware-edges")``.

    python examples/custom_backend.py
"""
import os

os.environ.setdefault("MUJOCO_GL", "egl")


from hybridpose import Camera, Frame, HybridEstimator, Measurement, registry  # noqa: E402
from hybridpose.core import LOST_COVARIANCE  # noqa: E402
from hybridpose.metrics import rotation_error_deg  # noqa: E402
from hybridpose.objects import load_object  # noqa: E402
from hybridpose.render import Renderer  # noqa: E402
from hybridpose.render.sequences import SequenceSpec, make_sequence  # noqa: E402


@registry.register("tracker", "dark-aware-edges")
class DarkAwareTracker:
    """The ``edges`` tracker, but lost (pose None: the contract of every backend) on dark frames."""

    def __init__(self, object, min_mean_grey: float = 3.0):
        self.inner = registry.create("tracker", "edges", object=object)
        self.object = object              # the estimator crops its CNN checks around this model
        self.lost_quality = self.inner.lost_quality    # the estimator never asks a fit to hold below it
        self.tells_covered = self.inner.tells_covered  # whether track() can see the object covered
        self.min_mean_grey = min_mean_grey

    def init(self, frame, pose):
        self.inner.init(frame, pose)

    def reset(self):
        self.inner.reset()

    def track(self, frame, prior=None, search_px=None, lost_quality=None, covered_lost_quality=None):
        if frame.image.mean() < self.min_mean_grey:
            return Measurement(None, LOST_COVARIANCE, 0.0, "tracker:dark-aware-edges", frame.timestamp)
        return self.inner.track(frame, prior, search_px, lost_quality, covered_lost_quality)


truss = load_object("truss")
camera = Camera.default()
spec = SequenceSpec("fly-around", frames=45, fps=30.0, lighting="eclipse", seed=4)
est = HybridEstimator.from_names(object=truss, tracker="dark-aware-edges", regressor="default", fusion="isam2")
with Renderer(truss, camera) as renderer:
    for f in make_sequence(spec, truss, camera):
        e = est.step(Frame(renderer.render(f.pose, sun_scale=f.sun_scale, rng=f.index).rgb, camera, f.timestamp, f.index))
        err = f"{rotation_error_deg(e.pose, f.pose):5.2f}°" if e.pose is not None else "  —  "
        print(f"{f.index:3d} sun ×{f.sun_scale:4.2f}  {e.status:8s} {err}")

import numpy as np
import pytest

from hybridpose import Estimate, Frame, Measurement, registry
from hybridpose.geometry import Camera, Pose


def test_available_and_create():
    assert set(registry.available("trajectory")) >= {"tumble", "approach", "fly-around", "distance-sweep"}
    with pytest.raises(ValueError, match="role: expected one of"):
        registry.available("planner")


def test_entry_point_plugins_are_loaded(monkeypatch):
    class EP:
        name, value = "my-object", "somewhere:factory"

        def load(self):
            return lambda: "plugin!"

    registry.available("fusion")  # the built-ins first: their modules register once, at import
    monkeypatch.setattr(registry, "entry_points", lambda group: [EP()] if group == "hybridpose.fusion" else [])
    try:
        assert registry.rescan("fusion") == ["my-object"] and registry.rescan("fusion") == []
        assert registry.create("fusion", "my-object") == "plugin!" and "my-object" in registry.available("fusion")
    finally:
        registry.unregister("fusion", "my-object")
    assert "my-object" not in registry.available("fusion")
    with pytest.raises(KeyError, match="my-object"):
        registry.unregister("fusion", "my-object")


def test_register_refuses_a_different_factory_under_a_taken_name():
    @registry.register("fusion", "test-dup")
    def a():
        return 1

    with pytest.raises(ValueError, match="already registered"):
        registry.register("fusion", "test-dup")(lambda: 2)
    registry.unregister("fusion", "test-dup")


def test_frame_and_measurement_validate():
    cam = Camera.default().scaled(32)
    Frame(np.zeros((32, 32, 3), np.uint8), cam, 0.0)
    with pytest.raises(ValueError, match="image: expected \\(H, W, 3\\) uint8"):
        Frame(np.zeros((32, 32, 3), np.float32), cam, 0.0)
    with pytest.raises(ValueError, match="does not match the camera"):
        Frame(np.zeros((16, 32, 3), np.uint8), cam, 0.0)
    Measurement(Pose.identity(), np.eye(6) * 1e-4, 0.9, "tracker:test", 0.0)
    with pytest.raises(ValueError, match="quality"):
        Measurement(None, np.eye(6), 1.5, "x", 0.0)
    with pytest.raises(ValueError, match="covariance: expected shape \\(6, 6\\)"):
        Measurement(None, np.eye(3), 0.5, "x", 0.0)
    with pytest.raises(ValueError, match="positive semi-definite"):
        Measurement(None, -np.eye(6), 0.5, "x", 0.0)
    with pytest.raises(ValueError, match="status"):
        Estimate(None, np.eye(6), 0.0, status="happy")


def test_baselines_are_built_by_name_but_not_offered():
    from hybridpose.objects import load_object

    offered, every = registry.available("tracker"), registry.available("tracker", baselines=True)
    assert offered == ["combined", "edges"] and set(every) - set(offered) == {"klt-pnp", "rapid", "rapid-gos", "rapid-ols"}
    assert registry.create("tracker", "rapid", object=load_object("cube")).name
    with pytest.raises(ValueError, match=r"available: combined, edges \(baselines: klt-pnp, rapid"):
        registry.get("tracker", "nope")


def test_an_estimates_status_is_an_enum_that_reads_and_prints_as_its_word():
    import json

    from hybridpose import Status

    e = Estimate(pose=None, covariance=np.eye(6), timestamp=0.0, status="lost")
    assert e.status is Status.LOST and e.status == "lost" and e.status in ("tracking", "lost")
    assert f"{e.status}|{e.status:>6}" == "lost|  lost" and json.dumps({"s": e.status}) == '{"s": "lost"}'
    with pytest.raises(ValueError, match="status: expected one of"):
        Estimate(pose=None, covariance=np.eye(6), timestamp=0.0, status="drifting")


def test_a_regressor_is_made_from_a_registered_name_or_a_checkpoint_path_in_one_place(tmp_path):
    assert not registry.is_checkpoint_path("default")
    assert registry.is_checkpoint_path(str(tmp_path / "fit" / "best.pt"))
    with pytest.raises(FileNotFoundError, match="best.pt: no such checkpoint file"):
        registry.create_regressor(str(tmp_path / "fit" / "best.pt"))
    with pytest.raises(ValueError, match="unknown regressor 'nonesuch'"):
        registry.create_regressor("nonesuch")


def test_the_package_and_a_tracker_import_without_torch():
    # torch costs about three seconds to import; a tracker user, `import hybridpose`, the CLI's help and
    # a hybrid with no network (a printed part found by its print), its run record included, must not
    # pay it (the networks load it)
    import subprocess
    import sys

    code = ("import sys, hybridpose, hybridpose.estimator, hybridpose.regressors.keypoint_memory\n"
            "from hybridpose.objects import load_object\n"
            "from hybridpose.registry import create\n"
            "create('tracker', 'combined', object=load_object('truss'))\n"
            "hybridpose.HybridEstimator.from_names(object=load_object('truss'), tracker='combined', regressor='none')\n"
            "from hybridpose.machine import describe_cpu\n"
            "assert describe_cpu()['torch_cpu_capability'] is None\n"
            "from hybridpose.regressors import PoseRegressor\n"
            "print('torch' in sys.modules)\n"
            "from hybridpose.regressors import build_model\n"
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["False", "True"]

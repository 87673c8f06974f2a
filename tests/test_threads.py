"""Threads set in one place: torch (and ONNX Runtime, which follows it), OpenCV and numba."""
import cv2
import numba
import pytest
import torch

from hybridpose.threads import ENV_VAR, default_threads, set_threads


@pytest.fixture(autouse=True)
def _one_thread_after():
    yield
    set_threads(1)


def test_one_call_sets_every_library():
    assert set_threads(2) == 2
    assert torch.get_num_threads() == 2 and cv2.getNumThreads() == 2
    assert numba.get_num_threads() == min(2, numba.config.NUMBA_NUM_THREADS)
    assert set_threads(1) == 1 and torch.get_num_threads() == 1 and cv2.getNumThreads() == 1


def test_the_default_is_one_thread_or_what_the_environment_says(monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    assert default_threads() == 1 and set_threads() == 1
    monkeypatch.setenv(ENV_VAR, "2")
    assert set_threads() == 2 and torch.get_num_threads() == 2
    monkeypatch.setenv(ENV_VAR, "many")
    with pytest.raises(ValueError, match=f"{ENV_VAR}: expected a whole number"):
        default_threads()


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2"])
def test_a_count_that_is_no_count_is_refused(bad):
    with pytest.raises(ValueError, match="threads: expected a whole number ≥ 1"):
        set_threads(bad)


def test_the_estimator_runs_on_the_threads_it_is_given():
    from hybridpose.estimator import HybridEstimator

    est = HybridEstimator.from_names(object="truss", fusion="none", threads=2)
    assert est.threads == 2 and torch.get_num_threads() == 2
    assert HybridEstimator(est.tracker, est.regressor, est.fusion).threads == 1

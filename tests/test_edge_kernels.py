"""The moving-edge fit's compiled kernels (hybridpose/edges/kernels.py) against independent
oracles: cv2.projectPoints, NumPy's linear algebra, geometry.se3_exp / line_jacobian, MuJoCo's depth buffer."""

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hybridpose.geometry import Camera, Pose, line_jacobian, se3_exp
from hybridpose.geometry.se3 import se3_exp_one
from hybridpose.edges import kernels as ek
from hybridpose.edges import ModelView


CAM = Camera.default()


def random_pose(rng, distance=0.8):
    return Pose.from_rotvec_t(rng.normal(size=3), np.r_[rng.uniform(-0.1, 0.1, 2), distance])


def test_project_samples_matches_cv2(rng):
    pose = random_pose(rng)
    pts = rng.uniform(-0.3, 0.3, (200, 3))
    dirs = rng.normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    keep, uv, normals = ek.project_samples(pts, dirs, pose.R, pose.t, CAM.K, CAM.width, CAM.height, 20.0, True)
    rvec = cv2.Rodrigues(pose.R)[0]
    ref = cv2.projectPoints(pts, rvec, pose.t, CAM.K, None)[0].reshape(-1, 2)
    np.testing.assert_allclose(uv, ref, atol=1e-9)
    inside = (ref >= 20).all(1) & (ref[:, 0] <= CAM.width - 21) & (ref[:, 1] <= CAM.height - 21)
    np.testing.assert_array_equal(keep, inside)
    # the normal is a unit vector across the image of the edge (a short step along it, projected)
    ahead = cv2.projectPoints(pts + 1e-6 * dirs, rvec, pose.t, CAM.K, None)[0].reshape(-1, 2) - ref
    ahead /= np.linalg.norm(ahead, axis=1, keepdims=True)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.einsum("si,si->s", normals, ahead), 0.0, atol=1e-5)
    keep_all, _, _ = ek.project_samples(pts, dirs, pose.R, pose.t, CAM.K, CAM.width, CAM.height, 20.0, False)
    assert keep_all.all()


def _steps_numpy(profiles, search_px, min_contrast, limits=None):
    """The edge search's step finder written with NumPy array operations (an independent oracle)."""
    k = np.arange(-search_px - 1, search_px + 2, dtype=np.float32)
    g = np.abs(profiles[:, 2:] - profiles[:, :-2]) * 0.5
    ks = k[1:-1]
    score = g * np.exp(-0.5 * (ks / max(search_px, 1)) ** 2)
    if limits is not None:
        score = np.where(np.abs(ks)[None, :] > limits[:, None], -np.inf, score)
    j = np.argmax(score, axis=1)
    rows = np.arange(len(j))
    jl, jr = np.clip(j - 1, 0, len(ks) - 1), np.clip(j + 1, 0, len(ks) - 1)
    a, b, c = g[rows, jl], g[rows, j], g[rows, jr]
    den = a - 2 * b + c
    inner = (j > 0) & (j < len(ks) - 1)
    flank = (np.zeros(len(j), bool) if limits is None
             else inner & (limits < search_px) & ((a > b) | (c > b)))
    sub = np.where(inner & (den < -1e-6) & ~flank, 0.5 * (a - c) / np.where(den == 0, 1, den), 0.0)
    return ks[j] + sub, (b >= min_contrast) & ~flank, profiles.mean(1)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 20), st.integers(0, 2**31 - 1))
def test_strongest_steps_match_numpy(search_px, seed):
    rng = np.random.default_rng(seed)
    # smooth random profiles with a few steps, as image edges look after bilinear sampling
    prof = np.cumsum(rng.normal(0, 3, (64, 2 * search_px + 3)) * (rng.random((64, 2 * search_px + 3)) < 0.2),
                     axis=1).astype(np.float32) * 10 + 60
    full = np.full(64, np.float32(search_px))
    limits = rng.uniform(0, search_px, 64).astype(np.float32)   # each line stopped somewhere
    for lim in (full, limits):
        offset, valid, bright = ek.strongest_steps(prof, search_px, 4.0, lim)
        ref_offset, ref_valid, ref_bright = _steps_numpy(prof, search_px, 4.0, lim)
        np.testing.assert_allclose(offset, ref_offset, atol=1e-5)
        np.testing.assert_array_equal(valid, ref_valid)
        np.testing.assert_allclose(bright, ref_bright, rtol=1e-5, atol=1e-3)  # grey levels
    # the step chosen lies within the limit; its sub-pixel refinement (at a peak only) moves it by at most half a pixel
    assert np.all(np.abs(ek.strongest_steps(prof, search_px, 4.0, limits)[0]) <= np.floor(limits) + 0.5 + 1e-6)


def test_edge_clearance_is_the_distance_to_the_nearest_other_model_edge():
    """Two parallel horizontal edges 7 px apart and a third far away: each sample's normal meets the
    other edge at 7 px (oracle: the geometry; within the raster's half pixel), the far edge beyond ``max_px`` gives ``max_px + 1``; a
    sample's own edge and its collinear neighbour (another id on the same line) do not count."""
    xs = np.arange(20.0, 60.0, 4.0)
    uv = np.concatenate([np.stack([xs, np.full_like(xs, 30.0)], 1), np.stack([xs, np.full_like(xs, 37.0)], 1),
                         np.stack([xs, np.full_like(xs, 80.0)], 1)])
    normals = np.tile([0.0, 1.0], (len(uv), 1))
    tangents = np.tile([2.4, 0.0], (len(uv), 1))
    n = len(xs)
    ids = np.concatenate([np.where(xs < 40, 0, 3), np.full(n, 1), np.full(n, 2)]).astype(np.int64)  # ids 0 and 3: one line
    got = ek.edge_clearance(uv, normals, tangents, ids, 100, 100, 12)
    np.testing.assert_allclose(got[:2 * n], 7.0, atol=0.5)   # the raster's half-pixel rounding
    np.testing.assert_allclose(got[2 * n:], 13.0)


@pytest.mark.parametrize("frac", [0.0, 0.1, 0.3, 0.5, 0.7, 0.9])
def test_edge_search_finds_a_step_edge(frac):
    """A vertical step between columns 100 and 101 (at x = 100.5) is found from samples left of it,
    through cv2.remap as the fit samples the image; a flat image has no edge."""
    gray = np.zeros((60, 200), np.float32)
    gray[:, 101:] = 100.0
    uv = np.array([[95.0 + frac, y] for y in range(10, 50, 5)])
    normals = np.tile([1.0, 0.0], (len(uv), 1))
    mu, mv = ek.search_maps(uv, normals, 8)
    np.testing.assert_allclose(mu[0], uv[0, 0] + np.arange(-9, 10), atol=1e-5)
    prof = cv2.remap(gray, mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    offset, valid, _ = ek.strongest_steps(prof, 8, 4.0, np.full(len(uv), np.float32(8)))
    assert valid.all()
    np.testing.assert_allclose(offset, 100.5 - uv[:, 0], atol=0.1)
    offset, valid, bright = ek.strongest_steps(np.full_like(prof, 80.0), 8, 4.0, np.full(len(uv), np.float32(8)))
    assert not valid.any() and np.allclose(bright, 80.0)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-3.0, 3.0), min_size=6, max_size=6), st.sampled_from([1.0, 1e-3, 1e-6, 0.0]))
def test_se3_exp_one_matches_the_batched_path(xi, scale):
    """The compiled one-vector exponential the kernels call against geometry's batched NumPy path
    (itself checked against gtsam in test_geometry.py)."""
    xi = np.asarray(xi) * np.r_[scale, scale, scale, 1, 1, 1]
    R, t = se3_exp_one(xi)
    R_ref, t_ref = se3_exp(xi[None])
    np.testing.assert_allclose(R, R_ref[0], atol=1e-12)
    np.testing.assert_allclose(t, t_ref[0], atol=1e-12)


def test_solve6_matches_numpy(rng):
    for _ in range(20):
        A = rng.normal(size=(6, 6))
        H = A @ A.T + 1e-3 * np.eye(6)
        g = rng.normal(size=6)
        np.testing.assert_allclose(ek.solve_spd6(H, g), np.linalg.solve(H, g), rtol=1e-8, atol=1e-10)
    H = np.diag([1.0, 2, 3, 4, 5, -1])  # not positive definite: solved by LU as NumPy would
    np.testing.assert_allclose(ek.solve_spd6(H, np.ones(6)), np.linalg.solve(H, np.ones(6)))


def _line_problem(rng, pose, n=300):
    pts = rng.uniform(-0.3, 0.3, (n, 3))
    uv, _ = line_jacobian(pose, pts, CAM.K, np.tile([1.0, 0.0], (n, 1)))
    ang = rng.uniform(0, np.pi, n)
    normals = np.c_[np.cos(ang), np.sin(ang)]
    return pts, normals, uv


def _gauss_newton_step_numpy(pose, pts, normals, targets, cap):
    """One step of the fit written with NumPy and geometry.line_jacobian (an independent oracle)."""
    uv, J = line_jacobian(pose, pts, CAM.K, normals)
    r = np.einsum("si,si->s", normals, uv - targets)
    scale = min(max(1.4826 * np.median(np.abs(r)), 0.5), cap)
    u = r / (4.685 * scale)
    w = np.where(np.abs(u) < 1, (1 - u**2) ** 2, 0.0)
    delta = -np.linalg.solve((J * w[:, None]).T @ J + 1e-9 * np.eye(6), (J * w[:, None]).T @ r)
    dR, dt = se3_exp(delta)
    return pose.R @ dR, pose.R @ dt + pose.t


def test_gauss_newton_step_matches_numpy(rng):
    for _ in range(10):
        truth = random_pose(rng)
        pts, normals, targets = _line_problem(rng, truth)
        targets = targets + rng.normal(0, 0.5, targets.shape)
        targets[:30] += rng.normal(0, 20, (30, 2))                # outliers for the Tukey weights
        start = truth.retract(np.r_[rng.normal(0, 0.01, 3), rng.normal(0, 0.005, 3)])
        R, t, ok = ek.gauss_newton_lines(start.R, start.t, pts, normals, targets, CAM.K, 3.0, 1)
        R_ref, t_ref = _gauss_newton_step_numpy(start, pts, normals, targets, 3.0)
        assert ok
        np.testing.assert_allclose(R, R_ref, atol=1e-10)
        np.testing.assert_allclose(t, t_ref, atol=1e-10)


def test_gauss_newton_converges_to_the_pose_the_lines_come_from(rng):
    truth = random_pose(rng)
    pts, normals, targets = _line_problem(rng, truth)
    start = truth.retract(np.r_[rng.normal(0, 0.02, 3), rng.normal(0, 0.01, 3)])
    R, t, ok = ek.gauss_newton_lines(start.R, start.t, pts, normals, targets, CAM.K, 4.0, 20)
    assert ok
    assert np.degrees(np.arccos(np.clip((np.trace(R.T @ truth.R) - 1) / 2, -1, 1))) < 1e-5
    np.testing.assert_allclose(t, truth.t, atol=1e-7)
    # fewer than 6 samples of weight: no step
    _, _, ok = ek.gauss_newton_lines(start.R, start.t, pts[:5], normals[:5], targets[:5], CAM.K, 4.0, 3)
    assert not ok


DEPTH_TOL_M = 0.005  # a depth pixel "shows" a sample within this
PATCH_PX = 2  # …in a (2·PATCH_PX + 1)² patch around its projection


def depth_oracle(view: ModelView, pose, camera, depth: np.ndarray, margin_px: float = PATCH_PX):
    """What MuJoCo's depth image ``depth`` (H, W) metres says of the edge samples with a face turned to
    the camera, inside the image by ``margin_px``: (index (S,) into ``view.points``, uv (S, 2) px,
    seen (S,) bool: a pixel near it shows its depth, covered (S,) bool: every such pixel shows
    something nearer)."""
    cand, uv, _ = ek.facing_samples(view.points, view.normal_dot_point, view.face_normals, view.faces,
                                    pose.R, pose.t, camera.K, camera.width, camera.height, float(margin_px))
    z = (view.points[cand] @ pose.R.T + pose.t)[:, 2]
    seen, covered = np.zeros(len(cand), bool), np.zeros(len(cand), bool)
    for k, (u, v) in enumerate(np.rint(uv).astype(int)):
        patch = depth[max(v - PATCH_PX, 0):v + PATCH_PX + 1, max(u - PATCH_PX, 0):u + PATCH_PX + 1]
        seen[k] = np.any(np.abs(patch - z[k]) < DEPTH_TOL_M)
        covered[k] = np.all((patch > 0) & (patch < z[k] - DEPTH_TOL_M))
    return cand, uv, seen, covered


def test_visible_edge_samples_agree_with_mujoco_depth(truss, truss_depth_views):
    """Samples the facet raster calls visible are where MuJoCo's depth buffer sees that depth (within
    2 px); front-facing samples inside the image it calls hidden have something nearer over them."""
    view = ModelView(truss)
    agree_visible, agree_hidden = [], []
    for pose, depth in truss_depth_views:
        cand, _, seen, covered = depth_oracle(view, pose, CAM, depth, margin_px=3.0)
        visible = np.isin(cand, view.visible_index(pose, CAM, margin_px=3.0))
        agree_visible.extend(seen[visible])
        agree_hidden.extend(covered[~visible])
    assert len(agree_visible) > 500 and len(agree_hidden) > 50
    # the 3×3 test at half resolution admits samples within ≈ 3 px of their own facet: not all agree
    # (a far-first painter's raster scored 0.90 and 0.83 on these poses)
    assert np.mean(agree_visible) > 0.93
    assert np.mean(agree_hidden) > 0.88


def test_draw_segments_matches_cv2_polylines(rng):
    """The same 1-px lines as cv2.polylines, up to where each breaks a tie between two pixels: every
    pixel drawn lies within 1 px of one of cv2's and the other way round, and the counts agree; a
    segment partly outside the raster is clipped, a raster offset shifts it."""
    a = rng.uniform(-30, 230, (300, 2))
    b = a + rng.uniform(-15, 15, (300, 2))
    ours = np.zeros((150, 200), np.uint8)
    ek.draw_segments(ours, a, b, 0, 0)
    ref = np.zeros_like(ours)
    cv2.polylines(ref, list(np.round(np.stack([a, b], 1)).astype(np.int32)), False, 255, 1)
    near = np.ones((3, 3), np.uint8)
    assert not (ours & ~cv2.dilate(ref, near)).any() and not (ref & ~cv2.dilate(ours, near)).any()
    assert abs(int((ours > 0).sum()) - int((ref > 0).sum())) < 0.1 * (ref > 0).sum()
    shifted = np.zeros((150, 200), np.uint8)
    ek.draw_segments(shifted, a + [7, 3], b + [7, 3], 7, 3)
    assert (shifted == ours).all()

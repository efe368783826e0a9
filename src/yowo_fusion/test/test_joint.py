from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from yowo_common.bundle import Observations
from yowo_common.camera import CameraModel
from yowo_common.geometry import inv_se3, look_at, rotation_angle_deg, se3
from yowo_fusion.joint import JointParams, JointProblem, solve_joint

OFFSET = np.array([0.0, -0.11, -0.06])  # head top in the ego camera frame


def observe(cams, poses, points, sigma, rng, max_range=12.0):
    ci, pi, uv = [], [], []
    for c, (cam, T) in enumerate(zip(cams, poses)):
        p, ok = cam.project_world(T, points)
        ok &= cam.in_image(p) & (np.linalg.norm(points - T[:3, 3], axis=1) < max_range)
        ci += [c] * ok.sum()
        pi += np.flatnonzero(ok).tolist()
        uv.append(p[ok] + rng.normal(size=(ok.sum(), 2)) * sigma)
    return Observations(np.array(ci, int), np.array(pi, int), np.vstack(uv), np.full(len(ci), max(sigma, 0.5)))


def drifted(T_true, rng, step_deg=0.03, step_m=0.002, noise_m=0.0005):
    """An ego map's error: locally precise (sub-mm per frame), drifting as a random walk
    (a few cm over the walk); the first pose exact (the gauge)."""
    out, D = [T_true[0]], np.eye(4)
    for T in T_true[1:]:
        D = (
            se3(
                Rotation.from_rotvec(rng.normal(size=3) * np.radians(step_deg)).as_matrix(), rng.normal(size=3) * step_m
            )
            @ D
        )
        E = D @ T
        out.append(se3(E[:3, :3], E[:3, 3] + rng.normal(size=3) * noise_m))
    return out


def make_problem(seed=0, drift_scale=1.0):
    rng = np.random.default_rng(seed)
    t = np.arange(0, 30, 0.1)
    xy = np.column_stack([4 + 2.5 * np.sin(t / 5), 3 + 1.5 * np.sin(t / 3)])
    heading = np.arctan2(np.gradient(xy[:, 1]), np.gradient(xy[:, 0]))
    # Ego camera: at the head, looking ahead and slightly down, with head yaw.
    R_body_opt = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)
    T_ego = []
    for (x, y), h, tt in zip(xy, heading, t):
        R = Rotation.from_euler("ZYX", [h + 0.4 * np.sin(tt), 0.3, 0]).as_matrix() @ R_body_opt
        T_ego.append(se3(R, [x, y, 1.65]))
    stamps = (t * 1e9).astype(np.int64)
    top = np.array([T[:3, :3] @ OFFSET + T[:3, 3] for T in T_ego])
    bottom = top * [1, 1, 0]
    agent = np.vstack([top, bottom])
    agent_stamps = np.concatenate([stamps, stamps])
    agent_ids = np.repeat([0, 1], len(t))
    # Landmarks on the walls of an 8 x 6 room.
    n = 400
    side = rng.integers(4, size=n)
    u, z = rng.uniform(0, 1, n), rng.uniform(0.2, 2.6, n)
    landmarks = np.column_stack(
        [
            np.select([side == 0, side == 1, side == 2], [u * 8, u * 8, 0.0], 8.0),
            np.select([side == 0, side == 1, side == 2], [0.0, 6.0, u * 6], u * 6),
            z,
        ]
    )
    ego_cam = CameraModel.from_fov(640, 480, 70)
    cmc_cams = [CameraModel.from_fov(640, 480, 85) for _ in range(3)]
    T_cmc = [
        look_at([0.3, 0.3, 3.0], [4, 3, 0.8]),
        look_at([7.7, 0.4, 3.2], [4, 3, 0.8]),
        look_at([4.0, 5.7, 2.9], [4, 2.5, 0.8]),
    ]
    ego_obs = observe([ego_cam] * len(T_ego), T_ego, landmarks, 0.7, rng)
    scene_obs = observe(cmc_cams, T_cmc, landmarks, 0.7, rng)
    agent_obs = observe(cmc_cams, T_cmc, agent, 1.0, rng)
    truth = dict(T_ego=T_ego, landmarks=landmarks, T_cmc=T_cmc, agent=agent)

    def jitter(T, rot_deg, trans_m):
        return se3(
            Rotation.from_rotvec(rng.normal(size=3) * np.radians(rot_deg)).as_matrix() @ T[:3, :3],
            T[:3, 3] + rng.normal(size=3) * trans_m,
        )

    problem = JointProblem(
        ego_camera=ego_cam,
        ego_stamps_ns=stamps,
        T_world_ego=drifted(T_ego, rng, 0.03 * drift_scale, 0.002 * drift_scale),
        landmarks=landmarks + rng.normal(size=landmarks.shape) * 0.02,
        ego_obs=ego_obs,
        cmc_cameras=cmc_cams,
        T_world_cmc=[jitter(T, 1.0, 0.08) for T in T_cmc],
        cmc_scene_obs=scene_obs,
        agent_points=agent + rng.normal(size=agent.shape) * 0.04,
        agent_stamps_ns=agent_stamps,
        agent_ids=agent_ids,
        cmc_agent_obs=agent_obs,
        head_offset=np.zeros(3),
    )  # the paper's "head top = camera"
    return problem, truth


def max_pos_err(A, B):
    return max(np.linalg.norm(a[:3, 3] - b[:3, 3]) for a, b in zip(A, B))


def test_joint_optimisation_improves_cameras_and_ego():
    problem, truth = make_problem()
    before_cmc = max_pos_err(problem.T_world_cmc, truth["T_cmc"])
    before_ego = max_pos_err(problem.T_world_ego, truth["T_ego"])
    res = solve_joint(problem)
    after_cmc = max_pos_err(res.T_world_cmc, truth["T_cmc"])
    after_ego = max_pos_err(res.T_world_ego, truth["T_ego"])
    assert after_cmc < 0.2 * before_cmc and after_cmc < 0.02
    assert after_ego < 0.5 * before_ego
    np.testing.assert_allclose(res.head_offset, OFFSET, atol=0.02)
    assert res.final_error < res.initial_error
    # The covariance is a proper 6x6 and its position sigma is of the size of the achieved error.
    cov = res.cmc_covariances[0]
    assert cov.shape == (6, 6) and np.all(np.linalg.eigvalsh(cov) > 0)
    assert np.sqrt(np.trace(cov[:3, :3])) < 0.05


def test_head_offset_model_beats_head_top_equals_camera():
    """The paper's a2e assumes the head top is the ego camera centre; with a real 12 cm
    offset that biases the CMCs and bends the ego map towards the CMCs' head tops (the
    Huber on the a2e residual limits it); estimating the rigid offset removes the bias (an
    ego map with little drift, which would otherwise dominate the CMC error)."""
    problem, truth = make_problem(seed=1, drift_scale=0.2)
    ours = solve_joint(problem)
    paper = solve_joint(problem, JointParams(estimate_head_offset=False))
    np.testing.assert_allclose(paper.head_offset, 0.0, atol=1e-6)
    assert max_pos_err(ours.T_world_cmc, truth["T_cmc"]) < 0.85 * max_pos_err(paper.T_world_cmc, truth["T_cmc"])
    assert rms_pos_err(ours.T_world_ego, truth["T_ego"]) < 0.75 * rms_pos_err(paper.T_world_ego, truth["T_ego"])


def rms_pos_err(A, B):
    return float(np.sqrt(np.mean([np.sum((a[:3, 3] - b[:3, 3]) ** 2) for a, b in zip(A, B)])))


def test_joint_optimisation_corrects_a_drifting_ego_map_between_keyframes():
    """Ego observations on keyframes only (every 5th frame): the keyframes are the anchors,
    the frames between them follow their corrections, and the whole drifting trajectory
    ends closer to the truth -- the frames between keyframes as much as the keyframes."""
    problem, truth = make_problem(seed=2)
    problem.ego_obs = problem.ego_obs.subset(problem.ego_obs.camera % 5 == 0)
    res = solve_joint(problem)
    assert set(res.anchors.tolist()) >= set(range(0, len(truth["T_ego"]), 5))
    between = [f for f in range(len(truth["T_ego"])) if f % 5]
    for frames in (range(0, len(truth["T_ego"]), 5), between):
        before = rms_pos_err([problem.T_world_ego[f] for f in frames], [truth["T_ego"][f] for f in frames])
        after = rms_pos_err([res.T_world_ego[f] for f in frames], [truth["T_ego"][f] for f in frames])
        assert after < 0.4 * before and after < 0.02, (before, after)


def with_agent_point(problem, P, cameras, stamp_ns):
    """The problem plus one agent point (head top) seen by the given CMCs where P projects."""
    k = len(problem.agent_points)
    obs = problem.cmc_agent_obs
    uv = np.vstack([problem.cmc_cameras[i].project_world(problem.T_world_cmc[i], P[None])[0] for i in cameras])
    return replace(
        problem,
        agent_points=np.vstack([problem.agent_points, P]),
        agent_stamps_ns=np.append(problem.agent_stamps_ns, stamp_ns),
        agent_ids=np.append(problem.agent_ids, 0),
        cmc_agent_obs=Observations(
            np.append(obs.camera, cameras),
            np.append(obs.point, [k] * len(cameras)),
            np.vstack([obs.uv, uv]),
            np.append(obs.sigma_px, [1.0] * len(cameras)),
        ),
    )


def sigmas(cov):
    return np.sqrt(np.diag(cov))


def test_an_indeterminate_agent_point_leaves_every_camera_its_covariance():
    """An agent point the data cannot place (seen by one CMC only, at a stamp outside the
    ego recording: its depth is free) made the marginals of the whole system fail and every
    camera lost its covariance (the floor: 35 of 42 cameras `weak`). It carries no
    information on the poses: every camera keeps the covariance it has without it."""
    problem, truth = make_problem(seed=3)
    base = solve_joint(problem)
    P = problem.T_world_cmc[0][:3, :3] @ [0.0, 0.0, 3.0] + problem.T_world_cmc[0][:3, 3]
    res = solve_joint(with_agent_point(problem, P, [0], problem.ego_stamps_ns[-1] + 10**11))
    assert res.covariance_failure == "" and res.held_points == [f"a{len(problem.agent_points)}"]
    for a, b in zip(res.cmc_covariances, base.cmc_covariances):
        np.testing.assert_allclose(sigmas(a), sigmas(b), rtol=0.02)
    assert max_pos_err(res.T_world_cmc, truth["T_cmc"]) < 0.02


def test_a_camera_the_data_cannot_place_is_reported_without_covariance():
    """A camera that sees two points only is indeterminate (the optimiser damps it, the
    marginals cannot): the poses come back, the covariances are unknown (NaN), with the reason."""
    problem, truth = make_problem(seed=3)
    obs = problem.cmc_agent_obs
    two = np.flatnonzero(obs.camera == 0)[[0, 100]]
    problem = replace(
        problem,
        cmc_cameras=problem.cmc_cameras + [problem.cmc_cameras[0]],
        T_world_cmc=problem.T_world_cmc + [problem.T_world_cmc[0]],
        cmc_agent_obs=Observations(
            np.append(obs.camera, [3, 3]),
            np.append(obs.point, obs.point[two]),
            np.vstack([obs.uv, obs.uv[two]]),
            np.append(obs.sigma_px, obs.sigma_px[two]),
        ),
    )
    res = solve_joint(problem)
    assert all(np.isnan(c).all() for c in res.cmc_covariances)
    assert "covariance unavailable" in res.covariance_failure and "c3" in res.covariance_failure
    assert max_pos_err(res.T_world_cmc[:3], truth["T_cmc"]) < 0.02


def test_ground_points_hold_a_group_that_lost_the_head_top():
    """Noisy keypoints: the group triangulated the head top at 3 stamps, the ground point at
    every stamp. The ground points, under the predicted head top, still hold the group
    horizontally (the floor alone leaves it to the 3 head tops: 7 cm here)."""
    problem, truth = make_problem(seed=5)
    stamps = np.unique(problem.agent_stamps_ns)
    keep = (problem.agent_ids == 1) | np.isin(problem.agent_stamps_ns, stamps[::100])
    index = np.cumsum(keep) - 1
    problem.agent_points, problem.agent_stamps_ns = problem.agent_points[keep], problem.agent_stamps_ns[keep]
    problem.agent_ids = problem.agent_ids[keep]
    obs = problem.cmc_agent_obs.subset(keep[problem.cmc_agent_obs.point])
    problem.cmc_agent_obs = Observations(obs.camera, index[obs.point], obs.uv, obs.sigma_px)
    problem.cmc_scene_obs = problem.cmc_scene_obs.subset(np.zeros(len(problem.cmc_scene_obs), bool))  # no images
    res = solve_joint(problem)
    assert max_pos_err(res.T_world_cmc, truth["T_cmc"]) < 0.04


def broken(T_true, at, jump):
    """An ego map that broke at frame `at`: every later pose moved by the rigid `jump`
    (about the break point), as when a lost track is resumed from a wrong guess."""
    pivot = se3(np.eye(3), T_true[at][:3, 3])
    J = pivot @ jump @ inv_se3(pivot)
    return [T if f < at else J @ T for f, T in enumerate(T_true)]


def test_agent_track_repairs_a_broken_ego_map():
    """Agent anchoring: the ego map broke halfway (the rest 0.3 m and 8 deg off) on a bare
    stretch (no landmarks after the break, so nothing but the agent can tell). The CMCs'
    view of the agent puts the second piece back: to the agent track's noise where the
    ego map flags the break, most of the way where it does not (the chain's Huber gives
    way), and the CMCs end where they are."""
    problem, truth = make_problem(seed=6, drift_scale=0.0)
    at = len(truth["T_ego"]) // 2
    jump = se3(Rotation.from_euler("z", 8, degrees=True).as_matrix(), [0.25, -0.15, 0.0])
    problem.T_world_ego = broken(truth["T_ego"], at, jump)
    problem.ego_obs = problem.ego_obs.subset(problem.ego_obs.camera < at)
    after = range(at, len(truth["T_ego"]))
    before_err = rms_pos_err([problem.T_world_ego[f] for f in after], [truth["T_ego"][f] for f in after])
    for flagged in (True, False):
        problem.ego_weak_frames = (np.arange(len(truth["T_ego"])) == at) if flagged else None
        res = solve_joint(problem)
        repaired = rms_pos_err([res.T_world_ego[f] for f in after], [truth["T_ego"][f] for f in after])
        assert before_err > 0.4 and repaired < (0.04 if flagged else 0.1), (flagged, before_err, repaired)
        assert max_pos_err(res.T_world_cmc, truth["T_cmc"]) < 0.05


def test_a_weak_step_between_held_attitudes_opens_in_translation_only():
    """The ego map slid 0.3 m at a flagged step on a bare stretch (its attitude right: the
    walls and floor held it) and one CMC sees the agent after it. The agent track puts the
    piece back either way; where the ego map says it held both sides' attitude the step's
    rotation stays measured and the piece comes back turned half as much."""
    problem, truth = make_problem(seed=1, drift_scale=0.0)
    n = len(truth["T_ego"])
    at = n // 2
    problem.T_world_ego = broken(truth["T_ego"], at, se3(np.eye(3), [0.25, -0.15, 0.0]))
    problem.ego_obs = problem.ego_obs.subset(problem.ego_obs.camera < at)
    late = problem.agent_stamps_ns[problem.cmc_agent_obs.point] >= problem.ego_stamps_ns[at]
    problem.cmc_agent_obs = problem.cmc_agent_obs.subset(~late | (problem.cmc_agent_obs.camera == 1))
    problem.ego_weak_frames = np.arange(n) == at
    turned = []
    for held in (None, np.ones(n, bool)):
        problem.ego_attitude_held = held
        res = solve_joint(problem)
        assert rms_pos_err(res.T_world_ego[at:], truth["T_ego"][at:]) < 0.01
        turned.append(
            max(rotation_angle_deg(res.T_world_ego[f][:3, :3], truth["T_ego"][f][:3, :3]) for f in range(at, n))
        )
    assert turned[1] < 0.6 * turned[0] and turned[1] < 0.35, turned


def test_a_gyro_tracked_ego_map_keeps_its_rotation():
    """An ego map tracked with the gyro drifts in translation, hardly in rotation: told so
    (ego_imu, JointParams.ego_between_sigma_imu), the JO bends its chain's rotation less
    and the ego poses keep their attitude better, while the cameras are placed as well."""
    problem, truth = make_problem(seed=3)
    problem.T_world_ego = drifted(truth["T_ego"], np.random.default_rng(7), step_deg=0.003, step_m=0.002)

    def worst_attitude_deg(res):
        return max(rotation_angle_deg(a[:3, :3], b[:3, :3]) for a, b in zip(res.T_world_ego, truth["T_ego"]))

    plain, gyro = solve_joint(problem), solve_joint(replace(problem, ego_imu=True))
    assert worst_attitude_deg(gyro) < 0.8 * worst_attitude_deg(plain), (
        worst_attitude_deg(gyro),
        worst_attitude_deg(plain),
    )
    assert max_pos_err(gyro.T_world_cmc, truth["T_cmc"]) < 0.02


def test_estimated_intrinsics_are_refined_with_the_ego_anchored_points():
    """A camera without CameraInfo: the group SfM's estimate (focal 6 % short, k1 too weak,
    no k2, as where a wide lens's k2 went into its focal) is refined by the joint solution to
    the lens's focal, k1 and k2; held as estimated, the camera's pose keeps the error."""
    from yowo_cmc.intrinsics import EstimatedCamera, centred

    problem, truth = make_problem(seed=3, drift_scale=0.3)
    rng = np.random.default_rng(3)
    ideal = problem.cmc_cameras[0]
    f = ideal.K[0, 0]
    lens = centred(640, 480, f, -0.15, 0.035)
    guess = centred(640, 480, 0.94 * f, -0.07)
    guess = EstimatedCamera(guess.width, guess.height, guess.K, guess.D, focal_sigma_px=8.0, k1_sigma=0.02)

    def through_lens(obs, points):
        """Camera 0's observations as the lens saw them, then as the guessed model's ideal pixels."""
        sel = obs.camera == 0
        raw, _ = lens.project_world(truth["T_cmc"][0], points[obs.point[sel]])
        uv = obs.uv.copy()
        uv[sel] = guess.undistort_pixels(raw + rng.normal(size=raw.shape) * 0.7)
        return replace(obs, uv=uv)

    problem = replace(
        problem,
        cmc_cameras=[CameraModel(640, 480, guess.K)] + problem.cmc_cameras[1:],
        cmc_scene_obs=through_lens(problem.cmc_scene_obs, truth["landmarks"]),
        cmc_agent_obs=through_lens(problem.cmc_agent_obs, truth["agent"]),
        cmc_estimated={0: guess},
    )
    refined = solve_joint(problem)
    held = solve_joint(problem, JointParams(refine_estimated_intrinsics=False))
    cam = refined.cmc_intrinsics[0]
    assert isinstance(cam, EstimatedCamera) and held.cmc_intrinsics == {}
    assert abs(cam.K[0, 0] / f - 1) < 0.01, cam.K[0, 0] / f
    assert abs(cam.D[0] + 0.15) < 0.02 and abs(cam.D[1] - 0.035) < 0.02, cam.D[:2]
    assert 0 < cam.focal_sigma_px < 0.01 * f and np.isfinite(cam.k2_sigma)
    err = [np.linalg.norm(r.T_world_cmc[0][:3, 3] - truth["T_cmc"][0][:3, 3]) for r in (refined, held)]
    assert err[0] < 0.5 * err[1] and err[0] < 0.03, err
    # Its residuals are ideal pixels of the refined model: as small as the others'.
    res = refined.cmc_agent_residuals[problem.cmc_agent_obs.camera == 0]
    assert np.sqrt(np.nanmean(res**2)) < 2.0

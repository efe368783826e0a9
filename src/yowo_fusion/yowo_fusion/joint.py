"""Joint optimisation of ego poses, scene landmarks, CMC poses and the agent track
(paper eq. factor_graph_all) with GTSAM built-in factors:

- c2k: projection factors (GenericProjectionFactorCal3_S2, Huber) for ego poses x
  landmarks, CMC poses x landmarks (scene keypoints) and CMC poses x agent points;
- a2e (eq. f_e2e): the agent's head top against the ego camera. The paper treats the
  camera/head-top offset as noise; here the head is rigid, so the head top is
  T_world_ego(t) * o with one unknown offset o (in the ego camera frame) estimated
  jointly: an auxiliary point Q_k, the head top in its anchor's frame, is exactly linear
  in o (a JacobianFactor), and the built-in ReferenceFrameFactor ties it through the
  anchor pose to the agent point (Huber): nonlinear in the pose, so the agent track can
  turn a piece of the ego map by degrees, not only nudge it;
- kin (eq. f_kin): constant-velocity second difference of the head-top track and
  constant top-to-bottom vector between successive frames, both linear (exact); our
  addition: that vector is vertical (the ground point is under the head top).
Ego poses: only anchor frames are variables: the keyframes (they carry the ego
observations) and a frame at least every max_anchor_gap_s, chained by the ego map's
relative poses (Huber): millimetres between keyframes where the ego map tracked well,
ego_weak_between_sigma where it did not (JointProblem.ego_weak_frames: a tracking break,
a stretch of keyframes with almost no landmarks). There the agent track seen by the CMC
groups holds the pieces together (agent anchoring): a drifting or broken ego map is
repaired, not only the CMCs fitted to it. Every other frame is the ego map's tracked
motion from its nearest anchor: the a2e factor predicts its head top through that fixed
relative pose, and after the solve it takes the anchors' corrections (T_new T_old^-1)
interpolated in time. Free per-frame poses would follow each a2e residual (head-top
triangulation noise and the head's bob, centimetres) and lose the ego map's millimetre
frame-to-frame accuracy.
Gauge: the ego map's first pose (a tight prior), its chain of relative poses and the
landmarks' depth-derived positions relative to the keyframe that first saw them (scale;
relative, so a piece of the map moves with its landmarks). No prior holds an anchor to
the ego map's absolute estimate: that would hold a broken piece where the ego map put
it. The agent's ground points get a prior on the floor plane z = 0 (the ego map's
floor), which also observes the vertical part of the head offset."""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np
from gtsam.symbol_shorthand import A, C, D, H, L, M, O, Q, X
from gtsam.symbol_shorthand import K as CAL

from yowo_cmc.intrinsics import EstimatedCamera, add_calibrations, estimated_cameras
from yowo_common.bundle import (
    FIXED_SIGMA,
    Observations,
    add_projection_factors,
    optimize,
    pose3,
    reprojection_residuals,
)
from yowo_common.camera import CameraModel
from yowo_common.geometry import inv_se3

from .alignment import interpolation_pairs

TOP, BOTTOM = 0, 1
UNKNOWN_COVARIANCE = np.full((6, 6), np.nan)  # a pose whose covariance could not be computed
UNKNOWN_COVARIANCE.setflags(write=False)


@dataclass(frozen=True)
class JointParams:
    huber_k: float = 1.345  # Huber threshold of the projection and head-top (a2e) factors [sigmas]
    # Pixel noise of the ego map's landmark observations; 1.5x it for a CMC keypoint whose
    # group estimated none of its own.
    ego_sigma_px: float = 1.0
    landmark_prior_sigma_m: float = 0.05  # sigma of each ego landmark's depth-derived position
    ego_between_sigma: tuple[float, float] = (0.001, 0.002)  # sigma of the ego motion between anchors [rad, m]
    # The same for an ego map tracked with the gyro (JointProblem.ego_imu) [rad, m]. Its rotation
    # between anchors is what the ego stage measures best, with gyro factors and walls-and-floor
    # attitudes the JO does not carry (docs/notes/floor.md).
    ego_between_sigma_imu: tuple[float, float] = (0.0002, 0.002)
    # Sigma of an anchor step over a frame the ego map does not vouch for (JointProblem.ego_weak_frames)
    # [rad, m]. A break joined by a guess, or tracking on next to no landmarks. Loose, not free: a
    # true break still opens through the Huber kernel, while tracked low-overlap steps (mostly
    # right) are not bent by a group whose own geometry is weak (docs/notes/fusion.md).
    ego_weak_between_sigma: tuple[float, float] = (0.05, 0.1)
    # The same between two frames whose attitude the ego map held to the building's walls and
    # floor (JointProblem.ego_attitude_held) [rad, m]. Its rotation is measured, only its
    # translation is loose: the held keyframes' walls and floor fit to about 1 deg each, so a
    # step between two of them to ~1.4 deg.
    ego_held_weak_between_sigma: tuple[float, float] = (0.025, 0.1)
    # Huber threshold of the ego chain's whitened 6-DoF residual [sigmas]. Above the ~sqrt(6) of
    # a good step, so the chain is Gaussian where the ego map holds and gives way at a break it missed.
    ego_between_huber_k: float = 5.0
    # A chain step the solution leaves more than this off the ego map's is a break the ego map
    # did not flag [sigmas]. Solved again with it weak (and reported in JointResult.ego_breaks).
    ego_break_sigmas: float = 20.0
    floor_sigma_m: float = 0.03  # sigma of the agent's ground point on the floor z = 0
    a2e_sigma_m: float = 0.05  # sigma of a head top against the one the ego pose predicts (a2e)
    kin_accel_sigma_m: float = 0.05  # sigma of the head top's second difference per grid step
    kin_body_sigma_m: float = 0.05  # sigma of the change of the top-to-bottom vector per grid step
    upright_sigma_m: float = 0.05  # sigma of the ground point's horizontal offset from under the head top
    max_a2e_gap_s: float = 0.2  # ego poses further apart than this are not interpolated
    max_anchor_gap_s: float = 0.5  # frames without ego observations: an anchor at least this often
    estimate_head_offset: bool = True  # the head offset estimated; False: the paper's model, head top = ego camera
    # Why: the agent track the ego map places metrically, and the scene points, observe the
    # focal length the group alone could only infer from its own views.
    refine_estimated_intrinsics: bool = True  # intrinsics a group SfM estimated (no CameraInfo) refined here
    # Wide CCTV lenses have a k2, and the ego-anchored points spread over the image observe it;
    # held at 0 its share goes into the focal length.
    estimated_k2_prior_sigma: float = 0.05  # sigma of the prior around 0 on such a camera's k2; 0: k2 held at 0 [1]
    iterations: int = 200  # Levenberg-Marquardt iterations at most [count]
    # LM stops once an iteration lowers the error by less than this [share]. Ceres' default
    # function tolerance: past it the Huber weights creep for iterations that move no result,
    # at several times the CPU (docs/notes/speed.md).
    relative_error_tol: float = 1e-6
    # Sigma of the prior that holds an agent point or landmark the data leaves indeterminate, for
    # the covariances only (not the solve; JointResult.held_points).
    marginals_point_prior_sigma_m: float = 1.0
    marginals_max_held_points: int = 10  # points held so at most; past them the covariances are unknown [count]


@dataclass(kw_only=True)
class JointProblem:
    ego_camera: CameraModel
    ego_stamps_ns: np.ndarray  # (F,) sorted
    T_world_ego: list[np.ndarray]  # (F) initial
    landmarks: np.ndarray  # (P, 3) initial (also the depth prior)
    ego_obs: Observations  # camera = ego frame index, point = landmark index
    cmc_cameras: list[CameraModel]  # ideal (undistorted) intrinsics
    T_world_cmc: list[np.ndarray]  # initial
    cmc_scene_obs: Observations  # camera = CMC index, point = landmark index
    agent_points: np.ndarray  # (K, 3) initial, world
    agent_stamps_ns: np.ndarray  # (K,)
    agent_ids: np.ndarray  # (K,)
    cmc_agent_obs: Observations  # camera = CMC index, point = agent point index
    head_offset: np.ndarray = field(default_factory=lambda: np.array([0.0, -0.1, -0.05]))  # o, ego frame
    agent_chain: np.ndarray | None = None  # (K,) track id (CMC group) of each agent point; None: one track
    # (F,) True where the ego map's motion from the previous frame is unreliable; None: nowhere
    ego_weak_frames: np.ndarray | None = None
    # (F,) True where the ego map held the frame's attitude to the building; None: nowhere
    ego_attitude_held: np.ndarray | None = None
    ego_imu: bool = False  # the ego map was tracked with the gyro (ego_between_sigma_imu)
    # CMC index -> the intrinsics (with distortion) its group SfM estimated: the camera's
    # observations are ideal pixels of this model, and the solution refines it.
    cmc_estimated: dict[int, EstimatedCamera] = field(default_factory=dict)


@dataclass(kw_only=True)
class JointResult:
    T_world_ego: list[np.ndarray]
    landmarks: np.ndarray
    T_world_cmc: list[np.ndarray]
    agent_points: np.ndarray
    head_offset: np.ndarray
    cmc_covariances: list[np.ndarray]  # 6x6 per CMC, ROS order (x, y, z, rx, ry, rz), world frame
    cmc_agent_residuals: np.ndarray  # (M, 2) px
    cmc_scene_residuals: np.ndarray
    initial_error: float
    final_error: float
    anchors: np.ndarray  # frame indices optimised (the rest followed them)
    covariance_failure: str = ""  # why cmc_covariances are NaN (unknown): an indeterminate system
    ego_breaks: np.ndarray = field(default_factory=lambda: np.zeros(0, int))  # frames of unflagged breaks found
    held_points: list[str] = field(default_factory=list)  # indeterminate points held for the covariances
    # CMC index -> refined intrinsics of the cameras in JointProblem.cmc_estimated; their
    # residuals above are ideal pixels of these.
    cmc_intrinsics: dict[int, EstimatedCamera] = field(default_factory=dict)


def ros_covariance(cov_gtsam: np.ndarray, R_world_cam: np.ndarray) -> np.ndarray:
    """GTSAM Pose3 marginal (body tangent [w, v]) -> ROS order (x, y, z, rx, ry, rz) in the world."""
    J = np.zeros((6, 6))
    J[:3, 3:] = R_world_cam  # position perturbation = R v
    J[3:, :3] = R_world_cam  # rotation perturbation (left, world) = R w
    return J @ cov_gtsam @ J.T


def anchor_frames(stamps_ns: np.ndarray, observed: np.ndarray, max_gap_s: float) -> np.ndarray:
    """The frames with observations, the first and last frame, and enough frames between
    them that no two consecutive anchors are more than max_gap_s apart."""
    anchors = set(np.unique(observed).tolist()) | {0, len(stamps_ns) - 1}
    last = 0
    for f in range(len(stamps_ns)):
        if f in anchors or stamps_ns[f] - stamps_ns[last] > max_gap_s * 1e9:
            anchors.add(f)
            last = f
    return np.array(sorted(anchors), int)


def nearest_anchor(stamps_ns: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """For every frame, the anchor nearest in time."""
    anchor_ns = stamps_ns[anchors]
    after = np.clip(np.searchsorted(anchor_ns, stamps_ns), 0, len(anchors) - 1)
    before = np.maximum(after - 1, 0)
    closer_before = np.abs(stamps_ns - anchor_ns[before]) <= np.abs(anchor_ns[after] - stamps_ns)
    return anchors[np.where(closer_before, before, after)]


def propagate_corrections(
    T_old: np.ndarray, stamps_ns: np.ndarray, anchors: np.ndarray, T_anchor_new: list[np.ndarray]
) -> np.ndarray:
    """Every frame moved by its anchors' corrections T_new T_old^-1, interpolated in time
    between the two anchors around it (anchors keep their own pose exactly)."""
    C = [gtsam.Pose3(Tn @ inv_se3(T_old[a])) for a, Tn in zip(anchors, T_anchor_new)]
    after = np.clip(np.searchsorted(stamps_ns[anchors], stamps_ns), 0, len(anchors) - 1)
    before = np.maximum(after - 1, 0)
    out = np.empty_like(T_old)
    for f, (i, j) in enumerate(zip(before, after)):
        span = stamps_ns[anchors[j]] - stamps_ns[anchors[i]]
        w = float(np.clip((stamps_ns[f] - stamps_ns[anchors[i]]) / span, 0.0, 1.0)) if span > 0 else 1.0
        out[f] = C[i].slerp(w, C[j]).matrix() @ T_old[f]
    return out


def _linear(keys_and_blocks, b, sigma, values) -> gtsam.LinearContainerFactor:
    dim = len(b)
    jf = gtsam.JacobianFactor(
        *[x for kb in keys_and_blocks for x in kb], np.asarray(b, float), gtsam.noiseModel.Isotropic.Sigma(dim, sigma)
    )
    return gtsam.LinearContainerFactor(jf, values)


def solve_joint(p: JointProblem, params: JointParams = JointParams()) -> JointResult:
    """The joint solution; where it found breaks the ego map did not flag, the solution
    with those steps weak."""
    res = _solve(p, params)
    if not len(res.ego_breaks):
        return res
    weak = np.zeros(len(p.T_world_ego), bool) if p.ego_weak_frames is None else np.array(p.ego_weak_frames, bool)
    weak[res.ego_breaks] = True
    again = _solve(replace(p, ego_weak_frames=weak), params)
    again.ego_breaks = np.union1d(res.ego_breaks, again.ego_breaks)
    return again


def _broken_steps(p: JointProblem, params: JointParams, anchors: np.ndarray, result) -> np.ndarray:
    """The frames of the chain steps (not weak already) the solution leaves more than
    ego_break_sigmas off the ego map's relative pose."""
    T = np.asarray(p.T_world_ego)
    weak = np.zeros(len(T), bool) if p.ego_weak_frames is None else np.asarray(p.ego_weak_frames, bool)
    sigma = np.repeat(_between_sigma(p, params), 3)
    out = []
    for f0, f1 in zip(anchors[:-1], anchors[1:]):
        if weak[f0 + 1 : f1 + 1].any():
            continue
        step = result.atPose3(X(int(f0))).between(result.atPose3(X(int(f1))))
        if (
            np.linalg.norm(gtsam.Pose3.Logmap(pose3(inv_se3(T[f0]) @ T[f1]).between(step)) / sigma)
            > params.ego_break_sigmas
        ):
            out += range(f0 + 1, f1 + 1)
    return np.array(out, int)


def _solve(p: JointProblem, params: JointParams) -> JointResult:
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    # Both ends of a weak step are anchors: the frames beside it must not take a share of
    # the other side's correction.
    weak = np.flatnonzero(p.ego_weak_frames) if p.ego_weak_frames is not None else np.zeros(0, int)
    anchors = anchor_frames(
        p.ego_stamps_ns, np.concatenate([p.ego_obs.camera, weak, weak - 1]), params.max_anchor_gap_s
    )
    T_ego0 = np.asarray(p.T_world_ego)
    for f in anchors:
        values.insert(X(f), pose3(T_ego0[f]))
    _add_ego_chain(graph, p, params, anchors)
    graph.add(
        gtsam.PriorFactorPose3(
            X(int(anchors[0])), pose3(p.T_world_ego[anchors[0]]), gtsam.noiseModel.Isotropic.Sigma(6, FIXED_SIGMA)
        )
    )
    lm_used = np.union1d(p.ego_obs.point, p.cmc_scene_obs.point).astype(int)
    for j in lm_used:
        values.insert(L(j), gtsam.Point3(*p.landmarks[j]))
    _add_landmark_priors(graph, values, p, params, lm_used)
    for i, T in enumerate(p.T_world_cmc):
        values.insert(C(i), pose3(T))
    for k, P in enumerate(p.agent_points):
        values.insert(A(k), gtsam.Point3(*P))
    values.insert(O(0), gtsam.Point3(*p.head_offset))
    if not params.estimate_head_offset:
        graph.add(
            gtsam.PriorFactorPoint3(O(0), gtsam.Point3(0, 0, 0), gtsam.noiseModel.Isotropic.Sigma(3, FIXED_SIGMA))
        )

    add_projection_factors(graph, p.ego_obs, [p.ego_camera] * len(p.T_world_ego), X, L, params.huber_k)
    unknown = p.cmc_estimated if params.refine_estimated_intrinsics else {}
    estimate_k1 = all(np.isfinite(c.k1_sigma) for c in unknown.values())
    k2_sigma = params.estimated_k2_prior_sigma
    add_calibrations(graph, values, unknown, estimate_k1, k2_sigma)
    for obs, point_key in ((p.cmc_scene_obs, L), (p.cmc_agent_obs, A)):
        calibrated = np.isin(obs.camera, list(unknown))
        add_projection_factors(graph, obs.subset(~calibrated), p.cmc_cameras, C, point_key, params.huber_k)
        _add_uncalibrated_projections(graph, obs.subset(calibrated), unknown, point_key, params.huber_k)
    _add_a2e(graph, values, p, params, anchors)
    for k in np.flatnonzero(p.agent_ids == BOTTOM):
        # z of the ground point is 0 (the ego map's floor): linear in the point, exact.
        graph.add(
            _linear([(A(int(k)), np.array([[0.0, 0.0, 1.0]]))], [-p.agent_points[k][2]], params.floor_sigma_m, values)
        )
    _add_kinematics(graph, values, p, params)

    result, initial_error, final_error, _ = optimize(graph, values, params.iterations, params.relative_error_tol)
    T_ego = list(
        propagate_corrections(T_ego0, p.ego_stamps_ns, anchors, [result.atPose3(X(int(f))).matrix() for f in anchors])
    )
    landmarks = p.landmarks.copy()
    for j in lm_used:
        landmarks[j] = result.atPoint3(L(j))
    T_cmc = [result.atPose3(C(i)).matrix() for i in range(len(p.T_world_cmc))]
    agent = np.array([result.atPoint3(A(k)) for k in range(len(p.agent_points))]).reshape(-1, 3)
    covs, failure, held, marginals = [UNKNOWN_COVARIANCE] * len(T_cmc), "", [], None
    try:
        marginals, held = _marginals(graph, result, params)
        covs = [ros_covariance(marginals.marginalCovariance(C(i)), T[:3, :3]) for i, T in enumerate(T_cmc)]
    except RuntimeError as exc:
        # The optimiser damps a (nearly) indeterminate system, the marginals cannot: the poses
        # stand, their covariance is unknown.
        failure = covariance_unavailable(exc)
    refined = estimated_cameras(result, unknown, estimate_k1, marginals, k2_sigma > 0)
    cameras = [CameraModel(c.width, c.height, refined[i].K) if i in refined else c for i, c in enumerate(p.cmc_cameras)]
    agent_obs, scene_obs = (reidealised(o, unknown, refined) for o in (p.cmc_agent_obs, p.cmc_scene_obs))
    return JointResult(
        T_world_ego=T_ego,
        landmarks=landmarks,
        T_world_cmc=T_cmc,
        agent_points=agent,
        head_offset=np.asarray(result.atPoint3(O(0))),
        cmc_covariances=covs,
        cmc_agent_residuals=reprojection_residuals(cameras, T_cmc, agent, agent_obs),
        cmc_scene_residuals=reprojection_residuals(cameras, T_cmc, landmarks, scene_obs),
        initial_error=initial_error,
        final_error=final_error,
        anchors=anchors,
        covariance_failure=failure,
        ego_breaks=_broken_steps(p, params, anchors, result),
        held_points=held,
        cmc_intrinsics=refined,
    )


def reidealised(obs: Observations, before: dict[int, CameraModel], after: dict[int, CameraModel]) -> Observations:
    """Observations whose camera's intrinsics changed from `before` to `after` (index ->
    model with distortion) as ideal pixels of the new model; the others unchanged."""
    uv = obs.uv.copy()
    for c, new in after.items():
        sel = obs.camera == c
        uv[sel] = new.undistort_pixels(before[c].distort_pixels(uv[sel]))
    return replace(obs, uv=uv)


def _add_uncalibrated_projections(graph, obs: Observations, unknown: dict[int, CameraModel], point_key, huber_k):
    """Projection factors of cameras whose intrinsics are variables (K(i), add_calibrations):
    their raw pixels, from the ideal ones through the current model."""
    huber = gtsam.noiseModel.mEstimator.Huber.Create(huber_k)
    models: dict[float, gtsam.noiseModel.Base] = {}  # one per pixel sigma, as add_projection_factors
    for c in np.unique(obs.camera):
        sel = obs.camera == c
        raw = unknown[int(c)].distort_pixels(obs.uv[sel])
        for j, uv, s in zip(obs.point[sel], raw, obs.sigma_px[sel]):
            model = models.get(float(s))
            if model is None:
                model = models[float(s)] = gtsam.noiseModel.Robust.Create(
                    huber, gtsam.noiseModel.Isotropic.Sigma(2, float(s))
                )
            graph.add(
                gtsam.GeneralSFMFactor2Cal3Bundler(gtsam.Point2(*uv), model, C(int(c)), point_key(int(j)), CAL(int(c)))
            )


def _marginals(graph, result, params: JointParams) -> tuple[gtsam.Marginals, list[str]]:
    """The marginals of the solution. A point the data leaves indeterminate (one the solution
    put behind every camera that sees it: its projections carry no Jacobian; one seen by one
    camera only) stops the Cholesky of the whole system, and every camera would lose its
    covariance for it: such a point gets a loose prior and the marginals are tried again.
    It carries no information on the poses, so the prior changes none of their covariances.
    Returns the marginals and the points held so."""
    held, names = gtsam.NonlinearFactorGraph(graph), []
    noise = gtsam.noiseModel.Isotropic.Sigma(3, params.marginals_point_prior_sigma_m)
    for _ in range(params.marginals_max_held_points):
        try:
            return gtsam.Marginals(held, result), names
        except RuntimeError as exc:
            symbol = _indeterminate_symbol(exc)
            if symbol is None or symbol[0] not in "al":
                raise
            key = gtsam.Symbol(symbol[0], int(symbol[1:])).key()
            held.add(gtsam.PriorFactorPoint3(key, result.atPoint3(key), noise))
            names.append(symbol)
    return gtsam.Marginals(held, result), names


def _indeterminate_symbol(exc: RuntimeError) -> str | None:
    """The variable GTSAM's IndeterminateLinearSystemException names (e.g. 'a600'), or None."""
    near = re.search(r"Symbol: (\w+)", str(exc))
    return near.group(1) if near else None


def solver_failure(exc: RuntimeError) -> str:
    """A short reason from GTSAM's exception (IndeterminateLinearSystemException names the variable)."""
    symbol = _indeterminate_symbol(exc)
    return f"indeterminate system near variable {symbol}" if symbol else str(exc).strip().splitlines()[0]


def covariance_unavailable(exc: RuntimeError) -> str:
    return f"covariance unavailable ({solver_failure(exc)})"


def _chains(p: JointProblem) -> np.ndarray:
    return np.zeros(len(p.agent_ids), int) if p.agent_chain is None else np.asarray(p.agent_chain)


def _between_sigma(p: JointProblem, params: JointParams) -> tuple[float, float]:
    return params.ego_between_sigma_imu if p.ego_imu else params.ego_between_sigma


def _add_ego_chain(graph, p: JointProblem, params: JointParams, anchors: np.ndarray) -> None:
    """The ego map's relative pose between consecutive anchors (Huber), loose where a frame
    between them is one the ego map does not vouch for (in translation only where the ego
    map held both anchors' attitude to the building)."""
    T = np.asarray(p.T_world_ego)
    weak = np.zeros(len(T), bool) if p.ego_weak_frames is None else np.asarray(p.ego_weak_frames, bool)
    held = np.zeros(len(T), bool) if p.ego_attitude_held is None else np.asarray(p.ego_attitude_held, bool)
    huber = gtsam.noiseModel.mEstimator.Huber.Create(params.ego_between_huber_k)
    models = [
        gtsam.noiseModel.Robust.Create(huber, gtsam.noiseModel.Diagonal.Sigmas(np.repeat(sigma, 3)))
        for sigma in (_between_sigma(p, params), params.ego_weak_between_sigma, params.ego_held_weak_between_sigma)
    ]
    for f0, f1 in zip(anchors[:-1], anchors[1:]):
        kind = 0 if not weak[f0 + 1 : f1 + 1].any() else 2 if held[f0] and held[f1] else 1
        graph.add(gtsam.BetweenFactorPose3(X(int(f0)), X(int(f1)), pose3(inv_se3(T[f0]) @ T[f1]), models[kind]))


def _add_landmark_priors(graph, values, p: JointProblem, params: JointParams, landmarks: np.ndarray) -> None:
    """Each ego landmark's depth-derived position in the frame of the first keyframe that
    saw it (M_j, held there; ReferenceFrameFactor to the world point L_j): it moves with its
    piece of the ego map. A landmark only CMCs matched keeps an absolute prior."""
    T = np.asarray(p.T_world_ego)
    first = np.full(len(p.landmarks), -1)
    order = np.argsort(p.ego_obs.camera, kind="stable")[::-1]  # the earliest frame written last
    first[p.ego_obs.point[order]] = p.ego_obs.camera[order]
    noise = gtsam.noiseModel.Isotropic.Sigma(3, params.landmark_prior_sigma_m)
    held = gtsam.noiseModel.Isotropic.Sigma(3, FIXED_SIGMA)
    for j in landmarks:
        f = int(first[j])
        if f < 0:
            graph.add(gtsam.PriorFactorPoint3(L(int(j)), gtsam.Point3(*p.landmarks[j]), noise))
            continue
        local = gtsam.Point3(*(T[f][:3, :3].T @ (p.landmarks[j] - T[f][:3, 3])))
        values.insert(M(int(j)), local)
        graph.add(gtsam.PriorFactorPoint3(M(int(j)), local, held))
        graph.add(gtsam.ReferenceFrameFactorPoint3Pose3(M(int(j)), X(f), L(int(j)), noise))


def _add_a2e(graph, values, p: JointProblem, params: JointParams, anchors: np.ndarray) -> None:
    """Head top A_k = T_a Q_k, Q_k = T_a^-1 T_f o + (interpolated - frame f's position) in
    the anchor's frame, f the frame nearest to the agent point's stamp and a the anchor
    nearest to f, both relative poses from the ego map.
    A ground point whose group lost the head top at that stamp is tied horizontally to the
    predicted head top (it stands under it, up to the gait's sway): without it a group that
    tracked mostly the feet (noisy keypoints) keeps only the floor's z and slides and turns
    freely on the floor."""
    chain = _chains(p)
    tops = set(zip(chain[p.agent_ids == TOP].tolist(), p.agent_stamps_ns[p.agent_ids == TOP].tolist()))
    bottom = np.flatnonzero(p.agent_ids == BOTTOM)
    lone = bottom[[(int(chain[k]), int(p.agent_stamps_ns[k])) not in tops for k in bottom]].astype(int)
    _add_head_top_factors(
        graph, values, p, params, anchors, np.flatnonzero(p.agent_ids == TOP), False, params.a2e_sigma_m
    )
    _add_head_top_factors(
        graph, values, p, params, anchors, lone, True, float(np.hypot(params.a2e_sigma_m, params.upright_sigma_m))
    )


def _add_head_top_factors(
    graph,
    values,
    p: JointProblem,
    params: JointParams,
    anchors: np.ndarray,
    members: np.ndarray,
    lone: bool,
    sigma: float,
) -> None:
    """A_k ~ T_a Q_k (Huber, sigma) for the agent points in members; for lone ground points
    only horizontally, through the predicted head top H_k = T_a Q_k."""
    left, right, a, ok = interpolation_pairs(
        p.ego_stamps_ns, p.agent_stamps_ns[members], int(params.max_a2e_gap_s * 1e9)
    )
    o = p.head_offset
    T = np.asarray(p.T_world_ego)
    nearest = nearest_anchor(p.ego_stamps_ns, anchors)
    model = gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(params.huber_k), gtsam.noiseModel.Isotropic.Sigma(3, sigma)
    )
    I3 = np.eye(3)
    for k, f0, f1, w in zip(members[ok], left[ok], right[ok], a[ok]):
        k, f = int(k), int(f1 if w >= 0.5 else f0)
        g = int(nearest[f])
        Ra, ta = T[g][:3, :3], T[g][:3, 3]
        between = (1 - w) * T[f0][:3, 3] + w * T[f1][:3, 3] - T[f][:3, 3]
        R_rel = Ra.T @ T[f][:3, :3]
        c = Ra.T @ (T[f][:3, 3] + between - ta)
        values.insert(Q(k), gtsam.Point3(*(R_rel @ o + c)))
        # Q_k - R_rel o = c: linear in the offset, exact.
        graph.add(_linear([(Q(k), I3), (O(0), -R_rel)], np.zeros(3), FIXED_SIGMA * 1e3, values))
        if not lone:
            graph.add(gtsam.ReferenceFrameFactorPoint3Pose3(Q(k), X(g), A(k), model))
            continue
        predicted = Ra @ (R_rel @ o + c) + ta
        values.insert(H(k), gtsam.Point3(*predicted))
        graph.add(gtsam.ReferenceFrameFactorPoint3Pose3(Q(k), X(g), H(k), model))
        graph.add(
            _linear([(A(k), I3[:2]), (H(k), -I3[:2])], (predicted - p.agent_points[k])[:2], FIXED_SIGMA * 1e3, values)
        )


def _add_kinematics(graph, values, p: JointProblem, params: JointParams) -> None:
    """eq. f_kin on consecutive grid samples: second difference of the head top, and the
    change of the top-to-bottom vector D_k (an auxiliary variable D_k = top_k - bottom_k,
    because a JacobianFactor takes at most three keys)."""
    chain = _chains(p)
    for c in np.unique(chain):
        _add_chain_kinematics(graph, values, p, params, np.flatnonzero(chain == c), int(c))


def _add_chain_kinematics(graph, values, p: JointProblem, params: JointParams, members: np.ndarray, chain: int):
    stamps = np.unique(p.agent_stamps_ns[members])
    step = np.median(np.diff(stamps)) if len(stamps) > 1 else 0
    index = {(int(p.agent_stamps_ns[k]), int(p.agent_ids[k])): int(k) for k in members}
    I3 = np.eye(3)
    body_keys = {}
    for n, s in enumerate(stamps):
        n = chain * 10_000_000 + n  # D keys unique across chains
        t, b = index.get((int(s), TOP)), index.get((int(s), BOTTOM))
        if t is not None and b is not None:
            d = p.agent_points[t] - p.agent_points[b]
            values.insert(D(n), gtsam.Point3(*d))
            graph.add(_linear([(D(n), I3), (A(t), -I3), (A(b), I3)], np.zeros(3), FIXED_SIGMA * 1e3, values))
            # Upright: the ground point is under the head top (horizontal part of D ~ 0, up to
            # the gait's sway). Without it, along a straight walk the whole group can roll
            # about the head-top line, the ground points sliding sideways on the floor.
            graph.add(_linear([(D(n), I3[:2])], -d[:2], params.upright_sigma_m, values))
            body_keys[int(s)] = (n, d)
    body_noise = gtsam.noiseModel.Isotropic.Sigma(3, params.kin_body_sigma_m)
    for s in stamps:
        s0, s1, s2 = int(s), int(s + step), int(s + 2 * step)
        t0, t1, t2 = (index.get((x, TOP)) for x in (s0, s1, s2))
        if None not in (t0, t1, t2):
            r = p.agent_points[t2] - 2 * p.agent_points[t1] + p.agent_points[t0]
            graph.add(_linear([(A(t0), I3), (A(t1), -2 * I3), (A(t2), I3)], -r, params.kin_accel_sigma_m, values))
        if s0 in body_keys and s1 in body_keys:
            graph.add(
                gtsam.BetweenFactorPoint3(D(body_keys[s0][0]), D(body_keys[s1][0]), gtsam.Point3(0, 0, 0), body_noise)
            )

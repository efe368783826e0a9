"""The limit in `yowo bench`: the Cramer-Rao bound of each CMC's pose in its group
given the simulated detector noise, and its record in a bench case."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .ground_truth import read_ground_truth
from .metrics import relative_pose_errors

# Bumped when the bound's computation changes: a resumed run recomputes the stored
# cases' bounds (a property of the recording and YOWO's groups, seconds per case).
BOUND_VERSION = 3


def bound_case(case: dict, bag: Path, preset) -> dict:
    """A bench case's bound record for YOWO's groups (preset: the recording's CapturePreset)."""
    bound = relative_pose_bound(bag, case["relative"]["YOWO"]["groups"], preset)
    out = {"version": BOUND_VERSION, "cameras": len(bound)}
    # RMS (the bound proper) and mean: the paper's tables average the error's magnitude.
    for k, what in enumerate(("position_m", "rotation_deg", "mean_position_m", "mean_rotation_deg")):
        out[what] = {n: b[k] for n, b in bound.items()}
    return out


def relative_pose_bound(bag: Path, groups: dict[str, list[str]], preset) -> dict[str, float]:
    """Cramer-Rao bound of each CMC's position in its group: the marginal covariance of
    the group bundle adjustment evaluated at the ground truth (_camera_covariance) with the
    simulated detector's noise, gauge fixed by the first camera and the scale of the
    first baseline. Observations are the recorded detections, each snapped to the
    nearest frame of the group's first camera (the estimator interpolates the tracks to
    a common grid; the bound takes the cameras as synchronised). Returns camera -> (RMS
    KU-aligned position error [m], RMS rotation error [deg], mean position error, mean
    rotation error) that an efficient estimator would reach (the bound pushed through the
    evaluation's alignment)."""
    import gtsam
    from gtsam.symbol_shorthand import L, X

    from yowo_common.bundle import cal3, pose3
    from yowo_common.geometry import transform_points
    from yowo_common.ros.bag import list_topics, read_messages
    from yowo_common.rosconv import camera_info_to_model, points_to_array, stamp_to_ns
    from yowo_common.topics import GT_AGENT_KEYPOINTS, parse_cmc_topic

    truth = read_ground_truth(bag)
    gt = truth.cameras
    spec = preset.detector
    period = int(1e9 / preset.cmc_hz)
    agent: dict[int, np.ndarray] = {}
    dets: dict[str, list[tuple[int, int]]] = {}
    cams = {}
    # Only the topics used: a full read would decode every image of the recording.
    kinds = {t.name: (parse_cmc_topic(t.name) or ("", ""))[1] for t in list_topics(bag)}
    topics = [t for t, kind in kinds.items() if t == GT_AGENT_KEYPOINTS or kind in ("agent_keypoints", "camera_info")]
    for topic, _, msg in read_messages(bag, topics):
        if topic == GT_AGENT_KEYPOINTS:
            # The cameras' ground truth is in YOWO's map frame, the agent's in the simulator's.
            agent[stamp_to_ns(msg.header.stamp)] = transform_points(
                truth.T_map_sim, points_to_array([p.position for p in msg.poses])
            )
        elif kinds[topic] == "agent_keypoints":
            # On the ego clock, as the agent's ground truth is (a synchronised efficient estimator).
            stamp = truth.true_time_ns(msg.camera_name, stamp_to_ns(msg.header.stamp))
            dets.setdefault(msg.camera_name, []).extend((stamp, k.id) for k in msg.keypoints)
        elif kinds[topic] == "camera_info" and parse_cmc_topic(topic)[0] not in cams:
            cams[parse_cmc_topic(topic)[0]] = camera_info_to_model(msg)
    bounds = {}
    for names in groups.values():
        obs: dict[tuple[int, int], list] = {}
        # Snapping to an absolute grid would split two cameras whose frames lie 0.4 and
        # 0.8 periods past it into different slots: they would share no point.
        phase = min((stamp for stamp, _ in dets.get(names[0], [])), default=0)
        for i, n in enumerate(names):
            for stamp, kp in dets.get(n, []):
                if stamp in agent and kp < len(agent[stamp]):
                    obs.setdefault((round((stamp - phase) / period), kp), []).append((i, n, agent[stamp][kp], kp))
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for i, n in enumerate(names):
            values.insert(X(i), pose3(gt[n]))
        for key, views in enumerate(v for v in obs.values() if len({i for i, *_ in v}) >= 2):
            values.insert(L(key), gtsam.Point3(*views[0][2]))  # shared point: the grid slot's first sample
            for i, n, _, kp in views:
                sigma = spec.sigma_px.get(kp, spec.sigma_body_px)
                graph.add(
                    gtsam.GenericProjectionFactorCal3_S2(
                        gtsam.Point2(*cams[n].project_world(gt[n], views[0][2][None])[0][0]),
                        gtsam.noiseModel.Isotropic.Sigma(2, max(sigma, 0.1)),
                        X(i),
                        L(key),
                        cal3(cams[n]),
                    )
                )
        # Gauge priors tight against the cm-level bounds yet loose enough for a stable Cholesky.
        graph.add(gtsam.PriorFactorPose3(X(0), pose3(gt[names[0]]), gtsam.noiseModel.Isotropic.Sigma(6, 1e-5)))
        base = float(np.linalg.norm(gt[names[1]][:3, 3] - gt[names[0]][:3, 3]))
        graph.add(gtsam.RangeFactorPose3(X(0), X(1), base, gtsam.noiseModel.Isotropic.Sigma(1, 1e-5)))
        # The metric is KU-aligned, so push the bound through the same alignment: sample
        # the joint marginal, perturb the ground truth, align, measure (Monte Carlo).
        cov = _camera_covariance(graph, values, len(names))
        if cov is None:
            continue  # no bound for this group (too little parallax)
        rng = np.random.default_rng(0)
        errors = {n: [] for n in names}
        for delta in rng.multivariate_normal(np.zeros(len(cov)), cov, size=200):
            est = {names[0]: gt[names[0]]}
            for i, n in enumerate(names[1:]):
                est[n] = pose3(gt[n]).retract(delta[6 * i : 6 * i + 6]).matrix()
            for e in relative_pose_errors(est, gt, {"g": names})[0]:
                errors[e.name].append((e.eps_pos_m, e.eps_rot_deg))
        bounds.update({n: (*np.sqrt(np.mean(np.square(v), axis=0)), *np.mean(v, axis=0)) for n, v in errors.items()})
    return bounds


def _camera_covariance(graph, values, num_cameras: int) -> np.ndarray | None:
    """Joint covariance of cameras 1..N-1 (6 each, tangent space) of a bundle graph over
    poses X(i) and points L(j): the points are eliminated (Schur complement) point by
    point as A_c^T (I - Q Q^T) A_c, Q an orthonormal basis of the point's Jacobian
    columns. The textbook H_cc - H_cl H_ll^-1 H_lc loses to rounding on nearly
    parallax-free points (information eigenvalues of -1e15 on small s0); the projection
    is positive semi-definite by construction. (GTSAM's Marginals runs a Cholesky that
    gives up on the ill-conditioned but regular two-camera groups.) None when the
    cameras' information is singular."""
    from gtsam.symbol_shorthand import X

    n = 6 * num_cameras
    col = {X(i): 6 * i for i in range(num_cameras)}
    H_cc = np.zeros((n, n))
    rows: dict[int, tuple[list, list]] = {}  # point key -> (camera rows, point rows)
    linear = graph.linearize(values)
    for k in range(linear.size()):
        f = linear.at(k)
        A, keys = f.jacobian()[0], list(f.keys())
        dims = [6 if key in col else 3 for key in keys]
        blocks = dict(zip(keys, np.split(A, np.cumsum(dims)[:-1], axis=1)))
        A_c = np.zeros((len(A), n))
        for key in keys:
            if key in col:
                A_c[:, col[key] : col[key] + 6] = blocks[key]
        point = [key for key in keys if key not in col]
        if point:
            entry = rows.setdefault(point[0], ([], []))
            entry[0].append(A_c)
            entry[1].append(blocks[point[0]])
        else:
            H_cc += A_c.T @ A_c
    for cam_rows, point_rows in rows.values():
        A_c, A_l = np.vstack(cam_rows), np.vstack(point_rows)
        U, sv, _ = np.linalg.svd(A_l, full_matrices=False)
        Q = U[:, sv > 1e-10 * sv[0]]  # a point seen without parallax is free along its ray
        R = A_c - Q @ (Q.T @ A_c)
        H_cc += R.T @ R
    info = H_cc[6:, 6:] - H_cc[6:, :6] @ np.linalg.solve(H_cc[:6, :6], H_cc[:6, 6:])
    eig = np.linalg.eigvalsh(info)
    if eig[0] <= 1e-12 * eig[-1]:
        return None
    return np.linalg.inv(info)

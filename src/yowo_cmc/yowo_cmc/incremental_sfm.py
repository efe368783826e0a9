"""Incremental reconstruction of one CMC group (paper "CMC Processing"): the initial
pair's relative pose (E = K^T F K with the cheirality check, or its alternatives,
chosen by geometric verification), triangulation, and the next camera by overlap and
PnP RANSAC; cameras of unknown intrinsics get their focal length on the way."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from yowo_common.camera import CameraModel
from yowo_common.geometry import inv_se3, se3
from yowo_common.pnp import sqpnp_ransac

from .intrinsics import centred, focal_from_fundamental, pnp_unknown_focal
from .params import SfmParams
from .scene_graph import MAX_IDS, RANSAC_SEED, GridObservations, PairGeometry, overlap_score, spread_subset


def triangulate(cameras: list[CameraModel], poses: list[np.ndarray], uvs: list[np.ndarray]) -> np.ndarray:
    """Linear multi-view triangulation (DLT) of one point."""
    A = []
    for cam, T, uv in zip(cameras, poses, uvs):
        P = cam.K @ inv_se3(T)[:3]
        A += [uv[0] * P[2] - P[0], uv[1] * P[2] - P[1]]
    _, _, Vt = np.linalg.svd(np.array(A))
    X = Vt[-1]
    return X[:3] / X[3] if abs(X[3]) > 1e-12 else np.full(3, np.nan)


def view_residuals_px(
    X: np.ndarray, cameras: list[CameraModel], poses: list[np.ndarray], uvs: list[np.ndarray]
) -> list[float]:
    """The reprojection residual (px) of the point X in each of its views."""
    return [float(np.linalg.norm(cam.project_world(T, X[None])[0][0] - uv)) for cam, T, uv in zip(cameras, poses, uvs)]


def ideal_view(model: CameraModel, raw: dict[int, np.ndarray]) -> tuple[CameraModel, dict[int, np.ndarray]]:
    """A camera's pinhole model and its observations {key: uv} undistorted by `model`."""
    if not model.has_distortion:
        return CameraModel(model.width, model.height, model.K), raw
    keys = list(raw)
    ideal = model.undistort_pixels(np.array([raw[k] for k in keys]).reshape(-1, 2))
    return CameraModel(model.width, model.height, model.K), dict(zip(keys, ideal))


def _translation_given_rotation(R_cam_world: np.ndarray, X: np.ndarray, xn: np.ndarray) -> np.ndarray:
    """Least-squares t of x ~ R X + t from normalised image points: linear once R is known."""
    RX = X @ R_cam_world.T
    A = np.zeros((2 * len(X), 3))
    A[0::2, 0] = A[1::2, 1] = 1.0
    A[0::2, 2], A[1::2, 2] = -xn[:, 0], -xn[:, 1]
    rhs = np.column_stack([xn[:, 0] * RX[:, 2] - RX[:, 0], xn[:, 1] * RX[:, 2] - RX[:, 1]]).ravel()
    return np.linalg.lstsq(A, rhs, rcond=None)[0].reshape(3, 1)


class IncrementalSfm:
    """Incremental reconstruction of one group in its local frame (reference camera = identity)."""

    def __init__(
        self,
        obs: GridObservations,
        members: list[int],
        params: SfmParams,
        id_gate_scale: dict[int, float] | None = None,
        unknown: frozenset[int] = frozenset(),
    ):
        # Its own lists of intrinsics and observations: those of a camera of unknown intrinsics
        # (`unknown`) change with each estimate (pinhole K, pixels undistorted by its k1).
        self.obs = replace(obs, cameras=list(obs.cameras), per_camera=list(obs.per_camera))
        self.raw = obs.per_camera
        self.members, self.params = members, params
        self.unknown = unknown & set(members)
        self.estimated: dict[int, CameraModel] = {}  # unknown camera -> its current estimate (with k1)
        # keypoint id -> factor on the triangulation gates (at least the camera's noise scale)
        self.id_gate_scale = id_gate_scale or {}
        self.poses: dict[int, np.ndarray] = {}
        self.points: dict[int, np.ndarray] = {}
        self.failed: dict[int, str] = {}

    def initialise(self, pair: PairGeometry) -> None:
        if {pair.a, pair.b} & self.unknown:
            self._pair_focals(pair)
        self.poses[pair.a] = np.eye(4)
        candidates = self._relative_candidates(pair.a, pair.b, pair.keys[pair.inliers], pair.F)
        self.poses[pair.b] = max(candidates, key=lambda T: self._verify(pair.b, T))
        self.triangulate_new()

    def _pair_focals(self, pair: PairGeometry) -> None:
        """Initial focal lengths of the pair's unknown cameras from its fundamental matrix."""
        a, b, F = pair.a, pair.b, pair.F
        if a in self.unknown and b not in self.unknown:
            a, b, F = b, a, F.T
        size = {c: (self.obs.cameras[c].width, self.obs.cameras[c].height) for c in (a, b)}
        fa, fb = focal_from_fundamental(
            F, None if a in self.unknown else self.obs.cameras[a].K, size[a], size[b], self.params.hfov_range_deg
        )
        for c, f in ((a, fa), (b, fb)):
            if c in self.unknown:
                self.set_intrinsics(c, centred(*size[c], f))

    def set_intrinsics(self, c: int, model: CameraModel) -> None:
        """A new estimate of unknown camera c's intrinsics: its pinhole model and pixels follow."""
        self.estimated[c] = model
        self.obs.cameras[c], self.obs.per_camera[c] = ideal_view(model, self.raw[c])

    def _relative_candidates(self, a: int, b: int, keys: np.ndarray, F: np.ndarray | None = None) -> list[np.ndarray]:
        """Candidate poses T_a_b (unit baseline) from the 2D-2D matches `keys`."""
        pa = np.array([self.obs.per_camera[a][k] for k in keys])
        pb = np.array([self.obs.per_camera[b][k] for k in keys])
        Ka, Kb = self.obs.cameras[a].K, self.obs.cameras[b].K
        na = cv2.undistortPoints(pa[:, None], Ka, None).reshape(-1, 2)
        nb = cv2.undistortPoints(pb[:, None], Kb, None).reshape(-1, 2)
        # Deviation from the paper (E = K^T F K, eq. F2E): the agent's points lie close to two
        # horizontal planes (head and floor), where the 7-DoF F is nearly degenerate and its E
        # can be far off; the calibrated 5-point solver on the F inliers is well conditioned.
        cv2.setRNGSeed(RANSAC_SEED)
        thresh = (
            self.params.ransac_px * max(self.obs.noise_scale[a], self.obs.noise_scale[b]) / np.sqrt(Ka[0, 0] * Kb[0, 0])
        )
        sub = spread_subset(pa, self.obs.cameras[a], self.params)
        E = None
        if len(sub) >= 5:
            E, _ = cv2.findEssentialMat(na[sub], nb[sub], np.eye(3), cv2.USAC_MAGSAC, 0.9999, thresh)
        if (E is None or E.shape != (3, 3)) and F is not None:
            E = Kb.T @ F @ Ka
        candidates = []
        if E is not None and E.shape == (3, 3):
            _, R, t, _ = cv2.recoverPose(E, na, nb, np.eye(3))  # SVD + cheirality check
            candidates.append(inv_se3(se3(R, t.ravel())))  # T_a_b: R_ab = R^T, X_b = -R^T t
        # Our addition to the paper's geometric verification: each keypoint id of a walking
        # agent stays near one horizontal plane (head top, floor point), so its matches also
        # fit a homography. At high noise the 5-point E of the two nearly planar layers can
        # fall into a wrong solution where a per-id homography's decomposition is close;
        # _verify picks among them.
        ids = keys % MAX_IDS
        for i in np.unique(ids):
            if np.sum(ids == i) < self.params.min_matches:
                continue
            cv2.setRNGSeed(RANSAC_SEED)
            H, _ = cv2.findHomography(na[ids == i], nb[ids == i], cv2.USAC_MAGSAC, thresh)
            if H is not None:
                _, Rs, ts, _ = cv2.decomposeHomographyMat(H, np.eye(3))
                candidates += [
                    inv_se3(se3(R, t.ravel() / np.linalg.norm(t))) for R, t in zip(Rs, ts) if np.linalg.norm(t) > 1e-9
                ]
        return candidates

    def _verify(self, c: int, T: np.ndarray) -> tuple[int, float]:
        """Geometric verification of a candidate pose T of camera c: how many of c's points
        seen by a posed camera triangulate acceptably with it, then minus their mean
        reprojection error (px). Scored on a spread subset (a long stop is one spot)."""
        poses = {**self.poses, c: T}
        keys = list(self.obs.per_camera[c])
        uv = np.array([self.obs.per_camera[c][k] for k in keys]).reshape(-1, 2)
        count, errs = 0, []
        for i in spread_subset(uv, self.obs.cameras[c], self.params):
            views = [v for v in poses if keys[i] in self.obs.per_camera[v]]
            if len(views) < 2:
                continue
            cams = [self.obs.cameras[v] for v in views]
            uvs = [self.obs.per_camera[v][keys[i]] for v in views]
            X = triangulate(cams, [poses[v] for v in views], uvs)
            if np.isfinite(X).all() and self._acceptable(
                X, cams, [poses[v] for v in views], uvs, self._gate_scales(keys[i], views)
            ):
                count += 1
                errs += view_residuals_px(X, cams, [poses[v] for v in views], uvs)
        return count, -float(np.mean(errs)) if errs else 0.0

    def _views(self, key: int) -> list[int]:
        return [c for c in self.poses if key in self.obs.per_camera[c]]

    def triangulate_new(self, gate_px: float | None = None) -> None:
        """Triangulate the keys seen by >= 2 posed cameras that have no point yet, each kept if
        it reprojects within gate_px (default max_reproj_px) times the cameras' noise scale."""
        candidates = set().union(*(self.obs.per_camera[c].keys() for c in self.poses)) - set(self.points)
        for key in candidates:
            views = self._views(key)
            if len(views) < 2:
                continue
            cams = [self.obs.cameras[c] for c in views]
            poses = [self.poses[c] for c in views]
            uvs = [self.obs.per_camera[c][key] for c in views]
            X = triangulate(cams, poses, uvs)
            scales = self._gate_scales(key, views) if gate_px is None else [self.obs.noise_scale[c] for c in views]
            if np.isfinite(X).all() and self._acceptable(X, cams, poses, uvs, scales, gate_px):
                self.points[key] = X

    def _gate_scales(self, key: int, views: list[int]) -> list[float]:
        id_scale = self.id_gate_scale.get(int(key) % MAX_IDS, 1.0)
        return [max(self.obs.noise_scale[c], id_scale) for c in views]

    def _acceptable(self, X, cams, poses, uvs, scales, gate_px: float | None = None) -> bool:
        gate_px = self.params.max_reproj_px if gate_px is None else gate_px
        rays = []
        for cam, T, uv, scale in zip(cams, poses, uvs, scales):
            proj, front = cam.project_world(T, X[None])
            if not front[0] or np.linalg.norm(proj[0] - uv) > gate_px * scale:
                return False
            rays.append((X - T[:3, 3]) / np.linalg.norm(X - T[:3, 3]))
        cos = max(abs(float(r1 @ r2)) for i, r1 in enumerate(rays) for r2 in rays[i + 1 :])
        return np.degrees(np.arccos(min(cos, 1.0))) >= self.params.min_angle_deg

    def next_camera(self) -> int | None:
        """The unregistered member whose 2D points on existing 3D points cover its image best."""
        best, best_score = None, 0.0
        for c in self.members:
            if c in self.poses or c in self.failed:
                continue
            keys = [k for k in self.obs.per_camera[c] if k in self.points]
            if len(keys) < self.params.min_pnp:
                continue
            uv = np.array([self.obs.per_camera[c][k] for k in keys])
            score = overlap_score(uv, self.obs.cameras[c], self.params) if self.params.overlap_ordering else len(uv)
            if score > best_score:
                best, best_score = c, score
        return best

    def register(self, c: int) -> bool:
        """Pose camera c on the group's points it sees (PnP, with its focal length if
        unknown), the 2D-2D alternatives competing in the verification; False (the reason
        in `failed`) if PnP finds too few consistent points."""
        keys = [k for k in self.obs.per_camera[c] if k in self.points]
        obj = np.array([self.points[k] for k in keys])
        found = self._pnp(c, keys, obj)
        if found is None:
            return False
        rvec, tvec, idx = found
        img = np.array([self.obs.per_camera[c][k] for k in keys])
        if len(idx) < self.params.min_pnp:
            self.failed[c] = f"PnP found {len(idx)} consistent agent points (needs {self.params.min_pnp})"
            return False
        K = self.obs.cameras[c].K
        rvec, tvec = cv2.solvePnPRefineLM(obj[idx], img[idx], K, None, rvec, tvec)
        candidates = [inv_se3(se3(cv2.Rodrigues(rvec)[0], tvec.ravel()))] + self._rotation_candidates(c, obj, img)
        self.poses[c] = max(candidates, key=lambda T: self._verify(c, T))
        self.triangulate_new()
        return True

    def _pnp(self, c: int, keys: list[int], obj: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(rvec, tvec, inlier indices) of camera c's PnP RANSAC on the points `obj` of
        `keys`; an unknown camera's focal length is searched and set on the way. None (the
        reason in `failed`) if no focal length fits."""
        gate = self.params.pnp_px * self.obs.noise_scale[c]
        if c not in self.unknown:
            return sqpnp_ransac(
                obj, np.array([self.obs.per_camera[c][k] for k in keys]), self.obs.cameras[c].K, gate, seed=RANSAC_SEED
            )
        cam = self.obs.cameras[c]
        found = pnp_unknown_focal(
            obj,
            np.array([self.raw[c][k] for k in keys]),
            (cam.width, cam.height),
            self.params.hfov_range_deg,
            self.params.focal_steps,
            gate,
            self.params.min_pnp,
            self.params.estimate_k1,
            RANSAC_SEED,
        )
        if found is None:
            self.failed[c] = (
                f"PnP with unknown focal length found no focal with {self.params.min_pnp} consistent agent points"
            )
            return None
        model, rvec, tvec, idx = found
        self.set_intrinsics(c, model)
        return rvec, tvec, idx

    def _rotation_candidates(self, c: int, obj: np.ndarray, img: np.ndarray) -> list[np.ndarray]:
        """Poses of camera c whose rotation comes from its 2D-2D geometry with a posed camera
        and whose translation is fitted to its 2D-3D matches (obj, img)."""
        # Our addition: the group's points this camera sees may all be one id (one plane),
        # where PnP at high noise can flip. Rotations from the 2D-2D geometry with each posed
        # camera (as for the initial pair) compete with it in the same verification.
        K = self.obs.cameras[c].K
        norm = cv2.undistortPoints(img[:, None], K, None).reshape(-1, 2)
        candidates = []
        for r in list(self.poses):
            shared = np.array([k for k in self.obs.per_camera[c] if k in self.obs.per_camera[r]], dtype=np.int64)
            if len(shared) < self.params.min_matches:
                continue
            for T_rc in self._relative_candidates(r, c, shared):
                R_cl = (self.poses[r][:3, :3] @ T_rc[:3, :3]).T
                t = _translation_given_rotation(R_cl, obj, norm)
                err = np.linalg.norm(cv2.projectPoints(obj, cv2.Rodrigues(R_cl)[0], t, K, None)[0][:, 0] - img, axis=1)
                inl = err <= self.params.pnp_px * self.obs.noise_scale[c]
                if inl.sum() >= self.params.min_pnp:
                    rv, tv = cv2.solvePnPRefineLM(obj[inl], img[inl], K, None, cv2.Rodrigues(R_cl)[0], t)
                    candidates.append(inv_se3(se3(cv2.Rodrigues(rv)[0], tv.ravel())))
        return candidates

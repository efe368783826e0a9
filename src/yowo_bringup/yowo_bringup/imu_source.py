"""Where the ego IMU's calibration comes from when a recording holds no
/ego/imu/calibration: Kalibr's camchain-imucam.yaml and imu.yaml given by the user, or the
extrinsics a driver publishes on /tf_static with noise from the Kalibr file or the
documented defaults (InputParams). The result is the calibration text the ego mapper
parses (yowo_ego.imu.ImuCalibration.from_yaml), and what the run log says about it."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

NOISE_KEYS = (
    "gyroscope_noise_density",
    "gyroscope_random_walk",
    "accelerometer_noise_density",
    "accelerometer_random_walk",
)


@dataclass(frozen=True)
class ImuNoiseDefaults:
    """Used where no Kalibr imu.yaml is given: densities of the Bosch BMI055 data sheet (the
    IMU of the RealSense D435i/D455), random walks mid-range of what users measure on it."""

    gyroscope_noise_density: float = 2.44e-4  # gyroscope white noise, used without a Kalibr imu.yaml [rad/s/√Hz]
    gyroscope_random_walk: float = 1.0e-5  # gyroscope bias random walk [rad/s²/√Hz]
    accelerometer_noise_density: float = 1.47e-3  # accelerometer white noise [m/s²/√Hz]
    accelerometer_random_walk: float = 2.5e-4  # accelerometer bias random walk [m/s³/√Hz]


@dataclass
class ImuSource:
    """The IMU calibration a run uses ('' text: none, `reason` says why) and how it was found."""

    calibration_yaml: str = ""
    extrinsics: str = ""  # where T_cam_imu came from
    noise: str = ""  # where the noise densities came from
    reason: str = ""  # why the IMU is not used
    T_cam_imu: np.ndarray | None = field(default=None, repr=False)

    def describe(self) -> dict:
        if not self.calibration_yaml:
            return {"used": False, "reason": self.reason}
        return {
            "used": True,
            "extrinsics": self.extrinsics,
            "noise": self.noise,
            "T_cam_imu": [[round(float(v), 9) for v in row] for row in self.T_cam_imu],
        }


def _load(path: str, what: str) -> dict:
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{path}: no such {what} file")
    try:
        doc = yaml.safe_load(p.read_text())
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not YAML: {exc}") from exc
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: expected a YAML mapping ({what})")
    return doc


def kalibr_camchain(path: str, camera_topic: str = "") -> tuple[np.ndarray, float]:
    """(T_cam_imu, timeshift_cam_imu [s]) of the camera of a Kalibr camchain-imucam.yaml: the
    one whose rostopic is `camera_topic`, else cam0."""
    doc = _load(path, "Kalibr camchain-imucam")
    cams = {k: v for k, v in doc.items() if isinstance(v, dict) and "T_cam_imu" in v}
    if not cams:
        raise ValueError(f"{path}: no camera with T_cam_imu (is it Kalibr's camchain-imucam.yaml?)")
    by_topic = [v for v in cams.values() if camera_topic and v.get("rostopic") == camera_topic]
    cam = by_topic[0] if by_topic else cams.get("cam0", cams[sorted(cams)[0]])
    try:
        T = np.array(cam["T_cam_imu"], dtype=float)
        shift = float(cam.get("timeshift_cam_imu", 0.0))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: T_cam_imu / timeshift_cam_imu are not numbers: {exc}") from exc
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise ValueError(f"{path}: T_cam_imu must be a finite 4x4 matrix, got shape {T.shape}")
    return T, shift


def kalibr_imu_noise(path: str) -> dict[str, float]:
    """The noise densities and random walks of a Kalibr imu.yaml (flat, or under imu0 as
    Kalibr's results write it)."""
    doc = _load(path, "Kalibr imu")
    if "imu0" in doc and isinstance(doc["imu0"], dict):
        doc = doc["imu0"]
    missing = [k for k in NOISE_KEYS if k not in doc]
    if missing:
        raise ValueError(f"{path}: missing {', '.join(missing)} (Kalibr imu.yaml keys)")
    try:
        return {k: float(doc[k]) for k in NOISE_KEYS}
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: a noise value is not a number: {exc}") from exc


def static_transform(transforms, target: str, source: str) -> np.ndarray | None:
    """T_target_source (maps `source`-frame points into `target`) from /tf_static's
    (parent, child, T_parent_child) edges, walked in either direction; None when no path
    joins the two frames."""
    edges: dict[str, list[tuple[str, np.ndarray]]] = {}
    for parent, child, T in transforms:
        edges.setdefault(parent, []).append((child, np.asarray(T, dtype=float)))
        edges.setdefault(child, []).append((parent, np.linalg.inv(np.asarray(T, dtype=float))))
    seen, queue = {target: np.eye(4)}, deque([target])
    while queue:
        frame = queue.popleft()
        for nxt, T_frame_nxt in edges.get(frame, []):
            if nxt not in seen:
                seen[nxt] = seen[frame] @ T_frame_nxt
                queue.append(nxt)
    return seen.get(source)


def calibration_text(T_cam_imu: np.ndarray, noise: dict[str, float], rate_hz: float, shift_s: float) -> str:
    """The calibration as /ego/imu/calibration carries it (Kalibr's keys)."""
    return yaml.safe_dump(
        {
            **noise,
            "update_rate": float(rate_hz),
            "timeshift_cam_imu": float(shift_s),
            "T_cam_imu": [[float(v) for v in row] for row in T_cam_imu],
        },
        sort_keys=False,
    )


def resolve_imu(
    *,
    camchain: str,
    imu_yaml: str,
    defaults: ImuNoiseDefaults,
    rate_hz: float,
    camera_frame: str,
    imu_frame: str,
    tf_edges,
    camera_topic: str = "",
) -> ImuSource:
    """The IMU's calibration from the user's Kalibr files, else /tf_static. ValueError for a
    Kalibr file that cannot be read (named)."""
    if imu_yaml:
        noise, noise_from = kalibr_imu_noise(imu_yaml), f"Kalibr {imu_yaml}"
    else:
        noise = {k: getattr(defaults, k) for k in NOISE_KEYS}
        noise_from = "defaults (inputs.imu_noise_defaults: BMI055 data sheet)"
    if camchain:
        T, shift = kalibr_camchain(camchain, camera_topic)
        where = f"Kalibr {camchain}"
    else:
        shift = 0.0
        T = static_transform(tf_edges, camera_frame, imu_frame) if camera_frame and imu_frame else None
        if T is None:
            frames = f"from '{camera_frame or '?'}' to '{imu_frame or '?'}'"
            return ImuSource(
                reason=f"no extrinsics for the IMU: /tf_static has no path {frames}, the recording "
                "no /ego/imu/calibration; pass Kalibr's camchain-imucam.yaml with "
                "--set inputs.imu_camchain=FILE"
            )
        where = f"/tf_static ({camera_frame} -> {imu_frame})"
    return ImuSource(calibration_text(T, noise, rate_hz, shift), where, noise_from, T_cam_imu=T)

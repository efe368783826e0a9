"""Per-CMC agent keypoint tracks: smoothing (Savitzky-Golay), outlier gating,
undistortion, and interpolation to other cameras' stamps."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from yowo_common.camera import CameraModel

from .params import TrackParams

# scipy.signal and yowo_common.bundle (gtsam) are imported where tracks are smoothed: the
# keypoint trackers build tracks (keypoint_input) but never smooth them, and these two
# imports were most of a tracker's start-up.


@dataclass
class KeypointTrack:
    """One keypoint id seen by one camera over time (sorted by stamp)."""

    stamps_ns: np.ndarray  # (N,) int64
    uv: np.ndarray  # (N, 2) px
    confidence: np.ndarray  # (N,)

    def __len__(self) -> int:
        return len(self.stamps_ns)

    def subset(self, keep: np.ndarray) -> "KeypointTrack":
        return KeypointTrack(self.stamps_ns[keep], self.uv[keep], self.confidence[keep])


@dataclass
class CameraTracks:
    """Everything one CMC saw of the agent: its intrinsics and a track per keypoint id."""

    name: str
    camera: CameraModel
    tracks: dict[int, KeypointTrack] = field(default_factory=dict)
    frame_period_ns: int = 100_000_000  # nominal frame spacing (for gap detection / tolerances)

    @property
    def num_observations(self) -> int:
        return sum(len(t) for t in self.tracks.values())

    def span_ns(self) -> tuple[int, int] | None:
        """First and last stamp at which the agent was seen (None: never)."""
        stamps = [t.stamps_ns for t in self.tracks.values() if len(t.stamps_ns)]
        if not stamps:
            return None
        return int(min(s.min() for s in stamps)), int(max(s.max() for s in stamps))

    def shifted(self, offset_s: float) -> "CameraTracks":
        """These tracks on a clock `offset_s` behind this camera's own (stamps - offset)."""
        d = round(offset_s * 1e9)
        return CameraTracks(
            self.name,
            self.camera,
            {i: KeypointTrack(t.stamps_ns - d, t.uv, t.confidence) for i, t in self.tracks.items()},
            self.frame_period_ns,
        )


def segments(stamps_ns: np.ndarray, max_gap_ns: int) -> list[slice]:
    """Contiguous runs of samples with no gap longer than max_gap_ns."""
    if len(stamps_ns) == 0:
        return []
    breaks = np.flatnonzero(np.diff(stamps_ns) > max_gap_ns) + 1
    edges = [0, *breaks.tolist(), len(stamps_ns)]
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:])]


def _savgol(uv: np.ndarray, window: int, polyorder: int) -> np.ndarray:
    from scipy.signal import savgol_filter

    n = len(uv)
    w = min(window, n if n % 2 else n - 1)
    if w <= polyorder:
        return uv.copy()
    return savgol_filter(uv, w, polyorder, axis=0, mode="interp")


def _window(period_ns: int, params: TrackParams) -> int:
    return max(3, int(round(params.window_s * 1e9 / period_ns)) | 1)


def noise_px(track: KeypointTrack, period_ns: int, params: TrackParams) -> float:
    """Per-axis pixel noise of a raw track: robust sigma (MAD) of the residuals to the
    Savitzky-Golay fit over full windows, divided by sqrt(1 - c0), c0 being the fit's
    centre weight (the fit follows each sample's own noise by c0). Outliers are dropped
    first against the median pre-filtered fit: in the plain fit one outlier shifts a
    whole window of residuals. nan if too few samples."""
    from scipy.signal import savgol_coeffs, savgol_filter

    from yowo_common.bundle import robust_sigma

    track = track.subset(track.confidence >= params.min_confidence)
    window = _window(period_ns, params)
    max_gap = int(params.gap_factor * period_ns)
    if window <= params.polyorder + 1 or len(track) < params.min_noise_samples:  # an exact fit: no residual
        return float("nan")
    r0 = np.concatenate(
        [
            track.uv[seg] - _savgol(_running_median(track.uv[seg], 5), window, params.polyorder)
            for seg in segments(track.stamps_ns, max_gap)
        ]
    )
    track = track.subset(np.linalg.norm(r0, axis=1) <= 4.0 * robust_sigma(r0))
    half = window // 2
    res = [
        (track.uv[seg] - savgol_filter(track.uv[seg], window, params.polyorder, axis=0))[half:-half]
        for seg in segments(track.stamps_ns, max_gap)
        if seg.stop - seg.start > window
    ]
    r = np.concatenate(res) if res else np.zeros((0, 2))
    if len(r) < params.min_noise_samples:
        return float("nan")
    c0 = savgol_coeffs(window, params.polyorder)[half]
    return robust_sigma(r) / np.sqrt(1.0 - c0)


def noise_scale(cam: CameraTracks, params: TrackParams) -> float:
    """How much noisier than nominal a camera's best keypoint id is (>= 1): the factor on
    its pixel thresholds. The best id, as the geometry leans on it and other ids (body
    points) are noisier by nature, not by detector trouble."""
    sigmas = [noise_px(t, cam.frame_period_ns, params) for t in cam.tracks.values()]
    sigmas = [s for s in sigmas if np.isfinite(s)]
    return max(1.0, min(sigmas) / params.nominal_noise_px) if sigmas else 1.0


def clean_track(track: KeypointTrack, period_ns: int, params: TrackParams, scale: float = 1.0) -> KeypointTrack:
    """Drop low-confidence samples and outliers (far from the smoothed track; the gate
    times the camera's noise scale), then smooth what remains, segment by segment."""
    track = track.subset(track.confidence >= params.min_confidence)
    window = _window(period_ns, params)
    max_gap = int(params.gap_factor * period_ns)
    keep = np.ones(len(track), bool)
    for seg in segments(track.stamps_ns, max_gap):
        # Median pre-filter so a single outlier does not drag the polynomial fit.
        uv = track.uv[seg]
        ref = _savgol(_running_median(uv, 5), window, params.polyorder)
        keep[seg] = np.linalg.norm(uv - ref, axis=1) <= params.gate_px * scale
    track = track.subset(keep)
    smooth = track.uv.copy()
    for seg in segments(track.stamps_ns, max_gap):
        smooth[seg] = _savgol(track.uv[seg], window, params.polyorder)
    return KeypointTrack(track.stamps_ns, smooth, track.confidence)


def _running_median(uv: np.ndarray, k: int) -> np.ndarray:
    if len(uv) < k:
        return uv.copy()
    pad = np.pad(uv, ((k // 2, k // 2), (0, 0)), mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(pad, k, axis=0)
    return np.median(windows, axis=-1)


def undistort_tracks(cam: CameraTracks) -> CameraTracks:
    """Tracks in ideal pinhole pixels (same K, no distortion)."""
    return CameraTracks(
        cam.name,
        CameraModel(cam.camera.width, cam.camera.height, cam.camera.K),
        {i: KeypointTrack(t.stamps_ns, cam.camera.undistort_pixels(t.uv), t.confidence) for i, t in cam.tracks.items()},
        cam.frame_period_ns,
    )


def track_splines(track: KeypointTrack, max_gap_ns: int, origin_ns: int) -> list[tuple[float, float, object]]:
    """Per segment of a track (no gap over max_gap_ns) with two samples or more: its first
    and last time [s since origin_ns] and the spline through its samples (cubic, or of the
    highest degree its samples allow; derivatives for the clock fits)."""
    from scipy.interpolate import make_interp_spline

    ts = (track.stamps_ns - origin_ns) / 1e9
    return [
        (ts[s][0], ts[s][-1], make_interp_spline(ts[s], track.uv[s], k=min(3, s.stop - s.start - 1)))
        for s in segments(track.stamps_ns, max_gap_ns)
        if s.stop - s.start >= 2
    ]


def interpolate(track: KeypointTrack, stamps_ns: np.ndarray, max_gap_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Track position at the given stamps: a sample's own at its stamp, the cubic spline
    through its segment between samples (no extrapolation, no bridging of gaps over
    max_gap_ns). Returns (uv (K, 2), valid mask (K,)). Cameras whose clocks differ sample
    the agent at other instants: at half a frame of a 10 Hz track, linear interpolation
    cuts a 2 Hz swing (ankles, wrists) by a fifth, the spline by about 1 %."""
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    uv = np.full((len(stamps_ns), 2), np.nan)
    ok = np.zeros(len(stamps_ns), bool)
    if len(track) == 0:
        return uv, ok
    origin = int(track.stamps_ns[0])
    t = (stamps_ns - origin) / 1e9
    for t0, t1, spline in track_splines(track, max_gap_ns, origin):
        inside = (t >= t0) & (t <= t1)
        if inside.any():
            uv[inside], ok[inside] = spline(t[inside]), True
    right = np.minimum(np.searchsorted(track.stamps_ns, stamps_ns), len(track) - 1)
    exact = track.stamps_ns[right] == stamps_ns
    uv[exact] = track.uv[right[exact]]
    return uv, ok | exact


def sigma_factors(track: KeypointTrack, stamps_ns: np.ndarray, params: TrackParams) -> np.ndarray:
    """Per stamp, the factor on a bundle adjustment's sigma from the confidence of the
    track's nearest sample: full / its confidence for weak samples (weak_confidence_ratio),
    1 otherwise. Simulated keypoints (confidence 0.85 +- 0.03, outliers 0.7x) are never weak."""
    if len(track) == 0:
        return np.ones(len(stamps_ns))
    after = np.minimum(np.searchsorted(track.stamps_ns, stamps_ns), len(track) - 1)
    before = np.maximum(after - 1, 0)
    nearest = np.where(
        np.abs(track.stamps_ns[before] - stamps_ns) < np.abs(track.stamps_ns[after] - stamps_ns), before, after
    )
    conf = track.confidence[nearest]
    full = float(np.percentile(track.confidence, 90))
    return np.where(conf < params.weak_confidence_ratio * full, full / np.maximum(conf, 1e-3), 1.0)


def resample(
    cam: CameraTracks, stamps_ns: np.ndarray, params: TrackParams, scale: float | None = None
) -> tuple[CameraModel, dict[int, tuple[np.ndarray, np.ndarray]]]:
    """Clean and undistort every keypoint track of a camera and interpolate it at the
    given stamps: (ideal pinhole model, {id: (uv (K, 2), valid (K,))}). `scale`: the
    camera's noise_scale when the caller has it already."""
    scale = noise_scale(cam, params) if scale is None else scale
    cleaned = CameraTracks(
        cam.name,
        cam.camera,
        {i: clean_track(t, cam.frame_period_ns, params, scale) for i, t in cam.tracks.items()},
        cam.frame_period_ns,
    )
    ideal = undistort_tracks(cleaned)
    max_gap = int(params.gap_factor * cam.frame_period_ns)
    return ideal.camera, {i: interpolate(t, stamps_ns, max_gap) for i, t in ideal.tracks.items()}

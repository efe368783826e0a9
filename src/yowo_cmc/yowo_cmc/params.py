"""The parameters of the CMC tracks and the group SfM, apart from the algorithms: the
configuration tree (config.py) imports these, and a keypoint tracker needs the tree but
none of the SfM's libraries (scipy.signal, gtsam, networkx), which are slow to import."""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class TrackParams:
    window_s: float = 0.7           # Savitzky-Golay window
    polyorder: int = 2
    gap_factor: float = 2.5         # a gap longer than this many frame periods splits a segment
    gate_px: float = 8.0            # residual to the smoothed track above which a sample is dropped
    min_confidence: float = 0.1
    # Our addition (the paper's CMC BA has no detection confidence): a sample rated below
    # this fraction of its track's full confidence (90th percentile; not the median, as
    # most of a track can be weak) is a weaker kind of detection (the image detector's
    # ground point from the feet alone: 0.3x a full one); the bundle adjustment scales its
    # sigma by full confidence / its confidence.
    weak_confidence_ratio: float = 0.5
    # The pixel thresholds here and in SfmParams were tuned on detections whose best
    # keypoint id has ~1 px noise (estimated 0.9-1.9 px by noise_px). A camera whose best id
    # is noisier than this has them scaled by the ratio (noise_scale); never below 1.
    nominal_noise_px: float = 1.5
    min_noise_samples: int = 20     # residuals needed for a track's noise estimate


@dataclass(frozen=True)
class SfmParams:
    min_matches: int = 8                 # per edge of the scene graph (paper: eight)
    ransac_px: float = 2.0               # MAGSAC threshold on the epipolar error
    grid_cols: int = 16                  # N_GW
    grid_rows: int = 12                  # N_GH
    per_cell: int = 6                    # correspondences per grid cell fed to RANSAC
    min_pnp: int = 8
    pnp_px: float = 4.0
    max_reproj_px: float = 6.0           # triangulated points beyond this are not kept
    min_angle_deg: float = 1.0           # triangulation angle below which points are unreliable
    initial_sigma_px: float = 1.5
    tracks: TrackParams = field(default_factory=TrackParams)
    # Switches for the ECCMP-style baseline: the pair with most inliers first, then the
    # camera with most 2D-3D matches, one sigma for every keypoint id.
    min_init_fraction: float = 0.5      # of the initial pair's inliers that must triangulate
    overlap_ordering: bool = True
    per_id_sigma: bool = True
    # Variance component estimation: robust BA rounds, each weighting a keypoint id by the
    # residual spread of the previous round (real pose keypoints: 1-18 px by id on Pose2Sim's
    # demo, face lowest, wrists and hips highest). One re-estimate (2 rounds) keeps weights
    # from the first, equally weighted round's residuals, which the noisy ids inflate for
    # all; stop early once no sigma moves by more than sigma_tolerance. (Pose2Sim's demo,
    # OpenPose keypoints, clocks as recorded: 1.09 % of the mean baseline / 0.99 deg with 2
    # rounds, 0.63 % / 0.83 deg with 4; a factor per camera on top measured worse, 0.97 %.)
    sigma_rounds: int = 4
    sigma_tolerance: float = 0.05
    # Our addition to the paper's edge rule: an edge's inliers must also cover both
    # images (eq. overlap of each side >= this). A camera that sees the agent only
    # through a doorway shares many matches with the next room's cameras, all in one
    # strip of its image: a weak edge that pulls a whole group off by centimetres.
    # (The ECCMP-style baseline sets 0: no overlap scores.)
    min_edge_overlap: float = 0.5
    # True: cameras left out of the 2-edge-connected groups pair up along their strongest
    # edges (more cameras get a relative calibration). Off by default: such pairs (often
    # in corridors) align to the map worse than their cameras register one by one
    # (standard s0, with joint optimisation: 2.8 cm / 0.38 deg avg with, 2.2 cm / 0.24 deg
    # without). False: only a pair that is a component of its own is a group.
    pair_leftovers: bool = False

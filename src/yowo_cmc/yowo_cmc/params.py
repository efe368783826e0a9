"""The sections of the cmc configuration (config.py, its root) apart from their
algorithms: the keypoint tracks, the group SfM, the clock offsets, the model-free
detector and the pose model. A keypoint tracker needs the tree but none of the SfM's
libraries (scipy.signal, gtsam, networkx), which are slow to import."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class TrackParams:
    window_s: float = 0.7  # Savitzky-Golay window
    polyorder: int = 2
    gap_factor: float = 2.5  # a gap longer than this many frame periods splits a segment
    gate_px: float = 8.0  # residual to the smoothed track above which a sample is dropped
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
    min_noise_samples: int = 20  # residuals needed for a track's noise estimate


@dataclass(frozen=True)
class SfmParams:
    min_matches: int = 8  # per edge of the scene graph (paper: eight)
    ransac_px: float = 2.0  # MAGSAC threshold on the epipolar error
    grid_cols: int = 16  # N_GW
    grid_rows: int = 12  # N_GH
    per_cell: int = 6  # correspondences per grid cell fed to RANSAC
    min_pnp: int = 8
    pnp_px: float = 4.0
    max_reproj_px: float = 6.0  # triangulated points beyond this are not kept
    min_angle_deg: float = 1.0  # triangulation angle below which points are unreliable
    initial_sigma_px: float = 1.5
    tracks: TrackParams = field(default_factory=TrackParams)
    # Switches for the ECCMP-style baseline: the pair with most inliers first, then the
    # camera with most 2D-3D matches, one sigma for every keypoint id.
    min_init_fraction: float = 0.5  # of the initial pair's inliers that must triangulate
    overlap_ordering: bool = True
    class_sigma: bool = True
    # Variance component estimation: robust BA rounds, each weighting a keypoint class by the
    # residual spread of the previous round. Real pose keypoints differ in noise by class (face
    # ~1 px, body 3-12 px, hands 5-27 px between views). A sigma per id measured better on a
    # moving person (Pose2Sim's demo 0.76 % of the mean baseline against 1.10 % per class) but
    # on a seated one an id's errors are the same view-dependent bias in every frame, its sigma
    # rests on a few numbers, and ids that happen to fit a wrong pose gain weight and pull it
    # further (caliscope's demo: 6.75 % per id, 1.67 % per class). Classes split at these ids:
    # 0 derived head top, 1 derived ground point, 2-99 body joints, 100-499 hands, >= 500 face
    # (docs/pose_model.md and docs/usage.md "Real multi-camera recordings"). One re-estimate (2 rounds) keeps
    # weights from the first, equally weighted round's residuals, which the noisy classes
    # inflate for all; stop early once no sigma moves by more than sigma_tolerance.
    sigma_class_bounds: tuple[int, ...] = (1, 2, 100, 500)
    sigma_rounds: int = 4
    sigma_tolerance: float = 0.05
    # Triangulation gate (px, times the noise scale) for points re-tried in the rounds after the
    # first BA: wider than max_reproj_px, which guards the incremental registration against
    # outliers (a 9-12 px gate there broke the model-free detector's group on small normal s0).
    # Real keypoints' view-dependent errors are 10-25 px: with 6 px the rounds keep only the
    # views that agree with the current poses. caliscope 2.22 -> 1.67 %, Pose2Sim 1.30 -> 1.10 %.
    rounds_reproj_px: float = 9.0
    # True: a group whose robust rounds measured a keypoint class noisier than tracks.nominal_noise_px
    # (real pose keypoints: 3-5 px between views) is reconstructed again with that class's gates
    # widened by sigma / nominal (group_sfm.geometric_gate_scales), for the classes at least
    # min_gate_scale times nominal: a gate a few per cent wider changes nothing but doubles the
    # group's time (the simulator's dim_light s0 measured one class at 1.01x nominal).
    geometric_gates: bool = True
    min_gate_scale: float = 1.2
    # ... and kept only if the first reconstruction's points, triangulated with the new poses,
    # reproject (median) within this factor of their residual under the first poses.
    max_agreement_ratio: float = 1.5
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
    # A group whose cameras hang together by a cut this weak (inliers across it / inliers at
    # the smaller side's cameras) is split there: two rooms joined by glimpses through a
    # doorway (a few keypoints in a few dozen frames) make one self-consistent reconstruction
    # whose far room is turned by tens of degrees; each side alone is aligned to the ego map
    # by its own view of the walk. Measured weakest cuts: the 42-camera floor's two doorway
    # joins 0.013 / 0.016 (rooms 8+9: 265 inliers across, ~11,000 within each room), its two
    # rooms seen together by one camera 0.215; Pose2Sim's demo 0.63, caliscope's 0.70 (4
    # cameras around one person). 0: never split.
    max_cut_conductance: float = 0.1
    # Cameras without intrinsics (group_sfm_node's estimate_intrinsics): their focal length is
    # searched between these horizontal fields of view [deg] (pair: two-view geometry; PnP:
    # focal_steps values, log spaced) and refined in the group bundle adjustment.
    hfov_range_deg: tuple[float, float] = (20.0, 150.0)
    focal_steps: int = 24
    # ... with their radial distortion k1 (False: held at 0, which biases the focal of a distorted lens)
    estimate_k1: bool = True


@dataclass(frozen=True)
class ClockParams:
    # Search range of a pair's offset |clock b - clock a|: twice the largest |offset| of one
    # camera (+-1 s each: pairs up to 2 s apart), with a margin.
    max_offset_s: float = 2.5
    coarse_step_frames: float = 0.5  # coarse grid step, in frame periods of the faster camera
    min_correspondences: int = 40  # co-visible samples (all keypoint ids) a pair needs at a shift
    coarse_points: int = 150  # correspondences (spatially spread) per essential-matrix fit
    # RANSAC iterations per fit: at a wrong shift most correspondences are outliers and
    # the fit would run to OpenCV's 1000; near the right one it stops far sooner.
    coarse_iterations: int = 300
    # Coarse to fine: first a cheap fit (search_iterations, search_points) every
    # search_step_frames, then the full cost on the coarse grid only within one search step of
    # the search_candidates best of those shifts (the best, then the next best more than a
    # search step from those picked, ...). The cheap cost ranks shifts as the full one does
    # (the same average over all of camera a's samples, so rooms walked one after the other
    # still cost their unmatched samples) but is noisier: on the simulator's recordings and
    # the synthetic views the true minimum was among its best 3. Pose2Sim's demo (60 fps):
    # 601 full fits per pair before, 301 cheap + <= 25 full now (23 -> 7.7 s CPU).
    # 0: the full cost at every shift.
    search_candidates: int = 5
    search_step_frames: float = 1.0  # in frame periods of the faster camera (a multiple of coarse_step_frames)
    search_iterations: int = 50
    search_points: int = 60
    # A pair's best shift counts only if it stands this many noise levels below the median
    # cost (clock.prominence). Real recordings of a seated person (caliscope's 4-camera
    # demo, stamps from one host clock): 2.7-8.2, with spurious offsets of 0.1-0.96 s that
    # cost the group 5.4 -> 18 % of the mean baseline; Pose2Sim's demo 18.7-41; the
    # simulator's walks 9.7-17.5.
    min_prominence: float = 6.0
    truncate_px: float = 3.0  # coarse cost: Sampson error truncated here (x the pair's noise scale)
    huber_px: float = 1.0  # refinement: Huber loss scale (x the pair's noise scale)
    # A pair's sigma from the curvature assumes independent residuals, with their spread;
    # the tracks are Savitzky-Golay smoothed, which shrinks the residuals by sqrt(c0) (the
    # filter's centre weight) but not the slow noise a shift is fitted to: the sigma is
    # scaled by 1 / sqrt(c0).
    correlated_sigma: bool = True
    max_pair_sigma_s: float = 0.02  # pair estimates less certain are not used (agent barely moving)
    min_sigma_s: float = 1e-5  # floor on a pair's sigma: noise-free pairs would get unbounded weight
    max_residual_sigma: float = 5.0  # a pair this many sigma off the global solution is dropped ...
    min_residual_s: float = 0.005  # ... if it is also this far off (sigmas can be optimistic)
    apply: bool = True  # the group SfM runs on stamps corrected by the estimated offsets
    # ... those farther than this many sigma from 0: one within its noise of 0 is kept at 0
    # (synchronised cameras stay on their stamps; applying noise cost accuracy: Pose2Sim's
    # demo, pose model, offsets 3-17 ms at sigma 8-12 ms: 2.29 % of the mean baseline applied,
    # 1.88 % at 0).
    min_significance: float = 3.0
    # Per group, the pairwise offsets are refined in one fit with the group's poses and
    # agent points (the pairs' epipolar fits each see two cameras only: 10-40 ms off on
    # the simulator's recordings, a few cm of relative pose).
    refine: bool = True
    refine_range_s: float = 0.1  # largest correction of the refinement
    refine_max_points: int = 3000  # agent points in the fit (evenly spread in time)
    refine_min_observations: int = 50  # a member's observations the fit needs to refine its offset


@dataclass(frozen=True)
class DetectorParams:
    warmup_s: float = 20.0  # the background starts as the per-pixel median over this long
    warmup_samples: int = 40  # frames (evenly spaced) in that median
    hold_jpeg_quality: int = 95  # frames waiting for the background are held JPEG-encoded
    diff_low: float = 10.0  # colour difference (grey levels, max over channels) of agent pixels
    diff_high: float = 30.0  # a blob needs pixels this different (hysteresis seeds)
    min_area: float = 4e-4  # blob area gates, fraction of the image
    max_area: float = 0.5
    background_rate: float = 0.02  # running-average weight per frame away from the agent
    flaw_rate: float = 0.3  # weight inside blobs that are background flaws (fast healing)
    flaw_edge_ratio: float = 1.5  # a blob whose outline edge is weaker than this times both the
    #                                  background's edge there and the frame's texture around is a flaw
    shadow_ratio: tuple[float, float] = (0.6, 0.95)  # brightness ratio to the background of shadow pixels
    shadow_chroma: float = 8.0  # colour deviation (grey levels) allowed in shadow pixels
    track_jump: float = 0.5  # largest move of the blob centre per frame, in blob heights
    track_gap_s: float = 1.0  # a track unseen longer than this starts anew
    geometry_frames: int = 40  # distinct silhouettes before the first estimate of d and rho
    min_geometry_frames: int = 8  # at the end of the stream, fewer: no keypoints
    max_geometry_frames: int = 400
    distinct_px: float = 4.0  # a silhouette is new for the geometry when its centre moved this far
    settle_deg: float = 0.2  # frames are emitted once two successive estimates of d agree this well
    settle_rho: float = 0.003  # ... and of rho
    scene_cone_deg: float = 8.0  # scene edges may move the agent's vertical this far (by its misfit)
    top_band_px: float = 3.0  # outline points this close to the top set the head's sideways position
    head_radius: float = 0.05  # head radius / agent height (anthropometric; 0 disables the correction)
    max_height_misfit: float = 0.1  # silhouettes whose head and lowest point imply a height ratio this far
    #                                  from rho are partly hidden: no keypoints (the gait alone scatters 0.035)
    foot_reach: float = 0.11  # mean horizontal distance, / agent height, from the point under the head
    #                                  to the sole point nearest to the camera (shoe length and stride;
    #                                  measured on simulated walks of the anthropometric body model)


@dataclass(frozen=True)
class PoseModelParams:
    model: str = "movenet"  # "movenet" (multi-person, one pass) or "blazepose" (detector + landmarks)
    threads: int = 1  # LiteRT interpreter threads (one core per camera)
    input_size: int = 256  # movenet: long side of the network input (multiple of 32; 256 is
    #                                   the model's training size, larger finds smaller persons, slower)
    min_person_score: float = 0.2  # persons below this score are dropped
    # Top-down refinement (movenet): the whole-frame pass sees a small person in a big frame at a few
    # pixels per joint (Pose2Sim's 1080x1920 videos: ~110 px tall in the 256 input), so each person
    # found is passed through the model again on a square crop around its box, resized to input_size
    # (the person ~200 px tall there, whatever the frame size). Measured (docs/pose_model.md): hand-marked
    # photos median 1.2 -> 0.9 % of the height; simulator ankles 6.5 -> 2.1 px, head top 11 -> 6.6 px
    # (shoulders 11 -> 14 px); 640x480 on one core 41 -> 17 frames/s.
    refine_crop: bool = True  # movenet: the second pass on each person's crop (PoseKeypointSource:
    #                                   on the agent only, one more pass per image)
    refine_margin: float = 1.3  # the box times this fits in the crop (the whole-frame box can be
    #                                   short of a limb; the crop must hold the whole person)
    refine_aspect: float = 1.0  # the crop's short side / long side (1: square; 0.5 halves the crop
    #                                   pass's cost, but on Pose2Sim gave 3.3 % against the square's 1.4 %)
    refine_max_zoom: float = 1.0  # the crop is never magnified more than this (a small person's crop
    #                                   grows instead): upsampling adds no detail, and the model's
    #                                   confidences drop on the blurred input (320x240: hips 0.6 -> 0.3)
    max_persons: int = 6  # blazepose: landmark passes per image (movenet: always <= 6)
    detector_score: float = 0.5  # blazepose: person detector score threshold (MediaPipe's)
    nms_iou: float = 0.3  # blazepose: overlapping person detections merged above this IoU
    joint_score: float = 0.3  # joints below this confidence do not feed the derived ids 0 and 1
    min_keypoint_score: float = 0.3  # keypoints below this are left out of a KeypointFrame (MoveNet puts
    #                                   joints cut by the border on the border at 0.1-0.26)
    border_px: float = 0.0  # joints farther than this outside the image get confidence 0
    ankle_to_ground: float = 0.15  # movenet ground point: below the ankles by this times hip-to-ankle
    #                                   (ankle joint ~10 cm above the floor in shoes, hip ~93 cm)
    # Left/right: a model labels them by appearance and swaps them for a person seen from behind or
    # above; a swapped id is a gross outlier across cameras (docs/pose_model.md, "Left and right").
    lr_window_s: float = 0.6  # the walking direction of a pair's midpoint: a line fit over this
    #                                   span centred on the frame (frames go out lr_window_s / 2 late)
    lr_min_motion: float = 0.08  # ... decides only if the midpoint moves this much over the window
    #                                   (fraction of the person's box size; walking: ~0.25)
    lr_min_offset: float = 0.06  # a pair whose left-to-right offset across the walking direction
    #                                   (or, standing, its offset) is below this (fraction of the box
    #                                   size) is ambiguous: dropped
    lr_resolve: bool = True  # False: the model's own labels as they come (to measure them)
    lr_track_s: float = 1.0  # standing: the pair follows its last decided assignment in the
    #                                   same track if that is at most this old; else it is dropped

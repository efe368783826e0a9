"""The sections of the cmc configuration (config.py, its root) apart from their
algorithms: the keypoint tracks, the group SfM, the clock offsets, the model-free
detector and the pose model. A keypoint tracker needs the tree but none of the SfM's
libraries (scipy.signal, gtsam, networkx), which are slow to import."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class KeypointFormatParams:
    # The detector's skeleton of every camera's agent keypoints: a format (coco17, coco18,
    # body25, body25b, halpe26, blazepose33, holistic) or a YAML table {id: {name, class}}; ''
    # undeclared. Declared, ids 0 and 1 are derived from the joints where the detector does
    # not publish them and the noise classes come from the skeleton (yowo_cmc.skeletons).
    skeleton: str = ""
    # CAMERA=SKELETON entries over `skeleton` for single cameras; every declared camera must
    # use one skeleton, as ids are matched across cameras.
    cameras: tuple[str, ...] = ()


@dataclass(frozen=True)
class TrackParams:
    window_s: float = 0.7  # Savitzky-Golay window the tracks are smoothed over
    polyorder: int = 2  # polynomial order of the Savitzky-Golay smoothing [order]
    gap_factor: float = 2.5  # a gap longer than this many frame periods splits a segment [x]
    gate_px: float = 8.0  # residual to the smoothed track above which a sample is dropped (x the noise scale)
    min_confidence: float = 0.1  # samples of a lower detection confidence are dropped [confidence]
    # A sample rated below this share of its track's full confidence is a weaker kind of
    # detection [share]. Our addition (the paper's CMC BA has no detection confidence): full
    # is the track's 90th percentile (not the median, as most of a track can be weak), a
    # weak sample e.g. the image detector's ground point from the feet alone; the bundle
    # adjustment scales its sigma by full confidence / its confidence.
    weak_confidence_ratio: float = 0.5
    # Noise of a camera's best keypoint id that the pixel thresholds (here and in SfmParams)
    # are tuned for. A camera whose best id is noisier (noise_px) has them scaled by the
    # ratio (noise_scale); never below 1.
    nominal_noise_px: float = 1.5
    min_noise_samples: int = 20  # residuals needed for a track's noise estimate [count]


@dataclass(frozen=True)
class SfmParams:
    # Inlier correspondences a camera pair needs for an edge of the scene graph (paper: eight) [count].
    min_matches: int = 8
    ransac_px: float = 2.0  # MAGSAC threshold on the epipolar error (x the pair's noise scale)
    grid_cols: int = 16  # columns of the image grid of the overlap scores and RANSAC subsets (paper: N_GW) [count]
    grid_rows: int = 12  # rows of that grid (paper: N_GH) [count]
    per_cell: int = 6  # correspondences per grid cell fed to RANSAC [count]
    # Consistent 2D-3D matches a camera needs to be registered by PnP (and agent points a group needs) [count].
    min_pnp: int = 8
    pnp_px: float = 4.0  # PnP RANSAC threshold on the reprojection error (x the camera's noise scale)
    max_reproj_px: float = 6.0  # triangulated points reprojecting farther are not kept (x the noise scale)
    min_angle_deg: float = 1.0  # triangulation angle below which points are unreliable
    # Keypoint sigma of the first bundle adjustment, before the classes' own (x the camera's noise scale).
    initial_sigma_px: float = 1.5
    tracks: TrackParams = field(default_factory=TrackParams)  # cleaning and smoothing of the tracks
    # Share of the initial pair's inliers that must triangulate, else the next pair is tried [share].
    min_init_fraction: float = 0.5
    # The initial pair by match score and the next camera by overlap score. False: by inlier
    # and 2D-3D match counts, as the ECCMP-style baseline.
    overlap_ordering: bool = True
    # A sigma per keypoint class, re-estimated in robust rounds. False: one sigma for every
    # keypoint id, as the ECCMP-style baseline.
    class_sigma: bool = True
    # Keypoint ids at which the keypoint classes split [id]. Variance component estimation:
    # robust BA rounds, each weighting a keypoint class by the residual spread of the previous
    # round, as real pose keypoints differ in noise by class (face, body, hands). A sigma per
    # id would fit a moving person, but on a seated one an id's errors are the same
    # view-dependent bias in every frame, its sigma rests on a few numbers, and ids that
    # happen to fit a wrong pose gain weight and pull it further. Classes: 0 derived head
    # top, 1 derived ground point, 2-99 body joints, 100-499 hands, >= 500 face
    # (docs/pose_model.md and docs/usage.md "Real multi-camera recordings").
    sigma_class_bounds: tuple[int, ...] = (1, 2, 100, 500)
    # Robust BA rounds at most, two at least [count]. One re-estimate (2 rounds) keeps weights
    # from the first, equally weighted round's residuals, which the noisy classes inflate for all.
    sigma_rounds: int = 4
    sigma_tolerance: float = 0.05  # the rounds stop once no class's sigma moves by more than this [share]
    # Triangulation gate of the points re-tried in the rounds after the first BA (x the noise
    # scale). Wider than max_reproj_px, which guards the incremental registration against
    # outliers (as wide there, it broke the model-free detector's groups); real keypoints'
    # view-dependent errors exceed max_reproj_px, which would keep only the views that agree
    # with the current poses.
    rounds_reproj_px: float = 9.0
    # A group is reconstructed again with the gates of its noisy keypoint classes widened. Its
    # robust rounds measure each class (real pose keypoints disagree between views more than
    # tracks.nominal_noise_px); the gates of a class at least min_gate_scale times nominal are
    # widened by sigma / nominal (group_sfm.geometric_gate_scales).
    geometric_gates: bool = True
    # Sigma / nominal noise from which a class's gates are widened [x]. A gate a few per cent
    # wider changes nothing but doubles the group's time.
    min_gate_scale: float = 1.2
    # The widened reconstruction is kept only if the first one's points, triangulated with
    # its poses, reproject (median) within this factor of their residual under the first poses [x].
    max_agreement_ratio: float = 1.5
    # Eq. overlap score that an edge's inliers need in each of its two images [score]. Our
    # addition to the paper's edge rule: a camera that sees the agent only through a doorway
    # shares many matches with the next room's cameras, all in one strip of its image: a weak
    # edge that pulls a whole group off. The ECCMP-style baseline sets 0 (no overlap scores).
    min_edge_overlap: float = 0.5
    # Cameras left out of the 2-edge-connected groups pair up along their strongest edges.
    # Off by default: such pairs (often in corridors) align to the map worse than their
    # cameras registered one by one. False: only a pair that is a component of its own is a group.
    pair_leftovers: bool = False
    # A group is split at a cut this weak: inliers across it / inliers at the smaller side's
    # cameras [share]. Two rooms joined by glimpses through a doorway make one self-consistent
    # reconstruction whose far room is turned; each side alone is aligned to the ego map by its
    # own view of the walk. A doorway's cut is far weaker than one between cameras that watch
    # the same room. 0: never split.
    max_cut_conductance: float = 0.1
    # Horizontal fields of view between which the focal length of a camera without intrinsics
    # is searched (group_sfm_node's estimate_intrinsics). Pair: two-view geometry; PnP:
    # focal_steps values, log spaced; the group bundle adjustment refines it.
    hfov_range_deg: tuple[float, float] = (20.0, 150.0)
    focal_steps: int = 24  # focal lengths an unknown camera's PnP tries over hfov_range_deg [count]
    # An unknown camera's radial distortion k1 is estimated too. False: held at 0, which
    # biases the focal of a distorted lens.
    estimate_k1: bool = True


@dataclass(frozen=True)
class ClockParams:
    # Largest offset of a pair's clocks searched, either way (clock b - clock a). Twice the
    # largest |offset| of one camera (+-1 s each: pairs up to 2 s apart), with a margin.
    max_offset_s: float = 2.5
    coarse_step_frames: float = 0.5  # step of the coarse shift grid, in frame periods of the faster camera [frames]
    min_correspondences: int = 40  # co-visible samples (all keypoint ids) a pair needs at a shift [count]
    coarse_points: int = 150  # correspondences (spatially spread) per essential-matrix fit [count]
    # RANSAC iterations per essential-matrix fit [count]. At a wrong shift most correspondences
    # are outliers and the fit would run to OpenCV's 1000; near the right one it stops far sooner.
    coarse_iterations: int = 300
    # Best shifts of the cheap search around which the full cost is evaluated [count]. Coarse
    # to fine: first a cheap fit (search_iterations, search_points) every search_step_frames,
    # then the full cost on the coarse grid only within one search step of the
    # search_candidates best of those shifts (the best, then the next best more than a search
    # step from those picked, ...). The cheap cost ranks shifts as the full one does (the same
    # average over all of camera a's samples, so rooms walked one after the other still cost
    # their unmatched samples) but is noisier. 0: the full cost at every shift.
    search_candidates: int = 5
    # Step of the cheap search, in frame periods of the faster camera (a multiple of coarse_step_frames) [frames].
    search_step_frames: float = 1.0
    search_iterations: int = 50  # RANSAC iterations per fit of the cheap search [count]
    search_points: int = 60  # correspondences per fit of the cheap search [count]
    # A pair's best shift counts only if it stands this far below the median cost
    # (clock_pairs.prominence) [noise levels]. A seated person's spurious minima stand lower
    # than a walk's true ones.
    min_prominence: float = 6.0
    truncate_px: float = 3.0  # coarse cost: Sampson error truncated here (x the pair's noise scale)
    huber_px: float = 1.0  # refinement: Huber loss scale (x the pair's noise scale)
    # A pair's sigma is scaled for the smoothed tracks' correlated residuals. The sigma from
    # the curvature assumes independent residuals, with their spread; the tracks are
    # Savitzky-Golay smoothed, which shrinks the residuals by sqrt(c0) (the filter's centre
    # weight) but not the slow noise a shift is fitted to: the sigma is scaled by 1 / sqrt(c0).
    correlated_sigma: bool = True
    max_pair_sigma_s: float = 0.02  # pair estimates less certain are not used (agent barely moving)
    min_sigma_s: float = 1e-5  # floor on a pair's sigma: noise-free pairs would get unbounded weight
    max_residual_sigma: float = 5.0  # a pair this far off the global solution is dropped (see min_residual_s) [sigma]
    # A pair max_residual_sigma off the global solution is dropped only if also this far off.
    # Sigmas can be optimistic.
    min_residual_s: float = 0.005
    apply: bool = True  # the group SfM runs on stamps corrected by the estimated offsets
    # An offset is applied only if it is farther than this from 0 [sigma]. One within its noise
    # of 0 is kept at 0: synchronised cameras stay on their stamps, as applying noise costs accuracy.
    min_significance: float = 3.0
    # Per group, the pairwise offsets are refined in one fit with the group's poses and agent
    # points. The pairs' epipolar fits each see two cameras only.
    refine: bool = True
    refine_range_s: float = 0.1  # largest correction of the refinement
    refine_max_points: int = 3000  # agent points in the refinement's fit (evenly spread in time) [count]
    refine_min_observations: int = 50  # a member's observations the fit needs to refine its offset [count]


@dataclass(frozen=True)
class DetectorParams:
    warmup_s: float = 20.0  # the background starts as the per-pixel median over this long
    warmup_samples: int = 40  # frames (evenly spaced over warmup_s) in that median [count]
    hold_jpeg_quality: int = 95  # JPEG quality of the frames held until the background exists [0-100]
    diff_low: float = 10.0  # colour difference to the background (max over channels) of agent pixels [grey levels]
    diff_high: float = 30.0  # colour difference a blob needs somewhere (hysteresis seeds) [grey levels]
    min_area: float = 4e-4  # smallest blob area, a share of the image [share]
    max_area: float = 0.5  # largest blob area, a share of the image [share]
    background_rate: float = 0.02  # running-average weight of a frame in the background away from the agent [share]
    flaw_rate: float = 0.3  # running-average weight inside blobs that are background flaws (fast healing) [share]
    # A blob whose outline edge is weaker than this times both the background's edge there and
    # the frame's texture around it is a flaw of the background [x].
    flaw_edge_ratio: float = 1.5
    shadow_ratio: tuple[float, float] = (0.6, 0.95)  # brightness ratio to the background of shadow pixels [x]
    shadow_chroma: float = 8.0  # colour deviation allowed in shadow pixels [grey levels]
    track_jump: float = 0.5  # largest move of the blob centre per frame, in blob heights [x]
    track_gap_s: float = 1.0  # a track unseen longer than this starts anew
    geometry_frames: int = 40  # distinct silhouettes before the first estimate of d and rho [count]
    min_geometry_frames: int = 8  # distinct silhouettes needed at the end of the stream, else no keypoints [count]
    max_geometry_frames: int = 400  # distinct silhouettes kept (thinned evenly over time beyond) [count]
    distinct_px: float = 4.0  # a silhouette is new for the geometry when its centre moved this far
    settle_deg: float = 0.2  # frames wait until two successive estimates of d agree this well
    # Frames also wait until two successive estimates of rho (agent / camera height) agree this well [ratio].
    settle_rho: float = 0.003
    scene_cone_deg: float = 8.0  # scene edges may move the agent's vertical this far (by its misfit)
    top_band_px: float = 3.0  # outline points this close to the top set the head's sideways position
    # Head radius / agent height, for the round head's correction (anthropometric; 0 disables it) [ratio].
    head_radius: float = 0.05
    # Silhouettes whose head and lowest point imply a height ratio this far from rho are partly
    # hidden: no keypoints [ratio]. The gait alone scatters it far less.
    max_height_misfit: float = 0.1
    # Mean horizontal distance from the point under the head to the sole point nearest to the
    # camera, per agent height [ratio]. Shoe length and stride, measured on simulated walks of
    # the anthropometric body model.
    foot_reach: float = 0.11


@dataclass(frozen=True)
class PoseModelParams:
    model: str = "movenet"  # "movenet" (multi-person, one pass) or "blazepose" (detector + landmarks)
    threads: int = 1  # LiteRT interpreter threads (one core per camera) [count]
    # Movenet: long side of the network input, a multiple of 32 [px]. The model's training
    # size; larger finds smaller persons, slower.
    input_size: int = 256
    min_person_score: float = 0.2  # persons scored below this are dropped [score]
    # Movenet: each person found is passed through the model again on a crop around its box.
    # The whole-frame pass sees a small person in a big frame at a few pixels per joint; the
    # crop, resized to input_size, shows the person at the same size whatever the frame size
    # (docs/pose_model.md). PoseKeypointSource refines the agent only: one more pass per image.
    refine_crop: bool = True
    # The person's box times this fits in the crop [x]. The whole-frame box can be short of a
    # limb; the crop must hold the whole person.
    refine_margin: float = 1.3
    # The crop's short side / long side [ratio]. 1: square; a narrower crop costs less but
    # measured worse (docs/pose_model.md).
    refine_aspect: float = 1.0
    # Largest magnification of the crop [x]. A small person's crop grows instead: upsampling
    # adds no detail, and the model's confidences drop on the blurred input.
    refine_max_zoom: float = 1.0
    max_persons: int = 6  # blazepose: landmark passes per image (movenet: always <= 6) [count]
    detector_score: float = 0.5  # blazepose: person detector score threshold (MediaPipe's) [score]
    nms_iou: float = 0.3  # blazepose: overlapping person detections merged above this IoU [share]
    joint_score: float = 0.3  # joints below this confidence do not feed the derived ids 0 and 1 [confidence]
    # Keypoints below this confidence are left out of a KeypointFrame [confidence]. MoveNet puts
    # joints cut by the border on the border, at a low confidence.
    min_keypoint_score: float = 0.3
    border_px: float = 0.0  # joints farther than this outside the image get confidence 0
    # Movenet ground point: below the ankles' midpoint by this times hip-to-ankle [x]. The ankle
    # joint lies about 10 cm above the floor in shoes, the hip about 93 cm.
    ankle_to_ground: float = 0.15
    # Span of the line fit that gives a pair's walking direction, centred on the frame: frames
    # go out lr_window_s / 2 late. Left/right: a model labels them by appearance and swaps them
    # for a person seen from behind or above; a swapped id is a gross outlier across cameras
    # (docs/pose_model.md, "Left and right").
    lr_window_s: float = 0.6
    # Move of a pair's midpoint over lr_window_s from which the walking direction decides, a
    # share of the person's box size [share]. Walking moves it several times as far.
    lr_min_motion: float = 0.08
    # A pair whose left-to-right offset across the walking direction (or, standing, its offset)
    # is below this share of the box size is ambiguous: dropped [share].
    lr_min_offset: float = 0.06
    lr_resolve: bool = True  # False: the model's own labels as they come (to measure them)
    # Standing, a pair follows its last decided assignment in the same track if that is at most
    # this old; else it is dropped.
    lr_track_s: float = 1.0


@dataclass(frozen=True)
class PeopleParams:
    """Every person a camera sees (yowo_cmc.person_tracks) and which of them is the walker
    (yowo_cmc.walker), for the pose model's source."""

    # A person's box centre may move this far from where its track heads, in body heights
    # (its box's height), plus max_speed_heights_s per second since the track's last image
    # [body heights].
    max_move_heights: float = 0.3
    max_speed_heights_s: float = 1.5  # a fast walk's pace in body heights [1/s]
    max_size_change: float = 0.5  # largest |log| of a box height ratio between images [log]
    # Largest clothes-colour (Bhattacharyya) distance at which a person may continue a track
    # [distance]. Two people in different clothes are far apart; one person's own look changes
    # with the view and the light.
    max_appearance_distance: float = 0.45
    # Largest clothes-colour distance at which two tracks of one camera, never in view at once,
    # are joined as one person's [distance].
    link_appearance_distance: float = 0.4
    appearance_weight: float = 1.0  # weight of the colour distance against the move [body heights]
    appearance_rate: float = 0.1  # share of each new image in a track's appearance [share]
    lost_after_s: float = 1.5  # a track not seen for this long ends; a later person starts a new one
    # Persons whose boxes overlap at least this much are crowded: their keypoints may be each
    # other's, so neither image is used as the walker's [IoU].
    crowded_iou: float = 0.1
    # Walker evidence: each track's stops and walks against the ego camera's, the walker's
    # moving and standing in step with the head camera's.
    smooth_s: float = 1.0  # speeds are averaged over this window before moving/standing is read
    grid_s: float = 0.1  # time step on which tracks and the ego trajectory are compared
    track_moving_heights_s: float = 0.15  # a track faster than this is walking [body heights/s]
    ego_moving_mps: float = 0.25  # the head camera faster than this is walking [m/s]
    # A tracker in a graph run waits for the ego camera's odometry to reach its last image; it
    # stops waiting when none has come for this long (an ego stage that stalled).
    ego_wait_s: float = 60.0
    # Largest clock offset between a ceiling camera and the ego camera searched [s]; an NVR's
    # clock can be seconds off.
    max_clock_offset_s: float = 10.0
    min_track_s: float = 2.0  # shorter tracks are no candidates for the walker
    # A track's evidence counts when the ego camera both walked and stood for at least this
    # share of the time they overlap: moving all along tells nobody apart [share].
    min_state_share: float = 0.1
    # Agreement (balanced over the ego's walking and standing) a track needs to be the walker;
    # an unrelated person agrees half of the time [share].
    accept_agreement: float = 0.75
    # Lead of the agreement's lower confidence bound over that of any other person seen at the
    # same time in the same camera [share]. Less: no track is clearly the walker, and the camera
    # is not registered from a guess.
    min_margin: float = 0.05
    # The one person a camera ever sees is not the walker when its agreement is below this (it
    # moves unlike the head camera) [share].
    reject_agreement: float = 0.6
    # A CMC-only run takes everyone the pose model saw, matched across cameras
    # (yowo_cmc.people_identity), as evidence of the cameras' relative poses, not the walker only.
    # Off: on simulated walks with bystanders crossing the same rooms the matching by epipolar
    # geometry alone pairs different people (docs/notes/people.md).
    others_as_evidence: bool = False
    # Most of a person's keypoints seen by two cameras at once are inliers of the pair's one
    # geometry of every person matched (pose keypoints have outliers; another person's fit only
    # by chance): the share needed for the two to be one person [share].
    match_min_share: float = 0.5
    # A wrong match pulls the one geometry away from the right ones: the share of the keypoints
    # held before that the geometry must still hold with a newly matched person [share].
    match_min_kept: float = 0.7


@dataclass(frozen=True)
class CoverageParams:
    # Share of the image grid's cells (cmc.sfm.grid_cols x grid_rows, the overlap score's grid)
    # in which a camera must see the agent [share]. A pose and its intrinsics are fixed by
    # points spread over the image; a fifth of the cells is a walk through much of the view.
    min_cell_share: float = 0.2
    # A third of the image (across or down) holding less than this share of a camera's
    # observations counts as empty [share]. A few stray detections do not cover a region.
    min_region_share: float = 0.02
    # Agent keypoint observations (grid time x keypoint id) a camera needs [count]. Several
    # seconds of a walker's skeleton; fewer leave the pose to a handful of poses of the agent.
    min_observations: int = 200
    # Nearest-to-farthest spread of the agent's depths (5th to 95th percentile) a camera
    # needs, a share of the median depth [share]. One depth only couples the focal length
    # with the distance along the optical axis.
    min_depth_spread: float = 0.2
    # Grid times at which another camera must see the agent too for the pair to count as
    # co-visible [count]. The group SfM matches cameras through such shared times.
    min_covisible_times: int = 30
    # Reprojection RMSE above which a camera's pose is called poorly determined [px]. A few
    # times a pose keypoint's noise.
    max_rmse_px: float = 5.0
    guidance_period_s: float = 1.0  # how often the group SfM publishes the walk guidance during the walk [s]

"""The `fusion` section of YOWO's configuration tree (FusionParams), and the settings of
other stages the fusion applies again to their data (UpstreamParams)."""

from __future__ import annotations

from dataclasses import dataclass

from yowo_cmc.keypoint_tracks import TrackParams
from yowo_ego.layout import LayoutParams
from yowo_ego.scene import CloudParams

from .alignment import AlignParams
from .isolated import IsolatedParams
from .joint import JointParams
from .scene_matching import SceneMatchParams
from .weak_places import WeakPlaceParams


@dataclass(frozen=True)
class UpstreamParams:
    """Settings of other stages that the fusion applies again to their data. They are not the
    fusion's section: each lives in the tree once, where its stage reads it (UPSTREAM_HOMES;
    the node gets each in a parameter of the field's name): how the group SfM cleans the
    CMC keypoint tracks (cmc.sfm.tracks) and how the ego stage builds its cloud and layout
    (ego.cloud, ego.layout), which the fusion rebuilds at the jointly optimised poses."""

    tracks: TrackParams = TrackParams()
    cloud: CloudParams = CloudParams()
    layout: LayoutParams = LayoutParams()


# Where each of UpstreamParams' fields lives in the configuration tree.
UPSTREAM_HOMES = {"tracks": "cmc.sfm.tracks", "cloud": "ego.cloud", "layout": "ego.layout"}


@dataclass(frozen=True)
class FusionParams:
    align: AlignParams = AlignParams()  # groups aligned to the ego trajectory, clock offsets (alignment.py)
    joint: JointParams = JointParams()  # the joint optimisation's factors and solver (joint.py)
    scene: SceneMatchParams = SceneMatchParams()  # scene keypoints matched with pose priors
    isolated: IsolatedParams = IsolatedParams()  # a camera of no group registered alone
    weak_places: WeakPlaceParams = WeakPlaceParams()  # the ego map's weak places, for walk guidance
    # Scene keypoints on each camera's background matched to the ego map's landmarks, for the
    # joint optimisation and the isolated cameras' refinement.
    use_scene_keypoints: bool = True
    joint_optimisation: bool = True  # the joint optimisation; False: ablation "without joint optimisation"
    # A camera whose reprojection RMSE exceeds this is weak; a group whose cameras do is the one
    # at fault where it and the ego map disagree.
    ok_rmse_px: float = 3.0
    ok_position_sigma_m: float = 0.10  # a camera whose position sigma (its covariance's largest) exceeds this is weak
    # Frames tracked from a keyframe with fewer landmark observations than this are weak
    # (weak_ego_frames) [count]. Its BA had next to nothing (bare walls, dark); where the ego
    # stage says how it tracked, only such frames with less overlap than weak_tracking_fitness
    # are: depth tracks a bare wall well, a low-overlap step in the dark goes wrong
    # (docs/notes/fusion.md).
    weak_keyframe_landmarks: int = 20
    # A landmark-poor frame is weak only if tracked with less overlap than this, where the ego
    # stage says [share].
    weak_tracking_fitness: float = 0.5
    # The same with an ego IMU [share]. The gyro measured each step's rotation: only a step with
    # less overlap is weak, as a loose step let a two-camera group bend a good map.
    weak_tracking_fitness_imu: float = 0.4
    # A frame after a gap in the ego map's frames longer than this is weak (lost track, rejected frames).
    weak_frame_gap_s: float = 0.3
    # A camera whose registration rests on a stretch of the ego map with a larger share of weak
    # frames than this is never ok (nor one whose stretch holds a gap) [share].
    ok_weak_share: float = 0.2
    # A camera whose stretch of the ego map the joint optimisation moved by more than this (RMS
    # over its ego positions; the map's first pose stays) is never ok. The ego stage's map was
    # that far off there, and what put it back (agent tracks, the chain of steps from the
    # nearest of them) is not checked by anything else (docs/notes/fusion.md).
    ok_map_moved_m: float = 0.10
    absurd_margin_m: float = 0.5  # a registered pose this far below the floor or above a ceiling over it is refused
    # A registered pose whose image up points below the horizontal by more than this cosine is
    # refused (upside down) [cos].
    max_upside_down_cos: float = 0.5
    # A group whose head-top track and the head top the ego trajectory predicts differ by more
    # than this (RMS) is never ok: one of the two is wrong. After the joint optimisation it says
    # so; before it (the group as aligned, the ego map as the ego stage made it) the joint
    # optimisation had to reconcile the two, and which one it bent is not known.
    ok_track_rms_m: float = 0.10
    # Window of its walk on which a self-consistent group that does not fit a broken ego map as
    # a whole is aligned (the best-fitting one: one piece of the map); 0: such a group's cameras
    # are registered one by one. The joint optimisation fits the other pieces to its track.
    rescue_window_s: float = 6.0
    # A joint solution is kept only if every group's head-top track fits its ego trajectory
    # within this (RMS). The worst group beyond it is left out and the rest solved again: a map
    # bent where no agent track holds it leaves far more, while the frames beside a repaired
    # break can stay off by more than ok_track_rms_m (docs/notes/floor.md).
    max_unexplained_track_rms_m: float = 0.3
    # Joint solves at most, each leaving one more such group out [count]. A floor's solve takes minutes.
    max_joint_solves: int = 3
    # A head top only one camera of a group saw enters the joint optimisation as an agent point
    # of its own, started at the head top the ego trajectory predicts. It cannot be triangulated,
    # yet with that prediction it anchors the map across the camera's ray. Our addition: the
    # paper's agent points are the groups' triangulated ones.
    single_view_head_tops: bool = True

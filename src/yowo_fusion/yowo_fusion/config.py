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
    align: AlignParams = AlignParams()
    joint: JointParams = JointParams()
    scene: SceneMatchParams = SceneMatchParams()
    isolated: IsolatedParams = IsolatedParams()
    use_scene_keypoints: bool = True
    joint_optimisation: bool = True  # False: ablation "without joint optimisation"
    ok_rmse_px: float = 3.0
    ok_position_sigma_m: float = 0.10
    # Where the ego map is not to be trusted (weak_ego_frames): frames tracked from a keyframe
    # with fewer landmark observations than this (its BA had next to nothing: bare walls, dark)
    # and, where the ego stage says how it tracked, with less overlap than weak_tracking_fitness
    # (depth tracks a bare wall well; a low-overlap step in the dark goes wrong). Registration
    # [m] at 0.65 / 0.5: small texture_poor s0-s2 with IMU 0.084 / 0.048, 0.078 / 0.052,
    # 0.230 / 0.066; s0 without 0.076 / 0.064; dim_light s1 without 0.111 / 0.145...
    weak_keyframe_landmarks: int = 20
    weak_tracking_fitness: float = 0.5
    # With an ego IMU the gyro measured each step's rotation: only a step with less overlap than
    # this is weak (a loose step let a two-camera group bend a good map: small texture_poor s2
    # with IMU, registration 0.104 m at 0.5, 0.034 at 0.4; without the IMU, 0.4 broke s1).
    weak_tracking_fitness_imu: float = 0.4
    # ...or after a gap in its frames longer than this (lost track, rejected frames).
    weak_frame_gap_s: float = 0.3
    # A camera whose registration rests on a stretch of the ego map with more weak frames
    # than this share is never ok (nor one whose stretch holds a gap).
    ok_weak_share: float = 0.2
    # ...nor one whose stretch the joint optimisation moved by more than this (RMS over its ego
    # positions; the map's first pose stays): the ego stage's map was that far off there, and
    # what put it back (agent tracks, the chain of steps from the nearest of them) is not checked
    # by anything else. Small texture_poor s1 / s2 without the IMU: stretches moved 0.16-1.1 m
    # held `ok` cameras 0.12-0.17 m off; dim_light s1 without the IMU 0.10 / 0.14 m (cameras
    # 0.015-0.10 m off); the other 16 hard small runs, with the IMU or without, at most 0.08 m.
    ok_map_moved_m: float = 0.10
    # A registered pose this far below the floor or above a ceiling over it [m], or whose image
    # up points below the horizontal by more than this cosine (upside down), is refused.
    absurd_margin_m: float = 0.5
    max_upside_down_cos: float = 0.5
    # A group's head-top track and the head top the ego trajectory predicts differ by more than
    # this (RMS): one of the two is wrong. After the joint optimisation it says so; before it
    # (the group as aligned, the ego map as the ego stage made it) the joint optimisation had to
    # reconcile the two, and which one it bent is not known: never ok either.
    ok_track_rms_m: float = 0.10
    # A self-consistent group that does not fit a broken ego map as a whole is aligned on
    # the stretch of this many seconds of its walk that fits best (one piece of the map),
    # and the joint optimisation fits the other pieces to its track; 0: such a group's
    # cameras are registered one by one.
    rescue_window_s: float = 6.0
    # A joint solution is kept only if every group's head-top track fits its ego trajectory
    # within this (RMS); the worst group beyond it is left out and the rest solved again. A
    # map bent where no agent track holds it leaves ~0.5 m (small symmetric s0 without IMU:
    # cameras 0.28 -> 1.3 m off); the frames beside a repaired break can stay off by more
    # than ok_track_rms_m (test world, 1.5 m / 40 deg break: 0.24 m, cameras within 5 cm).
    max_unexplained_track_rms_m: float = 0.3
    # Joint solves at most (each leaves one more such group out; a floor's solve takes minutes).
    max_joint_solves: int = 3
    # A head top only one camera of a group saw at a stamp cannot be triangulated, yet with the
    # head top the ego trajectory predicts it anchors the map across that camera's ray: such an
    # observation enters the joint optimisation as an agent point of its own (started at the
    # predicted head top). Our addition: the paper's agent points are the groups' triangulated ones.
    single_view_head_tops: bool = True

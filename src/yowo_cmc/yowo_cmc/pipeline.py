"""The CMC stage on every camera's tracks: clock offsets from the agent's motion
(yowo_cmc.clock), the group SfM on stamps corrected by them (yowo_cmc.group_sfm; an offset
within clock.min_significance sigma of 0 is not applied), the
offsets refined per group with its poses and points, and the group SfM once more on the
refined stamps. What the group SfM node and the offline API both run."""

from __future__ import annotations

from dataclasses import replace

import cv2

from .clock import ClockEstimate, attach_to_groups, estimate_clock_offsets
from .clock_refine import refine_group_offsets
from .config import CmcParams
from .group_sfm import GroupingResult, calibrate_groups
from .keypoint_tracks import CameraTracks
from .skeletons import camera_skeleton


def significant(offsets: dict[str, float], sigmas: dict[str, float], k: float) -> dict[str, float]:
    """The offsets, those within k sigma of 0 set to 0."""
    return {n: o if abs(o) > k * sigmas.get(n, 0.0) else 0.0 for n, o in offsets.items()}


def alone_in_time(tracks: list[CameraTracks], max_offset_s: float) -> dict[str, str]:
    """Cameras that saw the agent at no instant another camera did, even with their clocks
    up to `max_offset_s` apart (a clock set wrong, stamps of zero): no group can hold them,
    and the groups' common time grid would stretch over the gap."""
    if len(tracks) < 2:
        return {}
    spans = {t.name: t.span_ns() for t in tracks}
    slack = round(max_offset_s * 1e9)
    out = {}
    for name, span in spans.items():
        others = [s for n, s in spans.items() if n != name and s is not None]
        if span is not None and not any(span[0] <= o[1] + slack and o[0] <= span[1] + slack for o in others):
            out[name] = (
                f"saw the walker at no instant another camera did (its keypoint stamps "
                f"{span[0] / 1e9:.3f}..{span[1] / 1e9:.3f} s)"
            )
    return out


def calibrate_cmcs_apart(
    tracks: list[CameraTracks], params: CmcParams = CmcParams(), estimate_intrinsics: frozenset[str] = frozenset()
) -> GroupingResult:
    """calibrate_cmcs; where it fails, without the one camera whose data makes it fail (tried
    one at a time), which is left ungrouped with the error: one camera's fault stays its own."""
    try:
        return calibrate_cmcs(tracks, params, estimate_intrinsics)
    except (ValueError, ArithmeticError, IndexError, cv2.error, RuntimeError) as exc:
        if len(tracks) > params.isolate_failure_max_cameras:
            raise
        for culprit in tracks:
            others = [t for t in tracks if t is not culprit]
            try:
                grouping = calibrate_cmcs(others, params, estimate_intrinsics)
            except (ValueError, ArithmeticError, IndexError, cv2.error, RuntimeError):
                continue
            grouping.ungrouped[culprit.name] = f"the group SfM fails with this camera's data ({exc})"
            return grouping
        raise


def calibrate_cmcs(
    tracks: list[CameraTracks], params: CmcParams = CmcParams(), estimate_intrinsics: frozenset[str] = frozenset()
) -> GroupingResult:
    """Groups with relative poses and agent tracks. Each group's points are stamped on
    its reference camera's clock, and `clock_offsets_s` says how far each member's clock
    is from it (member's stamp of an instant = reference's + offset). `estimate_intrinsics`:
    the cameras whose intrinsics the group SfM estimates (their tracks carry a nominal model)."""
    # The declared skeleton's noise classes (plan_run checked that the cameras agree on one).
    skeleton = next((s for t in tracks if (s := camera_skeleton(params.keypoints, t.name)) is not None), None)
    apart = alone_in_time(tracks, params.clock.max_offset_s)
    if apart:
        grouping = calibrate_cmcs([t for t in tracks if t.name not in apart], params, estimate_intrinsics)
        grouping.ungrouped.update(apart)
        return grouping
    unknown = frozenset(estimate_intrinsics)
    if not params.estimate_clock_offsets:
        return calibrate_groups(tracks, params.sfm, estimate=unknown, skeleton=skeleton)
    estimate = estimate_clock_offsets(tracks, params.clock, params.sfm)
    if not params.clock.apply:
        grouping = calibrate_groups(tracks, params.sfm, estimate=unknown, skeleton=skeleton)
        attach_to_groups(grouping.groups, estimate)
        return grouping
    # Each camera's offset to the reference camera of its co-visibility component
    # (cameras without an estimate keep their own clock).
    offsets = {n: c.offset_s for n, c in estimate.cameras.items() if c.offset_s is not None}
    # Their sigmas, each against the camera its offset was last fitted relative to (0 there).
    sigmas = {n: c.sigma_s or 0.0 for n, c in estimate.cameras.items() if c.offset_s is not None}
    components = {n: c.reference for n, c in estimate.cameras.items() if c.reference is not None}
    offsets = significant(offsets, sigmas, params.clock.min_significance)
    corrected = [t.shifted(offsets.get(t.name, 0.0)) for t in tracks]
    grouping = calibrate_groups(corrected, params.sfm, components, unknown, skeleton=skeleton)
    if params.clock.refine and grouping.groups:
        refined, sigmas = _refined_offsets(grouping, corrected, estimate, offsets, sigmas, unknown, params)
        if refined != offsets:
            grouping = calibrate_groups(
                [t.shifted(refined.get(t.name, 0.0)) for t in tracks],
                params.sfm,
                components,
                unknown,
                skeleton=skeleton,
            )
        offsets = refined
    for g in grouping.groups:
        ref = offsets.get(g.reference, 0.0)
        # The group's points onto its reference camera's own clock.
        g.point_stamps_ns = g.point_stamps_ns + round(ref * 1e9)
        g.clocks_applied = True
        for n in g.names:
            g.clock_offsets_s[n] = offsets.get(n, 0.0) - ref
            g.clock_sigmas_s[n] = (
                0.0 if n == g.reference else float((sigmas.get(n, 0.0) ** 2 + sigmas.get(g.reference, 0.0) ** 2) ** 0.5)
            )
    return grouping


def _refined_offsets(
    grouping: GroupingResult,
    corrected: list[CameraTracks],
    estimate: ClockEstimate,
    applied: dict[str, float],
    sigmas: dict[str, float],
    unknown: frozenset[str],
    params: CmcParams,
) -> tuple[dict[str, float], dict[str, float]]:
    """The offsets and their sigmas with each group's members' offsets refined with its
    poses and points (`corrected`: the tracks on the `applied` offsets)."""
    offsets, sigmas = dict(applied), dict(sigmas)
    # The refinement projects with each member's intrinsics: the group's estimates where it made them.
    estimated = {n: c for g in grouping.groups for n, c in g.cameras.items() if n in unknown}
    shifted = {t.name: replace(t, camera=estimated.get(t.name, t.camera)) for t in corrected}
    # Only clocks that some pair's cost curve pinned: where none has a clear minimum (a
    # seated person), the refinement's sigma takes view-dependent keypoint errors for
    # independent noise, and applying its offsets costs accuracy.
    pinned = {n for n, c in estimate.cameras.items() if c.offset_s is not None}
    for g in grouping.groups:
        ref = applied.get(g.reference, 0.0)
        refined = refine_group_offsets(g, shifted, params.clock, params.sfm) if g.reference in pinned else {}
        for n, (delta, sigma) in ((n, r) for n, r in refined.items() if n in pinned):
            # The refined sigma is against the group's reference, so that is the clock a
            # member within its noise stays on (not the clock estimate's reference camera).
            relative = applied.get(n, 0.0) + delta - ref
            offsets[n] = ref + (relative if abs(relative) > params.clock.min_significance * sigma else 0.0)
            sigmas[n], sigmas[g.reference] = sigma, 0.0
    return offsets, sigmas

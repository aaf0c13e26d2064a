"""Step 2 of the relocation (`core.reconstruction.relocate.Relocator.relocate`): the fitted axis moved onto the wall
stereo measures without bias, checked against the tube's outline, placed across the cameras' views by the tube's
limbs in their colour images where the Scene has them (core.relocation.limbs), and levelled by the cameras facing
the backbone."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from ntcr_recon.core.reconstruction.relocation_steps import Aligned, Axis, Scene
from ntcr_recon.core.relocation.alignment import (
    WallTrust,
    align_to_trusted_wall,
    shift_scatter,
)
from ntcr_recon.core.relocation.backbone import level_by_backbone
from ntcr_recon.core.relocation.bend_plane import held_to_bend_plane
from ntcr_recon.core.relocation.centerline import Centerline, TubeCoordinates
from ntcr_recon.core.relocation.cross_view import cross_view_spread
from ntcr_recon.core.relocation.limbs import interpolation_error, placed_by_limbs
from ntcr_recon.core.relocation.notches import spine_wall
from ntcr_recon.core.relocation.outline import across_views_from, outline_offset, outline_rigid_offset, went_astray
from ntcr_recon.core.relocation.reference import along_rays
from ntcr_recon.core.relocation.tip import tube_end
from ntcr_recon.core.relocation.wall import band_gate

# Alignment passes: each selects the trusted points about the axis the previous one moved.
ALIGNMENT_PASSES = 3
# Limb passes: each reads the limbs about where the previous one left the axis (it moves it about half way).
LIMB_PASSES = 2


def align(scene: Scene, fitted: Axis, model: Centerline | None = None) -> Aligned:
    """Step 2: the fitted axis moved onto the wall stereo measures without bias (core.relocation.alignment), checked
    against the tube's outline in each camera's view (relocation.outline), levelled by the cameras facing the
    backbone and placed across the views by the tube's limbs in the colour images (relocation.limbs, where the
    Scene has them); and each point moved along its viewing ray onto the wall (core.relocation.reference). Without
    the points' cameras (seen_by None: a cloud from elsewhere), the fit as it is."""
    cloud, settings, seen_by = scene.cloud, scene.settings, scene.seen_by
    if seen_by is None:
        return Aligned(fitted)
    geometry, footprint = scene.geometry, settings.cell
    viewpoints = np.take(scene.origins, seen_by, axis=0)
    end = tube_end(fitted.coords, geometry.outer_radius, settings.gate, footprint, max_s=geometry.reach)
    # trusted wall lies within the wall's band on the spines: the fit's gate, a millimetre wide, lets in
    # pixels a matcher mixed with the background behind, which pull the axis across the cameras' views
    trusted_gate = _wall_band_gate(fitted.coords, fitted.centerline, geometry, settings.gate, footprint)
    # which points face their camera depends on where the axis is: selected again about the moved axis
    trust = WallTrust(geometry, trusted_gate, footprint, end)
    alignment = align_to_trusted_wall(fitted.centerline, fitted.coords, fitted.frames, viewpoints, trust, xyz=cloud.xyz,
                                      passes=ALIGNMENT_PASSES)
    centerline = alignment.centerline
    coords, frames = centerline.project_with_frames(cloud.xyz, alignment.arc_lengths)
    # the alignment against the middle of the tube's outline in each camera's view: where it followed a wall
    # stereo moved across the views and the fit did not, the fit places the axis across them (relocation.outline)
    outline_of = functools.partial(outline_offset, xyz=cloud.xyz, viewpoints=viewpoints, camera=seen_by,
                                   geometry=geometry, gate=settings.gate, end_s=end)
    aligned_outline, across_from_fit = outline_of(coords, frames), None
    fit_outline = outline_of(fitted.coords, fitted.frames) if went_astray(aligned_outline, footprint) else None
    if fit_outline is not None and not went_astray(fit_outline, footprint):
        centerline = across_views_from(fitted.centerline, centerline, scene.origins)
        alignment = alignment.moved_to(centerline, fitted.centerline)
        coords, frames = centerline.project_with_frames(cloud.xyz, coords.s)
        across_from_fit = aligned_outline, fit_outline
    # how much the lean it removed varies along the tube: the axis is known no better (quality)
    scatter = shift_scatter(fitted.centerline, centerline, end)
    # the cameras facing the backbone place the axis along their views by the plain tube's level
    leveled, backbone_shift = level_by_backbone(centerline, coords, frames, viewpoints, seen_by, scene.origins, trust)
    outline = aligned_outline if across_from_fit is None else None  # of the axis as it stands
    # across the views the limbs in the colour images place the axis sharper than any depth (core.relocation.limbs)
    placed, limbs = _placed_by_limbs(leveled, scene, end)
    # off the plane the notches bend the robot in lies what depth places worst: held to it (relocation.bend_plane)
    plane = held_to_bend_plane(placed, geometry, end, scene.origins) if model is None else None
    # the axis after each step that moved it (what benchmarks/stage_errors.py measures each step by)
    steps = [("fit", fitted.centerline), ("trusted wall", centerline), ("backbone", leveled), ("limbs", placed)]
    if plane is not None:
        placed = plane.centerline
        steps.append(("bend plane", placed))
    if model is not None:
        placed = model
        steps.append(("model", model))
    if placed is not centerline:  # levelled or placed by the limbs or the model: the points projected once onto it
        centerline, outline = placed, None
        coords, frames = centerline.project_with_frames(cloud.xyz, coords.s)
    # what each camera alone says about the axis across its view: the fused axis is known no better
    cross_view = cross_view_spread(centerline, coords, frames, viewpoints, seen_by, len(scene.origins), trust)
    # and each camera's whole outline across its view: a pose a millimetre off, beyond the wall's gate and the limbs'
    # search, shows there (not needed where the limbs were found in both views: theirs decides, trace.rigid_offset)
    outlines = (None if limbs is not None and limbs.rigid is not None else
                outline_rigid_offset(coords, frames, cloud.xyz, viewpoints, seen_by, len(scene.origins), geometry, end))
    # each point as its camera saw it: along its viewing ray onto the wall
    rays = along_rays(coords, frames, viewpoints, geometry.outer_radius, settings.gate)
    return Aligned(Axis(centerline, coords, frames, rays), alignment, cross_view, backbone_shift,
                   # the axis against the middle of the tube's outline in each camera's view (depth errors lie
                   # along the rays)
                   outline_of(coords, frames) if outline is None else outline, across_from_fit, scatter, limbs,
                   outlines, plane, _moving(steps))


def _moving(steps: list[tuple[str, Centerline]]) -> tuple[tuple[str, Centerline], ...]:
    """The first step and each that moved the axis the step before left (a step that did not run left it as is)."""
    return tuple(step for i, step in enumerate(steps) if not i or step[1] is not steps[i - 1][1])


def _placed_by_limbs(leveled: Centerline, scene: Scene, end: float):
    """relocation.limbs.placed_by_limbs, LIMB_PASSES times (a pass placing nothing leaves the last one's word), and
    its figures with how far all of them moved the axis (m, RMS over the levelled axis's samples)."""
    placed, limbs = leveled, None
    for _ in range(LIMB_PASSES if scene.views else 0):
        moved, figures = placed_by_limbs(placed, scene.views, scene.geometry.outer_radius,
                                         scene.geometry.notch_pitch, end)
        if limbs is not None and moved is placed:
            break
        placed, limbs = moved, figures
    if limbs is not None and placed is not leveled and limbs.centres is not None:
        s = leveled.s[leveled.s <= placed.length]
        apart = placed.frames_at(s)[0] - leveled.frames_at(s)[0]
        # the passes' moves together at the windows the last one placed, each against what the others interpolate
        at = np.clip(limbs.centres, 0.0, min(leveled.length, placed.length))
        moves = placed.frames_at(at)[0] - leveled.frames_at(at)[0]
        limbs = dataclasses.replace(limbs, moved_rms=float(np.sqrt(np.mean(np.sum(apart**2, axis=1)))),
                                    interpolated=interpolation_error(limbs.centres, moves))
    return placed, limbs


def _wall_band_gate(coords: TubeCoordinates, centerline: Centerline, geometry, gate: float, footprint: float
                    ) -> float:
    """The gate of the wall points the alignment trusts (m): the outer wall's band on the spines (its level's
    distance from r_o plus its spread, notches.spine_wall), never wider than the fit's gate."""
    _, level, spread = spine_wall(coords, centerline, geometry, gate, footprint)
    return band_gate(level, spread, gate)

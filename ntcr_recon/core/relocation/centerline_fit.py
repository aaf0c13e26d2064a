"""The robot's centreline estimated from the cloud, using the known outer radius.

Each camera sees one (flattened) side of the tube, so a free circle fit of a cross-section would follow the
flattening; with the radius known, a fixed-radius fit of the arcs that both cameras see recovers the axis.
The estimate alternates, until the centreline moves less than a tolerance:

1. correspondences: every point is projected onto the current centreline (its nearest centreline sample,
   then along the local tangent) giving its arc length s and its offset in the normal plane;
2. a Gauss-Newton step of the point-to-reference objective (Eq. 10 with the reference tube swept along the
   centreline): per slab of arc length, the fixed-radius circle residual |p - c| - r_o, robustly weighted
   (points deep inside the tube are cut faces or bore, points far outside are outliers);
3. all slab updates solved jointly with a smoothness prior along s (a smoothing length relative to the outer
   radius) on the second differences' departure from the steady bend the curve holds (solved with it), and
   the base anchored at the configured base position;
4. the curve re-parametrised by arc length.

A cold start marches from the base along the base axis, fitting one slab at a time; a warm start (the
previous frame's centreline, a still or slowly moving robot) needs one or two iterations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from ntcr_recon.core.base.compiled import jit
from ntcr_recon.core.base.robust import median
from ntcr_recon.core.relocation.centerline import Centerline, TubeCoordinates, base_pose, unit_direction
from ntcr_recon.core.relocation.tip import tube_end
from ntcr_recon.core.relocation.wall import band_gate, surface_band
from ntcr_recon.core.robot.geometry import TubeGeometry


@dataclass(frozen=True)
class CenterlineSettings:
    """Lengths (metres) derived from the robot and the camera (see `settings_for`)."""

    bin_length: float       # slab length along s
    smoothing_length: float
    gate: float             # a point farther than this from the reference surface is an outlier
    tolerance: float        # convergence: RMS move of the centreline's samples
    max_iterations: int
    cell: float             # resolution along s of coverage profiles (about a pixel footprint)


def settings_for(geometry: TubeGeometry, pixel_footprint: float, relocation) -> CenterlineSettings:
    """Slab length, smoothing, gate and tolerance from the robot's radius and the pixel footprint."""
    r_o = geometry.outer_radius
    footprint = geometry.pixel_footprint_or_default(pixel_footprint)
    return CenterlineSettings(
        bin_length=max(relocation.bin_radius_fraction * r_o, 2.0 * footprint),
        smoothing_length=relocation.smoothing_radius_fraction * r_o,
        gate=relocation.gate_radius_fraction * r_o + relocation.gate_pixels * footprint,
        tolerance=relocation.tolerance_radius_fraction * r_o,
        max_iterations=relocation.max_iterations,
        cell=footprint,
    )


def fixed_radius_circle_fit(slab: np.ndarray, x: np.ndarray, y: np.ndarray, slabs: int, radius: float,
                            gate: float, iterations: int = 5, point_weight: np.ndarray | None = None
                            ) -> tuple[np.ndarray, np.ndarray]:
    """Per slab, the centre (cx, cy) of a circle of known radius through its points (vectorised over slabs).

    Gauss-Newton on r_i = |p_i - c| - radius with a robust weight: points deeper than gate / 2 inside the
    circle (cut faces, bore) or farther than gate outside (outliers) do not count; Tukey-like taper within.
    point_weight: optional prior weight of each point (e.g. its share of two neighbouring slabs).
    Returns centres (slabs, 2) and the 2x2 information matrices (slabs, 2, 2) (zero where unobserved).
    """
    if point_weight is None:
        point_weight = np.ones(len(x))
    if len(slab) and (slab.min() < 0 or slab.max() >= slabs):  # (the kernel does not check its indices)
        raise ValueError(f"slab indices must lie in [0, {slabs}), got {slab.min()}..{slab.max()}")
    centre, sums = _circle_fit_kernel(slab, x, y, point_weight, slabs, radius, gate, iterations)
    a, b, c = sums[:, 0], sums[:, 1], sums[:, 2]
    information = np.stack([np.stack([a, b], axis=1), np.stack([b, c], axis=1)], axis=1)
    return centre, information


@jit
def _circle_fit_kernel(slab, x, y, point_weight, slabs, radius, gate, iterations):
    """fixed_radius_circle_fit's iterations: centres (slabs, 2) and the last step's weighted sums (slabs, 5) of
    nx nx, nx ny, ny ny, r nx, r ny (n: the unit offset of a point from its slab's centre, r: its residual)."""
    centre = np.zeros((slabs, 2))
    sums = np.zeros((slabs, 5))
    for _ in range(iterations):
        sums[:] = 0.0
        for i in range(x.shape[0]):
            k = slab[i]
            dx, dy = x[i] - centre[k, 0], y[i] - centre[k, 1]
            distance = max(np.sqrt(dx * dx + dy * dy), 1e-12)
            residual = distance - radius
            nx, ny = dx / distance, dy / distance
            scaled = (2.0 * residual if residual < 0 else residual) / gate
            if not abs(scaled) < 1.0:
                continue
            taper = 1.0 - scaled * scaled
            weight = taper * taper * point_weight[i]
            sums[k, 0] += weight * (nx * nx)
            sums[k, 1] += weight * (nx * ny)
            sums[k, 2] += weight * (ny * ny)
            sums[k, 3] += weight * (residual * nx)
            sums[k, 4] += weight * (residual * ny)
        largest = 0.0
        for k in range(slabs):
            a, b, c, gx, gy = sums[k, 0], sums[k, 1], sums[k, 2], sums[k, 3], sums[k, 4]
            damping = 1e-6 * (a + c) + 1e-30
            det = (a + damping) * (c + damping) - b * b
            step_x = ((c + damping) * gx - b * gy) / det
            step_y = ((a + damping) * gy - b * gx) / det
            centre[k, 0] += step_x
            centre[k, 1] += step_y
            largest = max(largest, abs(step_x), abs(step_y))
        if largest < 1e-3 * gate:
            break
    return centre, sums


@jit
def _hat_shares_kernel(s, x, y, selected, step, slabs):
    """Each selected point's shares of its two neighbouring nodes (nodes `step` apart along s, `slabs` of them;
    linear hat weights): (slab, x, y, weight) of every positive share on a node, the lower nodes' first."""
    picked = np.flatnonzero(selected)
    position_in_steps = s[picked] / step
    lower = np.floor(position_in_steps).astype(np.intp)
    share = position_in_steps - lower
    slab, weight = np.empty(2 * len(picked), np.intp), np.empty(2 * len(picked))
    slab_x, slab_y = np.empty(2 * len(picked)), np.empty(2 * len(picked))
    kept = 0
    for upper in range(2):
        for j in range(len(picked)):
            node, node_weight = lower[j] + upper, share[j] if upper else 1.0 - share[j]
            if 0 <= node < slabs and node_weight > 0:
                slab[kept], weight[kept] = node, node_weight
                slab_x[kept], slab_y[kept] = x[picked[j]], y[picked[j]]
                kept += 1
    return slab[:kept], slab_x[:kept], slab_y[:kept], weight[:kept]


@jit
def _slab_directions_kernel(slab, x, y, weight, slabs):
    """Per slab the weight of its points and the length of the weighted sum of their unit directions
    (x, y) / |(x, y)| about the axis."""
    counts, cos_sum, sin_sum = np.zeros(slabs), np.zeros(slabs), np.zeros(slabs)
    for i in range(slab.shape[0]):
        cos_angle, sin_angle = unit_direction(x[i], y[i])
        counts[slab[i]] += weight[i]
        cos_sum[slab[i]] += weight[i] * cos_angle
        sin_sum[slab[i]] += weight[i] * sin_angle
    return counts, np.hypot(cos_sum, sin_sum)


def _smooth_update(nodes: np.ndarray, tangents: np.ndarray, targets: np.ndarray, information: np.ndarray,
                   anchor: np.ndarray, smoothing_steps: float, bend_axes: np.ndarray, bend_steps: float
                   ) -> np.ndarray:
    """Positions P minimising sum (P - target)^T W (P - target) + lam |second differences of P - bend|^2
    + lam bend_steps^2 |first differences of the bend|^2 + anchor term, jointly with the bend.

    The bend is the curvature the curve holds (per node, on its normal and binormal: bend_axes (M, 2, 3)), a
    field free to follow what varies slower than `bend_steps` nodes: only departures of the curvature from it
    pay the smoothness prior. A prior on the curvature itself holds no bend at a free end (a natural end)
    and swings the end of a bent robot out of its bend; this one treats a steady bend the same at the end
    as within, and still smooths what changes within a smoothing length.
    nodes: current positions (M, 3); the data say nothing along the tangent, so each node is held at its
    place along its tangent (else the smoothness prior would let the curve stretch freely) and weakly
    everywhere. information: (M, 3, 3) data weights. lam = smoothing_steps^4 sets the cut-off length.
    """
    bands, rhs = _smoothing_system_kernel(nodes, tangents, targets, information, np.asarray(anchor, dtype=float),
                                          smoothing_steps, np.ascontiguousarray(bend_axes, dtype=float),
                                          bend_steps)
    solution = scipy.linalg.solveh_banded(bands, rhs).reshape(len(nodes), 5)
    return solution[:, :3]


@jit
def _smoothing_system_kernel(nodes, tangents, targets, information, anchor, smoothing_steps, bend_axes,
                             bend_steps):
    """_smooth_update's normal equations, in LAPACK's upper band storage (11, 5M) and their right-hand side.

    Unknowns per node m: its position (5m .. 5m + 2) and its bend on its two axes (5m + 3, 5m + 4). A second
    difference of nodes i, i+1, i+2 less the bend of i+1 couples unknowns at most 10 apart: symmetric,
    positive definite and banded: bands[10 - offset, column] = system[column - offset, column]. No dense
    matrix, no matrix product (which would wake BLAS threads for nothing).
    """
    count = nodes.shape[0]
    traces = information[:, 0, 0] + information[:, 1, 1] + information[:, 2, 2]
    observed = traces[traces > 0]
    typical = median(observed) if observed.size else 1.0
    weak = 1e-4 * typical
    lam = typical * smoothing_steps**4
    steady = lam * bend_steps**2  # the bend's own smoothness: its cut-off bend_steps nodes
    clamp = 1e3 * typical  # the base is clamped at the configured pose
    bands, rhs = np.zeros((11, 5 * count)), np.zeros(5 * count)
    for m in range(count):
        for row in range(3):
            for column in range(3):
                along = typical * (tangents[m, row] * tangents[m, column])
                rhs[5 * m + row] += information[m, row, column] * targets[m, column]
                rhs[5 * m + row] += along * nodes[m, column]
                if column >= row:
                    block = information[m, row, column] + along
                    if column == row:
                        block += weak + (clamp if m == 0 else 0.0)
                    bands[10 - (column - row), 5 * m + column] = block
            rhs[5 * m + row] += weak * nodes[m, row] + (clamp * anchor[row] if m == 0 else 0.0)
        for k in range(2):
            bands[10, 5 * m + 3 + k] += 1e-9 * lam  # a bend no difference reaches stays nought
    # lam |P_i - 2 P_{i+1} + P_{i+2} - bend_{i+1}|^2
    coefficients = (1.0, -2.0, 1.0)
    for i in range(count - 2):
        middle = i + 1
        for first in range(3):
            for second in range(first, 3):
                value = lam * coefficients[first] * coefficients[second]
                for axis in range(3):  # position pair (i + first, i + second), per axis
                    bands[10 - 5 * (second - first), 5 * (i + second) + axis] += value
        for k in range(2):
            bends_column = 5 * middle + 3 + k
            bands[10, bends_column] += lam
            for node in range(3):
                for axis in range(3):  # position against bend: -lam coefficient (bend axis k's component)
                    value = -lam * coefficients[node] * bend_axes[middle, k, axis]
                    position_column = 5 * (i + node) + axis
                    if position_column < bends_column:
                        bands[10 - (bends_column - position_column), bends_column] += value
                    else:
                        bands[10 - (position_column - bends_column), position_column] += value
    # steady |bend_{m+1} - bend_m|^2 over the bends the second differences use (nodes 1 .. M - 2)
    for m in range(1, count - 2):
        for k in range(2):
            bands[10, 5 * m + 3 + k] += steady
            bands[10, 5 * (m + 1) + 3 + k] += steady
            bands[5, 5 * (m + 1) + 3 + k] -= steady
    return bands, rhs



def _march(xyz: np.ndarray, geometry: TubeGeometry, settings: CenterlineSettings) -> np.ndarray:
    """Cold start: from the base along its axis, fit one slab ahead at a time; returns polyline nodes."""
    base, axis, binormal = base_pose(geometry)
    r_o = geometry.outer_radius
    step = max(r_o, 2 * settings.bin_length)
    reach = 1.5 * r_o + settings.gate
    nodes = [base]
    tangent = axis
    limit = int(np.ceil(geometry.reach / step)) + 2  # never past the robot
    misses = 0
    allowed_misses = max(3, int(np.ceil(geometry.proximal_length / step)) + 1)
    for _ in range(limit):
        predicted = nodes[-1] + step * tangent
        offset = xyz - predicted
        along = np.einsum("ij,j->i", offset, tangent)  # not `@`: a BLAS product would wake its threads
        lateral = offset - along[:, None] * tangent
        near = (np.abs(along) <= step / 2) & (np.einsum("ij,ij->i", lateral, lateral) <= reach**2)
        centre = None
        if np.count_nonzero(near) >= 8:
            e2 = binormal - (binormal @ tangent) * tangent
            e2 /= np.linalg.norm(e2)
            e1 = np.cross(e2, tangent)
            local = lateral[near]
            centre, _ = fixed_radius_circle_fit(np.zeros(len(local), dtype=np.intp),
                                                np.einsum("ij,j->i", local, e1), np.einsum("ij,j->i", local, e2), 1,
                                                r_o, settings.gate, iterations=8)
            # a few points on one side let a circle of the radius sit anywhere on their far side: an axis
            # more than a radius off the straight prediction in one step is no tube the robot can bend to
            if np.hypot(centre[0, 0], centre[0, 1]) > r_o:
                centre = None
        if centre is None:
            # a stretch without data enough to place the axis (the base hidden by its clamp, an occlusion):
            # carry on straight for up to the proximal length (straight by construction) or a few steps
            misses += 1
            if misses > allowed_misses:
                break
            nodes.append(predicted)
            continue
        misses = 0
        node = predicted + centre[0, 0] * e1 + centre[0, 1] * e2
        direction = node - nodes[max(len(nodes) - 2, 0)]
        tangent = direction / np.linalg.norm(direction)
        nodes.append(node)
    while misses > 0 and len(nodes) > 2:  # drop the extrapolated nodes past the last observed slab
        nodes.pop()
        misses -= 1
    return np.array(nodes)


def _observed_end(coordinates: TubeCoordinates, geometry: TubeGeometry, settings: CenterlineSettings,
                  centerline: Centerline, viewpoints: np.ndarray | None, band: tuple[float, float]) -> float:
    """Where the tube seen ends, never past the robot's reach; band: the wall band of the coordinates."""
    return tube_end(coordinates, geometry.outer_radius, settings.gate, settings.cell, max_s=geometry.reach,
                    centerline=centerline, viewpoints=viewpoints, band=band)


def _moved(previous: Centerline, samples: np.ndarray) -> float:
    """RMS distance (m) of a new curve's `samples` from the `previous` curve (0 for none)."""
    return float(np.sqrt(np.mean(previous.project(samples).radius ** 2))) if len(samples) else 0.0


def estimate_centerline(xyz: np.ndarray, geometry: TubeGeometry, settings: CenterlineSettings,
                        prior: Centerline | None = None, viewpoints: np.ndarray | None = None
                        ) -> tuple[Centerline, int, tuple]:
    """Fit the centreline to a cloud in the base frame.

    viewpoints: (C, 3) the cameras' optical centres, so the tube's end is judged by what they can see.
    Returns the centreline (base to just past the last slab with data; the pipeline cuts it at the observed
    tip), the number of iterations run, and (coordinates, frames, exact): the points' projection onto the
    returned curve when exact, else onto the curve before it (its arc lengths a guess for projecting again).
    On convergence the curve the points were last projected onto is returned: the update beyond it moved
    less than the tolerance, and its projection is then exact for free.
    """
    base, _, binormal_hint = base_pose(geometry)
    step = settings.bin_length
    if prior is None:
        nodes = _march(xyz, geometry, settings)
        centerline = Centerline.from_points(nodes, binormal_hint, step)
    else:
        centerline = prior
    smoothing_steps = settings.smoothing_length / step
    # the robot bends at its notches: its steady bend is what holds over two notch pitches
    bend_steps = 2.0 * geometry.notch_pitch / step
    iterations = 0
    coordinates, frames = None, None
    for iterations in range(1, settings.max_iterations + 1):  # noqa: B007 - reported to the caller
        coordinates, frames = centerline.project_with_frames(xyz, None if coordinates is None else coordinates.s)
        near_tube = np.abs(coordinates.radius - geometry.outer_radius) < settings.gate
        near_tube &= coordinates.s > -settings.gate
        if np.count_nonzero(near_tube) < 16:
            break
        # stereo depth puts the seen wall a little inside (flattening) or outside the true one, about equally
        # all round: the circle is fitted at the radius this cloud's wall points lie at, its centre is the axis
        band = surface_band(coordinates.radius - geometry.outer_radius, settings.gate)
        # the curve reaches as far as the tube is seen, never past the robot's own length (and a margin)
        observed_end = _observed_end(coordinates, geometry, settings, centerline, viewpoints, band)
        slabs = max(int(np.ceil(observed_end / step)) + 1, 2)
        # each point feeds its two neighbouring nodes with linear (hat) weights, so the fit changes
        # smoothly as points slide along s between iterations
        slab, x, y, weight = _hat_shares_kernel(coordinates.s, coordinates.x, coordinates.y, near_tube, step, slabs)
        # the circles rest on the wall's band: mixed pixels pull a slab's circle across the view (most where the
        # end's and the last notch's edges leave few wall points); two pixel footprints at least, as a clean wall's
        # band is thinner than its pixels
        circle_gate = band_gate(*band, settings.gate, least=2 * settings.cell)
        centre, information_2d = fixed_radius_circle_fit(slab, x, y, slabs, geometry.outer_radius + band[0],
                                                          circle_gate, iterations=3, point_weight=weight)
        s_nodes = np.arange(slabs) * step
        position, tangent, normal, binormal = centerline.frames_at(s_nodes)
        basis = np.stack([normal, binormal], axis=2)                      # (M, 3, 2)
        targets = position + np.einsum("mij,mj->mi", basis, centre)
        information = np.einsum("mia,mab,mjb->mij", basis, information_2d, basis)
        # slabs too thinly observed to place a circle are left to the smoothness prior
        counts, resultant = _slab_directions_kernel(slab, x, y, weight, slabs)
        information[counts < 6] = 0.0
        # A slab seen on one side only (e.g. across a notch, where only the spine is left) places the axis
        # through the radius alone, so any radial bias of stereo depth moves it sideways: such slabs count
        # less, by 1 - |mean direction of their points about the axis|^2, and the smoothness prior bridges.
        balance = 1.0 - (resultant / np.maximum(counts, 1e-12)) ** 2
        information *= balance[:, None, None]
        updated = _smooth_update(position, tangent, targets, information, base, smoothing_steps,
                                 np.stack([normal, binormal], axis=1), bend_steps)
        previous = centerline
        centerline = Centerline.from_points(updated, binormal_hint, step)
        # the change of the curve's shape, not of its parametrisation: distance of the new samples from
        # the previous curve, over the interior and, apart, over the free end (where the tip sits: an RMS over
        # the whole length dilutes a moved end, and a warm start's prior, settled within, came with the last
        # frame's end); and the extent, to a slab (a cold start's march runs on over what lies past the end - an
        # end cap, the bore - and bends there: the curve is settled only once the slabs the tube's end leaves
        # have been fitted again; the last slab, there or not by a point, is not judged)
        common = min(previous.length, centerline.length)
        settled = common - 2 * settings.smoothing_length - 3 * step
        if (_moved(previous, centerline.points[centerline.s < settled]) < settings.tolerance
                and _moved(previous, centerline.points[(centerline.s >= settled) & (centerline.s < common - step)])
                < settings.tolerance and abs(centerline.length - previous.length) <= step):
            return previous, iterations, (coordinates, frames, True)
    return centerline, iterations, (coordinates, frames, False)

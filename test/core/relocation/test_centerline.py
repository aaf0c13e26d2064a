"""relocation.centerline: the Centerline's projection onto a curve. Points are drawn analytically on the true
surface (no renderer), so every figure is known exactly; each number asserted is printed."""

from __future__ import annotations

import math

import numpy as np

from ntcr_recon.core.relocation.centerline import Centerline


def test_projection_starts_from_the_nearest_sample_even_where_the_curve_comes_back_near_itself():
    """A hairpin (two legs 3 mm apart): points between the legs and far off are projected from their nearest
    sample, as a brute-force search over every sample finds it."""
    radius, leg = 1.5e-3, 10e-3
    turn = np.linspace(0.0, math.pi, 60)
    polyline = np.concatenate([
        np.stack([np.zeros(50), np.zeros(50), np.linspace(0.0, leg, 50)], axis=1),
        np.stack([radius - radius * np.cos(turn), np.zeros(60), leg + radius * np.sin(turn)], axis=1)[1:],
        np.stack([np.full(50, 2 * radius), np.zeros(50), np.linspace(leg, 0.0, 50)], axis=1)[1:]])
    centerline = Centerline.from_points(polyline, np.array([0.0, 1.0, 0.0]), 0.1e-3)
    rng = np.random.default_rng(7)
    points = np.concatenate([rng.uniform([-2e-3, -2e-3, -1e-3], [5e-3, 2e-3, 13e-3], (3000, 3)),
                             rng.normal(0.0, 20e-3, (200, 3))])
    squared = ((points[:, None, :] - centerline.points[None, :, :]) ** 2).sum(axis=2)
    nearest = np.argmin(squared, axis=1)
    guess = centerline.s[nearest] + ((points - centerline.points[nearest]) * centerline.tangents[nearest]).sum(axis=1)
    searched = centerline.project(points)
    brute = centerline.project(points, guess)
    on_far_leg = np.count_nonzero(centerline.s[nearest] > centerline.length / 2)
    print(f"\nhairpin: {on_far_leg} of {len(points)} points nearest the returning leg, "
          f"largest difference in s {np.abs(searched.s - brute.s).max():.1e} m")
    assert on_far_leg > 1000
    assert np.allclose(searched.s, brute.s, rtol=0.0, atol=1e-12)
    assert np.allclose(searched.x, brute.x, rtol=0.0, atol=1e-12)

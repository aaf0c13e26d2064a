"""Where each depth source's centreline error comes from: the error along and across the cameras' views after each
step of the alignment that moved the axis, and in the result, per accuracy-matrix row (issue 61: keep a correction
only where the matrix shows it is needed - on every depth source, not on the one it was developed with).

    .venv/bin/python benchmarks/stage_errors.py [--matcher emulated|sgbm|both] [--rows NAME,NAME...] [--seed 1]
    .venv/bin/python benchmarks/stage_errors.py --sweep 40 [--renderer simulator|views] [--seed 1000]

The steps are core.reconstruction.align_step's (Aligned.steps): the fit (circles fitted along the tube), the
trusted wall (the fit moved onto the wall stereo measures without bias), the backbone (levelled by the cameras
facing the uncut wall), the limbs (placed across the views by the tube's limbs in the colour images), the bend
plane (held to the plane the notches bend it in), and the result (its centreline, to its tip). A step that did not
move the axis shows `-`. Each row is rendered and reconstructed as accuracy_matrix.py does; per step the RMS error
(mm) along | across the views (quality.metrics.centerline_error_by_view, over the result's length). `--sweep N`
takes accuracy_sweep.py's random scenes instead (from --seed on), rendered by the simulator (with its emulated
matcher, or `--simulate='--matcher sgbm'`) or by the tests' own renderer (`--renderer views`): a step is judged on
every depth source, not only on the one it was developed with.

The summary, per depth source and step: the median error along and across, and in how many rows the step made
the error worse or better than the axis it was given (by more than CHANGED_MM in RMS; a step that did not run
counts as neither).
"""

from __future__ import annotations

import argparse
import functools
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import accuracy_matrix as matrix  # noqa: E402

# A step changed the error where it moved it by more than this (mm, RMS): below, the matcher's noise.
CHANGED_MM = 0.005

STEPS = ("fit", "trusted wall", "backbone", "limbs", "bend plane", "model", "result")


def stage_errors(row: matrix.Row, frames: int = 2, seed: int = 1) -> dict[str, tuple[float, float]]:
    """A matrix row (or a sweep's simulator scene) rendered as accuracy_matrix.py renders it: errors_of its
    reconstruction."""
    simulation = matrix.simulation_for(row, seed, frames)
    return errors_of(simulation.shape, matrix.row_config(row, simulation), matrix.frame_pairs(simulation))


def errors_of(shape, config, pairs: list) -> dict[str, tuple[float, float]]:
    """Per step that moved the axis, and the result: its error (m, RMS) along and across the cameras' views, up to
    the result's tip; the scene's true shape, the rig configuration and its frame pairs reconstructed as
    `ntcr-recon reconstruct` does (accuracy_matrix.reconstruct)."""
    from ntcr_recon.core.quality.metrics import centerline_error_by_view
    from ntcr_recon.core.reconstruction.reconstructor import Reconstructor

    reconstructor = Reconstructor(config)
    relocation = matrix.reconstruct(config, pairs, reconstructor)
    truth, _ = shape.centerline(np.linspace(0.0, shape.length, 4000))
    length = relocation.centerline.length
    axes = [*reconstructor.relocator.alignment_steps, ("result", relocation.centerline)]
    return {step: centerline_error_by_view(axis.up_to(min(length, axis.length)).points, truth, config.camera_origins)
            for step, axis in axes}


def format_errors(name: str, errors: dict[str, tuple[float, float]]) -> str:
    """One row: per step along | across (mm), `-` where the step did not move the axis."""
    cells = [f"{errors[step][0] * 1e3:6.3f} {errors[step][1] * 1e3:6.3f}" if step in errors else f"{'-':>6} {'-':>6}"
             for step in STEPS]
    return f"{name:<34} " + "  ".join(cells)


def changes(results: list[dict[str, tuple[float, float]]], step: str) -> tuple[int, int]:
    """In how many results the step made the error (RMS along and across together) worse, and better, than the
    axis the step before it that ran left (by more than CHANGED_MM)."""
    worse = better = 0
    for errors in results:
        ran = [s for s in STEPS if s in errors]
        if step not in ran or ran.index(step) == 0:
            continue
        before, after = (float(np.hypot(*errors[s])) * 1e3 for s in (ran[ran.index(step) - 1], step))
        worse += after > before + CHANGED_MM
        better += after < before - CHANGED_MM
    return worse, better


def scenes(args: argparse.Namespace):
    """(depth source, a thunk giving the scene's name and errors) for each matrix row and matcher, or each of the
    sweep's scenes."""
    if args.sweep:
        import accuracy_sweep

        source = "views" if args.renderer == "views" else ("simulator " + args.simulate).strip()
        for index in range(args.seed, args.seed + args.sweep):
            if args.renderer == "views":
                yield source, functools.partial(_views_errors, index, args.frames)
            else:
                row = matrix.with_simulate_options(accuracy_sweep.random_row(index), args.simulate)
                yield source, functools.partial(_row_errors, row, args.frames, index)
        return
    matchers = ["emulated", "sgbm"] if args.matcher == "both" else [args.matcher]
    for row in matrix.ROWS:
        if not args.rows or row.name in args.rows.split(","):
            for matcher in matchers:
                named = matrix.with_matcher(matrix.with_simulate_options(row, args.simulate), matcher, True)
                yield matcher, functools.partial(_row_errors, named, args.frames, args.seed)


def _row_errors(row: matrix.Row, frames: int, seed: int) -> tuple[str, dict]:
    return row.name, stage_errors(row, frames, seed)


def _views_errors(index: int, frames: int) -> tuple[str, dict]:
    """A sweep scene rendered by the tests' own renderer (accuracy_sweep.views_scene): its name and errors_of."""
    import accuracy_sweep

    name, shape, config, pairs, _ = accuracy_sweep.views_scene(index, frames)
    return name, errors_of(shape, config, pairs)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--matcher", choices=matrix.MATCHERS, default="both")
    parser.add_argument("--rows", default="", help="comma-separated row names (default: all)")
    parser.add_argument("--frames", type=int, default=2, help="frames per camera (default 2)")
    parser.add_argument("--seed", type=int, default=None, help="noise seed (default 1), or with --sweep the first "
                        "scene's index (default 1000)")
    parser.add_argument("--sweep", type=int, default=0, help="accuracy_sweep.py's random scenes instead of the matrix")
    parser.add_argument("--renderer", choices=("simulator", "views"), default="simulator",
                        help="with --sweep: the simulator (default) or the tests' own renderer")
    matrix.add_simulate_option(parser)
    args = parser.parse_args()
    args.seed = args.seed if args.seed is not None else (1000 if args.sweep else 1)
    unknown = {name for name in args.rows.split(",") if name} - {row.name for row in matrix.ROWS}
    if unknown:
        print(f"unknown rows: {sorted(unknown)}", file=sys.stderr)
        return 2
    print(f"{'row':<34} " + "  ".join(f"{step[:13]:>13}" for step in STEPS))
    print(f"{'':<34} " + "  ".join(f"{'along':>6} {'across':>6}" for _ in STEPS) + "   (mm, RMS)")
    by_source: dict[str, list] = {}
    for source, measure in scenes(args):
        name, errors = measure()
        by_source.setdefault(source, []).append(errors)
        print(format_errors(name, errors), flush=True)
    print("\nsummary per depth source and step: median along | across (mm); rows the step made worse / better")
    width = max(map(len, by_source), default=0)
    for source, results in by_source.items():
        for step in STEPS:
            ran = [errors[step] for errors in results if step in errors]
            if not ran:
                continue
            along, across = np.median(np.array(ran), axis=0) * 1e3
            worse, better = changes(results, step)
            print(f"  {source:<{width}} {step:<13} {along:6.3f} {across:6.3f}   ran in {len(ran):>2}/{len(results)}, "
                  f"worse in {worse:>2}, better in {better:>2}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""How well `calibration.refine` (relocation_node) finds a knocked second camera from the frames it relocates
(issue 62, part 2), over rigs it was not tuned on.

    .venv/bin/python benchmarks/refine_matrix.py [--rigs NAME,...] [--matcher emulated|sgbm|both]
        [--knocks 0,0.1,0.3,1] [--seed 1] [--frames 2]

Each rig's bent scene is rendered as benchmarks/calibration_matrix.py renders it. For each knock K, cam_b's pose in
the rig file is turned K degrees about a random axis through its optical centre and shifted K millimetres (seeded);
the frame pairs are fused and filtered with that file, as fusion_node and filter_node do, and refined as
relocation_node refines them (core.calibration.refine: recording_from_cloud, refine_relative). One row per rig,
matcher and knock: the refined pose's turn (deg) and shift of the robot's middle (mm) left against the truth, each
axis against twice its stated 1-sigma, whether it was called significant (EXTRINSICS_REFINED), and the scene
reconstructed with the exact, the knocked and the refined file (centreline RMSE, mm).

The summary counts: refinements called significant with an exact rig (false alarms) and with a knock of 1 (hits),
the refined file holding the centreline floor (0.08 mm) where the exact one does, and bettering the knocked one.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import calibration_matrix as calibration  # noqa: E402
from accuracy_matrix import MATCHERS  # noqa: E402

CENTERLINE_FLOOR_MM = calibration.CENTERLINE_FLOOR_MM


def refined(scenes: dict, knock: float, seed: int) -> dict:
    """cam_b knocked by `knock` deg and mm, refined from the bent scene's frames fused with the knocked file."""
    from ntcr_recon.core.calibration.refine import recording_from_cloud, refine_relative
    from ntcr_recon.core.calibration.rig_fit import CalibrationError, pivot_of
    from ntcr_recon.core.reconstruction.reconstructor import Reconstructor

    exact = scenes["config"]
    truth = exact.cameras["cam_b"].extrinsic
    knocked = calibration.with_poses(exact, {"cam_b": calibration.moved_pose(truth, knock, knock,
                                                                              np.random.default_rng(seed))})
    reconstructor = Reconstructor(knocked)
    recordings = []
    for index, pair in enumerate(scenes["bent"]["pairs"]):
        cloud = reconstructor.filter(reconstructor.fuse(pair))
        recordings.append(recording_from_cloud(f"frame {index}", cloud, knocked, reconstructor.relocator.views,
                                               seed=index))
    started = time.perf_counter()
    try:
        pose = refine_relative(recordings, knocked)
    except CalibrationError as error:
        return {"refused": ",".join(error.free), "knocked": knocked, "seconds": time.perf_counter() - started}
    error = calibration.pose_error(pose.extrinsic, truth, pivot_of(exact.robot))
    return {"pose": pose, "error": error, "knocked": knocked, "seconds": time.perf_counter() - started,
            "covered": np.abs(error) <= 2 * pose.uncertainty + 1e-6,
            "config": calibration.with_poses(exact, {"cam_b": pose.extrinsic})}


HEADER = (f"{'rig':<30} {'knock':>5} | {'off deg':>7} {'off mm':>6} {'2sig':>6} {'chi2':>6} {'sig':>3} | "
          f"{'centre mm exact / knocked / refined':>35} | {'s':>3}")


def format_row(name: str, knock: float, result: dict) -> str:
    centres = " / ".join(f"{result['centre'][key]:.3f}" if key in result["centre"] else "  -  "
                         for key in ("exact", "knocked", "refined"))
    if "refused" in result:
        return f"{name:<30} {knock:>5g} | refused, free: {result['refused']:<20} | {centres:>35} |"
    error = result["error"]
    return (f"{name:<30} {knock:>5g} | {np.linalg.norm(error[:3]):>7.3f} {np.linalg.norm(error[3:]):>6.3f} "
            f"{int(result['covered'].sum()):>4}/6 {result['pose'].chi2:>6.1f} "
            f"{'yes' if result['pose'].significant else 'no':>3} | "
            f"{centres:>35} | {result['seconds']:>3.0f}")


def summary(rows: list[tuple[str, float, dict]]) -> None:
    fitted = [(knock, r) for _, knock, r in rows if "refused" not in r]
    print(f"\nsummary: {len(fitted)} refined, {len(rows) - len(fitted)} refused (a parameter left free)")
    exact_rig = [r for knock, r in fitted if knock == 0]
    knocked = [r for knock, r in fitted if knock >= 1]
    print(f"  called significant with an exact rig (false alarms): {sum(r['pose'].significant for r in exact_rig)}"
          f"/{len(exact_rig)}; with a knock of 1 deg and 1 mm or more: {sum(r['pose'].significant for r in knocked)}"
          f"/{len(knocked)}")
    if fitted:
        errors = np.array([r["error"] for _, r in fitted])
        covered = np.sum([r["covered"] for _, r in fitted], axis=0)
        print("  refined pose off, median |error| per axis: turn x, y, z "
              + ", ".join(f"{v:.3f}" for v in np.median(np.abs(errors[:, :3]), axis=0)) + " deg; shift x, y, z "
              + ", ".join(f"{v:.3f}" for v in np.median(np.abs(errors[:, 3:]), axis=0)) + " mm; within twice the "
              "stated sigma: " + ", ".join(str(n) for n in covered) + f" of {len(fitted)}")
    floors = [r["centre"] for _, r in fitted if r["centre"].get("exact", np.inf) <= CENTERLINE_FLOOR_MM]
    held = sum(c["refined"] <= CENTERLINE_FLOOR_MM for c in floors)
    missing = [r["centre"] for _, r in fitted if r["centre"]["knocked"] > CENTERLINE_FLOOR_MM]
    better = sum(c["refined"] < c["knocked"] for c in missing)
    print(f"  centreline floor ({CENTERLINE_FLOOR_MM} mm) held with the refined file where the exact file holds it: "
          f"{held}/{len(floors)}; refined better than knocked where the knocked file misses it: "
          f"{better}/{len(missing)}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rigs", default="", help="comma-separated rig names of calibration_matrix (default: all)")
    parser.add_argument("--matcher", choices=MATCHERS, default="both")
    parser.add_argument("--knocks", default="0,0.1,0.3,1", help="cam_b knocked by, deg and mm alike")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--frames", type=int, default=2)
    args = parser.parse_args()
    wanted = {name for name in args.rigs.split(",") if name}
    rigs = [rig for rig in calibration.RIGS if not wanted or rig.name in wanted]
    if wanted - {rig.name for rig in rigs}:
        print(f"unknown rigs: {sorted(wanted - {rig.name for rig in rigs})}", file=sys.stderr)
        return 2
    matchers = ["emulated", "sgbm"] if args.matcher == "both" else [args.matcher]
    print(HEADER)
    rows = []
    for rig in rigs:
        for matcher in matchers:
            scenes = calibration.rendered(rig, matcher, args.frames, args.seed, labels=("bent",))
            exact = calibration.reconstructed(scenes, scenes["config"])[0]
            for knock in (float(v) for v in args.knocks.split(",")):
                result = refined(scenes, knock, args.seed)
                result["centre"] = {"exact": exact,
                                    "knocked": calibration.reconstructed(scenes, result["knocked"])[0]}
                if "config" in result:
                    result["centre"]["refined"] = calibration.reconstructed(scenes, result["config"])[0]
                rows.append((f"{rig.name}/{matcher}", knock, result))
                print(format_row(*rows[-1]), flush=True)
    summary(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())

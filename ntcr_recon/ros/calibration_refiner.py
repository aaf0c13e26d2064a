"""relocation_node's `calibration.refine`: the second camera's pose refined against the first as the graph runs
(core.calibration.refine), in a worker process so that the fit (seconds) never holds a frame up.

Each relocated frame is offered to the RefineWindow (a frame every refine_period / refine_frames seconds is kept);
once it is full and refine_period has passed, its frames go to the worker. The finished refinement is logged and
published on /diagnostics as its own status (`<node>: calibration refine`): level OK while the rig file's pose
agrees within what the refinement resolves, WARN with code EXTRINSICS_REFINED when it does not (write it with the
service `~/write_calibration`, std_srvs/Trigger, or recalibrate), and key-values: the change per base-frame axis
(`turn_deg.x`..., `shift_mm.x`...), their 1-sigma (`uncertainty_turn_deg.x`...), the frames, and the refined
pose (`translation`, `rotation`, as the rig file writes them). A refinement the frames cannot give (the robot
straight in every one, or bent along a camera's view) is a STALE status naming the parameters it leaves free and what
to do; the node goes on, and the last refinement stays the one ~/write_calibration writes.
"""

from __future__ import annotations

import multiprocessing
from pathlib import Path

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from ntcr_recon.core.calibration.refine import RefinedPose, RefineWindow, recording_from_cloud, refine_relative
from ntcr_recon.core.calibration.rig_fit import CalibrationError
from ntcr_recon.core.cloud.points import Cloud
from ntcr_recon.core.config.rig import RigConfig
from ntcr_recon.io.rig_file import RigFileError, pose_values, write_poses

REFINED_CODE = "EXTRINSICS_REFINED"


def _refine_in_worker(connection, recordings: list, config: RigConfig) -> None:
    """Sends the refinement, or the reason there is none (a string: exceptions cross processes badly)."""
    try:
        outcome: RefinedPose | str = refine_relative(recordings, config)
    except CalibrationError as error:
        outcome = str(error)
    except Exception as error:  # a bug: said on /diagnostics, the node goes on
        outcome = f"the refinement failed: {type(error).__name__}: {error}"
    connection.send(outcome)
    connection.close()


class OnlineRefiner:
    """The refinement's frames, its worker and its latest result, for one node."""

    def __init__(self, config: RigConfig, log, node_name: str):
        self.config, self.log, self.node_name = config, log, node_name
        self.window = RefineWindow(config.calibration)
        self.latest: RefinedPose | None = None
        # the running refinement: a spawned process (not forked: the node's DDS threads must not be copied), and
        # the end of the pipe its result comes on
        self._job: multiprocessing.Process | None = None
        self._result = None
        self._frame = 0

    def offer(self, cloud: Cloud, views: dict) -> None:
        """A relocated frame (its fused cloud and colour windows): kept when the window wants it; the window's
        frames sent to the worker when a refinement is due and none is running."""
        stamp = cloud.stamp_ns * 1e-9
        if cloud.camera is not None and self.window.wants(stamp):
            self._frame += 1
            self.window.offer(stamp, recording_from_cloud(f"frame {self._frame}", cloud, self.config, views,
                                                          seed=self._frame))
        if self._job is None and self.window.due(stamp):
            context = multiprocessing.get_context("spawn")
            self._result, sending = context.Pipe(duplex=False)
            self._job = context.Process(target=_refine_in_worker, args=(sending, self.window.take(stamp), self.config),
                                        name="calibration refine", daemon=True)
            self._job.start()
            sending.close()  # the worker's end: a worker that dies closes it, and the pipe then says so
            self.log.info(f"refining {self.config.camera_names[1]}'s pose against {self.config.camera_names[0]}'s "
                          f"over {len(self.window.frames)} frames")

    def poll(self) -> DiagnosticStatus | None:
        """The finished refinement's status (None while none finished since the last poll)."""
        if self._job is None or not self._result.poll():
            return None
        try:
            outcome = self._result.recv()
        except (EOFError, OSError):  # the worker died (memory, a signal): said, and the next period tries again
            outcome = f"the refinement's worker ended without a result (exit code {self._job.exitcode})"
        self._job.join(timeout=1.0)
        self._result.close()
        self._job = self._result = None
        return self.report(outcome)

    def report(self, outcome: RefinedPose | str) -> DiagnosticStatus:
        """A refinement's status (a string: why there is none), logged; a refinement becomes the latest."""
        if isinstance(outcome, str):
            self.log.warning(f"calibration refine: no refinement: {outcome}")
            return self._status(DiagnosticStatus.STALE, f"no refinement: {outcome}")
        self.latest = outcome
        figures = outcome.as_dict()
        said = (f"{outcome.camera} against {outcome.reference}: turns {figures['turn_deg']} deg, shifts "
                f"{figures['shift_mm']} mm from the rig file (1-sigma {figures['uncertainty_turn_deg']} deg, "
                f"{figures['uncertainty_shift_mm']} mm)")
        if outcome.significant:
            self.log.warning(f"calibration refine: {said}: the rig file's pose is off; write the refined one with "
                             "the service ~/write_calibration or recalibrate with `ntcr-recon calibrate`")
            return self._status(DiagnosticStatus.WARN, f"{REFINED_CODE}: {said}", outcome)
        self.log.info(f"calibration refine: {said}: agrees with the rig file")
        return self._status(DiagnosticStatus.OK, said, outcome)

    def _status(self, level: int, message: str, refined: RefinedPose | None = None) -> DiagnosticStatus:
        """The status with the refinement's figures as key-values (none without one)."""
        values = {"code": REFINED_CODE if refined is not None and refined.significant else ""}
        if refined is not None:
            figures, pose = refined.as_dict(), pose_values(refined.extrinsic)
            for key in ("turn_deg", "shift_mm", "uncertainty_turn_deg", "uncertainty_shift_mm"):
                values.update({f"{key}.{axis}": f"{v:.4f}" for axis, v in zip("xyz", figures[key], strict=True)})
            values.update(camera=refined.camera, frames=str(refined.frames),
                          significant=str(refined.significant).lower(),
                          translation=str(pose["translation"]), rotation=str(pose["rotation"]))
        status = DiagnosticStatus(name=f"{self.node_name}: calibration refine", hardware_id="ntcr", level=level,
                                  message=message)
        status.values = [KeyValue(key=key, value=str(value)) for key, value in values.items()]
        return status

    def write(self, rig_file: str, target: str) -> tuple[bool, str]:
        """The rig file with the refined camera's pose written to `target` (default <rig_file>.refined.yaml beside
        it), atomically: (done, what was written or why not)."""
        if self.latest is None:
            return False, "no refinement has finished yet (calibration.refine needs refine_period and a bent robot)"
        if not rig_file:
            return False, "parameter 'rig_file' is not set: the node does not know which rig file to edit"
        source = Path(rig_file).expanduser()
        out = Path(target).expanduser() if target else source.with_name(source.stem + ".refined.yaml")
        try:
            write_poses(source, out, {self.latest.camera: self.latest.extrinsic})
        except (OSError, RigFileError) as error:
            return False, f"could not write {out}: {error}"
        figures = self.latest.as_dict()
        return True, (f"wrote {out}: {self.latest.camera} turned {figures['turn_deg']} deg and shifted "
                      f"{figures['shift_mm']} mm from {source.name}")

    def close(self) -> None:
        """A running refinement is stopped (its frames are the node's: nothing is lost but the fit)."""
        if self._job is not None and self._job.is_alive():
            self._job.terminate()
            self._job.join(timeout=1.0)

"""What every ntcr_recon node shares: QoS profiles, validated parameters, a guarded callback and `run_node`.

A node is parameters + QoS + message conversion around one core function; this module keeps that
adapter part in one place so each node file holds only what is its own.
"""

from __future__ import annotations

import difflib
import functools
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numba
import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.signals import SignalHandlerOptions

# What a best-effort publisher (a camera driver set to sensor-data QoS) can be heard with: keep the last few.
SENSOR_QOS = qos_profile_sensor_data
# Camera clouds and their camera_info: reliable, the last 5 (best effort lost a fragmented cloud, and its pair, on a
# loaded machine). A reliable writer serves best-effort readers too (RViz), is realsense-ros's default, and with
# KEEP_LAST never waits for a slow reader.
CAMERA_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5, reliability=ReliabilityPolicy.RELIABLE)
# Stage outputs: reliable, depth 1 (a consumer wants the newest result, not a backlog).
STAGE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE)
# Stage inputs: reliable, depth 2. At depth 1 a large cloud (fragments, 5 million points ~60 MB) was pushed out by
# the next frame before its last fragment came: never taken, dropped nor counted (issue 66). The second place
# keeps it until the node has seen (and refused) it; a node that keeps up still takes each frame as it comes.
STAGE_INPUT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2, reliability=ReliabilityPolicy.RELIABLE)
# What a late subscriber still needs (the mesh): reliable and transient-local.
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
# The colour windows (relocation_node holds a cloud for them): latched a few frames deep, so that one published
# before the subscription matched (at start-up) still comes.
WINDOW_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=4, reliability=LATCHED_QOS.reliability,
                        durability=LATCHED_QOS.durability)


class ParameterError(ValueError):
    """A parameter value the node cannot work with; the message names the parameter."""


def describe(description: str, *, minimum: float | None = None, maximum: float | None = None,
             integer: bool = False, read_only: bool = False) -> ParameterDescriptor:
    """A ParameterDescriptor with an optional range, so `ros2 param describe` shows the bounds."""
    descriptor = ParameterDescriptor(description=description, read_only=read_only)
    if minimum is not None or maximum is not None:
        low = minimum if minimum is not None else -sys.float_info.max
        high = maximum if maximum is not None else sys.float_info.max
        if integer:
            descriptor.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=1)]
        else:
            descriptor.floating_point_range = [FloatingPointRange(from_value=float(low), to_value=float(high))]
    return descriptor


def max_points_parameter() -> tuple[int, ParameterDescriptor]:
    """The `max_points` parameter every node reading clouds declares (default and descriptor in one place)."""
    from ntcr_recon.ros.messages import DEFAULT_MAX_POINTS

    return DEFAULT_MAX_POINTS, describe("largest cloud accepted (points); a larger one is dropped before it is read",
                                        minimum=1, maximum=100_000_000, integer=True)


def finite_vector(name: str, value: Sequence[float], length: int) -> list[float]:
    """`value` as a list of `length` finite floats, or a ParameterError naming `name`."""
    values = list(value) if value is not None else []
    if len(values) != length or not all(isinstance(v, float | int) and v == v and abs(v) != float("inf")
                                        for v in values):
        raise ParameterError(f"parameter '{name}' must be {length} finite numbers, got {values!r}")
    return [float(v) for v in values]


def validate_on_change(node: Node, names: Sequence[str], apply: Callable[[dict[str, Any]], None]) -> None:
    """Refuse a parameter change that `apply` rejects, naming the parameter; otherwise apply it.

    `apply` receives the would-be values of the parameters `names` (current values overlaid with the
    change) and raises ParameterError (or ValueError) to refuse.
    """

    def on_set(parameters) -> SetParametersResult:
        proposed = {name: node.get_parameter(name).value for name in names}
        proposed.update({param.name: param.value for param in parameters})
        try:
            apply(proposed)
        except ValueError as error:
            node.get_logger().error(f"refused parameter change: {error}")
            return SetParametersResult(successful=False, reason=str(error))
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(on_set)


def guarded(callback: Callable) -> Callable:
    """Wrap a subscription (or timer) callback so bad input is logged and the node goes on with the next one."""

    @functools.wraps(callback)
    def wrapper(self: Node, *args) -> None:
        try:
            callback(self, *args)
        except ValueError as error:  # bad input: say what was wrong with it
            _drop(self, getattr(error, "reason", "invalid"), str(error))
        except Exception as error:  # a bug must not take the graph down either
            _drop(self, "error", f"unexpected {type(error).__name__}: {error}")

    return wrapper


def _drop(node: Node, reason: str, text: str) -> None:
    """A dropped message: counted with a rate-limited log line by a node's NodeStats, else logged."""
    stats = getattr(node, "stats", None)
    if stats is not None:
        stats.dropped(reason, text)
    else:
        node.get_logger().error(f"dropped a message: {text}")


EXECUTOR_VARIABLE = "NTCR_EXECUTOR"  # "events" (default) or "single": which rclpy executor the nodes spin on
SHUTDOWN_GRACE_S = 1.0  # how long an error in a take may precede the context's shutdown and still be a clean stop


def make_executor(context=None):
    """rclpy's EventsExecutor (rclpy >= 7.1.4): it takes each message as its event arrives instead of rebuilding
    a wait set per callback, a fraction of the default executor's cost per message; the SingleThreadedExecutor
    where it is missing or NTCR_EXECUTOR=single asks for it (to measure one against the other)."""
    if os.environ.get(EXECUTOR_VARIABLE, "events") == "events":
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:
            pass
        else:
            return EventsExecutor(context=context)
    return SingleThreadedExecutor(context=context)


def spin(executor, context, stop: threading.Event | None = None, failed: Callable[[], bool] | None = None) -> None:
    """Execute callbacks until the context shuts down, `stop` is set or `failed()` holds. spin_once in a loop:
    rclpy 7.1.5's EventsExecutor.spin() busy-loops without dispatching anything."""
    while context.ok() and not (stop is not None and stop.is_set()) and not (failed is not None and failed()):
        executor.spin_once(timeout_sec=0.25)


def failures(nodes: Sequence[Node]) -> list[str]:
    """What ended the nodes that cannot go on (a node sets `failure`, e.g. camera_node when its producer thread
    died): the process then exits non-zero, so that the runner / launch respawns it."""
    return [f"{node.get_name()}: {node.failure}" for node in nodes if getattr(node, "failure", None)]


def _shutting_down(context) -> bool:
    """True when the context is down or goes down within SHUTDOWN_GRACE_S (a Ctrl-C destroys handles under a
    take before rclpy's signal handler has finished shutting the context down)."""
    deadline = time.monotonic() + SHUTDOWN_GRACE_S
    while context.ok() and time.monotonic() < deadline:
        time.sleep(0.02)
    return not context.ok()


def run_node(node_factory: Callable[[], Node], args: list[str] | None = None) -> int:
    """Init rclpy, build the node, spin until Ctrl-C or shutdown, then clean up. Returns an exit code."""
    return run_nodes([node_factory], args)


def run_nodes(node_factories: Sequence[Callable[[], Node]], args: list[str] | None = None) -> int:
    """`run_node` for several nodes in one process, on one executor (still separate nodes talking over topics).

    Ctrl-C / SIGTERM only ask the loop to stop after the callback under way (rclpy's own handler raised
    KeyboardInterrupt inside it, which the EventsExecutor reports as a FATAL traceback, and shut the context
    down under a take); then the nodes are destroyed and rclpy shut down in order."""
    # one thread per node's kernels: the graph already runs a process per stage on every core there is (the
    # offline pipeline splits the filter's kernels over the cores instead; core/base/compiled.py)
    numba.set_num_threads(1)
    COMMAND_LINE_OVERRIDES[:] = command_line_overrides(sys.argv if args is None else args)
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    context = rclpy.get_default_context()
    # the numba kernels compiled (first start after an install: one log line) and loaded before any node
    # subscribes, never inside the first frames (core/base/compiled.py); a Ctrl-C meanwhile ends the process cleanly
    try:
        from ntcr_recon.sim.warm_up import ready_kernels

        ready_kernels(rclpy.logging.get_logger(os.path.basename(sys.argv[0]).removesuffix(".py") or "ntcr").info)
    except KeyboardInterrupt:
        rclpy.shutdown()
        return 0
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    nodes: list[Node] = []
    exit_code = 0
    try:
        for factory in node_factories:
            nodes.append(factory())
        refuse_unknown_overrides(nodes)
        executor = make_executor(context)
        for node in nodes:
            executor.add_node(node)
        spin(executor, context, stop, lambda: bool(failures(nodes)))
        for failure in failures(nodes):
            print(f"error: {failure}", file=sys.stderr)
            exit_code = 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:
        # e.g. "Unable to convert call argument '0' to Python object" from a take interrupted by Ctrl-C: a clean
        # stop when a stop was asked for (our SIGINT / SIGTERM handler: with SignalHandlerOptions.NO the context
        # is not shut down by a Ctrl-C) or the context is going down; any other RuntimeError is a bug and stays one.
        if not (stop.is_set() or _shutting_down(context)):
            raise
    except (ParameterError, ParameterException) as error:  # refused at start-up: say which, exit non-zero
        print(f"error: {error}", file=sys.stderr)
        return 2
    finally:
        for node in nodes:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return exit_code


# ---- command-line overrides (`--ros-args -p NAME:=VALUE`) -----------------------------------------------------
# rcl drops a `-p` value whose type differs from the parameter file's value of the same key without a word
# (`-p robot.notch_count:=abc` or `:=16.5` with notch_count 16 in the file: the node ran with 16), and a `-p` of
# a name no node declares is never read. So run_nodes reads the command line's overrides itself: RigNode checks
# each by the schema (and applies one rcl dropped), and a name no node of the process declares is refused with
# the nearest one suggested, as the rig file's loader refuses an unknown key.

COMMAND_LINE_OVERRIDES: list[tuple[str | None, str, str]] = []  # (node or None, name, text), set by run_nodes
BUILTIN_PARAMETERS = ("use_sim_time", "start_type_description_service")
BUILTIN_PREFIXES = ("qos_overrides.",)


def command_line_overrides(argv: Sequence[str]) -> list[tuple[str | None, str, str]]:
    """(node name or None, parameter name, value text) of every `-p` / `--param` [NODE:]NAME:=VALUE of the
    command line's --ros-args sections."""
    overrides, in_ros, argv = [], False, list(argv)
    for index, token in enumerate(argv):
        if token == "--ros-args":
            in_ros = True
        elif token == "--":
            in_ros = False
        elif in_ros and token in ("-p", "--param") and index + 1 < len(argv):
            name, sep, text = argv[index + 1].partition(":=")
            if not sep:
                continue  # rcl refuses it itself
            node, _, name = name.rpartition(":")
            overrides.append((node or None, name, text))
    return overrides


def ros_argument_value(text: str) -> Any:
    """A `-p NAME:=VALUE` value as rcl types it (YAML: an integer, a double, a bool, a list, else a string)."""
    import yaml

    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        return text
    return value if isinstance(value, bool | list | str | int | float) else text


def _targets(node: Node, target: str | None) -> bool:
    return target is None or target.lstrip("/") in (node.get_name(), node.get_fully_qualified_name().lstrip("/"))


def refuse_unknown_overrides(nodes: Sequence[Node]) -> None:
    """ParameterError for a `-p` name that no node of the process declares, the nearest declared one suggested."""
    known = sorted({name for node in nodes for name in node._parameters})
    for target, name, text in COMMAND_LINE_OVERRIDES:
        if name in known or name in BUILTIN_PARAMETERS or name.startswith(BUILTIN_PREFIXES):
            continue
        if target is not None and not any(_targets(node, target) for node in nodes):
            continue  # meant for a node of another process
        nearest = difflib.get_close_matches(name, known, n=1)
        hint = f"; did you mean {nearest[0]!r}?" if nearest else " (`ros2 param list` shows the parameters)"
        raise ParameterError(f"-p {name}:={text}: unknown parameter {name!r}{hint}")


# ---- rig-configured nodes -------------------------------------------------------------------------------------
# Every stage node reads the same rig configuration (config/*.yaml, passed as a ROS parameter file) as the CLI.
# Its nested sections become dotted parameters (`cam_a.translation`, `filters.sor_alpha`); each is declared with
# the descriptor of its key in the core's configuration schema (description, unit, range), and values are checked
# by that same schema, so a bad value is refused at start and on change with the loader's message, which names
# the dotted key, its unit and its range.

def rig_parameter_descriptor(key) -> ParameterDescriptor:
    """The ParameterDescriptor of a schema Key (ntcr_recon.core.base.schema): its description, unit and range, the
    range also as integer_range / floating_point_range for scalars so `ros2 param describe` shows the bounds."""
    setting = key.setting
    limits = setting.range_text()
    descriptor = ParameterDescriptor(
        description=f"{setting.description}" + (f"; {limits}" if limits else f" [{setting.unit}]" if setting.unit
                                                else ""),
        additional_constraints=limits, dynamic_typing=True)  # types: the schema accepts 30 for 30.0
    bounds = list(setting.choices) if setting.choices else [setting.minimum, setting.maximum]
    if key.length is not None or None in bounds or not all(isinstance(b, int | float) for b in bounds):
        return descriptor
    low, high = min(bounds), max(bounds)
    if setting.off is not None:
        low = min(low, setting.off)
    if key.scalar is int:
        descriptor.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=1)]
    elif key.scalar is float:
        descriptor.floating_point_range = [FloatingPointRange(from_value=float(low), to_value=float(high))]
    return descriptor


# Rig keys a running node cannot apply (its topics are made once): refused on change, as read-only.
READ_ONLY_RIG_PREFIXES = ("topics.",)


class RigNode(Node):
    """A node configured by the rig configuration (attribute `rig`, a RigConfig) plus its own parameters.

    `own_parameters`: name -> (default, ParameterDescriptor). Subclasses implement `configure(rig, params)`,
    which checks their own parameters (raise ParameterError naming one to refuse) and applies both; it runs at
    start-up and again on every accepted parameter change.
    """

    def __init__(self, node_name: str, own_parameters: dict[str, tuple[Any, ParameterDescriptor]]) -> None:
        from ntcr_recon.core.config.parameters import rig_parameter_keys

        super().__init__(node_name)
        # read-only, as the topics: the subscriptions and publishers are made once, from the start values
        self.declare_parameter("camera_names", ["cam_a", "cam_b"], ParameterDescriptor(
            description="rig configuration: names of the cameras, each with its own section", dynamic_typing=True,
            read_only=True))
        camera_names = self.get_parameter("camera_names").value
        if not isinstance(camera_names, list | tuple) or not all(isinstance(n, str) and n for n in camera_names):
            raise ParameterError(f"parameter 'camera_names' must be a list of camera names, got {camera_names!r}")
        self._camera_names = tuple(camera_names)
        rig_keys = rig_parameter_keys(camera_names)
        for name, key in rig_keys.items():
            # Declared without the range first: an out-of-range start value is then refused by the schema below,
            # with its message (naming the key, unit and range), rather than by rclpy's own.
            default = None if key.setting.required else list(key.default) if isinstance(key.default, tuple) \
                else key.default
            self.declare_parameter(name, default, ParameterDescriptor(
                description=key.setting.description, dynamic_typing=True))
        for name, (default, descriptor) in own_parameters.items():
            self.declare_parameter(name, default, descriptor)
        self._rig_names = ["camera_names", *rig_keys]
        self._own_names = list(own_parameters)
        names = self._rig_names + self._own_names
        self._refuse_unknown_rig_keys(rig_keys)
        self._apply_command_line(rig_keys)
        self._configure_from({name: self.get_parameter(name).value for name in names})
        for name, key in rig_keys.items():
            descriptor = rig_parameter_descriptor(key)
            descriptor.read_only = name.startswith(READ_ONLY_RIG_PREFIXES)
            self.set_descriptor(name, descriptor)
        validate_on_change(self, names, self._configure_from)

    def _refuse_unknown_rig_keys(self, rig_keys) -> None:
        """A key of a rig section (a camera's, robot, filters...) this node does not know, from the parameter
        file or the command line, is a typo: refused naming the nearest, as the rig file's loader refuses it."""
        from ntcr_recon.core.config.rig import STAGE_SECTIONS

        sections = {"robot", *STAGE_SECTIONS, *self._camera_names}
        for name in self._parameter_overrides:
            section, dot, _ = name.partition(".")
            if dot and section in sections and name not in rig_keys:
                nearest = difflib.get_close_matches(name, [k for k in rig_keys if k.startswith(section + ".")], n=1)
                hint = f"; did you mean {nearest[0]!r}?" if nearest else ""
                raise ParameterError(f"rig configuration: unknown key {name}{hint}")

    def _apply_command_line(self, rig_keys) -> None:
        """Each `-p` of a rig key checked by the schema (ParameterError naming it) and applied: rcl keeps the
        parameter file's value when the `-p` value's type differs (an integer for a double key, say)."""
        from rclpy.parameter import Parameter

        from ntcr_recon.core.base.schema import convert
        from ntcr_recon.core.config.rig import ConfigError

        # as rcl does, the last `-p` of a name is the one in force (an earlier one of it is no error)
        last = {(target, name): (target, name, text) for target, name, text in COMMAND_LINE_OVERRIDES}
        for target, name, text in last.values():
            if not _targets(self, target) or not self.has_parameter(name):
                continue
            value, current = ros_argument_value(text), self.get_parameter(name).value
            if name in rig_keys:
                try:
                    value = convert(name, rig_keys[name], value)
                except ConfigError as error:
                    raise ParameterError(f"-p {name}:={text}: rig configuration: {error}") from error
                value = list(value) if isinstance(value, tuple) else value
            elif isinstance(current, float) and isinstance(value, int) and not isinstance(value, bool):
                value = float(value)  # `-p rate:=2` for a double parameter
            if current == value and type(current) is type(value):
                continue
            try:  # a node's own parameter: its declared type and range decide
                result = Node.set_parameters(self, [Parameter(name, value=value)])[0]
            except (ParameterException, TypeError, ValueError) as error:
                raise ParameterError(f"-p {name}:={text}: {error}") from error
            if not result.successful:
                raise ParameterError(f"-p {name}:={text}: {result.reason}")

    def set_parameters_atomically(self, parameter_list):
        """The schema checks a rig parameter's new value first, so a refusal names the key, its unit and range
        (rclpy's range check on the descriptor would answer first, in its own words)."""
        refusal = self._schema_refusal(parameter_list)
        return refusal if refusal is not None else super().set_parameters_atomically(parameter_list)

    def set_parameters(self, parameter_list):
        return [self.set_parameters_atomically([parameter]) for parameter in parameter_list]

    def _schema_refusal(self, parameter_list) -> SetParametersResult | None:
        from ntcr_recon.core.base.schema import convert
        from ntcr_recon.core.config.parameters import parameter_key
        from ntcr_recon.core.config.rig import ConfigError

        for parameter in parameter_list:
            key = parameter_key(parameter.name, self._camera_names)
            if key is None or parameter.value is None:
                continue
            try:
                convert(parameter.name, key, parameter.value)
            except ConfigError as error:
                self.get_logger().error(f"refused parameter change: rig configuration: {error}")
                return SetParametersResult(successful=False, reason=f"rig configuration: {error}")
        return None

    def _configure_from(self, values: dict[str, Any]) -> None:
        from ntcr_recon.core.config.rig import ConfigError, rig_config_from_mapping, unflatten_parameters

        rig_values = {name: values[name] for name in self._rig_names if values[name] is not None}
        try:
            rig = rig_config_from_mapping(unflatten_parameters(rig_values))
        except ConfigError as error:
            raise ParameterError(f"rig configuration: {error}") from error
        self.configure(rig, {name: values[name] for name in self._own_names})

    def configure(self, rig, params: dict[str, Any]) -> None:
        raise NotImplementedError

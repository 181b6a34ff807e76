"""Shared pieces of the recording tests: the stack's messages, waiting, spinning, reading back."""
import threading

import rclpy
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile
from rclpy.serialization import serialize_message
from softblock_interfaces.msg import (Assembly, AssemblyState, Chain, ChainState, HvChannelState,
                                      HvState, SequenceEvent)

from softblock_ros.client import wait_until
from recording.mcap_file import RecordingWriter
from softblock_ros.recording.qos_metadata import offered_qos_yaml

TIMEOUT = 30.0  # [s] liveness deadline only: the suite shares two loaded cores


def wait_for(predicate, what: str, timeout: float = TIMEOUT):
    """Polls `predicate` until truthy and returns its value; ClientError names `what` on timeout."""
    return wait_until(predicate, timeout, what)


class Spinner:
    """Spins nodes in a background thread until closed; an exception there is raised by close()."""

    def __init__(self, context, *nodes):
        self.executor = SingleThreadedExecutor(context=context)
        for node in nodes:
            self.executor.add_node(node)
        self.error: BaseException | None = None
        self._closing = False
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        try:
            self.executor.spin()
        except BaseException as error:  # raised again by close(), not lost with the thread
            if self._closing:
                # rclpy's Executor.shutdown destroys its guard conditions without waiting for
                # spin to leave its wait, which may then raise: the stop close() asked for.
                return
            self.error = error
            raise

    def close(self):
        """Stops spinning; raises if spinning had ended with an exception (naming it)."""
        self._closing = True
        self.executor.shutdown()
        self._thread.join()
        if self.error is not None:
            raise RuntimeError(f"the spin thread died: {self.error!r}") from self.error


def stamp(node_or_ns, message):
    """Sets message.header.stamp from a node's clock or from nanoseconds; returns the message."""
    ns = node_or_ns if isinstance(node_or_ns, int) else node_or_ns.get_clock().now().nanoseconds
    message.header.stamp.sec, message.header.stamp.nanosec = divmod(ns, 1_000_000_000)
    return message


def hv_state(voltages: dict, faults: dict | None = None) -> HvState:
    """HvState with one channel per entry of `voltages` (name -> V); current = V * 1e-8 A."""
    faults = faults or {}
    return HvState(device_id="sim-hv", backend="sim", channels=[
        HvChannelState(name=name, index=number, setpoint=float(voltage), target=float(voltage),
                       measured_voltage=float(voltage), measured_current=voltage * 1e-8,
                       ceiling=4000.0, output_enabled=True, faults=faults.get(name, (0, ""))[0],
                       fault_text=faults.get(name, (0, ""))[1])
        for number, (name, voltage) in enumerate(voltages.items())])


def sequence_event(step_index: int, step_name: str, phase: str, message: str = ""):
    return SequenceEvent(sequence="grasp", step_index=step_index, step_name=step_name,
                         phase=phase, message=message)


def assembly_state(angles: dict) -> AssemblyState:
    """AssemblyState with one chain per entry of `angles` (name -> block angles [rad])."""
    return AssemblyState(assembly_name="gripper", safe_voltage=4000.0, chains=[
        ChainState(name=name, hv_channel=name, voltage=1000.0, block_angles=list(values),
                   block_valid=[True] * len(values))
        for name, values in angles.items()])


def assembly(name: str = "gripper") -> Assembly:
    return Assembly(name=name, chains=[Chain(name="front", hv_channel="front")])


def read_decoded(path: str) -> dict:
    """topic -> list of (schema name, decoded message, log_time, publish_time), via mcap-ros2."""
    topics: dict = {}
    with open(path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            topics.setdefault(channel.topic, []).append(
                (schema.name, decoded, message.log_time, message.publish_time))
    return topics


def new_context():
    context = rclpy.Context()
    rclpy.init(context=context)
    return context


def type_name_of(message) -> str:
    """'pkg/msg/Type' of a message instance."""
    return f"{type(message).__module__.split('.')[0]}/msg/{type(message).__name__}"


def write_recording(path: str, entries, qos_by_topic: dict | None = None) -> str:
    """Writes (topic, message, time_ns) entries with the recorder's writer, as if recorded live.

    Log and publish time are `time_ns`; QoS defaults to reliable/volatile depth 10.
    """
    qos_by_topic = qos_by_topic or {}
    writer = RecordingWriter(path)
    channels = {}
    for topic, message, time_ns in entries:
        if topic not in channels:
            offered = offered_qos_yaml([qos_by_topic.get(topic, QoSProfile(depth=10))])
            channels[topic] = writer.add_topic(topic, type_name_of(message), offered)
        writer.write(channels[topic], serialize_message(message), time_ns, time_ns)
    writer.close()
    return path

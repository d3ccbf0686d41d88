"""Independent check of a fiberflow recording: open it with the Python `mcap` reader and
decode every message with `mcap-ros2-support` from the ros2msg schema stored in the file.
Prints a JSON summary; exits non-zero if anything fails to decode."""
import json
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

path = sys.argv[1]
counts = {}
last_step = {}
touched_total = 0
with open(path, "rb") as f:
    reader = make_reader(f, decoder_factories=[DecoderFactory()])
    for schema, channel, message, decoded in reader.iter_decoded_messages():
        counts[schema.name] = counts.get(schema.name, 0) + 1
        if schema.name == "fiberflow_msgs/msg/FiberGroupState":
            n = sum(decoded.segments_per_fiber)
            assert len(decoded.centre) == 3 * n, "centre length"
            assert decoded.schema_version == 5
            # one force per segment in two-way runs, none one-way
            assert len(decoded.hydro_force) in (0, 3 * n), "hydro_force length"
            # contact: the touched segments, ascending, each with a force and a count
            touched = list(decoded.contact_segment)
            assert touched == sorted(set(touched)) and all(i < n for i in touched)
            assert len(decoded.contact_force) == 3 * len(touched), "contact_force length"
            assert len(decoded.contacts) == len(touched), "contacts length"
            touched_total += len(touched)
            last_step[decoded.group] = decoded.step
        if schema.name == "fiberflow_msgs/msg/FlowStatus":
            assert len(decoded.fiber_force_plus) in (0, 3), "fiber_force_plus length"
        if schema.name == "sensor_msgs/msg/PointCloud2":
            assert decoded.point_step == 16 and len(decoded.data) == 16 * decoded.width
        if schema.name == "sensor_msgs/msg/Image":
            assert decoded.encoding == "rgb8" and decoded.step == 3 * decoded.width
            assert len(decoded.data) == decoded.step * decoded.height > 0
        if schema.name == "fiberflow_msgs/msg/FlowSlice":
            assert len(decoded.values) == len(decoded.u_plus) * len(decoded.v_plus)
    summary = reader.get_summary()
print(
    json.dumps(
        {
            "counts": counts,
            "last_step": last_step,
            "channels": len(summary.channels),
            "contact_segments": touched_total,
        }
    )
)

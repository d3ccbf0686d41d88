"""The flow part of a run's recording, small enough to keep: a copy of RUN/run.mcap with only
the run's announcement, the flow status and profiles, and the first and last state of each
fibre group (what `fiberflow analyze` reads for the flow statistics and the loading).

    python3 scripts/flow_part.py RUN/run.mcap OUT/run.mcap      # then: fiberflow analyze OUT
"""
import sys, re
from mcap.reader import make_reader
from mcap.writer import Writer, CompressionType
src, dst = sys.argv[1], sys.argv[2]
keep = re.compile(r'/(control/announce|flow/status|flow/profiles)$')
first_state = {}
last_state = {}
with open(src,'rb') as f:
    for schema, ch, msg in make_reader(f).iter_messages():
        if ch.topic.endswith('/state'):
            last_state[ch.topic] = msg.log_time
with open(src, 'rb') as f, open(dst, 'wb') as o:
    r = make_reader(f)
    w = Writer(o, compression=CompressionType.ZSTD)
    w.start(profile='ros2', library='flow-extract')
    for rec in r.iter_metadata():
        w.add_metadata(rec.name, rec.metadata)
    schemas, chans = {}, {}
    for schema, ch, msg in r.iter_messages():
        t = ch.topic
        is_state = t.endswith('/state')
        if not keep.search(t) and not (is_state and (t not in first_state or msg.log_time == last_state[t])):
            continue
        if is_state:
            first_state[t] = True
        if schema.id not in schemas:
            schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
        if ch.id not in chans:
            chans[ch.id] = w.register_channel(t, ch.message_encoding, schemas[schema.id], ch.metadata)
        w.add_message(chans[ch.id], msg.log_time, msg.data, msg.publish_time, msg.sequence)
    w.finish()

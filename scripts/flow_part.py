"""The flow part of a run's recording, small enough to keep: a copy of RUN/run.mcap with only
the run's announcement, the flow status and the flow profiles (what `fiberflow analyze` reads
for the flow statistics and the drag), and, instead of the fibres' states, their total mass
in wall units (rho_f = 1) from the first state of every piece, as the metadata record
`fiberflow.flow_part` (key `fiber_mass_plus`), which the analysis reads for the loading.

    python3 scripts/flow_part.py RUN/run.mcap OUT/run.mcap      # then: fiberflow analyze OUT
"""
import math
import re
import sys

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from mcap_ros2.decoder import DecoderFactory

src, dst = sys.argv[1], sys.argv[2]
keep = re.compile(r'/(control/announce|flow/status|flow/profiles)$')

# the fibres' mass: sum over fibres of rho_s/rho_f * pi d^2 / 4 * l * segments, from the
# first state of each piece (group, first fibre)
mass = 0.0
pieces = set()
fibers = 0
with open(src, 'rb') as f:
    for schema, ch, msg, state in make_reader(
            f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
        if not ch.topic.endswith('/state'):
            continue
        piece = (state.group, state.first_fiber)
        if piece in pieces:
            continue
        pieces.add(piece)
        fibers += len(state.segments_per_fiber)
        for i, n in enumerate(state.segments_per_fiber):
            d, l, r = state.diameter[i], state.segment_length[i], state.density_ratio[i]
            mass += r * math.pi / 4 * d * d * l * n

with open(src, 'rb') as f, open(dst, 'wb') as o:
    r = make_reader(f)
    w = Writer(o, compression=CompressionType.ZSTD)
    w.start(profile='ros2', library='fiberflow flow_part.py')
    for rec in r.iter_metadata():
        w.add_metadata(rec.name, rec.metadata)
    w.add_metadata('fiberflow.flow_part', {
        'fiber_mass_plus': repr(mass),
        'pieces': str(len(pieces)),
        'fibers': str(fibers),
        'source': src,
    })
    schemas, chans = {}, {}
    for schema, ch, msg in r.iter_messages():
        if not keep.search(ch.topic):
            continue
        if schema.id not in schemas:
            schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
        if ch.id not in chans:
            chans[ch.id] = w.register_channel(ch.topic, ch.message_encoding, schemas[schema.id],
                                              ch.metadata)
        w.add_message(chans[ch.id], msg.log_time, msg.data, msg.publish_time, msg.sequence)
    w.finish()
print(f'{dst}: flow part of {src}, {fibers} fibres in {len(pieces)} pieces, '
      f'mass {mass:.6g} (wall units)')

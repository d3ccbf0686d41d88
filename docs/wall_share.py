#!/usr/bin/env python3
"""Share of fibre segments by distance from the nearer wall, every 100 t+ of a recording.

    python3 docs/wall_share.py RUN_FOLDER > shares.csv

Reads the run's segments (run.mcap, run-1.mcap, ...) with the Python `mcap` reader
(pip install mcap mcap-ros2-support) and, for the first full state of each multiple of
100 t+, prints the segments' shares in the y+ bands 0-5, 5-15, 15-30, 30-60 and 60-150
from the nearer wall (centres in wall units with the centreline at y = 0, h+ = 150).
"""
import glob
import sys

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

run = sys.argv[1]
files = sorted(glob.glob(run + "/run*.mcap"), key=lambda p: (len(p), p))
edges = [0, 5, 15, 30, 60, 150.0001]
rows = {}
for f in files:
    with open(f, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages():
            if not channel.topic.endswith("/state"):
                continue
            t = round(msg.t_plus)
            if t % 100 != 0 or t in rows:
                continue
            c = np.array(msg.centre).reshape(-1, 3)
            wall = 150.0 - np.abs(c[:, 1])
            counts, _ = np.histogram(wall, bins=edges)
            rows[t] = (len(wall), counts / len(wall))
print("t_plus,segments,share_yplus_0_5,share_5_15,share_15_30,share_30_60,share_60_150")
for t in sorted(rows):
    n, s = rows[t]
    print(f"{t},{n}," + ",".join(f"{x:.4f}" for x in s))

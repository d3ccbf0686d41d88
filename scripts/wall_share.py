#!/usr/bin/env python3
"""Share of fibre segments by distance from the nearer wall, every 100 t+ of a run.

    fiberflow export RUN_FOLDER --what states
    python3 scripts/wall_share.py RUN_FOLDER/export [EVERY_T_PLUS] > shares.csv

Reads the exported fibre states (docs/export.md; pip install pandas pyarrow) and, for each
recorded step at a multiple of EVERY_T_PLUS (default 100) t+, prints the shares of all
groups' segments in the y+ bands 0-5, 5-15, 15-30, 30-60 and 60-150 from the nearer wall
(centres in wall units with the centreline at y = 0, h+ = 150).
"""
import sys

import numpy as np
import pandas as pd

every = float(sys.argv[2]) if len(sys.argv) > 2 else 100.0
s = pd.read_parquet(sys.argv[1] + "/states.parquet", columns=["t_plus", "centre_y_plus"])
s["t"] = (s["t_plus"] / every).round() * every
s = s[np.isclose(s["t_plus"], s["t"], atol=1e-6)]
edges = [0, 5, 15, 30, 60, 150.0001]
print("t_plus,segments,share_yplus_0_5,share_5_15,share_15_30,share_30_60,share_60_150")
for t, g in s.groupby("t"):
    counts, _ = np.histogram(150.0 - g["centre_y_plus"].abs(), bins=edges)
    print(f"{t:g},{len(g)}," + ",".join(f"{x:.4f}" for x in counts / len(g)))

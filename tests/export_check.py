#!/usr/bin/env python3
"""Checks `fiberflow export` against the recording, independently of the project's code.

    python3 tests/export_check.py RUN_FOLDER EXPORT_FOLDER

Decodes every segment of the run (run.mcap, run-1.mcap, ...) with the Python `mcap`
readers (mcap, mcap-ros2-support), puts sharded groups back together (slices by
first_fiber), keeps the first complete copy of each (group, step) and each step, orders
rows by (step, group, fibre, segment), and compares every column of every Parquet table
read with pyarrow, bit for bit (floats as their 64-bit patterns, nulls as nulls). Also
checks that every column carries a unit and a description. Prints a JSON summary of row
counts; exits non-zero on the first difference.
"""
import glob
import json
import os
import re
import sys

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

run, exported = sys.argv[1], sys.argv[2]


def segment_index(path):
    name = os.path.basename(path)
    if name == "run.mcap":
        return 0
    m = re.fullmatch(r"run-([1-9][0-9]*)\.mcap", name)
    return int(m.group(1)) if m else None


segments = sorted(
    (p for p in glob.glob(os.path.join(run, "*.mcap")) if segment_index(p) is not None),
    key=segment_index,
)
assert segments, f"{run}: no segments"

states, metrics = {}, {}  # (group, step) -> slices in fibre order, first complete copy
open_slices = {"state": {}, "metrics": {}}
flow, profiles = {}, {}  # step -> message, first copy


def add(kind, done, msg, nfib):
    key = (msg.group, msg.step)
    if key in done:
        return
    pieces = open_slices[kind].setdefault(key, {})
    pieces[msg.first_fiber] = (nfib, msg)
    at = 0
    for first in sorted(pieces):
        if first != at:
            return
        at += pieces[first][0]
    if at == msg.group_fibers:
        done[key] = [pieces[f][1] for f in sorted(pieces)]
        del open_slices[kind][key]


for seg in segments:
    with open(seg, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages():
            t = channel.topic
            if t.endswith("/state"):
                if len(msg.axis) == 0:
                    continue
                add("state", states, msg, len(msg.segments_per_fiber))
            elif t.endswith("/metrics") and "/fibers/" in t:
                add("metrics", metrics, msg, len(msg.z1))
            elif t.endswith("/flow/status"):
                flow.setdefault(msg.step, msg)
            elif t.endswith("/flow/profiles"):
                profiles.setdefault(msg.step, msg)

f64 = lambda v: np.asarray(v, dtype=np.float64)


def state_columns():
    cols = {k: [] for k in (
        "step t_plus group fiber segment segments segment_length_plus diameter_plus "
        "density_ratio layer".split())}
    vec = {}
    contact_rows = {k: [] for k in "step t_plus group fiber segment contacts".split()}
    contact_force = []
    for key in sorted(states, key=lambda k: (k[1], k[0])):
        for s in states[key]:
            spf = np.asarray(s.segments_per_fiber, dtype=np.int64)
            nseg = int(spf.sum())
            fibre = np.repeat(s.first_fiber + np.arange(len(spf)), spf)
            segment = np.concatenate([np.arange(n) for n in spf])
            cols["step"].append(np.full(nseg, s.step, np.uint64))
            cols["t_plus"].append(np.full(nseg, s.t_plus))
            cols["group"] += [s.group] * nseg
            cols["fiber"].append(fibre)
            cols["segment"].append(segment)
            cols["segments"].append(np.repeat(spf, spf))
            cols["segment_length_plus"].append(np.repeat(f64(s.segment_length), spf))
            cols["diameter_plus"].append(np.repeat(f64(s.diameter), spf))
            cols["density_ratio"].append(np.repeat(f64(s.density_ratio), spf))
            cols["layer"].append(np.repeat(np.asarray(bytearray(s.layer), np.uint8) if isinstance(s.layer, (bytes, bytearray)) else np.asarray(s.layer, np.uint8), spf))
            for name in ("centre", "axis", "velocity", "angular_velocity", "hydro_force"):
                a = f64(getattr(s, name))
                a = a.reshape(-1, 3) if a.size else np.full((nseg, 3), np.nan)
                for c, xyz in enumerate("xyz"):
                    suffix = "" if name == "axis" else "_plus"
                    vec.setdefault(f"{name}_{xyz}{suffix}", []).append(a[:, c])
            cf = np.zeros((nseg, 3))
            cn = np.zeros(nseg, np.uint32)
            idx = np.asarray(s.contact_segment, np.int64)
            if idx.size:
                cf[idx] = f64(s.contact_force).reshape(-1, 3)
                cn[idx] = np.asarray(s.contacts, np.uint32)
                contact_rows["step"].append(np.full(idx.size, s.step, np.uint64))
                contact_rows["t_plus"].append(np.full(idx.size, s.t_plus))
                contact_rows["group"] += [s.group] * idx.size
                contact_rows["fiber"].append(fibre[idx])
                contact_rows["segment"].append(segment[idx])
                contact_rows["contacts"].append(cn[idx])
                contact_force.append(cf[idx])
            for c, xyz in enumerate("xyz"):
                vec.setdefault(f"contact_force_{xyz}_plus", []).append(cf[:, c])
            vec.setdefault("contacts", []).append(cn)
    cols.update(vec)
    if contact_force:
        cf = np.concatenate(contact_force)
        for c, xyz in enumerate("xyz"):
            contact_rows[f"contact_force_{xyz}_plus"] = [cf[:, c]]
    return cols, contact_rows


def metric_columns():
    cols = {}
    for key in sorted(metrics, key=lambda k: (k[1], k[0])):
        for m in metrics[key]:
            n = len(m.z1)
            cols.setdefault("step", []).append(np.full(n, m.step, np.uint64))
            cols.setdefault("t_plus", []).append(np.full(n, m.t_plus))
            cols.setdefault("group", []).extend([m.group] * n)
            cols.setdefault("fiber", []).append(m.first_fiber + np.arange(n))
            com = f64(m.centre_of_mass).reshape(-1, 3)
            for c, xyz in enumerate("xyz"):
                cols.setdefault(f"centre_of_mass_{xyz}_plus", []).append(com[:, c])
            for name, col in (("z1", "z1"), ("sigma2", "sigma2"), ("end_to_end", "end_to_end_plus")):
                cols.setdefault(col, []).append(f64(getattr(m, name)))
    return cols


def flow_columns():
    cols = {}
    for step in sorted(flow):
        s = flow[step]
        for col, v in (("step", s.step), ("t_plus", s.t_plus), ("dt_plus", s.dt_plus),
                       ("cfl", s.cfl), ("max_divergence", s.max_divergence),
                       ("bulk_velocity_plus", s.bulk_velocity), ("re_tau", s.re_tau),
                       ("pressure_gradient", s.pressure_gradient)):
            cols.setdefault(col, []).append(np.asarray([v]))
        ff = f64(s.fiber_force_plus)
        for c, xyz in enumerate("xyz"):
            cols.setdefault(f"fiber_force_{xyz}_plus", []).append(
                np.asarray([ff[c] if ff.size else np.nan]))
    return cols


def profile_columns():
    cols = {}
    for step in sorted(profiles):
        p = profiles[step]
        n = len(p.y_plus)
        for col, v in (("step", p.step), ("t_plus", p.t_plus), ("samples", p.samples),
                       ("t_plus_span", p.t_plus_span), ("re_tau", p.re_tau),
                       ("bulk_velocity_plus", p.bulk_velocity)):
            cols.setdefault(col, []).append(np.full(n, v))
        for name in ("y_plus", "u_mean", "u_rms", "v_rms", "w_rms", "uv", "omega_z_mean",
                     "omega_x_rms", "omega_y_rms", "omega_z_rms"):
            col = name if name == "y_plus" else name + "_plus"
            cols.setdefault(col, []).append(f64(getattr(p, name)))
    return cols


def compare(table, expected):
    got = pq.read_table(os.path.join(exported, f"{table}.parquet"))
    rows = got.num_rows
    if rows:
        assert sorted(expected) == sorted(got.schema.names), f"{table}: columns differ"
    for f in got.schema:
        meta = {k.decode(): v.decode() for k, v in (f.metadata or {}).items()}
        assert "unit" in meta and meta.get("description"), f"{table}.{f.name}: no unit/description"
        col = got.column(f.name)
        want = expected.get(f.name, [])
        if pa.types.is_string(f.type):
            assert col.to_pylist() == list(want), f"{table}.{f.name}: differs"
            continue
        w = np.concatenate([np.atleast_1d(x) for x in want]) if want else np.zeros(0)
        assert len(w) == rows, f"{table}.{f.name}: {rows} rows, the recording has {len(w)}"
        nulls = col.is_null().to_numpy(zero_copy_only=False)
        if pa.types.is_floating(f.type):
            # NaN above marks "not recorded" (recorded values are finite: the messages' checks)
            want_null = np.isnan(w.astype(np.float64))
            assert f.nullable or not want_null.any(), f"{table}.{f.name}: nulls not allowed"
            assert (nulls == want_null).all(), f"{table}.{f.name}: nulls differ"
            g = col.fill_null(0.0).to_numpy().astype(np.float64)
            same = want_null | (g.view(np.uint64) == w.astype(np.float64).view(np.uint64))
            assert same.all(), f"{table}.{f.name}: first difference at row {int(np.argmin(same))}"
        else:
            assert not nulls.any(), f"{table}.{f.name}: unexpected nulls"
            g = col.to_numpy(zero_copy_only=False).astype(np.uint64)
            assert (g == w.astype(np.uint64)).all(), f"{table}.{f.name}: differs"
    return rows


summary = {"segments": len(segments)}
s_cols, c_cols = state_columns()
checks = {
    "states": s_cols,
    "contacts": c_cols,
    "metrics": metric_columns(),
    "flow": flow_columns(),
    "profiles": profile_columns(),
}
for table, cols in checks.items():
    if os.path.exists(os.path.join(exported, f"{table}.parquet")):
        summary[table] = compare(table, cols)
print(json.dumps(summary))

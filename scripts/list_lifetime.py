"""How long a contact neighbour list kept over steps would stay valid, measured on the
states of a recording that holds every step (docs/history/contact-cost.md, "How long any list would hold").

    fiberflow launch launch/flocs-wall.toml --out recordings/flocs-wall-30 \
        --set run.steps=30 --set recorder.states_every_steps=1 --set run.analyze=false
    fiberflow export recordings/flocs-wall-30 --what states
    pip install numpy pandas pyarrow scipy
    python3 scripts/list_lifetime.py recordings/flocs-wall-30/export

Per group it prints two measures:

* the skin an ideal list needs (any list, however it is kept): for the pairs of segments
  of different fibres whose centres are within l + d at step t, how much farther apart their
  centres were at the build step b. A list built at b with a smaller skin misses one of them.
* the lifetime of a list kept per region with the bound of docs/history/design-contact-and-hosts.md: regions
  are cubes of side R by position at b; a region's list holds while the box of the
  displacements since b over it and its 26 neighbours, plus twice their largest turn
  h|Δẑ|, plus the same for the next step's motion, stays within the skin s.
"""
import sys

import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

BOX = np.array([942.477796, 300.0, 471.238898])  # the fine grid's box, wall units
HALF = 1.5  # half a case-1 segment, wall units
REACH = 3.0 + 0.232  # centres of two touching segments are within l + d


def read(export):
    """group -> step -> (centres, axes, fibre of each segment), from the exported states
    (docs/export.md)."""
    centre = ["centre_x_plus", "centre_y_plus", "centre_z_plus"]
    axis = ["axis_x", "axis_y", "axis_z"]
    t = pd.read_parquet(export + "/states.parquet", columns=["group", "step", "fiber"] + centre + axis)
    states = {}
    for (group, step), d in t.groupby(["group", "step"], sort=True):
        states.setdefault(group, {})[step] = (
            d[centre].to_numpy(),
            d[axis].to_numpy(),
            d["fiber"].to_numpy(),
        )
    return states


def nearest(d):
    for k in (0, 2):
        d[:, k] -= BOX[k] * np.round(d[:, k] / BOX[k])
    return d


def folded(c):
    c = c.copy()
    c[:, 0] = np.mod(c[:, 0], BOX[0])
    c[:, 2] = np.mod(c[:, 2], BOX[2])
    c[:, 1] += 1000.0
    return c


def ideal_skin(st, b, ts):
    cb, _, fibre = st[b]
    out = []
    for t in ts:
        tree = cKDTree(folded(st[t][0]), boxsize=[BOX[0], 1e7, BOX[2]])
        pairs = tree.query_pairs(REACH, output_type="ndarray")
        pairs = pairs[fibre[pairs[:, 0]] != fibre[pairs[:, 1]]]
        need = np.linalg.norm(nearest(cb[pairs[:, 0]] - cb[pairs[:, 1]]), axis=1) - REACH
        out.append(f"{t - b}: {max(need.max(initial=0.0), 0):.2f}")
    return out


def spread_over_neighbours(a, dims, f):
    g = a.reshape(*dims, -1)
    out = g.copy()
    for ax in range(3):
        cur = out.copy()
        for sh in (-1, 1):
            r = np.roll(cur, sh, axis=ax)
            if ax == 1:  # not periodic across the channel
                if sh == 1:
                    r[:, 0] = cur[:, 0]
                else:
                    r[:, -1] = cur[:, -1]
            out = f(out, r)
    return out.reshape(a.shape)


def region_lifetimes(st, b, last, side, skins):
    c = st[b][0]
    ids = np.stack(
        [np.mod(c[:, 0], BOX[0]) / side, c[:, 1] / side, np.mod(c[:, 2], BOX[2]) / side], 1
    ).astype(int)
    ids[:, 1] -= ids[:, 1].min()
    dims = (int(BOX[0] // side), ids[:, 1].max() + 1, int(BOX[2] // side))
    ids[:, 0] = np.minimum(ids[:, 0], dims[0] - 1)
    ids[:, 2] = np.minimum(ids[:, 2], dims[2] - 1)
    flat = (ids[:, 0] * dims[1] + ids[:, 1]) * dims[2] + ids[:, 2]
    cells = int(np.prod(dims))
    occupied = np.bincount(flat, minlength=cells) > 0
    life = {s: np.full(cells, np.inf) for s in skins}

    def box_diameter(d):
        lo = np.full((cells, 3), np.nan)
        hi = np.full((cells, 3), np.nan)
        for k in range(3):
            np.fmin.at(lo[:, k], flat, d[:, k])
            np.fmax.at(hi[:, k], flat, d[:, k])
        lo = spread_over_neighbours(lo, dims, np.fmin)
        hi = spread_over_neighbours(hi, dims, np.fmax)
        return np.linalg.norm(np.nan_to_num(hi - lo), axis=1)

    def most_turn(a, t):
        turn = HALF * np.linalg.norm(st[t][1] - st[a][1], axis=1)
        m = np.zeros(cells)
        np.maximum.at(m, flat, turn)
        return spread_over_neighbours(m[:, None], dims, np.fmax)[:, 0]

    for t in range(b + 1, last):
        bound = (
            box_diameter(nearest(st[t][0] - c))
            + 2 * most_turn(b, t)
            + box_diameter(nearest(st[t + 1][0] - st[t][0]))
            + 2 * most_turn(t, t + 1)
        )
        for s in skins:
            life[s][occupied & (bound > s) & np.isinf(life[s])] = t - b
    out = []
    for s in skins:
        lt = life[s][occupied]
        lt = np.where(np.isinf(lt), last - b, lt)
        out.append(f"s {s}: median {np.median(lt):.0f}, 10% {np.percentile(lt, 10):.0f}")
    return out


def main():
    states = read(sys.argv[1])
    for group, st in states.items():
        steps = sorted(st)
        first, last = steps[0], steps[-1]
        y = st[first][0][:, 1]
        print(f"== {group}: {len(y)} segments, y+ {y.min() + 150:.0f}–{y.max() + 150:.0f}")
        for b in (first, (first + last) // 2):
            ts = [t for t in (1, 2, 3, 5, 8, 12) if b + t <= last]
            print(f"  built at {b}, ideal skin by steps since:", "; ".join(ideal_skin(st, b, [b + t for t in ts])))
        for side in (10.0, 20.0):
            print(f"  regions of {side:.0f}, built at {first}, lifetime in steps:",
                  "; ".join(region_lifetimes(st, first, last, side, (1.0, 2.0, 4.0))))
        c = folded(st[first][0])
        tree = cKDTree(c, boxsize=[BOX[0], 1e7, BOX[2]])
        sizes = [f"+{s}: {len(tree.query_pairs(REACH + s)):,}" for s in (0.0, 1.0, 2.0, 4.0)]
        print("  pairs of centres within l + d + skin:", "; ".join(sizes))


if __name__ == "__main__":
    main()

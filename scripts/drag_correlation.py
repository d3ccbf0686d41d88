"""How long the drag of a channel run stays correlated, from runs exported with
`fiberflow export RUN --what flow` (docs/realisations.md, "How long the drag remembers").

    python3 scripts/drag_correlation.py --from-plus 500 EXPORT1 EXPORT2 ...

Per run, the pressure gradient after --from-plus about the run's own mean; prints the
pooled autocorrelation, its integral time scale (up to the first zero crossing), and the
standard deviation of batch means of length L pooled over the runs, with sd * sqrt(L),
which stops growing once the batches are long enough to be independent.
"""
import argparse

import numpy as np
import pyarrow.parquet as pq

ap = argparse.ArgumentParser()
ap.add_argument("exports", nargs="+", help="folders written by fiberflow export --what flow")
ap.add_argument("--from-plus", type=float, default=500.0)
a = ap.parse_args()
series = []
for d in a.exports:
    t = pq.read_table(f"{d}/flow.parquet").to_pandas().sort_values("t_plus")
    t = t[t.t_plus >= a.from_plus]
    dt = float(np.median(np.diff(t.t_plus)))
    series.append(t.pressure_gradient.to_numpy())
n_min = min(len(x) for x in series)
max_lag = n_min // 3
acf = np.zeros(max_lag)
for x in series:
    y = x - x.mean()
    for k in range(max_lag):
        acf[k] += np.dot(y[: len(y) - k], y[k:]) / len(y)
acf /= acf[0]
first_zero = int(np.argmax(acf <= 0)) if (acf <= 0).any() else max_lag
print(f"status every {dt:g} t+; {len(series)} runs of {n_min * dt:g} t+ after t+ {a.from_plus:g}")
print(f"autocorrelation first crosses zero at {first_zero * dt:g} t+; "
      f"integral time scale {acf[:first_zero].sum() * dt:.0f} t+")
print("lag t+  autocorrelation")
for lag in (25, 50, 100, 200, 300, 400):
    k = int(round(lag / dt))
    if k < max_lag:
        print(f"{lag:6d}  {acf[k]:.3f}")
print("batch t+  batches  sd of batch means  sd*sqrt(batch t+)")
for length in (25, 50, 100, 200, 500, 1000, 2000):
    m = int(round(length / dt))
    means = [x[j * m:(j + 1) * m].mean() for x in series for j in range(len(x) // m)]
    if len(means) >= 2:
        sd = np.std(means, ddof=1)
        print(f"{length:8d}  {len(means):7d}  {sd:.4f}  {sd * np.sqrt(length):.3f}")

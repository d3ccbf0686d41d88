"""Tables and figures of the fibres' own time step (docs/two-way.md, "The fibres' own
step"), from the runs of scripts/fiber_step.sh:

    python3 scripts/fiber_step_tables.py OUT FIGURES

OUT holds one-way/dt-<step>-field-<step>[-sub-<substeps>] (launch/paper-1e4.toml) and
two-way/r<i>-dt-<step>-field-<step>[-sub-<substeps>] (launch/two-way.toml, its first 100
t+; dt the coupling step, the fibres' step dt/substeps); FIGURES gets fiber-step-sigma2.csv and .png (each
case's final <sigma^2> and MSD_23 slope against the fibres' step) and
fiber-step-two-way.csv and .png (the pressure gradient and the fibres' streamwise force on
the fluid over time, and their means over t+ 20-50 and 50-100).
"""
import csv
import os
import re
import sys

import matplotlib
matplotlib.use('Agg')
import matplotlib.pyplot as plt
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

out, figures = sys.argv[1], sys.argv[2]
os.makedirs(figures, exist_ok=True)


def step_of(name, key):
    m = re.search(key + r'-([0-9.]+)', name)
    return float(m.group(1)) if m else None


# one-way: the summary table of each run's analysis
rows = []
one = os.path.join(out, 'one-way')
for name in sorted(os.listdir(one)) if os.path.isdir(one) else []:
    dt = step_of(name, 'dt')
    summary = os.path.join(one, name, 'analysis', 'summary.md')
    if dt is None or not os.path.exists(summary):
        continue
    for line in open(summary):
        cells = [c.strip() for c in line.strip().strip('|').split('|')]
        if len(cells) < 10 or not cells[0].startswith('case') or 'l+' in cells[1]:
            continue
        lo, hi = re.findall(r'[0-9.]+', cells[9].split('[', 1)[1])[:2]
        sub = int(step_of(name, 'sub') or 1)
        rows.append({'fiber_dt_plus': dt / sub, 'coupling_dt_plus': dt, 'substeps': sub,
                     'field_dt_plus': step_of(name, 'field') or dt,
                     'case': cells[0],
                     'msd23_slope': float(cells[4].split()[0]),
                     'final_abs_z1': float(cells[8]),
                     'final_sigma2': float(cells[9].split()[0]),
                     'final_sigma2_lo': float(lo), 'final_sigma2_hi': float(hi)})
if rows:
    with open(os.path.join(figures, 'fiber-step-sigma2.csv'), 'w', newline='') as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    # one point per fibres' step: the run with the finest field step (substeps apart)
    finest = {}
    for r in rows:
        if r['substeps'] > 1:
            continue
        k = (r['case'], r['fiber_dt_plus'])
        if k not in finest or r['field_dt_plus'] < finest[k]['field_dt_plus']:
            finest[k] = r
    for case in sorted({r['case'] for r in rows}):
        rs = sorted((r for r in finest.values() if r['case'] == case),
                    key=lambda r: r['fiber_dt_plus'])
        x = [r['fiber_dt_plus'] for r in rs]
        y = [r['final_sigma2'] for r in rs]
        err = [[r['final_sigma2'] - r['final_sigma2_lo'] for r in rs],
               [r['final_sigma2_hi'] - r['final_sigma2'] for r in rs]]
        line = a.errorbar(x, y, yerr=err, marker='o', capsize=3, label=case)
        b.plot(x, [r['msd23_slope'] for r in rs], marker='o', label=case)
        subs = [r for r in rows if r['case'] == case and r['substeps'] > 1]
        a.plot([r['fiber_dt_plus'] for r in subs], [r['final_sigma2'] for r in subs], '*',
               markersize=12, color=line[0].get_color())
    a.set_xlabel('fibres\' time step Δt+')
    a.set_ylabel('final ⟨σ²⟩ (95% bootstrap interval)')
    a.set_xscale('log', base=2)
    b.set_xlabel('fibres\' time step Δt+')
    b.set_ylabel('MSD₂₃ slope')
    b.set_xscale('log', base=2)
    a.legend(fontsize=8)
    fig.suptitle('paper-1e4.toml (6 × 10⁴ fibres, 80.8 t+): the fibres\' step alone '
                 '(★: coupling step 0.2 in substeps)')
    fig.tight_layout()
    fig.savefig(os.path.join(figures, 'fiber-step-sigma2.png'), dpi=110)


# two-way: the flow status over the first 100 t+
def status(path):
    s = {}
    with open(path, 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, ch, _, d in reader.iter_decoded_messages():
            if ch.topic.endswith('/flow/status'):
                fx = d.fiber_force_plus[0] if len(d.fiber_force_plus) else 0.0
                s[round(d.t_plus, 6)] = (d.pressure_gradient, fx)
    return s


two = os.path.join(out, 'two-way')
series = {}
for name in sorted(os.listdir(two)) if os.path.isdir(two) else []:
    mcap = os.path.join(two, name, 'run.mcap')
    if os.path.exists(mcap):
        series[name] = status(mcap)
if series:
    # every 2 t+: the times all runs share
    common = sorted(set.intersection(*(set(t for t in s if abs(t / 2 - round(t / 2)) < 1e-6)
                                       for s in series.values())))
    with open(os.path.join(figures, 'fiber-step-two-way.csv'), 'w', newline='') as f:
        w = csv.writer(f)
        w.writerow(['run', 't_plus', 'pressure_gradient', 'fiber_force_x_plus'])
        for name, s in series.items():
            for t in common:
                w.writerow([name, t, s[t][0], s[t][1]])
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    for name, s in series.items():
        a.plot(common, [s[t][0] for t in common], label=name)
        b.plot(common, [s[t][1] for t in common], label=name)
    a.set_xlabel('t+')
    a.set_ylabel('pressure gradient Π (outer units)')
    b.set_xlabel('t+')
    b.set_ylabel('fibres\' force on the fluid F_x+')
    a.legend(fontsize=7)
    fig.suptitle('two-way.toml, loading 0.4, first 100 t+: the fibres\' step (and the field\'s)')
    fig.tight_layout()
    fig.savefig(os.path.join(figures, 'fiber-step-two-way.png'), dpi=110)
    for name, s in series.items():
        for lo, hi in [(20, 50), (50, 100)]:
            ts = [t for t in common if lo < t <= hi]
            pi = sum(s[t][0] for t in ts) / len(ts)
            fx = sum(s[t][1] for t in ts) / len(ts)
            print(f'{name}: t+ {lo}-{hi}: mean pressure gradient {pi:.5f}, mean F_x+ {fx:.1f}')
for r in rows:
    print(f"one-way dt {r['fiber_dt_plus']}: {r['case']} slope {r['msd23_slope']:.3f} "
          f"final sigma2 {r['final_sigma2']:.4f}")

#!/usr/bin/env python3
"""The TopoBench table's wall time on a quiet machine, from timed epochs of every cell.

Usage: topobench_clean_time.py [--only MODEL,...] [--keep-denormals] [--fixed EPOCHS2] TDL
DATA_DIR RUNS_CSV OUT_CSV [EPOCHS [DATASET...]]. Standard library only. With --only, only those models are timed again;
every other cell keeps its seconds per epoch from the OUT_CSV already there (after a change that
concerns a few models). --keep-denormals is passed to `tdl topobench` (the runs as they were
before denormals were flushed, for a side-by-side timing).

The runs of docs/topobench/runs.csv were made beside builds and tests, so their recorded seconds
say little about the table's cost. This runs every cell of RUNS_CSV once (data seed 0, EPOCHS
epochs, default 10, `--jobs 2` as the table runs), with nothing else on the machine, one
`tdl topobench` per dataset so each dataset is lifted once; a cell's seconds per epoch are its
run's seconds over its epochs (a run's fixed costs, collating the evaluation batches and the test
pass, included: an overestimate for runs of more epochs). The table's clean time is then the sum
over its runs of epochs x seconds per epoch, over the two runs that go side by side, plus each
dataset's liftings. OUT_CSV gets model,dataset,seconds_per_epoch,runs,epochs,estimated_seconds.
Every model of the table is timed on each DATASET given, also where RUNS_CSV has no run yet (its
runs and estimate are then 0: the epochs a run will take are not known before it runs).

--fixed EPOCHS2 times every cell a second time, at EPOCHS2 epochs, and separates a run's fixed
cost from its epochs: seconds per epoch (s2 - s1) / (EPOCHS2 - EPOCHS), fixed seconds s1 - EPOCHS
x that; where that fixed cost would be negative (noise: the longer run was the slower per epoch),
fixed 0 and the longer run's s2 / EPOCHS2 per epoch. Each run is then estimated as fixed + its
epochs x seconds per epoch. The fixed part (the split's batches collated, the test pass, the first epoch's fresh
pages) is paid once per run, not per epoch: without --fixed it is spread over EPOCHS epochs and
multiplied by each run's epochs. OUT_CSV then has a fixed_seconds column (0 without --fixed).
"""
import csv
import os
import re
import subprocess
import sys
import tempfile
import time

args = sys.argv[1:]
only = None
extra = []
fixed_epochs = None
while args and args[0] in ("--only", "--keep-denormals", "--fixed"):
    if args[0] == "--keep-denormals":
        extra.append(args.pop(0))
        continue
    if args[0] == "--fixed":
        if len(args) < 2 or not args[1].isdigit():
            sys.exit("--fixed needs a number of epochs (more than EPOCHS), e.g. --fixed 20")
        fixed_epochs = int(args[1])
        del args[:2]
        continue
    if len(args) < 2:
        sys.exit("--only needs a comma-separated list of models")
    only = args[1].split(",")
    args = args[2:]
if len(args) < 4:
    sys.exit(__doc__)
tdl, data_dir, runs_csv, out_csv = args[:4]
epochs = int(args[4]) if len(args) > 4 else 10
if fixed_epochs is not None and fixed_epochs <= epochs:
    sys.exit(f"--fixed {fixed_epochs}: needs more epochs than EPOCHS ({epochs})")
MODELS = ["GCN", "AllSetTransformer", "EDGNN", "UniGNN2", "CWN", "CCCN", "CCXN", "SCN", "SCCN",
          "SCCNN"]

runs = list(csv.DictReader(open(runs_csv)))
cells = {}
for r in runs:
    cells.setdefault((r["model"], r["dataset"]), []).append(int(r["epochs"]))
for d in args[5:]:
    for m in MODELS:
        cells.setdefault((m, d), [])
datasets = []
for _, d in cells:
    if d not in datasets:
        datasets.append(d)

per_epoch, fixed, lifting = {}, {}, {}
if only is not None:
    unknown = [m for m in only if m not in MODELS]
    if unknown:
        sys.exit(f"--only: unknown models {unknown} (the table's: {', '.join(MODELS)})")
    if not os.path.exists(out_csv):
        sys.exit(f"--only keeps the other cells' figures from {out_csv}, which does not exist")
    for r in csv.DictReader(open(out_csv)):
        if r["model"] not in only:
            per_epoch[(r["model"], r["dataset"])] = float(r["seconds_per_epoch"])
            fixed[(r["model"], r["dataset"])] = float(r.get("fixed_seconds") or 0)
    if fixed_epochs is None and any(fixed.values()):
        print(f"note: {out_csv} has fixed costs apart (--fixed); the models timed again without "
              "--fixed get none, so the two kinds of estimate mix", file=sys.stderr)
    missing = [c for c in cells if c[0] not in only and c not in per_epoch]
    if missing:
        sys.exit(f"{out_csv} has no seconds per epoch for {missing}: time them (without --only)")
env = dict(os.environ, OMP_NUM_THREADS="1")


def time_runs(d, models, n):
    """Each model's run of n epochs on dataset d: {model: (seconds, epochs)}, and the liftings."""
    with tempfile.TemporaryDirectory() as out:
        p = subprocess.run([tdl, "topobench", "--data-dir", data_dir, "--out", out, "--models",
                            ",".join(models), "--datasets", d, "--splits", "0", "--max-epochs",
                            str(n), "--jobs", "2"] + extra, env=env, capture_output=True,
                           text=True)
        if p.returncode != 0:
            sys.exit(f"tdl topobench on {d} ({n} epochs) failed:\n{p.stderr[-2000:]}")
        lift = sum(float(s) for s in re.findall(r"lifted \S+ in ([0-9.]+) s", p.stderr))
        return {r["model"]: (float(r["seconds"]), int(r["epochs"]))
                for r in csv.DictReader(open(os.path.join(out, "runs.csv")))}, lift


for d in datasets:
    models = [m for (m, dd) in cells if dd == d and (only is None or m in only)]
    if not models:
        continue
    start = time.time()
    first, lifting[d] = time_runs(d, models, epochs)
    second = time_runs(d, models, fixed_epochs)[0] if fixed_epochs else {}
    for m, (s1, e1) in first.items():
        per_epoch[(m, d)], fixed[(m, d)] = s1 / e1, 0.0
        if m in second and second[m][1] > e1:  # a run that stopped early gives no second point
            s2, e2 = second[m]
            slope = (s2 - s1) / (e2 - e1)
            if slope > 0 and s1 - e1 * slope >= 0:
                per_epoch[(m, d)], fixed[(m, d)] = slope, s1 - e1 * slope
            else:  # noise says no fixed cost (the longer run was the slower per epoch): its mean
                per_epoch[(m, d)] = s2 / e2
    print(f"{d}: {len(models)} cells timed in {time.time() - start:.0f} s", file=sys.stderr)

total = 0.0
with open(out_csv + ".tmp", "w", newline="") as f:
    w = csv.writer(f)
    w.writerow(["model", "dataset", "seconds_per_epoch", "runs", "epochs", "estimated_seconds",
                "fixed_seconds"])
    for (m, d), eps in cells.items():
        f_s = fixed.get((m, d), 0.0)
        s = per_epoch[(m, d)] * sum(eps) + f_s * len(eps)
        total += s
        w.writerow([m, d, f"{per_epoch[(m, d)]:.4f}", len(eps), sum(eps), f"{s:.1f}",
                    f"{f_s:.2f}"])
os.replace(out_csv + ".tmp", out_csv)
lift = sum(lifting.values())
print(f"runs: {len(runs)}, cells: {len(cells)}; run time {total / 3600:.2f} h of one core; "
      f"with two runs side by side {total / 2 / 3600:.2f} h, plus liftings {lift / 60:.1f} min"
      + (" (of the datasets timed again)" if only is not None else ""))

#!/usr/bin/env python3
"""The TopoBench table's wall time on a quiet machine, from timed epochs of every cell.

Usage: topobench_clean_time.py [--only MODEL,...] [--keep-denormals] TDL DATA_DIR RUNS_CSV OUT_CSV
[EPOCHS [DATASET...]]. Standard library only. With --only, only those models are timed again;
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
while args and args[0] in ("--only", "--keep-denormals"):
    if args[0] == "--keep-denormals":
        extra.append(args.pop(0))
        continue
    if len(args) < 2:
        sys.exit("--only needs a comma-separated list of models")
    only = args[1].split(",")
    args = args[2:]
if len(args) < 4:
    sys.exit(__doc__)
tdl, data_dir, runs_csv, out_csv = args[:4]
epochs = int(args[4]) if len(args) > 4 else 10
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

per_epoch, lifting = {}, {}
if only is not None:
    unknown = [m for m in only if m not in MODELS]
    if unknown:
        sys.exit(f"--only: unknown models {unknown} (the table's: {', '.join(MODELS)})")
    if not os.path.exists(out_csv):
        sys.exit(f"--only keeps the other cells' figures from {out_csv}, which does not exist")
    for r in csv.DictReader(open(out_csv)):
        if r["model"] not in only:
            per_epoch[(r["model"], r["dataset"])] = float(r["seconds_per_epoch"])
    missing = [c for c in cells if c[0] not in only and c not in per_epoch]
    if missing:
        sys.exit(f"{out_csv} has no seconds per epoch for {missing}: time them (without --only)")
env = dict(os.environ, OMP_NUM_THREADS="1")
for d in datasets:
    models = [m for (m, dd) in cells if dd == d and (only is None or m in only)]
    if not models:
        continue
    with tempfile.TemporaryDirectory() as out:
        start = time.time()
        p = subprocess.run([tdl, "topobench", "--data-dir", data_dir, "--out", out, "--models",
                            ",".join(models), "--datasets", d, "--splits", "0", "--max-epochs",
                            str(epochs), "--jobs", "2"] + extra, env=env, capture_output=True,
                           text=True)
        if p.returncode != 0:
            sys.exit(f"tdl topobench on {d} failed:\n{p.stderr[-2000:]}")
        lifting[d] = sum(float(s) for s in re.findall(r"lifted \S+ in ([0-9.]+) s", p.stderr))
        for r in csv.DictReader(open(os.path.join(out, "runs.csv"))):
            per_epoch[(r["model"], d)] = float(r["seconds"]) / int(r["epochs"])
        print(f"{d}: {len(models)} cells timed in {time.time() - start:.0f} s", file=sys.stderr)

total = 0.0
with open(out_csv + ".tmp", "w", newline="") as f:
    w = csv.writer(f)
    w.writerow(["model", "dataset", "seconds_per_epoch", "runs", "epochs", "estimated_seconds"])
    for (m, d), eps in cells.items():
        s = per_epoch[(m, d)] * sum(eps)
        total += s
        w.writerow([m, d, f"{per_epoch[(m, d)]:.4f}", len(eps), sum(eps), f"{s:.1f}"])
os.replace(out_csv + ".tmp", out_csv)
lift = sum(lifting.values())
print(f"runs: {len(runs)}, cells: {len(cells)}; run time {total / 3600:.2f} h of one core; "
      f"with two runs side by side {total / 2 / 3600:.2f} h, plus liftings {lift / 60:.1f} min"
      + (" (of the datasets timed again)" if only is not None else ""))

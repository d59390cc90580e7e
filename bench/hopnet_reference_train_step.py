"""Times the HOPNet reference's own training step beside topos's `bench_hopnet` BM_train_step.

One optimizer step of the authors' unchanged `train_one_epoch` on one experiment: MOVi-A scene 8
(477 timesteps) preprocessed by their `create_ccs_for_sample` (timed apart, not saved), starting
from the published MOVi-A weights, best of N (env N, default 3). The first step's mean loss per
timestep equals the training golden's (101.287 / 477).

Run from a runnable copy of the reference (hopnet-ref's setup.sh in the reference folder) after
sourcing its env.sh, with OpenBLAS free to pick its best kernels:

    cd RUN_DIR/hopnet && source ../env.sh && \\
      env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE $PY /path/to/topos/bench/hopnet_reference_train_step.py
"""
import ctypes
import importlib.util
import os
import sys
import tempfile
import time

sys.path[:0] = ["scripts", ".", "data"]
spec = importlib.util.spec_from_file_location("refmain", "scripts/main.py")
m = importlib.util.module_from_spec(spec)
spec.loader.exec_module(m)

import create_ccs  # noqa: E402  (the reference's data/create_ccs.py)
import torch  # noqa: E402
from data.movi_dataset import MoviDataset, movi_dataset_collate_fn  # noqa: E402
from torch.nn import MSELoss  # noqa: E402
from torch.optim import Adam  # noqa: E402

start = time.perf_counter()
data = create_ccs.create_ccs_for_sample(os.path.abspath("datasets/MOVi-A/8"), "unused", 0.1, False,
                                        0.0, processes=1, save=False)
preprocessing = time.perf_counter() - start
dataset = MoviDataset("./datasets/MOVi-A", "all", "./samples/normalization-movia.npy", False,
                      include_not_preprocessed=True)
dataset._MoviDataset__normalize_sample(data)  # what its __getitem__ does to a stored sample
batch = movi_dataset_collate_fn([data])
model = m.get_model("HOPNet", 128, 1, "relu", 2)
model.load_state_dict(torch.load("./checkpoints/modela_seed2_e39.pt", map_location="cpu"), strict=True)
optimizer = Adam(model.parameters(), lr=1e-4)


class NoWriter:  # the tensorboard writer train_one_epoch logs to
    def __getattr__(self, name):
        return lambda *a, **k: None


log = os.path.join(tempfile.mkdtemp(), "train.txt")
times = []
for _ in range(int(os.environ.get("N", "3"))):
    start = time.perf_counter()
    m.train_one_epoch(model, torch.device("cpu"), [batch], dataset.normalization, optimizer,
                      MSELoss(reduction="sum"), log, NoWriter(), 50, 0)
    times.append(time.perf_counter() - start)
print("reference preprocessing seconds: %.2f" % preprocessing)
print("reference train step seconds:", ["%.2f" % t for t in times])
print("best %.3f" % min(times))
try:
    blas = ctypes.CDLL("libopenblas.so.0")
    blas.openblas_get_corename.restype = ctypes.c_char_p
    print("reference BLAS: OpenBLAS core %s, torch threads %d"
          % (blas.openblas_get_corename().decode(), torch.get_num_threads()))
except (OSError, AttributeError):
    print("reference BLAS: not OpenBLAS")

"""topos.topomodelx (the TopoModelX drop-in) beside the C++ zoo's bench_zoo, on the same work.

    PYTHONPATH=build/python OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 \
      /usr/bin/python3 bench/bench_python_topomodelx.py
    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 ./build/bench/bench_zoo \
      --benchmark_filter='BM_zoo/(scn2|cwn|unigcnii)/grid101' --benchmark_repetitions=3

bench_zoo's grid101 cases rebuilt here with scipy: the triangulated 101 x 101 grid, 32 channels,
two layers, one thread, the same operators (SCN2: rescaled Hodge Laplacians, CWN: the 2-cell
adjacency pattern, B2 and B1ᵀ, UniGCNII: the triangles and self loops as hyperedges), passed as
a TopoModelX user passes them (torch sparse COO, converted by the drop-in at every call), and
forward + backward of Σ out·R (R fixed). Per case, the median over `--repeat` rounds of the mean
time per call (wall and this process's CPU time). `--allocator cache` (the default, as
bench_zoo's TOPOS_BENCH_ALLOCATOR) calls topos.nn.use_caching_cpu_allocator() first; `system`
keeps glibc's (bench_zoo's TOPOS_BENCH_ALLOCATOR=system).

`--topomodelx DIR` also times TopoModelX itself (its source folder, e.g. a checkout at a1f9a0f;
it needs only torch for these models) in the same process, on the same inputs, with the same
weights (the drop-in's state_dict loaded by name), rounds interleaved with the drop-in's, after
checking that both give the same outputs. UniGCNII is left out for TopoModelX by default: its
layer densifies the grid's incidence (519 s per forward, 7.6 GB). Give TopoModelX OpenBLAS's
best kernels: unset OPENBLAS_CORETYPE and OPENBLAS_L2_SIZE for the command; the kernels OpenBLAS
picked are printed.
"""

import argparse
import ctypes
import importlib
import os
import statistics
import sys
import time

import numpy as np
import scipy.sparse as sp
import torch

import topos.nn
from topos.topomodelx.nn.cell.cwn import CWN
from topos.topomodelx.nn.hypergraph.unigcnii import UniGCNII
from topos.topomodelx.nn.simplicial.scn2 import SCN2

C = 32


def grid101():
    tri = []
    for i in range(100):
        for j in range(100):
            a = i * 101 + j
            tri += [sorted((a, a + 1, a + 102)), sorted((a, a + 101, a + 102))]
    tri = sorted(tri)
    edges = sorted({(t[x], t[y]) for t in tri for x, y in ((0, 1), (0, 2), (1, 2))})
    eid = {e: k for k, e in enumerate(edges)}
    n0, n1, n2 = 101 * 101, len(edges), len(tri)
    r = [u for u, v in edges] + [v for u, v in edges]
    c = list(range(n1)) * 2
    B1 = sp.csr_matrix(([-1.0] * n1 + [1.0] * n1, (r, c)), shape=(n0, n1))
    rows, cols, vals = [], [], []
    for f, (a, b, cc) in enumerate(tri):
        for e, s in (((b, cc), 1.0), ((a, cc), -1.0), ((a, b), 1.0)):
            rows.append(eid[e]), cols.append(f), vals.append(s)
    B2 = sp.csr_matrix((vals, (rows, cols)), shape=(n1, n2))
    return tri, B1, B2


def normalized(L):
    d = np.asarray(abs(L).sum(axis=1)).ravel()
    s = sp.diags(1 / np.sqrt(np.maximum(d, 1.0)))
    return (s @ L @ s).tocsr()


def coo(m):
    m = m.tocoo()
    idx = torch.from_numpy(np.vstack((m.row, m.col))).long()
    return torch.sparse_coo_tensor(idx, torch.from_numpy(m.data).float(), m.shape).coalesce()


def cases():
    tri, B1, B2 = grid101()
    n = (B1.shape[0], B1.shape[1], B2.shape[1])
    torch.manual_seed(0)
    x = [torch.randn(k, C) for k in n]
    L0, Ld1, Lu1, L2 = B1 @ B1.T, B1.T @ B1, B2 @ B2.T, B2.T @ B2
    scn2 = (
        SCN2(C, C, C, n_layers=2),
        [*x, coo(normalized(L0)), coo(normalized(Ld1 + Lu1)), coo(normalized(L2))],
    )
    A2 = (abs(B2) @ abs(B2).T).tolil()
    A2.setdiag(0)
    A2 = A2.tocsr()
    A2.eliminate_zeros()
    A2.data[:] = 1.0
    cwn = (CWN(C, C, C, C, n_layers=2), [*x, coo(A2), coo(B2), coo(B1.T)])
    r = list(range(n[0])) + [v for f in tri for v in f]
    c = list(range(n[0])) + [n[0] + f for f in range(len(tri)) for _ in range(3)]
    H = sp.csr_matrix((np.ones(len(r)), (r, c)), shape=(n[0], n[0] + len(tri)))
    unigcnii = (UniGCNII(C, C, n_layers=2), [x[0], coo(H)])
    return {"scn2": scn2, "cwn": cwn, "unigcnii": unigcnii}


def timed(f, calls):
    w0, c0 = time.perf_counter(), time.process_time()
    for _ in range(calls):
        f()
    return (time.perf_counter() - w0) / calls, (time.process_time() - c0) / calls


def openblas_kernels():
    """The kernel set OpenBLAS chose in this process (what torch's products run on)."""
    for lib in ("libopenblas.so.0", "libopenblasp.so.0", "libblas.so.3"):
        try:
            f = ctypes.CDLL(lib).openblas_get_corename
        except (OSError, AttributeError):
            continue
        f.restype = ctypes.c_char_p
        return f().decode()
    return "unknown"


def topomodelx_twin(src, name, model):
    """TopoModelX's own model of `name`, with `model`'s (the drop-in's) weights."""
    if src not in sys.path:
        sys.path.insert(0, src)
    module, cls = {
        "scn2": ("topomodelx.nn.simplicial.scn2", "SCN2"),
        "cwn": ("topomodelx.nn.cell.cwn", "CWN"),
        "unigcnii": ("topomodelx.nn.hypergraph.unigcnii", "UniGCNII"),
    }[name]
    twin_cls = getattr(importlib.import_module(module), cls)
    if not twin_cls.__module__.startswith("topomodelx"):
        raise SystemExit(f"--topomodelx {src}: {module} did not come from TopoModelX's source")
    args = {"scn2": (C, C, C), "cwn": (C, C, C, C), "unigcnii": (C, C)}[name]
    kwargs = {"n_layers": 2}
    twin = twin_cls(*args, **kwargs)
    twin.load_state_dict(model.state_dict())
    return twin


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--calls", type=int, default=20)
    ap.add_argument("--allocator", choices=("cache", "system"), default="cache")
    ap.add_argument("--topomodelx", metavar="DIR", help="TopoModelX's source folder: time it too")
    ap.add_argument("--topomodelx-models", default="scn2,cwn")
    ap.add_argument("--models", default="scn2,cwn,unigcnii")
    args = ap.parse_args()
    torch.set_num_threads(1)
    if args.allocator == "cache":
        topos.nn.use_caching_cpu_allocator()
    print(
        f"torch threads 1, OPENBLAS_CORETYPE={os.environ.get('OPENBLAS_CORETYPE', '(unset)')}, "
        f"OpenBLAS kernels {openblas_kernels()}, allocator {args.allocator}",
        flush=True,
    )
    wanted = args.models.split(",")
    peers = args.topomodelx_models.split(",") if args.topomodelx else []
    for name, (model, inputs) in cases().items():
        if name not in wanted:
            continue
        model.eval()
        sides = [("topos", model)]
        if name in peers:
            twin = topomodelx_twin(args.topomodelx, name, model)
            twin.eval()
            with torch.no_grad():
                a, b = model(*inputs), twin(*inputs)
            err = max((x - y).abs().max().item() for x, y in zip(a, b))
            scale = max(y.abs().max().item() for y in b)
            if err > 1e-4 * max(1.0, scale):
                raise SystemExit(f"{name}: topos and TopoModelX differ by {err} (scale {scale})")
            sides.append(("topomodelx", twin))
        with torch.no_grad():
            R = [torch.randn_like(y) for y in model(*inputs)]

        def forward(m):
            with torch.no_grad():
                m(*inputs)

        def forward_backward(m):
            m.zero_grad()
            out = m(*inputs)
            sum((y * r).sum() for y, r in zip(out, R)).backward()

        for what, f in (("forward", forward), ("forward_backward", forward_backward)):
            runs = {side: [] for side, _ in sides}
            for side, m in sides:
                f(m)  # warm up
            for _ in range(args.repeat):  # rounds interleaved between the sides
                for side, m in sides:
                    runs[side].append(timed(lambda: f(m), args.calls))
            for side, _ in sides:
                wall = statistics.median(r[0] for r in runs[side]) * 1e3
                cpu = statistics.median(r[1] for r in runs[side]) * 1e3
                label = "" if side == "topos" else " [TopoModelX]"
                print(f"{name}/grid101/{what}{label}: {wall:.2f} ms wall, {cpu:.2f} ms CPU",
                      flush=True)


if __name__ == "__main__":
    main()

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
"""

import argparse
import statistics
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


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--calls", type=int, default=20)
    ap.add_argument("--allocator", choices=("cache", "system"), default="cache")
    args = ap.parse_args()
    torch.set_num_threads(1)
    if args.allocator == "cache":
        topos.nn.use_caching_cpu_allocator()
    for name, (model, inputs) in cases().items():
        model.eval()
        with torch.no_grad():
            R = [torch.randn_like(y) for y in model(*inputs)]

        def forward():
            with torch.no_grad():
                model(*inputs)

        def forward_backward():
            model.zero_grad()
            out = model(*inputs)
            sum((y * r).sum() for y, r in zip(out, R)).backward()

        for what, f in (("forward", forward), ("forward_backward", forward_backward)):
            f()  # warm up
            runs = [timed(f, args.calls) for _ in range(args.repeat)]
            wall = statistics.median(r[0] for r in runs) * 1e3
            cpu = statistics.median(r[1] for r in runs) * 1e3
            print(f"{name}/grid101/{what}: {wall:.2f} ms wall, {cpu:.2f} ms CPU", flush=True)


if __name__ == "__main__":
    main()

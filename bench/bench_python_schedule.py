"""A schedule built in Python and run by the C++ engine, beside the same layer in plain torch.

    PYTHONPATH=build/python OMP_NUM_THREADS=1 /usr/bin/python3 bench/bench_python_schedule.py

CWN's layer (docs/schedule-tutorial.md) with 16 channels, on the clique complex of an n × n grid
of triangles (n = 2: the fixed cost of a call; n = 60: 7,200 triangles) and on one thread. Per
case, the median of `--repeat` rounds of many calls, per call: wall time and the process's CPU
time (on a loaded machine the wall time includes waiting for a core; google-benchmark's "CPU"
column is the same measure):
  torch: the layer written with torch.sparse.mm on COO operators, the same parameters;
  topos: topos.nn.OperatorNetwork(schedule)(inputs, operators) with the operators converted
    once (topos.nn.SparseOperator), and with torch COO operators converted at every call;
  engine: the C++ network's forward called directly (no torch.nn.Module.__call__).
Forward alone, then forward + backward of the sum of squares.
"""

import argparse
import statistics
import time

import torch
import torch.nn.functional as F

import topos
from topos.nn import OperatorNetwork, OperatorSchedule, SparseOperator, Activation, from_, into

C = 16


def grid(n):
    t = []
    for i in range(n):
        for j in range(n):
            a = i * (n + 1) + j
            t += [[a, a + 1, a + n + 2], [a, a + n + 2, a + n + 1]]
    return topos.SimplicialComplex(t)


def schedule():
    s = OperatorSchedule()
    s.input("x_0", 0, C).input("x_1", 1, C).input("x_2", 2, C)
    s.operator_input("adjacency_1", 1, 1).operator_input("incidence_2", 2, 1).operator_input("incidence_1", 1, 0)
    s.step(
        into(1)
        .sum(
            from_(1).conv("conv_1_to_1", C).via("adjacency_1").act(Activation.elu),
            from_(2).conv("conv_2_to_1", C).via("incidence_2").act(Activation.elu),
            from_(0).conv("conv_0_to_1", C).via_t("incidence_1").act(Activation.elu),
        )
        .linear("update_fn.transform", C)
        .act(Activation.elu)
    )
    s.output("x_1", 1)
    return s


def torch_layer(p, x, ops):
    m = F.elu(torch.sparse.mm(ops["adjacency_1"], x["x_1"] @ p["conv_1_to_1.weight"]))
    m = m + F.elu(torch.sparse.mm(ops["incidence_2"], x["x_2"] @ p["conv_2_to_1.weight"]))
    m = m + F.elu(torch.sparse.mm(ops["incidence_1_t"], x["x_0"] @ p["conv_0_to_1.weight"]))
    return F.elu(F.linear(m, p["update_fn.transform.weight"], p["update_fn.transform.bias"]))


def timed(f, calls, repeat):
    wall, cpu = [], []
    for _ in range(max(calls // 10, 1)):  # warm the allocator and the caches first
        f()
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(calls):
            f()
        wall.append((time.perf_counter() - t0) / calls)
        cpu.append((time.process_time() - c0) / calls)
    return statistics.median(wall), statistics.median(cpu)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    torch.set_num_threads(1)
    for n, calls in ((2, 2000), (60, 20)):
        sc = grid(n)
        ops = {
            "adjacency_1": sc.adjacency_matrix(1),
            "incidence_2": sc.incidence_matrix(2),
            "incidence_1": sc.incidence_matrix(1),
        }
        prepared = {k: SparseOperator(v) for k, v in ops.items()}
        torch_ops = dict(ops, incidence_1_t=ops["incidence_1"].t().coalesce())
        g = torch.Generator().manual_seed(0)
        x = {f"x_{r}": torch.randn(k, C, generator=g) for r, k in enumerate(sc.shape)}
        net = OperatorNetwork(schedule())
        p = dict(net.named_parameters())
        y = net(x, prepared)["x_1"]
        torch.testing.assert_close(y, torch_layer(p, x, torch_ops), rtol=1e-4, atol=1e-5)

        cases = {
            "torch": lambda: torch_layer(p, x, torch_ops),
            "topos (SparseOperator)": lambda: net(x, prepared)["x_1"],
            "topos (torch COO each call)": lambda: net(x, ops)["x_1"],
            "engine (no Module.__call__)": lambda: net._network.forward(x, prepared, False)["x_1"],
        }
        print(f"grid {n}x{n}: cells {sc.shape}, {C} channels, one thread")
        for name, f in cases.items():
            fw, fc = timed(f, calls, args.repeat)
            bw, bc = timed(lambda: f().square().sum().backward(), max(calls // 2, 1), args.repeat)
            print(
                f"  {name:28s} forward {fw * 1e6:8.1f} us wall {fc * 1e6:8.1f} us CPU   "
                f"forward+backward {bw * 1e6:8.1f} us wall {bc * 1e6:8.1f} us CPU"
            )


if __name__ == "__main__":
    main()

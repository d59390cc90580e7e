"""The cost of calling topos from Python, beside bench_domains and `hopnet rollout` (C++).

    PYTHONPATH=build/python /usr/bin/python3 bench/bench_python.py [--reference DIR]

Prints, per case, the best of `--repeat` runs (wall time, one thread):
  grid101_complex / grid101_operators / rgg2000_operators: the same work as bench_domains'
    BM_grid101_complex, BM_grid101_operators and BM_rgg2000_operators (signed incidences, Hodge
    Laplacians, adjacencies), each result returned as a torch sparse COO tensor (float64);
  tiny_incidence: one incidence_matrix call on a 3-node complex (the fixed cost of a call);
  rollout_scene8: HOPNet's 102-step reference-mode rollout of MOVi-A scene 8 (the rollout loop,
    as `hopnet rollout` reports it), and the whole script-side run (open, load, roll out).
"""

import argparse
import os
import pathlib
import re
import time

import torch

import topos


def best(f, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return min(times)


def grid101_triangles():
    t = []
    for i in range(100):
        for j in range(100):
            a = i * 101 + j
            t += [[a, a + 1, a + 102], [a, a + 102, a + 101]]
    return torch.tensor(t)


def mesh_ops(sc, dtype):
    return [sc.incidence_matrix(k, dtype=dtype) for k in (1, 2)] + [
        sc.hodge_laplacian_matrix(k, dtype=dtype) for k in (0, 1, 2)
    ]


def rgg_ops(sc, dtype):
    return (
        [sc.incidence_matrix(k, dtype=dtype) for k in (1, 2, 3)]
        + [sc.hodge_laplacian_matrix(k, dtype=dtype) for k in range(4)]
        + [sc.adjacency_matrix(k, dtype=dtype) for k in range(3)]
    )


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--reference", default=os.environ.get("TOPOS_REFERENCE_DIR"))
    p.add_argument("--repeat", type=int, default=5)
    a = p.parse_args()
    torch.set_num_threads(1)
    d = torch.float64
    rows = []
    tri = grid101_triangles()
    rows.append(("grid101_complex", best(lambda: topos.SimplicialComplex.from_flat(tri, 101 * 101), a.repeat)))
    grid = topos.SimplicialComplex.from_flat(tri, 101 * 101)
    rows.append(("grid101_operators", best(lambda: mesh_ops(grid, d), a.repeat)))
    tiny = topos.SimplicialComplex([[0, 1, 2]])
    n = 20000
    rows.append(("tiny_incidence (per call)", best(lambda: [tiny.incidence_matrix(1) for _ in range(n)], 3) / n))
    rows.append(("tiny_incidence scipy (per call)", best(lambda: [tiny.incidence_matrix(1, format="scipy") for _ in range(2000)], 3) / 2000))
    if a.reference:
        ref = pathlib.Path(a.reference)
        lines = (ref / "tdl-bench" / "rgg2000_edges.txt").read_text().split("\n")
        edges = [tuple(map(int, l.split())) for l in lines if l.strip() and not l.startswith("#")]
        m = re.search(r"(\d[\d,]*) nodes", lines[0])  # the header gives the node count
        nodes = int(m.group(1).replace(",", "")) if m else 1 + max(max(e) for e in edges)
        rgg = topos.clique_complex(nodes, edges, 3)
        rows.append(("rgg2000_operators", best(lambda: rgg_ops(rgg, d), a.repeat)))
        data = ref / "data"
        t0 = time.perf_counter()
        ckpt = topos.hopnet.Checkpoint(data / "checkpoints" / "modela_seed2_e39.pt", stats=data / "normalization" / "movia.json")
        scene = topos.hopnet.Scene(data / "movi-a" / "8", assets=data / "kubasic")
        r = topos.hopnet.rollout(ckpt, scene, steps=102)
        whole = time.perf_counter() - t0
        loops = [r.seconds] + [topos.hopnet.rollout(ckpt, scene, steps=102).seconds for _ in range(a.repeat - 1)]
        rows.append(("rollout_scene8 (loop)", min(loops)))
        rows.append(("rollout_scene8 (open + load + roll out, first run)", whole))
    for name, s in rows:
        print(f"{name:52s} {s * 1e3:10.3f} ms")


if __name__ == "__main__":
    main()

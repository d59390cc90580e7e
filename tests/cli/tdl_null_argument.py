#!/usr/bin/env python3
"""tdl forward and tdl grad on a case whose forward argument is null (TopoModelX's None): SCNN
with conv_order_up 0 on a small simplicial complex, its upper Laplacian passed as None. The case is
written here (complex, operator, weights, features, projection); its outputs and gradients are
computed here with NumPy from the definition (a polynomial filter of the lower Laplacian per
layer, no activation) and compared with the files tdl writes.

Usage: tdl_null_argument.py TDL WORK
"""
import json
import os
import shutil
import subprocess
import sys

try:
    import numpy as np
except ImportError:
    print("SKIPPED: this test needs NumPy")
    sys.exit(0)

tdl, work = sys.argv[1], sys.argv[2]
shutil.rmtree(work, ignore_errors=True)
case = os.path.join(work, "case")
for sub in ("inputs", "state_dict", "grads"):
    os.makedirs(os.path.join(case, sub))

# Two triangles sharing an edge, and a pendant edge: 5 nodes, 6 edges, 2 triangles.
triangles = [[0, 1, 2], [1, 2, 3]]
edges = [[0, 1], [0, 2], [1, 2], [1, 3], [2, 3], [3, 4]]
nodes = [[v] for v in range(5)]
order_down, channels_in, hidden, layers = 2, 3, 4, 2

# B_1 (nodes x edges), TopoNetX's signs: -1 at an edge's first node, +1 at its second.
B1 = np.zeros((len(nodes), len(edges)))
for j, (u, v) in enumerate(edges):
    B1[u, j], B1[v, j] = -1.0, 1.0
L_down = B1.T @ B1

rng = np.random.default_rng(7)
x = rng.standard_normal((len(edges), channels_in)).astype(np.float32)
W = [rng.standard_normal((channels_in if l == 0 else hidden, hidden, 1 + order_down))
     .astype(np.float32) for l in range(layers)]
R = rng.standard_normal((len(edges), hidden)).astype(np.float32)

with open(os.path.join(case, "case.json"), "w") as f:
    json.dump({"name": "scnn-null-up", "domain": "simplicial", "model": "SCNN",
               "description": "SCNN with conv_order_up 0: its upper Laplacian is None",
               "config": {"in_channels": channels_in, "hidden_channels": hidden,
                          "conv_order_down": order_down, "conv_order_up": 0,
                          "aggr_norm": False, "update_func": None, "n_layers": layers},
               "forward": [{"name": "x_1", "from": "inputs"},
                           {"name": "down_laplacian_1", "from": "operators", "dense": False},
                           None],
               "kwargs": {}, "outputs": ["out_1"]}, f)
with open(os.path.join(case, "complex.json"), "w") as f:
    json.dump({"domain": "simplicial", "cells": {"0": nodes, "1": edges, "2": triangles}}, f)
with open(os.path.join(case, "operators.json"), "w") as f:
    json.dump({"down_laplacian_1": {"op": "down_laplacian_matrix",
                                    "args": {"rank": 1, "signed": True},
                                    "call": "sc.down_laplacian_matrix(rank=1)"}}, f)
np.save(os.path.join(case, "inputs", "x_1.npy"), x)
for l in range(layers):
    np.save(os.path.join(case, "state_dict", "layers.%d.weight.npy" % l), W[l])
with open(os.path.join(case, "state_dict.json"), "w") as f:
    json.dump([["layers.%d.weight" % l, list(W[l].shape)] for l in range(layers)], f)
np.save(os.path.join(case, "grads", "_R_out_1.npy"), R)

# The definition: y = sum_k (L_down^k h) W[:, :, k] per layer (k = 0 the identity).
P = [np.linalg.matrix_power(L_down, k) for k in range(1 + order_down)]
h = [x.astype(np.float64)]
for l in range(layers):
    h.append(sum(P[k] @ h[l] @ W[l][:, :, k].astype(np.float64) for k in range(1 + order_down)))
out = h[-1]
# d sum(out * R): G is the gradient reaching layer l's output.
grads, G = {}, R.astype(np.float64)
for l in reversed(range(layers)):
    grads["layers.%d.weight" % l] = np.stack(
        [(P[k] @ h[l]).T @ G for k in range(1 + order_down)], axis=2)
    G = sum(P[k].T @ G @ W[l][:, :, k].astype(np.float64).T for k in range(1 + order_down))


def run(command):
    done = subprocess.run([tdl, command, "--case", case, "--out", os.path.join(work, command)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit("tdl %s failed on a null argument:\n%s%s" % (command, done.stdout, done.stderr))


def close(name, got, want):
    scale = max(1.0, float(np.abs(want).max()))
    err = float(np.abs(got - want).max()) / scale
    print("%s: max relative error %.2e" % (name, err))
    if got.shape != want.shape or err > 1e-5:
        sys.exit("%s differs from the definition (shape %s, want %s, error %.2e)"
                 % (name, got.shape, want.shape, err))


run("forward")
close("out_1", np.load(os.path.join(work, "forward", "out_1.npy")), out)
run("grad")
for name, g in grads.items():
    close(name, np.load(os.path.join(work, "grad", name + ".npy")), g)
# A None where the order is not 0 is an error that says so (orders 1 and 1: the same weights).
spec = json.load(open(os.path.join(case, "case.json")))
spec["config"]["conv_order_down"] = spec["config"]["conv_order_up"] = 1
json.dump(spec, open(os.path.join(case, "case.json"), "w"))
done = subprocess.run([tdl, "forward", "--case", case, "--out", os.path.join(work, "bad")],
                      capture_output=True, text=True)
if done.returncode == 0 or "laplacian_up is needed" not in done.stdout + done.stderr:
    sys.exit("a None Laplacian of order 1 was not refused clearly:\n%s%s"
             % (done.stdout, done.stderr))
print("tdl forward and grad accept a null argument")

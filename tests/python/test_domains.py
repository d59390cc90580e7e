# The domains from Python: every operator of every TopoNetX golden case (tdl-golden), brute-force
# operators and liftings on random inputs, the output formats, sparse inputs, and bad input raising
# Python exceptions that name the argument or step.
import itertools
import json
import random
import threading
import time

import numpy as np
import pytest
import scipy.sparse
import torch

import topos
from topos import normalization as tn


def dense(m):
    """A topos result (any format) as a float64 numpy array."""
    if scipy.sparse.issparse(m):
        return m.toarray().astype(np.float64)
    return m.to_dense().to(torch.float64).numpy()


# ----- golden cases -----------------------------------------------------------------------------


def build_domain(case_dir):
    c = json.loads((case_dir / "complex.json").read_text())
    domain = c["domain"]
    if domain == "simplicial":
        ranks = [c["cells"][str(k)] for k in range(len(c["cells"]))]
        return topos.SimplicialComplex.from_ordered(ranks)
    if domain == "cell":
        assert c["nodes"] == list(range(len(c["nodes"])))
        return topos.CellComplex.from_ordered(len(c["nodes"]), c["edges"], c["cells"])
    if domain == "combinatorial":
        cells = c["cells"]
        assert cells["0"] == [[v] for v in range(len(cells["0"]))]
        cc = topos.CombinatorialComplex(num_nodes=len(cells["0"]))
        for k in range(1, len(cells)):
            for cell in cells[str(k)]:
                cc.add_cell(cell, k)
        return cc
    assert domain == "hypergraph"
    assert c["nodes"] == list(range(len(c["nodes"])))
    return topos.Hypergraph(c["hyperedges"], num_nodes=len(c["nodes"]))


def evaluate(domain, spec, done):
    """One entry of operators.json, from its `op` and `args` (never its name)."""
    op, a = spec["op"], spec["args"]
    fmt = dict(format="scipy")
    if op in ("incidence_matrix", "adjacency_matrix", "coadjacency_matrix") and (
        "signed" not in a
    ):
        second = a.get("to_rank", a.get("via_rank"))
        return getattr(domain, op)(a["rank"], second, **fmt)
    if op in (
        "incidence_matrix",
        "adjacency_matrix",
        "coadjacency_matrix",
        "hodge_laplacian_matrix",
        "up_laplacian_matrix",
        "down_laplacian_matrix",
    ):
        return getattr(domain, op)(a["rank"], signed=a["signed"], **fmt)
    if op == "normalized_laplacian_matrix":
        return domain.normalized_laplacian_matrix(a["rank"], **fmt)
    # Normalisations take earlier operators, passed as torch sparse COO (TopoModelX's users'
    # form) to exercise that input path.
    t = {k: torch.from_numpy(done[v]).to_sparse() for k, v in a.items() if isinstance(v, str)}
    if op == "compute_laplacian_normalized_matrix":
        return tn.compute_laplacian_normalized_matrix(t["L"], **fmt)
    if op == "compute_x_laplacian_normalized_matrix":
        return tn.compute_x_laplacian_normalized_matrix(t["L"], t["L_x"], **fmt)
    if op == "compute_kipf_adjacency_normalized_matrix":
        return tn.compute_kipf_adjacency_normalized_matrix(
            t["A"], add_identity=a["add_identity"], identity_multiplier=a["identity_multiplier"], **fmt
        )
    if op == "compute_xu_asymmetric_normalized_matrix":
        return tn.compute_xu_asymmetric_normalized_matrix(t["B"], is_sparse=a["is_sparse"], **fmt)
    if op == "compute_bunch_normalized_matrices":
        return tn.compute_bunch_normalized_matrices(t["B1"], t["B2"], **fmt)[a["output"]]
    # The golden format's algebra on earlier operators (numpy; not topos's to check).
    if op == "transpose":
        return done[a["of"]].T
    if op == "abs":
        return np.abs(done[a["of"]])
    if op == "sum":
        return sum(done[n] for n in a["of"])
    if op == "scale":
        return done[a["of"]] * a["factor"]
    if op == "identity":
        return np.eye(done[a["size_of"]].shape[a["axis"]])
    if op == "pinv":
        return np.linalg.pinv(done[a["of"]])
    raise AssertionError(f"unknown op {op}")


def golden_cases():
    import os
    import pathlib

    d = os.environ.get("TOPOS_REFERENCE_DIR")
    if not d:
        return [pytest.param(None, marks=pytest.mark.skip(reason="TOPOS_REFERENCE_DIR is not set"))]
    cases = sorted((pathlib.Path(d) / "tdl-golden" / "cases").iterdir())
    assert cases, f"no golden cases under {d}/tdl-golden/cases"
    return [pytest.param(c, id=c.name) for c in cases]


@pytest.mark.parametrize("case_dir", golden_cases())
def test_golden_operators(case_dir):
    domain = build_domain(case_dir)
    ops = json.loads((case_dir / "operators.json").read_text())
    assert ops, f"{case_dir}: no operators"
    done = {}
    for name, spec in ops.items():
        got = evaluate(domain, spec, done)
        got = dense(got) if not isinstance(got, np.ndarray) else got
        want = np.load(case_dir / "operators" / f"{name}.npy").astype(np.float64)
        assert got.shape == want.shape, f"{case_dir.name} {name}: shape {got.shape} != {want.shape}"
        # The golden matrices are float32 copies of TopoNetX's float64 ones.
        np.testing.assert_allclose(got, want, rtol=2e-6, atol=2e-6, err_msg=f"{case_dir.name} {name}")
        done[name] = got


# ----- brute force ------------------------------------------------------------------------------


def random_complex(seed, n=9, count=14, max_size=4):
    rng = random.Random(seed)
    simplices = [rng.sample(range(n), rng.randint(1, max_size)) for _ in range(count)]
    return simplices, topos.SimplicialComplex(simplices, num_nodes=n)


def closure(simplices):
    out = set()
    for s in simplices:
        for k in range(1, len(s) + 1):
            out.update(itertools.combinations(sorted(s), k))
    return out


@pytest.mark.parametrize("seed", range(6))
def test_simplicial_operators_brute_force(seed):
    simplices, sc = random_complex(seed)
    cells = closure(simplices)
    by_rank = {}
    for c in cells:
        by_rank.setdefault(len(c) - 1, []).append(c)
    by_rank[0] = [(v,) for v in range(9)]
    assert sc.dim == max(by_rank)
    assert sc.shape == tuple(len(by_rank[k]) for k in range(sc.dim + 1))
    for k in range(sc.dim + 1):
        by_rank[k].sort()  # TopoNetX's order: lexicographic
        assert [tuple(s) for s in sc.skeleton(k)] == by_rank[k]
    b = {}
    for k in range(1, sc.dim + 1):
        index = {c: i for i, c in enumerate(by_rank[k - 1])}
        want = np.zeros((len(by_rank[k - 1]), len(by_rank[k])))
        for j, s in enumerate(by_rank[k]):
            for i in range(len(s)):
                want[index[s[:i] + s[i + 1 :]], j] = (-1) ** i
        got = sc.incidence_matrix(k)
        assert got.layout == torch.sparse_coo and got.is_coalesced()
        np.testing.assert_array_equal(dense(got), want)
        np.testing.assert_array_equal(dense(sc.incidence_matrix(k, signed=False)), np.abs(want))
        np.testing.assert_array_equal(dense(sc.coincidence_matrix(k)), want.T)
        b[k] = want
    for k in range(1, sc.dim):
        np.testing.assert_array_equal(b[k] @ b[k + 1], 0)
    for k in range(sc.dim + 1):
        up = b[k + 1] @ b[k + 1].T if k + 1 in b else None
        down = b[k].T @ b[k] if k in b else None
        if up is not None:
            np.testing.assert_array_equal(dense(sc.up_laplacian_matrix(k)), up)
            np.testing.assert_array_equal(dense(sc.up_laplacian_matrix(k, signed=False)), np.abs(up))
            adj = np.abs(up - np.diag(np.diag(up)))
            np.testing.assert_array_equal(dense(sc.adjacency_matrix(k)), adj)
        if down is not None:
            np.testing.assert_array_equal(dense(sc.down_laplacian_matrix(k)), down)
            coadj = np.abs(down - np.diag(np.diag(down)))
            np.testing.assert_array_equal(dense(sc.coadjacency_matrix(k)), coadj)
        hodge = sum(x for x in (up, down) if x is not None)
        if hodge is not None:
            np.testing.assert_array_equal(dense(sc.hodge_laplacian_matrix(k)), hodge)
            # weighted: unit weights are the Hodge Laplacian; weights scale each term.
            np.testing.assert_array_equal(dense(sc.weighted_hodge_laplacian_matrix(k)), hodge)
    # Stored entries are exactly the nonzeros (TopoNetX's to_sparse of the dense matrix).
    for k in range(sc.dim + 1):
        L = sc.hodge_laplacian_matrix(k)
        assert L._nnz() == np.count_nonzero(dense(L))
    assert sc.euler_characteristic() == sum((-1) ** k * n for k, n in enumerate(sc.shape))


def test_formats_and_dtypes():
    _, sc = random_complex(3)
    want = dense(sc.hodge_laplacian_matrix(1, format="dense", dtype=torch.float64))
    coo = sc.hodge_laplacian_matrix(1)
    assert coo.dtype == torch.get_default_dtype() and coo.layout == torch.sparse_coo
    csr = sc.hodge_laplacian_matrix(1, format="csr", dtype=torch.float64)
    assert csr.layout == torch.sparse_csr and csr.dtype == torch.float64
    sp = sc.hodge_laplacian_matrix(1, format="scipy")
    assert isinstance(sp, scipy.sparse.csr_matrix) and sp.dtype == np.float64  # TopoNetX's type
    f32 = sc.hodge_laplacian_matrix(1, dtype=torch.float32, format="scipy")
    assert f32.dtype == np.float32
    for m in (coo, csr, sp, f32):
        np.testing.assert_array_equal(dense(m), want)
    # A sparse operator times features, as a model uses it.
    x = torch.randn(sc.shape[1], 4)
    torch.testing.assert_close(torch.sparse.mm(coo, x), torch.from_numpy(want).float() @ x)
    # Sparse inputs: COO, CSR and scipy give the same hypergraph.
    hg = topos.Hypergraph([[0, 1, 2], [1, 3], [2, 3, 4], [0, 4]])
    b = hg.incidence_matrix()
    for form in (b, b.to_sparse_csr(), hg.incidence_matrix(format="scipy"), b.double().coalesce()):
        h2 = topos.Hypergraph.from_incidence_matrix(form)
        assert [h2.hyperedge(i) for i in range(4)] == [[0, 1, 2], [1, 3], [2, 3, 4], [0, 4]]


def test_cell_complex():
    # A square and a triangle sharing edge (1, 2); edges in TopoNetX's order, oriented low -> high.
    cx = topos.CellComplex([[0, 1, 2, 3], [1, 4, 2]])
    assert cx.shape == (5, 6, 2)
    assert cx.edges == [[0, 1], [0, 3], [1, 2], [1, 4], [2, 3], [2, 4]]
    b1, b2 = dense(cx.incidence_matrix(1)), dense(cx.incidence_matrix(2))
    np.testing.assert_array_equal(b1 @ b2, 0)
    for j, (u, v) in enumerate(cx.edges):
        assert b1[u, j] == -1 and b1[v, j] == 1 and np.count_nonzero(b1[:, j]) == 2
    # The square 0 -> 1 -> 2 -> 3 -> 0 runs along (0,1), (1,2), (2,3) and against (0,3).
    np.testing.assert_array_equal(b2[:, 0], [1, -1, 1, 0, 1, 0])
    np.testing.assert_array_equal(dense(cx.hodge_laplacian_matrix(1)), b1.T @ b1 + b2 @ b2.T)
    cx.add_cell([0, 4], rank=1)
    assert cx.shape == (5, 7, 2)


def test_combinatorial_complex_and_hypergraph():
    cc = topos.CombinatorialComplex([[0, 1], [1, 2], [0, 1, 2, 3]], ranks=[1, 1, 2])
    assert cc.shape == (4, 2, 1)
    np.testing.assert_array_equal(dense(cc.incidence_matrix(0, 2)), [[1], [1], [1], [1]])
    np.testing.assert_array_equal(dense(cc.incidence_matrix(1, 2)), [[1], [1]])
    np.testing.assert_array_equal(dense(cc.adjacency_matrix(0, 1)), [[0, 1, 0, 0], [1, 0, 1, 0], [0, 1, 0, 0], [0] * 4])
    np.testing.assert_array_equal(dense(cc.coadjacency_matrix(1, 0)), [[0, 1], [1, 0]])
    assert cc.index([2, 1]) == (1, 1)
    hg = topos.Hypergraph([[0, 1, 2], [2, 3]], weights=[2.0, 0.5])
    np.testing.assert_array_equal(dense(hg.incidence_matrix(weighted=True)), [[2, 0], [2, 0], [2, 0.5], [0, 0.5]])
    np.testing.assert_array_equal(hg.node_degrees().numpy(), [1, 1, 2, 1])
    np.testing.assert_array_equal(dense(hg.adjacency_matrix()), [[0, 1, 1, 0], [1, 0, 1, 0], [1, 1, 0, 1], [0, 0, 1, 0]])
    np.testing.assert_array_equal(dense(hg.coadjacency_matrix()), [[0, 1], [1, 0]])


# ----- liftings -------------------------------------------------------------------------------


def random_graph(seed, n=12, p=0.35):
    rng = random.Random(seed)
    return [(u, v) for u in range(n) for v in range(u + 1, n) if rng.random() < p]


@pytest.mark.parametrize("seed", range(4))
def test_liftings_brute_force(seed):
    n, edges = 12, random_graph(seed)
    adj = {(u, v) for u, v in edges} | {(v, u) for u, v in edges}
    # Clique lifting from PyG's edge_index (both directions, as PyG stores an undirected graph).
    edge_index = torch.tensor(edges + [(v, u) for u, v in edges], dtype=torch.long).T
    sc = topos.clique_lifting(n, edge_index, complex_dim=3)
    for k in range(1, sc.dim + 1):
        want = [c for c in itertools.combinations(range(n), k + 1) if all((a, b) in adj for a, b in itertools.combinations(c, 2))]
        assert [tuple(s) for s in sc.skeleton(k)] == want
    assert sc.dim <= 3
    assert topos.clique_complex(n, edges, 1).shape == (n, len(edges))
    # Cycle basis: m - n + c independent simple cycles of the graph.
    basis = topos.cycle_basis(n, edges)
    parent = list(range(n))

    def find(x):
        while parent[x] != x:
            x = parent[x]
        return x

    for u, v in edges:
        parent[find(u)] = find(v)
    components = len({find(v) for v in range(n)})
    assert len(basis) == len(edges) - n + components
    for c in basis:
        assert len(set(c)) == len(c) >= 3
        assert all((c[i], c[(i + 1) % len(c)]) in adj for i in range(len(c)))
    cx = topos.cycle_lifting(n, edges, max_cell_length=None)
    assert cx.shape == (n, len(edges), len(basis))
    assert topos.cycle_lifting(n, edges, max_cell_length=3).shape[2] == sum(len(c) <= 3 for c in basis)
    # k-hop: hyperedge v = the ball of radius k around v.
    for k in (1, 2):
        hg = topos.khop_lifting(n, edges, k=k)
        for v in range(n):
            ball, frontier = {v}, {v}
            for _ in range(k):
                frontier = {b for a in frontier for (x, b) in adj if x == a} - ball
                ball |= frontier
            assert hg.hyperedge(v) == sorted(ball)
    # Between domains: same ids per rank.
    assert topos.to_combinatorial_complex(sc).shape == sc.shape
    assert topos.to_hypergraph(sc).num_hyperedges == sum(sc.shape[1:])


def test_from_flat_mesh():
    faces = torch.tensor([[0, 1, 2], [1, 2, 3], [2, 3, 4]])
    sc = topos.SimplicialComplex.from_flat(faces)
    assert sc.shape == (5, 7, 3)
    assert sc.shape == topos.SimplicialComplex(faces.tolist()).shape


# ----- the GIL -------------------------------------------------------------------------------


def gil_probe(call, seconds=0.6):
    """Runs `call` repeatedly in a thread for `seconds` while this thread wakes up every
    millisecond; returns the most wake-ups that fell inside one call. This thread needs the GIL
    to record a wake-up, so a call that holds it sees at most the one or two at its edges (where
    the worker runs bytecode), whatever the machine's load; one that releases it, many."""
    done = threading.Event()
    calls = []

    def work():
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            c0 = time.perf_counter()
            call()
            calls.append((c0, time.perf_counter()))
        done.set()

    ticks = []
    t = threading.Thread(target=work)
    t.start()
    while not done.is_set():
        time.sleep(0.001)
        ticks.append(time.perf_counter())
    t.join()
    return max(sum(c0 < x < c1 for x in ticks) for c0, c1 in calls)


def test_long_operator_releases_the_gil():
    # A clique complex whose rank-1 Hodge Laplacian takes about 0.1-0.3 s. (The probe itself,
    # checked on sum(range(10**7)), which holds the GIL: 0-3 wake-ups inside a call; this call:
    # 60-110 on the loaded 2-core machine.)
    rng = random.Random(1)
    n = 3000
    edges = [(u, v) for u in range(n) for v in rng.sample(range(n), 12) if u != v]
    sc = topos.clique_complex(n, edges, 3)
    inside = gil_probe(lambda: sc.hodge_laplacian_matrix(1, format="csr"))
    assert inside >= 10, f"this thread woke up only {inside} times during a call: the GIL was held"


# ----- errors -------------------------------------------------------------------------------


def test_errors_are_python_exceptions_naming_the_argument():
    sc = topos.SimplicialComplex([[0, 1, 2]])
    with pytest.raises(topos.ComplexError, match=r"incidence_matrix: rank 5 is outside \[0, 2\]"):
        sc.incidence_matrix(5)
    assert issubclass(topos.ComplexError, ValueError)
    with pytest.raises(ValueError, match="up_laplacian_matrix: rank 2 must be in"):
        sc.up_laplacian_matrix(2)
    with pytest.raises(TypeError, match="incidence_matrix: signed must be True or False, got int 2"):
        sc.incidence_matrix(1, 2)
    with pytest.raises(TypeError, match=r"SimplicialComplex\(simplices\)\[1\]\[0\] must be an integer node id, got str"):
        topos.SimplicialComplex([[0, 1], ["a", "b"]])
    with pytest.raises(TypeError, match=r"SimplicialComplex\(simplices\)\[0\] is the single node 0"):
        topos.SimplicialComplex([0, 1, 2])
    with pytest.raises(topos.ComplexError, match="repeats node 1"):
        topos.SimplicialComplex([[0, 1, 1]])
    with pytest.raises(topos.ComplexError, match="negative node id"):
        topos.SimplicialComplex([[0, -1]])
    with pytest.raises(TypeError, match=r"node ids must be integers, got a tensor of dtype Float"):
        topos.clique_lifting(3, torch.tensor([[0.0, 1.0], [1.0, 2.0]]))
    with pytest.raises(ValueError, match=r"clique_lifting\(edges\): an edge tensor must have shape \(2, E\)"):
        topos.clique_lifting(4, torch.tensor([[0, 1, 2], [1, 2, 3], [2, 3, 0]]))
    with pytest.raises(topos.ComplexError, match="uses node 7, outside"):
        topos.clique_lifting(3, [(0, 7)])
    with pytest.raises(ValueError, match="format 'torch' is not one of"):
        sc.incidence_matrix(1, format="torch")
    with pytest.raises(TypeError, match="dtype must be a floating dtype"):
        sc.incidence_matrix(1, dtype=torch.int64)
    L = sc.hodge_laplacian_matrix(0)
    with pytest.raises(TypeError, match=r"compute_laplacian_normalized_matrix\(L\): expected a sparse matrix, got a dense torch.Tensor.*to_sparse\(\)"):
        tn.compute_laplacian_normalized_matrix(L.to_dense())
    with pytest.raises(TypeError, match=r"\(L\): expected a sparse matrix, got a dense numpy.ndarray"):
        tn.compute_laplacian_normalized_matrix(np.eye(3))
    with pytest.raises(TypeError, match=r"\(B1\): expected a sparse matrix .*got list"):
        tn.compute_bunch_normalized_matrices([[1]], L)
    with pytest.raises(ValueError, match="expected a 2-D sparse matrix"):
        tn.compute_laplacian_normalized_matrix(torch.ones(2, 2, 2).to_sparse())
    with pytest.raises(topos.ComplexError, match="compute_bunch_normalized_matrices: B1 has"):
        tn.compute_bunch_normalized_matrices(sc.incidence_matrix(2), sc.incidence_matrix(1))
    with pytest.raises(KeyError, match=r"\[0, 5\] is not in the complex"):
        sc.index([0, 5])
    with pytest.raises(ValueError, match="Hypergraph\\(weights\\): expected 2 entries, got 3"):
        topos.Hypergraph([[0, 1], [1, 2]], weights=[1, 2, 3])
    with pytest.raises(ValueError, match="ranks are required"):
        topos.CombinatorialComplex([[0, 1]])
    with pytest.raises(topos.ComplexError, match="add_cell"):
        topos.CombinatorialComplex([[0, 1], [0, 1, 2]], ranks=[2, 1])  # rank condition
    with pytest.raises(ValueError, match=r"compute_laplacian_normalized_matrix\(L\): entry \(0, 5\) is outside the 2 x 2 shape"):
        tn.compute_laplacian_normalized_matrix(torch._sparse_coo_tensor_unsafe(torch.tensor([[0], [5]]), torch.tensor([1.0]), (2, 2)))
    with pytest.raises(ValueError, match="clique_lifting: num_nodes -3 must be >= 0"):
        topos.clique_lifting(-3, [])

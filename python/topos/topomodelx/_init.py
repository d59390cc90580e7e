"""TopoModelX's parameter initialisation, replayed on topos.topomodelx's models.

TopoModelX draws its initial parameters from torch's default generator while its modules are
constructed: ``torch.nn.Linear`` draws at construction (Kaiming-uniform weight, uniform bias),
its ``Conv`` draws a Xavier-uniform weight (gain 1.414) at construction, some layers call
``reset_parameters`` again, ``torch.randn`` draws normal values. Each function below makes the
same draws, in the same order, with the same functions and gains, into the model's own tensors
(torch's Python and LibTorch share the generator), so ``torch.manual_seed(s)`` before the
constructor gives TopoModelX's initial parameters bit for bit. ``p`` maps ``state_dict`` names to
tensors, ``a`` holds the constructor's arguments (defaults included, ``kwargs`` merged).
"""

import math

import torch
from torch.nn import init

GAIN = 1.414  # TopoModelX's default initialization_gain


def _xu(t, gain=GAIN):
    init.xavier_uniform_(t, gain=gain)


def _xn(t, gain=GAIN):
    init.xavier_normal_(t, gain=gain)


def _linear(p, prefix):
    """torch.nn.Linear's reset_parameters (at its construction, or called again)."""
    w = p[prefix + ".weight"]
    init.kaiming_uniform_(w, a=math.sqrt(5))
    b = p.get(prefix + ".bias")
    if b is not None:
        fan_in = w.shape[1]
        bound = 1 / math.sqrt(fan_in) if fan_in > 0 else 0
        init.uniform_(b, -bound, bound)


def _conv(p, prefix, att=False):
    """topomodelx.base.conv.Conv (xavier_uniform): the weight (absent without a linear
    transform), then the attention vector viewed as a column."""
    w = p.get(prefix + ".weight")
    if w is not None:
        _xu(w)
    if att:
        _xu(p[prefix + ".att_weight"].view(-1, 1))


def _mlp(p, prefix):
    """AllSet's MLP (a Sequential of bias-free Linear layers, norms, activations, dropouts): each
    Linear draws at construction; the norms draw nothing."""
    for k, t in list(p.items()):
        if k.startswith(prefix + ".") and k.endswith(".weight") and t.dim() == 2:
            _linear(p, k[: -len(".weight")])


def _scn2(p, a):
    for i in range(a["n_layers"]):
        for c in ("conv_0_to_0", "conv_1_to_1", "conv_2_to_2"):
            _conv(p, f"layers.{i}.{c}")


def _hsn(p, a):
    for i in range(a["n_layers"]):
        for c in ("level1_0_to_0", "level1_0_to_1", "level2_0_to_0", "level2_1_to_0"):
            _conv(p, f"layers.{i}.conv_{c}")


def _scconv(p, a):
    for i in range(a["n_layers"]):
        for c in ("0_to_0", "0_to_1", "1_to_1", "1_to_0", "1_to_2", "2_to_1", "2_to_2"):
            _conv(p, f"layers.{i}.conv_{c}")


def _sccn(p, a):
    r = a["max_rank"]
    for i in range(a["n_layers"]):
        for group, ranks in (
            ("convs_same_rank", range(r + 1)),
            ("convs_low_to_high", range(1, r + 1)),
            ("convs_high_to_low", range(r)),
        ):
            for k in ranks:
                _conv(p, f"layers.{i}.{group}.rank_{k}")


def _scnn(p, a):
    for i in range(a["n_layers"]):
        _xu(p[f"layers.{i}.weight"])


def _sccnn(p, a):
    for k in range(3):
        _linear(p, f"in_linear_{k}")
    for i in range(a["n_layers"]):
        for k in range(3):
            w = p.get(f"layers.{i}.weight_{k}")
            if w is not None:
                _xn(w)  # SCCNNLayer's default initialization is xavier_normal


def _scone(p, a):
    # SCoNe calls each layer's reset_parameters (gain 1.0) after building them all.
    for i in range(a["n_layers"]):
        for k in range(3):
            _xu(p[f"layers.{i}.weight_{k}"], gain=1.0)


def _sca_cmps(p, a):
    for i in range(a["n_layers"]):
        for j in range(a["complex_dim"] - 1):
            _conv(p, f"layers.{i}.lap_layers.{j}", att=a["att"])
            _conv(p, f"layers.{i}.inc_layers.{j}", att=a["att"])


def _san(p, a):
    n = sum(1 for k in p if k.endswith(".conv_harmonic.weight"))
    for i in range(n):
        for c in ("conv_down", "conv_up"):
            _conv(p, f"layers.{i}.{c}", att=True)
        _conv(p, f"layers.{i}.conv_harmonic")


def _dist2cycle(p, a):
    for i in range(a["n_layers"]):
        _linear(p, f"layers.{i}.fc_neigh")


def _cwn(p, a):
    for k in range(3):
        _linear(p, f"proj_{k}")
    for i in range(a["n_layers"]):
        _conv(p, f"layers.{i}.conv_1_to_1.conv_1_to_1")
        _conv(p, f"layers.{i}.conv_1_to_1.conv_2_to_1")
        _conv(p, f"layers.{i}.conv_0_to_1.conv_0_to_1")
        _linear(p, f"layers.{i}.update_fn.transform")


def _ccxn(p, a):
    for i in range(a["n_layers"]):
        _conv(p, f"layers.{i}.conv_0_to_0", att=a["att"])
        _conv(p, f"layers.{i}.conv_1_to_2", att=a["att"])


def _can(p, a):
    relu_gain = init.calculate_gain("relu")
    if a["att_lift"]:
        _xu(p["lift_layer.lifts.att_parameter"], gain=relu_gain)

    def attention(prefix):  # MultiHeadCellAttention's reset_parameters
        _xu(p[prefix + ".att_weight_src"], gain=1.0)
        _xu(p[prefix + ".att_weight_dst"], gain=1.0)
        _linear(p, prefix + ".lin")

    i = 0
    for layer in range(a["n_layers"]):
        pre = f"layers.{i}"
        # MultiHeadCellAttention: its Linear draws, then its reset_parameters; twice (lower,
        # upper); the skip connection's Linear; then CANLayer.reset_parameters draws them again.
        for att in ("lower_att", "upper_att"):
            _linear(p, f"{pre}.{att}.lin")
            attention(f"{pre}.{att}")
        if f"{pre}.lin.weight" in p:
            _linear(p, f"{pre}.lin")
        attention(f"{pre}.lower_att")
        attention(f"{pre}.upper_att")
        if f"{pre}.lin.weight" in p:
            _linear(p, f"{pre}.lin")
        i += 1
        if layer > 0 and a["pooling"]:
            _xu(p[f"layers.{i}.att_pool"], gain=relu_gain)
            i += 1


def _hmc(p, a):
    for i in range(len(a["channels_per_layer"])):
        for block in (
            "hbs_0_level1",
            "hbns_0_1_level1",
            "hbns_1_2_level1",
            "hbs_0_level2",
            "hbns_0_1_level2",
            "hbs_1_level2",
            "hbns_1_2_level2",
            "hbs_2_level2",
        ):
            pre = f"layers.{i}.{block}"
            if block.startswith("hbs_"):
                hop = 0
                while f"{pre}.weight.{hop}" in p:
                    _xu(p[f"{pre}.weight.{hop}"])
                    _xu(p[f"{pre}.att_weight.{hop}"].view(-1, 1))
                    hop += 1
            else:
                _xu(p[f"{pre}.w_s"])
                _xu(p[f"{pre}.w_t"])
                _xu(p[f"{pre}.att_weight"].view(-1, 1))


def _allset(p, a):
    for i in range(a["n_layers"]):
        for block in ("vertex2edge", "edge2vertex"):
            pre = f"layers.{i}.{block}"
            _mlp(p, pre + ".encoder")
            _mlp(p, pre + ".decoder")
            _conv(p, pre + ".conv")


def _allset_transformer(p, a):
    for i in range(a["n_layers"]):
        for block in ("vertex2edge", "edge2vertex"):
            pre = f"layers.{i}.{block}"
            qkv = [p[f"{pre}.multihead_att.{w}_weight"] for w in ("K", "Q", "V")]
            for w in qkv:  # torch.randn at construction
                w.normal_()
            _mlp(p, pre + ".mlp")
            _declare(p, *(f"{pre}.{n}.{w}" for n in ("ln0", "ln1") for w in ("weight", "bias")))
            for w in qkv:  # the block's reset_parameters
                _xu(w)


def _hmpnn(p, a):
    _linear(p, "linear_node")
    _linear(p, "linear_edge")
    for i in range(a["n_layers"]):
        _linear(p, f"layers.{i}.node_to_hyperedge_messenger.messaging_func.0")
        _linear(p, f"layers.{i}.hyperedge_to_node_messenger.messaging_func.linear")


def _hnhn(p, a):
    gain = a.get("bias_gain", GAIN)
    for i in range(a["n_layers"]):
        pre = f"layers.{i}"
        _declare(p, pre + ".bias_1_to_0", pre + ".bias_0_to_1")
        _conv(p, pre + ".conv_0_to_1")
        _conv(p, pre + ".conv_1_to_0")
        for b in ("bias_0_to_1", "bias_1_to_0"):
            if pre + "." + b in p:
                (_xn if a.get("bias_init") == "xavier_normal" else _xu)(p[pre + "." + b], gain)


def _hypergat(p, a):
    normal = a.get("initialization") == "xavier_normal"
    gain = a.get("initialization_gain", GAIN)
    f = _xn if normal else _xu
    for i in range(a["n_layers"]):
        pre = f"layers.{i}"
        f(p[pre + ".weight1"], gain)
        f(p[pre + ".weight2"], gain)
        f(p[pre + ".att_weight1"].view(-1, 1), gain)
        f(p[pre + ".att_weight2"].view(-1, 1), gain)


def _hypersage(p, a):
    for i in range(a["n_layers"]):  # initialization "uniform"
        w = p[f"layers.{i}.weight"]
        stdv = 1.0 / math.sqrt(w.size(1))
        w.uniform_(-stdv, stdv)


def _unigcn(p, a):
    for i in range(a["n_layers"]):
        _conv(p, f"layers.{i}.conv_level1_0_to_1")
        _conv(p, f"layers.{i}.conv_level2_1_to_0")
        _declare(p, *(k for k in list(p) if k.startswith(f"layers.{i}.bn.")))  # use_bn


def _linears(first, per_layer):
    def replay(p, a):
        if first:
            _linear(p, first)
        for i in range(a["n_layers"]):
            _linear(p, f"layers.{i}.{per_layer}")

    return replay


REPLAYS = {
    "SCN2": _scn2,
    "HSN": _hsn,
    "SCConv": _scconv,
    "SCCN": _sccn,
    "SCNN": _scnn,
    "SCCNN": _sccnn,
    "SCoNe": _scone,
    "SCACMPS": _sca_cmps,
    "SAN": _san,
    "Dist2Cycle": _dist2cycle,
    "CWN": _cwn,
    "CCXN": _ccxn,
    "CAN": _can,
    "HMC": _hmc,
    "AllSet": _allset,
    "AllSetTransformer": _allset_transformer,
    "HMPNN": _hmpnn,
    "HNHN": _hnhn,
    "HyperGAT": _hypergat,
    "HyperSAGE": _hypersage,
    "UniGCN": _unigcn,
    "UniGCNII": _linears("initial_linear_layer", "linear"),
    "UniGIN": _linears("initial_linear_layer", "linear"),
    "UniSAGE": _linears(None, "linear"),
}


class _Recorder(dict):
    """The tensors by name, noting the order in which the replay first reaches them."""

    def __init__(self, tensors):
        super().__init__(tensors)
        self.order = {}

    def __getitem__(self, k):
        self.order.setdefault(k, len(self.order))
        return super().__getitem__(k)

    def get(self, k, default=None):
        return self[k] if k in self else default


def _declare(p, *names):
    """Reaches tensors without drawing: TopoModelX registers them here (state_dict order)."""
    for k in names:
        if k in p:
            p[k]


def reset(tensors, model, arguments):
    """Initialises the tensors (name -> tensor) of `model` as TopoModelX's constructor does;
    returns the names in TopoModelX's state_dict order: the order in which its constructor
    creates them, which the replay follows (a tensor it does not reach, e.g. a norm's, stays
    after the one before it in `tensors`)."""
    p = _Recorder(tensors)
    with torch.no_grad():
        REPLAYS[model](p, arguments)
    names = list(tensors)
    rank, last = {}, -1.0
    for i, k in enumerate(names):
        if k in p.order:
            last = float(p.order[k])
            rank[k] = (last, 0)
        else:
            rank[k] = (last, i + 1)
    return sorted(names, key=lambda k: rank[k])

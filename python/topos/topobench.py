"""TopoBench from Python: its datasets, liftings, protocol and trainer, with any backbone.

    from topos import topobench
    from topos.topobench import Backbone, RankLayout

    layout = RankLayout("cell", encoded_ranks=[0, 1], cell_dimensions=2,
                        operators={"adjacency_0", "incidence_1"})
    mine = Backbone("Mine", layout, make)           # make(ctx) -> schedule or torch.nn.Module
    config = topobench.find_config("CWN", "MUTAG")  # TopoBench's line for a table model
    data = topobench.lift("MUTAG", layout, config)  # raw files from $TOPOS_DATASETS_DIR
    run = topobench.train_run(data, mine, config, seed=0)
    print(run.result.test_accuracy, run.curve)

The pipeline is the C++ one (topos/models/topobench/, docs/topobench.md): TopoBench's readers and
liftings, its model around the backbone (encoder, wrapper, readout, classifier), its random
splits and its trainer (Adam, StepLR, validation checks, early stopping, the best check's
parameters and buffers restored). ``make(ctx)`` builds the backbone for one run (``ctx.hidden``,
``ctx.n_layers``): a ``topos.nn.OperatorSchedule`` (or ``OperatorNetwork``) over ``x_r`` at the
hidden width runs in the C++ engine; any other ``torch.nn.Module`` is called as
``forward(x, operators)`` with dicts of cochains ``{"x_r": cells × hidden}`` and operators (torch
sparse COO, by the lifting's names) and returns ``{"x_r": ...}`` for every rank below
``cell_dimensions``. See docs/python.md, "TopoBench from Python".
"""

import dataclasses
import typing

from ._C.topobench import (  # noqa: F401
    BackboneContext,
    Batch,
    Check,
    LiftedDataset,
    Model,
    RankLayout,
    RunConfig,
    RunResult,
    RunsFolder,
    datasets,
    find_config,
    model_layout,
    models,
    read_dataset,
    read_hparams,
    split,
)
from ._C import topobench as _tb

__all__ = [
    "Backbone",
    "BackboneContext",
    "Batch",
    "Check",
    "LiftedDataset",
    "Model",
    "RankLayout",
    "RunConfig",
    "RunResult",
    "RunsFolder",
    "TrainedRun",
    "datasets",
    "default_config",
    "find_config",
    "lift",
    "model_layout",
    "models",
    "read_dataset",
    "read_hparams",
    "run",
    "split",
    "train_run",
]


class Backbone:
    """A backbone as a recipe: its name (runs.csv's ``model``), its ``RankLayout`` and
    ``make(ctx)``, called once per run after the encoder is built (so parameters are drawn in
    TopoBench's order from the run's seed), returning an ``OperatorSchedule``, an
    ``OperatorNetwork`` or a ``torch.nn.Module``."""

    def __init__(self, name, layout, make):
        if not isinstance(layout, RankLayout):
            raise TypeError(
                f"Backbone(layout): expected a topos.topobench.RankLayout, got {type(layout).__name__}"
            )
        if not callable(make):
            raise TypeError(f"Backbone(make): expected a callable make(ctx), got {type(make).__name__}")
        _tb.check_backbone(name, layout)  # the name (a field of runs.csv) and the encoded ranks
        self.name, self.layout, self.make = name, layout, make

    def __repr__(self):
        return f"Backbone({self.name!r}, {self.layout!r})"


@dataclasses.dataclass
class TrainedRun:
    """A finished run: its row of runs.csv, its validation checks, and the model at its best
    check (``model.state_dict()``, ``model(batch)``, ``model.backbone``: the Python module)."""

    result: RunResult
    curve: typing.List[Check]
    best_val_accuracy: float
    model: Model


def _layout_of(layout, arg):
    if isinstance(layout, Backbone):
        return layout.layout
    if isinstance(layout, str):
        return model_layout(layout)
    if isinstance(layout, RankLayout):
        return layout
    raise TypeError(
        f"{arg}: expected a RankLayout, a Backbone or a table model's name, got {type(layout).__name__}"
    )


def default_config():
    """The lifting settings TopoBench's rows use (signed simplicial incidences, cycles of at
    most 10 nodes as 2-cells), for ``lift`` without a config; train with ``find_config``'s."""
    c = RunConfig()
    c.signed_incidence = True
    c.max_cell_length = 10
    return c


def lift(dataset, layout, config=None, *, root=None, factored=False, progress=False):
    """Reads ``dataset`` (a table dataset: MUTAG, PROTEINS, NCI1, NCI109, IMDB-BINARY,
    IMDB-MULTI, REDDIT-BINARY, Cora, Citeseer) from ``root`` (default ``$TOPOS_DATASETS_DIR``)
    and lifts it to ``layout``'s domain with the operators it names, as TopoBench does.
    ``layout``: a ``RankLayout``, a ``Backbone`` or a table model's name; ``config``: the
    ``RunConfig`` whose lifting settings apply (``signed_incidence``, ``max_cell_length``)."""
    layout = _layout_of(layout, "lift(layout)")
    if config is None:
        config = default_config()
    elif not isinstance(config, RunConfig):
        raise TypeError(f"lift(config): expected a RunConfig, got {type(config).__name__}")
    return _tb.lift_dataset(dataset, layout, config, root=root, factored=factored, progress=progress)


def _check_pair(data, backbone, config, where):
    if not isinstance(data, LiftedDataset):
        raise TypeError(f"{where}(data): expected a LiftedDataset (topobench.lift), got {type(data).__name__}")
    if not isinstance(backbone, Backbone):
        raise TypeError(f"{where}(backbone): expected a topobench.Backbone, got {type(backbone).__name__}")
    if not isinstance(config, RunConfig):
        raise TypeError(f"{where}(config): expected a RunConfig (topobench.find_config), got {type(config).__name__}")
    lay = backbone.layout
    if data.layout.domain != lay.domain:
        raise ValueError(
            f"{where}(data): {data.dataset} was lifted to {data.layout.domain}, but {backbone.name} "
            f"works on {lay.domain}; lift it with the backbone's layout"
        )
    missing = sorted(set(lay.operators) - set(data.layout.operators))
    if missing:
        raise ValueError(
            f"{where}(data): {backbone.name} needs the operator '{missing[0]}', which {data.dataset} "
            f"was not lifted with; lift it with the backbone's layout (topobench.lift(..., backbone))"
        )
    if config.readout == "PropagateSignalDown":
        need = [f"incidence_{r}" for r in range(1, lay.cell_dimensions)]
        lacking = [op for op in need if op not in lay.operators]
        if lacking:
            raise ValueError(
                f"{where}(config): readout PropagateSignalDown reads {', '.join(need)}; add "
                f"'{lacking[0]}' to {backbone.name}'s layout operators, or set config.readout = ''"
            )


def train_run(data, backbone, config, seed, *, max_epochs=0, progress=False, on_check=None,
              flush_denormals=True):
    """One run of TopoBench's trainer: ``backbone`` in TopoBench's model, trained on ``data``
    split by ``seed`` with ``config``'s hyperparameters (``find_config``). ``max_epochs`` > 0
    caps the epochs (quick checks; not the protocol). ``on_check(check, model)`` is called after
    every validation check, the model in eval mode. With ``flush_denormals`` (the default) the
    run's float arithmetic flushes denormals to zero, as ``torch.set_flush_denormal(True)``
    would: values below 1.2e-38 become 0, and products that meet them stop running 4-5x slower
    (SCCNN's saturated sigmoids). Returns a ``TrainedRun``."""
    _check_pair(data, backbone, config, "train_run")
    out = _tb.train_run(
        data,
        backbone.name,
        backbone.layout,
        backbone.make,
        config,
        int(seed),
        max_epochs=max_epochs,
        progress=progress,
        on_check=on_check,
        flush_denormals=flush_denormals,
    )
    return TrainedRun(**out)


def run(backbone, dataset, config, *, seeds=None, out=None, root=None, max_epochs=0, progress=False,
        flush_denormals=True):
    """The runner: lifts ``dataset`` for ``backbone`` once, then one ``train_run`` per data seed
    (``config.data_seeds`` unless ``seeds``), each added to the ``RunsFolder`` ``out`` (runs.csv,
    curves.csv, summary.csv, index.html, table.md) when given; a run the folder already holds is
    skipped (resumable); ``flush_denormals`` as ``train_run``'s. Returns the new runs."""
    if not isinstance(config, RunConfig):
        raise TypeError(f"run(config): expected a RunConfig (topobench.find_config), got {type(config).__name__}")
    seeds = list(config.data_seeds if seeds is None else seeds)
    if not seeds:
        raise ValueError("run(seeds): no data seeds (config.data_seeds is empty and seeds was not given)")
    if not isinstance(backbone, Backbone):
        raise TypeError(f"run(backbone): expected a topobench.Backbone, got {type(backbone).__name__}")
    data = lift(dataset, backbone, config, root=root, progress=progress)
    folder = RunsFolder(out) if out is not None else None
    runs = []
    for seed in seeds:
        if folder is not None and folder.done(backbone.name, data.dataset, seed):
            continue
        r = train_run(data, backbone, config, seed, max_epochs=max_epochs, progress=progress,
                      flush_denormals=flush_denormals)
        if folder is not None:
            folder.add(r.result, r.curve)
        runs.append(r)
    return runs

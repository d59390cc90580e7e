"""HOPNet from Python: open a checkpoint, roll out a Kubric scene, score it.

    ckpt = topos.hopnet.Checkpoint("modela_seed2_e39.pt", stats="movia.json")
    scene = topos.hopnet.Scene("movi-a/8", assets="kubasic")
    r = topos.hopnet.rollout(ckpt, scene, steps=102)   # the GIL is released while it runs
    r.positions          # torch.float64 [frames, objects, 3]; frames 0..3 are the ground truth
    r.metrics()["pos_rmse"][50]

``Checkpoint`` opens the published checkpoints (the reference's state dicts) and topos's own;
``metrics(positions, quaternions, scene)`` scores any trajectory of the scene's objects.
"""

from ._C.hopnet import Checkpoint, Rollout, Scene, metrics, rollout  # noqa: F401

# HOPNet from Python: the published MOVi-A checkpoint's reference-mode rollout of scene 8 gives
# the reference's metrics (README: position RMSE 0.026131 / 0.083279 / 0.144398 / 0.271126 m at
# frames 25 / 50 / 75 / 100), trajectories as tensors, metrics of any trajectory, topos's own
# checkpoints, and bad input as Python exceptions.
import pytest
import torch

import topos
from topos import hopnet


@pytest.fixture(scope="module")
def ref(reference_dir):
    return reference_dir / "data"


@pytest.fixture(scope="module")
def checkpoint(ref):
    return hopnet.Checkpoint(ref / "checkpoints" / "modela_seed2_e39.pt", stats=ref / "normalization" / "movia.json")


@pytest.fixture(scope="module")
def scene(ref):
    return hopnet.Scene(ref / "movi-a" / "8", assets=ref / "kubasic")


@pytest.fixture(scope="module")
def reference_rollout(checkpoint, scene):
    return hopnet.rollout(checkpoint, scene, steps=102)


def test_reference_rollout_matches_the_papers_metrics(checkpoint, scene, reference_rollout):
    assert checkpoint.variant == "standard" and checkpoint.mode == "reference"
    assert checkpoint.num_parameters == 707078
    assert "variant standard, mode reference, stats" in repr(checkpoint)
    r = reference_rollout
    assert r.num_frames == 106
    m = r.metrics()
    golden = {25: (0.026131, 0.979), 50: (0.083279, 2.321), 75: (0.144398, 4.496), 100: (0.271126, 6.382)}
    # The golden values are rounded to six digits; the order of float32 sums (BLAS's blocking on
    # this CPU) moves frame 100's in the sixth (0.2711262-0.2711266 with OpenBLAS's Haswell and
    # SkylakeX kernels and oneDNN on 2026-11-30's AMD EPYC), so within a unit of it.
    for frame, (pos_rmse, ori_mae) in golden.items():
        assert abs(m["pos_rmse"][frame].item() - pos_rmse) <= 1e-6, f"frame {frame}"
        assert round(m["ori_mae"][frame].item(), 3) == ori_mae, f"frame {frame}"
    assert (m["pos_rmse"][:4] == 0).all()


def test_trajectory_tensors_and_metrics(scene, reference_rollout):
    r = reference_rollout
    n = scene.num_objects
    assert n == len(scene.shapes) == 3
    assert r.positions.shape == (106, n, 3) and r.positions.dtype == torch.float64
    assert r.quaternions.shape == (106, n, 4)
    assert scene.positions.shape == (scene.num_frames, n, 3)
    # Frames 0..3 are the ground truth; quaternions stay unit.
    torch.testing.assert_close(r.positions[:4], scene.positions[:4], rtol=0, atol=0)
    torch.testing.assert_close(r.quaternions.norm(dim=2), torch.ones(106, n, dtype=torch.float64))
    # metrics() of the tensors equals the rollout's own, and the ground truth scores zero.
    m = hopnet.metrics(r.positions, r.quaternions, scene)
    for k, v in r.metrics().items():
        torch.testing.assert_close(m[k], v, equal_nan=True)
    gt = hopnet.metrics(scene.positions, scene.quaternions, scene)
    assert gt["pos_rmse"].abs().max() == 0 and gt["pos_mae"].abs().max() == 0
    # Brute force: position RMSE over the objects, frame 60.
    d = (r.positions[60] - scene.positions[60]).norm(dim=1)
    assert abs(d.pow(2).mean().sqrt().item() - m["pos_rmse"][60].item()) < 1e-12


def test_topos_checkpoint_round_trip(checkpoint, scene, ref, tmp_path):
    path = tmp_path / "modela.pt"
    checkpoint.save(path)
    back = hopnet.Checkpoint(path, stats=ref / "normalization" / "movia.json")
    assert back.options == checkpoint.options
    a, b = checkpoint.state_dict(), back.state_dict()
    # The tensors are the model's own (no copy): two calls give the same memory.
    assert all(t.data_ptr() == checkpoint.state_dict()[k].data_ptr() for k, t in a.items())
    assert a.keys() == b.keys() and len(a) > 0
    for k in a:
        assert torch.equal(a[k], b[k]), k
    # topos's own file is a dict of tensors torch.load opens.
    assert "topos.config" in torch.load(path)
    steps = []
    r = hopnet.rollout(back, scene, steps=5, on_step=lambda done, total: steps.append((done, total)))
    assert steps == [(i, 5) for i in range(1, 6)]
    assert r.num_frames == 9


def test_reference_activation_from_the_file_name(ref):
    c = hopnet.Checkpoint(ref / "checkpoints" / "gelu_seed0_e39.pt")
    assert c.activation == "gelu"
    assert hopnet.Checkpoint(ref / "checkpoints" / "modela_seed2_e39.pt", activation="elu").activation == "elu"


def test_hopnet_errors(ref, checkpoint, scene, tmp_path):
    with pytest.raises(FileNotFoundError, match="checkpoint: no such file or folder: .*no_such.pt"):
        hopnet.Checkpoint(tmp_path / "no_such.pt")
    with pytest.raises(FileNotFoundError, match="stats: no such file or folder"):
        hopnet.Checkpoint(ref / "checkpoints" / "modela_seed2_e39.pt", stats=tmp_path / "s.json")
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(RuntimeError, match="bad.pt"):
        hopnet.Checkpoint(bad)
    with pytest.raises(ValueError, match="unknown mode 'fast'"):
        hopnet.Checkpoint(ref / "checkpoints" / "modela_seed2_e39.pt", mode="fast")
    with pytest.raises(TypeError, match="checkpoint must be a path"):
        hopnet.Checkpoint(3)
    no_stats = hopnet.Checkpoint(ref / "checkpoints" / "modela_seed2_e39.pt")
    with pytest.raises(ValueError, match="without normalisation statistics; pass stats="):
        hopnet.rollout(no_stats, scene)
    with pytest.raises(ValueError, match="steps must be positive"):
        hopnet.rollout(checkpoint, scene, steps=0)
    with pytest.raises(FileNotFoundError, match="assets: no such file or folder"):
        hopnet.Scene(ref / "movi-a" / "8", assets=tmp_path / "nothing")
    with pytest.raises(topos.DataError, match="metadata.json"):
        hopnet.Scene(tmp_path)  # a folder without metadata.json
    with pytest.raises(ValueError, match=r"metrics\(positions\): expected shape \(frames, 3, 3\)"):
        hopnet.metrics(torch.zeros(10, 2, 3), torch.zeros(10, 3, 4), scene)
    with pytest.raises(TypeError, match=r"metrics\(quaternions\): expected a floating tensor"):
        hopnet.metrics(torch.zeros(10, 3, 3), torch.zeros(10, 3, 4, dtype=torch.long), scene)


def test_rollout_cpu_gemm_libraries_agree(checkpoint, scene, reference_rollout):
    """cpu_gemm picks the library of one rollout's float32 products and restores the process's
    afterwards; the libraries differ in summation order only. Reference mode's 'auto' keeps the
    process's (BLAS: the reference's digits above)."""
    assert topos.nn.get_cpu_gemm() == "blas"
    base = reference_rollout.metrics()["pos_rmse"][4:]
    for library in ("topos", "onednn"):
        try:
            r = hopnet.rollout(checkpoint, scene, steps=102, cpu_gemm=library)
        except ValueError as e:  # a LibTorch without oneDNN says so
            assert library == "onednn" and "has no oneDNN" in str(e)
            continue
        assert topos.nn.get_cpu_gemm() == "blas"
        assert not torch.equal(r.positions, reference_rollout.positions), library
        torch.testing.assert_close(r.metrics()["pos_rmse"][4:], base, rtol=1e-3, atol=0)
    same = hopnet.rollout(checkpoint, scene, steps=102, cpu_gemm="auto")
    assert torch.equal(same.positions, reference_rollout.positions)
    with pytest.raises(ValueError, match="unknown cpu gemm 'mkl'"):
        hopnet.rollout(checkpoint, scene, steps=2, cpu_gemm="mkl")
    topos.nn.set_cpu_gemm("topos")
    try:
        assert topos.nn.get_cpu_gemm() == "topos"
    finally:
        topos.nn.set_cpu_gemm("blas")


def test_rollout_on_two_step_threads_gives_the_same_poses(checkpoint, scene, reference_rollout):
    """step_threads shares each parallel group's steps with helper threads; the poses are the
    one-thread poses bit for bit."""
    assert checkpoint.step_threads == 1
    checkpoint.step_threads = 2
    try:
        r = hopnet.rollout(checkpoint, scene, steps=102)
    finally:
        checkpoint.step_threads = 1
    assert torch.equal(r.positions, reference_rollout.positions)
    assert torch.equal(r.quaternions, reference_rollout.quaternions)
    with pytest.raises(ValueError, match="step_threads: 0 threads; give 1"):
        checkpoint.step_threads = 0
    assert checkpoint.step_threads == 1

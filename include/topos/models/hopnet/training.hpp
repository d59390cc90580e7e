// topos/models/hopnet/training.hpp
// Training data and loss of HOPNet (scripts/main.py). A trajectory's timesteps t = 2..T-2 each
// give one complex (contacts detected on the GT pose at t, or given, as the reference's
// collisions.json) and targets: node accelerations t0 and object accelerations t4 from GT
// positions. The timesteps are collated into batches (the whole trajectory, or chunks of it),
// so one forward and one backward serve many timesteps; the loss is
//   Σ_t [ (1/N) Σ_{n,d} (a0 − t0n)² + (1/O) Σ_{o,d} (a4 − t4n)² ]
// on normalised targets, optionally with the low-velocity collision mask. The timesteps are
// independent given the ground-truth inputs, so chunks' gradients add up to the whole one's.
// Without object cells (models/ablations.py) t0 has a row per virtual node too (its
// object's acceleration), there is no object term, the node term is divided by N+O, and virtual
// nodes get weight 0.
#pragma once

#include "topos/models/hopnet/rollout.hpp"
#include "topos/models/namespace_aliases.hpp"

#include <exception>
#include <thread>

namespace topos::models::hopnet {

/// Raw (double) features and targets of every training timestep of one scene.
struct TrajectoryFrames {
  std::vector<HopnetFrame> frames;
  std::vector<RowMatrix> t0, t4;  ///< per timestep: N×3, O×3 accelerations (m/frame²)
  std::vector<RowMatrix> mask;    ///< per timestep: O×1 object weights (1, or 0 when masked)
};

/// Contact candidates per frame (read_collisions_json).
using ContactsByFrame = std::map<std::int64_t, std::vector<ContactCandidate>>;

/// Features at t = first..last (inclusive; default 2..T-2) from the scene's GT poses. Contacts
/// are detected, or taken from `given` (the reference trains on collisions.json), which must
/// then hold every frame used. Where they are detected and `detected` is given, each frame's
/// candidates are stored there (what it held is cleared): given back, they build the same
/// frames without the detection (a trainer's cache across epochs).
inline TrajectoryFrames trajectory_frames(const Scene& scene, const HopnetGeometry& g,
                                          double collision_radius = 0.1,
                                          double min_z_collision_velocity = 0.0,
                                          std::int64_t first = 2, std::int64_t last = -1,
                                          const ContactsByFrame* given = nullptr,
                                          ContactsByFrame* detected = nullptr) {
  if (last < 0) last = scene.num_frames - 2;
  if (first < 2 || last > scene.num_frames - 2 || first > last)
    throw std::invalid_argument(scene.source + ": a training trajectory needs at least 4 frames");
  TrajectoryFrames out;
  if (detected) detected->clear();
  std::vector<Poses> p;
  for (std::int64_t t = 0; t < scene.num_frames; ++t) p.push_back(scene_poses(scene, t));
  std::vector<std::vector<PosedObject>> posed;
  for (const auto& q : p) posed.push_back(pose_objects(g, q));
  const std::int64_t N = g.num_nodes(), O = g.num_objects();
  for (std::int64_t t = first; t <= last; ++t) {
    std::vector<ContactCandidate> contacts;
    if (given) {
      const auto it = given->find(t);
      if (it == given->end())
        throw std::invalid_argument(scene.source + ": the given contacts have no frame " +
                                    std::to_string(t));
      contacts = it->second;
    } else {
      contacts = detect_contacts(g, posed[static_cast<std::size_t>(t)], collision_radius);
      if (detected) (*detected)[t] = contacts;
    }
    out.frames.push_back(build_frame(g, p[0], p[static_cast<std::size_t>(t - 2)],
                                     p[static_cast<std::size_t>(t - 1)],
                                     p[static_cast<std::size_t>(t)], contacts));
    RowMatrix a0(N, 3), a4(O, 3), m = RowMatrix::Ones(O, 1);
    for (std::int64_t o = 0; o < O; ++o) {
      const auto& xp = posed[static_cast<std::size_t>(t - 1)][static_cast<std::size_t>(o)].vertices;
      const auto& xt = posed[static_cast<std::size_t>(t)][static_cast<std::size_t>(o)].vertices;
      const auto& xn = posed[static_cast<std::size_t>(t + 1)][static_cast<std::size_t>(o)].vertices;
      a0.middleRows(g.node_offset[static_cast<std::size_t>(o)], xt.rows()) = xn - 2.0 * xt + xp;
      a4.row(o) = p[static_cast<std::size_t>(t + 1)].positions.row(o) -
                  2.0 * p[static_cast<std::size_t>(t)].positions.row(o) +
                  p[static_cast<std::size_t>(t - 1)].positions.row(o);
    }
    if (min_z_collision_velocity > 0) {
      for (const auto& c : contacts)
        for (auto o : {c.obj0, c.obj1}) {
          const double vz = p[static_cast<std::size_t>(t)].positions(o, 2) -
                            p[static_cast<std::size_t>(t - 1)].positions(o, 2);
          if (std::abs(vz) < min_z_collision_velocity / 240.0) m(o, 0) = 0;
        }
    }
    if (!g.lifting.object_cells()) {
      RowMatrix with_virtual(N + O, 3);
      with_virtual << a0, a4;
      a0 = std::move(with_virtual);
    }
    out.t0.push_back(std::move(a0));
    out.t4.push_back(std::move(a4));
    out.mask.push_back(std::move(m));
  }
  return out;
}

/// Adds a trajectory's raw features and targets to the statistics (`objects`: x4 and t4 too;
/// false without object cells, whose statistics have none).
inline void accumulate_stats(StatsAccumulator& acc, const TrajectoryFrames& tf,
                             bool objects = true) {
  for (std::size_t i = 0; i < tf.frames.size(); ++i) {
    const auto& f = tf.frames[i];
    acc.add("x0", f.x0), acc.add("x1", f.x1), acc.add("x2", f.x2), acc.add("x3", f.x3);
    acc.add("t0", tf.t0[i]);
    if (objects) acc.add("x4", f.x4), acc.add("t4", tf.t4[i]);
  }
}

/// One trajectory ready for the optimizer: its batch, normalised targets and weights.
struct TrainingItem {
  HopnetBatch batch;
  torch::Tensor t0, t4, node_weight, object_weight;  ///< weights: mask / N, mask / O per row
  std::int64_t timesteps = 0;
  TrainingItem to(const torch::Device& d) const {
    return {batch.to(d),         t0.to(d), t4.defined() ? t4.to(d) : t4, node_weight.to(d),
            object_weight.to(d), timesteps};
  }
};

/// The timesteps [begin, end) of a trajectory (end -1: to the last) as one item.
inline TrainingItem make_training_item(const HopnetGeometry& g, const TrajectoryFrames& tf,
                                       const Normalizer& norm, std::size_t begin = 0,
                                       std::size_t end = static_cast<std::size_t>(-1)) {
  end = std::min(end, tf.frames.size());
  if (begin >= end) throw std::invalid_argument("make_training_item: empty range of timesteps");
  TrainingItem it;
  std::vector<std::pair<const HopnetGeometry*, const HopnetFrame*>> frames;
  std::vector<torch::Tensor> t0, t4, nw, ow;
  const bool objects = g.lifting.object_cells();
  const double N = static_cast<double>(g.num_rank0()), O = static_cast<double>(g.num_objects());
  const auto node_object = torch::tensor(
      std::vector<std::int64_t>(g.node_object.begin(), g.node_object.end()), torch::kLong);
  for (std::size_t i = begin; i < end; ++i) {
    frames.push_back({&g, &tf.frames[i]});
    t0.push_back(norm.normalize("t0", tf.t0[i]));
    if (objects) t4.push_back(norm.normalize("t4", tf.t4[i]));
    const auto m = Normalizer::to_tensor(tf.mask[i]).squeeze(1);
    ow.push_back(objects ? m / O : torch::zeros({0}, torch::kFloat));
    auto w = m.index_select(0, node_object) / N;
    if (!objects)
      w = torch::cat(
          {w, torch::zeros({g.num_objects()}, torch::kFloat)});  // virtual nodes: never supervised
    nw.push_back(w);
  }
  it.batch = make_batch(frames, norm);
  it.t0 = torch::cat(t0);
  it.t4 = objects ? torch::cat(t4) : torch::Tensor();
  it.node_weight = torch::cat(nw).unsqueeze(1);
  it.object_weight = torch::cat(ow).unsqueeze(1);
  it.timesteps = static_cast<std::int64_t>(end - begin);
  return it;
}

/// Activation memory one training timestep needs (forward values kept for the backward), from
/// its cell counts: about kActivationRows rows of `hidden` float32 per node, face, contact
/// and read edge. Measured on MOVi-A and MOVi-B (docs/hopnet.md).
inline constexpr double kActivationRows = 40.0;
inline double timestep_activation_bytes(const HopnetGeometry& g, const HopnetFrame& f,
                                        std::int64_t hidden) {
  const double rows = static_cast<double>(g.num_nodes() + g.num_objects()) +
                      4.0 * static_cast<double>(f.num_faces()) +
                      2.0 * static_cast<double>(f.num_contacts());
  return kActivationRows * rows * static_cast<double>(hidden) * 4.0;
}

/// Timesteps per chunk so that a chunk's activations fit `budget_bytes` (at least 1; at most
/// the whole trajectory), from the trajectory's most expensive timestep.
inline std::int64_t auto_chunk(const HopnetGeometry& g, const TrajectoryFrames& tf,
                               std::int64_t hidden, double budget_bytes) {
  double worst = 1.0;
  for (const auto& f : tf.frames) worst = std::max(worst, timestep_activation_bytes(g, f, hidden));
  const auto t = static_cast<std::int64_t>(budget_bytes / worst);
  return std::clamp<std::int64_t>(
      t, 1, std::max<std::int64_t>(1, static_cast<std::int64_t>(tf.frames.size())));
}

/// A trajectory as consecutive chunks of `chunk` timesteps (<= 0: one chunk).
inline std::vector<TrainingItem> make_training_chunks(const HopnetGeometry& g,
                                                      const TrajectoryFrames& tf,
                                                      const Normalizer& norm, std::int64_t chunk) {
  std::vector<TrainingItem> out;
  const std::size_t T = tf.frames.size(), step = chunk <= 0 ? T : static_cast<std::size_t>(chunk);
  for (std::size_t b = 0; b < T; b += step)
    out.push_back(make_training_item(g, tf, norm, b, b + step));
  return out;
}

/// Per-timestep losses [timesteps] (node term + object term) of an item's outputs.
inline torch::Tensor timestep_losses(const HopnetOutput& out, const TrainingItem& it) {
  const auto node = ((out.a0 - it.t0).pow(2) * it.node_weight).sum(1);
  const auto obj = ((out.a4 - it.t4).pow(2) * it.object_weight).sum(1);
  return torch::zeros({it.timesteps}, node.options())
      .index_add(0, it.batch.complex.batch(0).to(node.device()), node)
      .index_add(0, it.batch.complex.batch(4).to(node.device()), obj);
}

/// The summed loss of one trajectory (divide by `timesteps` for the logged value).
inline torch::Tensor trajectory_loss(HopnetImpl& model, const TrainingItem& it,
                                     const Normalizer& norm) {
  const auto out = model.forward(it.batch, norm);
  const auto nodes = ((out.a0 - it.t0).pow(2) * it.node_weight).sum();
  return out.a4.defined() ? nodes + ((out.a4 - it.t4).pow(2) * it.object_weight).sum() : nodes;
}

namespace detail {
/// The summed loss of one chunk (and its per-timestep losses when asked).
inline torch::Tensor chunk_loss(HopnetImpl& model, const TrainingItem& c, const Normalizer& norm,
                                std::vector<double>* per_timestep) {
  if (!per_timestep) return trajectory_loss(model, c, norm);
  const auto l = timestep_losses(model.forward(c.batch, norm), c);
  const auto d = l.detach().to(torch::kCPU, torch::kDouble).contiguous();
  per_timestep->insert(per_timestep->end(), d.data_ptr<double>(), d.data_ptr<double>() + d.numel());
  return l.sum();
}
}  // namespace detail

/// Forward and backward of a trajectory given as chunks: the gradient of the summed loss is
/// accumulated into the parameters' gradients (zero them first). Returns the summed loss and,
/// when `per_timestep` is given, the per-timestep losses (all chunks, in order).
///
/// `workers` > 1 runs that many chunks at once, each on its own thread (chunk i on worker
/// i mod workers): a chunk's forward and backward are independent of the others', so the cores
/// share the whole step, elementwise and gather/scatter work included, without the per-matmul
/// synchronisation of multithreaded BLAS (give BLAS one thread then: nn::set_cpu_threads(1, 1)).
/// Each worker sums its chunks' gradients (torch::autograd::grad) and the workers' sums are added
/// in worker order, so the result does not depend on thread timing. Memory: `workers` chunks'
/// activations at once.
inline double backward_trajectory(HopnetImpl& model, const std::vector<TrainingItem>& chunks,
                                  const Normalizer& norm,
                                  std::vector<double>* per_timestep = nullptr, int workers = 1) {
  const std::size_t W = std::min(chunks.size(), static_cast<std::size_t>(std::max(1, workers)));
  if (W <= 1) {
    double total = 0;
    for (const auto& c : chunks) {
      const auto loss = detail::chunk_loss(model, c, norm, per_timestep);
      loss.backward();
      total += loss.item<double>();
    }
    return total;
  }
  const auto params = model.parameters();
  std::vector<std::vector<torch::Tensor>> sums(W, std::vector<torch::Tensor>(params.size()));
  std::vector<double> loss(chunks.size(), 0.0);
  std::vector<std::vector<double>> steps(chunks.size());
  std::vector<std::exception_ptr> errors(W);
  const auto work = [&](std::size_t w) {
    try {
      for (std::size_t i = w; i < chunks.size(); i += W) {
        const auto l =
            detail::chunk_loss(model, chunks[i], norm, per_timestep ? &steps[i] : nullptr);
        loss[i] = l.item<double>();
        const auto g = torch::autograd::grad({l}, params, {}, false, false, /*allow_unused=*/true);
        for (std::size_t k = 0; k < params.size(); ++k)
          if (g[k].defined()) sums[w][k] = sums[w][k].defined() ? sums[w][k].add_(g[k]) : g[k];
      }
    } catch (...) {
      errors[w] = std::current_exception();
    }
  };
  std::vector<std::thread> threads;
  for (std::size_t w = 1; w < W; ++w) threads.emplace_back(work, w);
  work(0);
  for (auto& t : threads) t.join();
  for (const auto& e : errors)
    if (e) std::rethrow_exception(e);
  torch::NoGradGuard no_grad;
  for (std::size_t k = 0; k < params.size(); ++k) {
    torch::Tensor g;
    for (std::size_t w = 0; w < W; ++w)
      if (sums[w][k].defined()) g = g.defined() ? g.add_(sums[w][k]) : sums[w][k];
    if (!g.defined()) continue;
    auto& grad = params[k].mutable_grad();
    if (grad.defined())
      grad.add_(g);
    else
      grad = g;
  }
  double total = 0;
  for (std::size_t i = 0; i < chunks.size(); ++i) {
    total += loss[i];
    if (per_timestep) per_timestep->insert(per_timestep->end(), steps[i].begin(), steps[i].end());
  }
  return total;
}

/// One optimizer step on one trajectory, as the reference trains: gradients reset to none (as
/// PyTorch >= 2.0's zero_grad, so a parameter the trajectory does not reach is skipped by Adam
/// rather than moved by its momentum), forward and backward by chunks, then `opt.step()`.
/// Returns the summed loss (and the per-timestep losses when asked).
/// `workers`: chunks run at once (backward_trajectory).
inline double train_step(HopnetImpl& model, torch::optim::Optimizer& opt,
                         const std::vector<TrainingItem>& chunks, const Normalizer& norm,
                         std::vector<double>* per_timestep = nullptr, int workers = 1) {
  for (auto& p : model.parameters()) p.mutable_grad() = torch::Tensor();
  const double loss = backward_trajectory(model, chunks, norm, per_timestep, workers);
  opt.step();
  return loss;
}

}  // namespace topos::models::hopnet

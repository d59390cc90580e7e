// python/src/hopnet.cpp
// topos._C.hopnet: a HOPNet checkpoint (published or topos's) with its normalisation statistics,
// a Kubric scene with its meshes, the autoregressive rollout (GIL released; Ctrl-C stops it
// between steps) and the paper's per-frame metrics, trajectories as torch tensors.
#include "convert.hpp"

#include "topos/models/hopnet/rollout.hpp"
#include "topos/models/hopnet/variants.hpp"
#include "topos/nn/device.hpp"

#include <pybind11/stl.h>

#include <cerrno>
#include <filesystem>
#include <memory>
#include <optional>

namespace topos::python {

using namespace topos::models::hopnet;

namespace {

struct Checkpoint {
  std::string path;
  Hopnet net{nullptr};
  std::optional<Normalizer> norm;
  std::optional<std::string> stats_path;
};

struct PyScene {
  Scene scene;
  std::vector<std::size_t> dynamic;  // object indices without the floor, metadata order
};

struct PyRollout {
  RolloutResult result;
  std::shared_ptr<PyScene> scene;
};

// [frames, dynamic objects, width] from per-frame (objects x width) matrices.
at::Tensor trajectory(const std::vector<Poses>& poses, const PyScene& s, bool quaternions) {
  const Index F = static_cast<Index>(poses.size()), D = static_cast<Index>(s.dynamic.size()),
              W = quaternions ? 4 : 3;
  at::Tensor t = at::empty({F, D, W}, at::kDouble);
  double* p = t.data_ptr<double>();
  for (Index f = 0; f < F; ++f) {
    const RowMatrix& m = quaternions ? poses[static_cast<std::size_t>(f)].quaternions
                                     : poses[static_cast<std::size_t>(f)].positions;
    for (Index d = 0; d < D; ++d)
      for (Index c = 0; c < W; ++c)
        *p++ = m(static_cast<Eigen::Index>(s.dynamic[static_cast<std::size_t>(d)]), c);
  }
  return t;
}

std::vector<Poses> ground_truth(const PyScene& s) {
  std::vector<Poses> p;
  for (Index f = 0; f < s.scene.num_frames; ++f) p.push_back(scene_poses(s.scene, f));
  return p;
}

at::Tensor vector_tensor(const std::vector<double>& v) {
  at::Tensor t = at::empty({static_cast<Index>(v.size())}, at::kDouble);
  std::copy(v.begin(), v.end(), t.data_ptr<double>());
  return t;
}

py::dict metrics_dict(const RolloutMetrics& m) {
  py::dict d;
  d["pos_rmse"] = vector_tensor(m.pos_rmse);
  d["pos_mae"] = vector_tensor(m.pos_mae);
  d["ori_rmse"] = vector_tensor(m.ori_rmse);
  d["ori_mae"] = vector_tensor(m.ori_mae);
  return d;
}

// Poses of every object (the floor at its fixed pose) from [frames, dynamic, 3|4] tensors.
std::vector<Poses> poses_from(const at::Tensor& positions, const at::Tensor& quaternions,
                              const PyScene& s) {
  const auto check = [&](const at::Tensor& t, const char* arg, Index w) {
    if (t.layout() != at::kStrided)
      throw py::type_error(std::string("metrics(") + arg + "): expected a dense tensor");
    if (t.dim() != 3 || t.size(1) != static_cast<Index>(s.dynamic.size()) || t.size(2) != w)
      throw py::value_error(std::string("metrics(") + arg + "): expected shape (frames, " +
                            std::to_string(s.dynamic.size()) + ", " + std::to_string(w) +
                            ") for this scene's objects, got " + c10::str(t.sizes()));
    if (!at::isFloatingType(t.scalar_type()))
      throw py::type_error(std::string("metrics(") + arg + "): expected a floating tensor, got " +
                           c10::toString(t.scalar_type()));
  };
  check(positions, "positions", 3);
  check(quaternions, "quaternions", 4);
  if (positions.size(0) != quaternions.size(0))
    throw py::value_error("metrics: positions have " + std::to_string(positions.size(0)) +
                          " frames, quaternions " + std::to_string(quaternions.size(0)));
  const at::Tensor p = positions.to(at::kCPU, at::kDouble).contiguous(),
                   q = quaternions.to(at::kCPU, at::kDouble).contiguous();
  const Poses fixed = scene_poses(s.scene, 0);  // the floor's pose (it never moves)
  std::vector<Poses> out;
  const Index F = p.size(0), D = static_cast<Index>(s.dynamic.size());
  const double* pp = p.data_ptr<double>();
  const double* qp = q.data_ptr<double>();
  for (Index f = 0; f < F; ++f) {
    Poses x = fixed;
    for (Index d = 0; d < D; ++d) {
      const auto o = static_cast<Eigen::Index>(s.dynamic[static_cast<std::size_t>(d)]);
      for (int c = 0; c < 3; ++c) x.positions(o, c) = pp[(f * D + d) * 3 + c];
      for (int c = 0; c < 4; ++c) x.quaternions(o, c) = qp[(f * D + d) * 4 + c];
    }
    out.push_back(std::move(x));
  }
  return out;
}

// A path argument: str or os.PathLike ("" for None).
std::string path_str(const py::object& o, const char* arg) {
  if (o.is_none()) return {};
  if (!py::isinstance<py::str>(o) && !py::hasattr(o, "__fspath__"))
    throw py::type_error(std::string(arg) + " must be a path (str or os.PathLike), got " +
                         type_name(o));
  return py::str(py::module_::import("os").attr("fspath")(o));
}

// A path to read ("" for None); one that does not exist is Python's FileNotFoundError.
std::string path_arg(const py::object& o, const char* arg) {
  const std::string p = path_str(o, arg);
  if (!p.empty() && !std::filesystem::exists(p)) {
    PyErr_SetObject(PyExc_FileNotFoundError,
                    py::make_tuple(ENOENT, std::string(arg) + ": no such file or folder", p).ptr());
    throw py::error_already_set();
  }
  return p;
}

}  // namespace

void bind_hopnet(py::module_& parent) {
  py::module_ m = parent.def_submodule("hopnet", "HOPNet (topos/models/hopnet/)");

  py::class_<Checkpoint, std::shared_ptr<Checkpoint>>(m, "Checkpoint",
                                                      "A HOPNet checkpoint, opened")
      .def(py::init([](const py::object& path_obj, const py::object& stats_obj,
                       const py::object& mode, const py::object& activation,
                       const py::object& collision_radius, const std::string& device) {
             auto c = std::make_shared<Checkpoint>();
             c->path = path_arg(path_obj, "checkpoint");
             const std::string stats = path_arg(stats_obj, "stats");
             CheckpointOverrides ov;
             if (!mode.is_none()) ov.mode = feature_mode_from_string(mode.cast<std::string>());
             if (!collision_radius.is_none()) {
               ov.collision_radius = collision_radius.cast<double>();
               if (!(*ov.collision_radius > 0))
                 throw py::value_error("collision_radius must be positive");
             }
             const torch::Device dev = nn::device_from_string(device);
             py::gil_scoped_release release;
             const auto dict = nn::read_tensor_dict(c->path);
             if (!activation.is_none()) {
               py::gil_scoped_acquire gil;
               ov.activation = nn::activation_from_string(activation.cast<std::string>());
             } else if (is_reference_checkpoint(dict)) {
               ov.activation = activation_from_reference_name(c->path);
             }
             c->net = load_hopnet(dict, c->path, ov);
             c->net->eval();
             c->net->to(dev);
             if (!stats.empty()) {
               const auto s = read_stats_json(stats);
               check_stats_fit(c->net->options, s, stats);
               c->norm.emplace(s);
               c->stats_path = stats;
             }
             return c;
           }),
           py::arg("path"), py::arg("stats") = py::none(), py::kw_only(),
           py::arg("mode") = py::none(), py::arg("activation") = py::none(),
           py::arg("collision_radius") = py::none(), py::arg("device") = "cpu")
      .def_property_readonly("path", [](const Checkpoint& c) { return c.path; })
      .def_property_readonly("stats", [](const Checkpoint& c) { return c.stats_path; })
      .def_property_readonly("variant",
                             [](const Checkpoint& c) { return variant_name(c.net->options); })
      .def_property_readonly(
          "mode", [](const Checkpoint& c) { return std::string(to_string(c.net->options.mode())); })
      .def_property_readonly(
          "activation",
          [](const Checkpoint& c) { return nn::activation_name(c.net->options.activation()); })
      .def_property_readonly("collision_radius",
                             [](const Checkpoint& c) { return c.net->options.collision_radius(); })
      .def_property_readonly(
          "options",
          [](const Checkpoint& c) {
            return py::module_::import("json").attr("loads")(c.net->options.to_json().dump());
          })
      .def_property_readonly("num_parameters",
                             [](const Checkpoint& c) { return c.net->num_parameters(); })
      .def_property(
          "step_threads", [](const Checkpoint& c) { return c.net->step_threads(); },
          [](Checkpoint& c, int n) { c.net->step_threads(n); },
          "threads that the network's independent steps share in a rollout (1: the calling "
          "thread alone; 2 on two free cores; the same poses); below 1 is a ValueError")
      .def(
          "state_dict",
          [](const Checkpoint& c) {
            py::dict d;
            for (const auto& p : c.net->named_parameters())
              d[py::str(p.key())] = p.value().detach();
            return d;
          },
          "the parameters by topos's names (the model's own memory, detached)")
      .def(
          "save",
          [](const Checkpoint& c, const py::object& path) {
            const std::string p = path_str(path, "path");
            py::gil_scoped_release release;
            save_hopnet(*c.net, p);
          },
          py::arg("path"), "a topos checkpoint (torch.load opens it)")
      .def("__repr__", [](const Checkpoint& c) {
        return "Checkpoint('" + c.path + "', variant " + variant_name(c.net->options) + ", mode " +
               to_string(c.net->options.mode()) +
               (c.norm ? ", stats '" + *c.stats_path + "'" : "") + ")";
      });

  py::class_<PyScene, std::shared_ptr<PyScene>>(m, "Scene", "A Kubric scene with its meshes")
      .def(py::init([](const py::object& path, const py::object& assets) {
             const std::string p = path_arg(path, "scene"), a = path_arg(assets, "assets");
             py::gil_scoped_release release;
             auto s = std::make_shared<PyScene>();
             MeshLibrary lib(a);
             s->scene = make_scene(data::read_kubric_metadata(p), lib);
             for (std::size_t o = 0; o < s->scene.num_objects(); ++o)
               if (!s->scene.objects[o].is_floor) s->dynamic.push_back(o);
             return s;
           }),
           py::arg("path"), py::arg("assets") = py::none(),
           "metadata.json or its folder; assets: KuBasic meshes (<shape>/collision_geometry.obj), "
           "built-in shapes when None")
      .def_property_readonly("source", [](const PyScene& s) { return s.scene.source; })
      .def_property_readonly("num_frames", [](const PyScene& s) { return s.scene.num_frames; })
      .def_property_readonly("num_objects", [](const PyScene& s) { return s.dynamic.size(); })
      .def_property_readonly("shapes",
                             [](const PyScene& s) {
                               std::vector<std::string> v;
                               for (auto o : s.dynamic) v.push_back(s.scene.objects[o].shape);
                               return v;
                             })
      .def_property_readonly("masses",
                             [](const PyScene& s) {
                               std::vector<double> v;
                               for (auto o : s.dynamic) v.push_back(s.scene.objects[o].mass);
                               return vector_tensor(v);
                             })
      .def_property_readonly(
          "positions", [](const PyScene& s) { return trajectory(ground_truth(s), s, false); },
          "ground truth, [frames, objects, 3] (m)")
      .def_property_readonly(
          "quaternions", [](const PyScene& s) { return trajectory(ground_truth(s), s, true); },
          "ground truth, [frames, objects, 4] (w, x, y, z)")
      .def("__repr__", [](const PyScene& s) {
        return "Scene('" + s.scene.source + "', " + std::to_string(s.dynamic.size()) +
               " objects, " + std::to_string(s.scene.num_frames) + " frames)";
      });

  py::class_<PyRollout>(m, "Rollout", "A rollout's trajectory (frames 0..3: the ground truth)")
      .def_property_readonly(
          "positions",
          [](const PyRollout& r) { return trajectory(r.result.poses, *r.scene, false); },
          "[frames, objects, 3] (m), the scene's objects in metadata order")
      .def_property_readonly(
          "quaternions",
          [](const PyRollout& r) { return trajectory(r.result.poses, *r.scene, true); },
          "[frames, objects, 4] (w, x, y, z)")
      .def_property_readonly(
          "invalid_ratio", [](const PyRollout& r) { return vector_tensor(r.result.invalid_ratio); })
      .def_property_readonly("seconds", [](const PyRollout& r) { return r.result.seconds; })
      .def_property_readonly("num_frames", [](const PyRollout& r) { return r.result.num_frames(); })
      .def(
          "metrics",
          [](const PyRollout& r) {
            return metrics_dict(rollout_metrics(r.result.poses, r.scene->scene));
          },
          "the paper's per-frame errors against the ground truth: pos_rmse, pos_mae (m), ori_rmse, "
          "ori_mae (degrees), float64 tensors indexed by frame");

  m.def(
      "rollout",
      [](const Checkpoint& c, std::shared_ptr<PyScene> scene, int steps,
         const py::object& collisions, const py::object& on_step, const std::string& cpu_gemm) {
        if (!c.norm)
          throw py::value_error("rollout: the checkpoint " + c.path +
                                " was opened without normalisation statistics; pass stats=... "
                                "(e.g. movia.json) to topos.hopnet.Checkpoint");
        if (steps < 1) throw py::value_error("rollout: steps must be positive");
        // The library of its products for this rollout only (hopnet rollout's --cpu-gemm).
        const nn::CpuGemm before = nn::get_cpu_gemm();
        struct Restore {
          nn::CpuGemm g;
          ~Restore() { nn::set_cpu_gemm(g); }
        } restore{before};
        nn::set_cpu_gemm(nn::cpu_gemm_for_rollout(cpu_gemm, before,
                                                  c.net->options.mode() == FeatureMode::reference));
        RolloutOptions opt;
        opt.steps = steps;
        opt.collision_radius = c.net->options.collision_radius();
        std::string coll;
        if (py::isinstance<py::str>(collisions) && collisions.cast<std::string>() == "auto") {
          if (c.net->options.mode() == FeatureMode::reference)
            coll = collisions_json_beside(scene->scene.source);
        } else {
          coll = path_arg(collisions, "collisions");
        }
        PyRollout r;
        r.scene = scene;
        {
          py::gil_scoped_release release;
          if (!coll.empty()) {
            const auto all = read_collisions_json(coll);
            auto it = all.find(3);
            if (it == all.end()) throw data::DataError(coll + ": has no frame 3");
            opt.first_contacts = it->second;
          }
          // Between steps: the GIL for Ctrl-C and the caller's progress callback.
          opt.on_step = [&](int done, int total) {
            py::gil_scoped_acquire gil;
            if (PyErr_CheckSignals() != 0) throw py::error_already_set();
            if (!on_step.is_none()) on_step(done, total);
          };
          const auto g = make_geometry(scene->scene, c.net->options.lifting());
          Hopnet net = c.net;  // the holder shares the module: the rollout runs it
          r.result = rollout(*net, *c.norm, scene->scene, g, opt);
        }
        return r;
      },
      py::arg("checkpoint"), py::arg("scene"), py::kw_only(), py::arg("steps") = 102,
      py::arg("collisions") = "auto", py::arg("on_step") = py::none(), py::arg("cpu_gemm") = "auto",
      "the autoregressive rollout from ground-truth frames 0..3 (collisions: 'auto' takes the "
      "first step's contacts from collisions.json beside the scene in reference mode; None "
      "detects them; or a path). cpu_gemm: the library of its float32 products for this rollout "
      "('blas', 'onednn', 'topos'; 'auto': topos.nn.set_cpu_gemm's in reference mode, which "
      "with BLAS gives the reference's digits; oneDNN in native mode)");

  m.def(
      "metrics",
      [](const at::Tensor& positions, const at::Tensor& quaternions,
         std::shared_ptr<PyScene> scene) {
        return metrics_dict(
            rollout_metrics(poses_from(positions, quaternions, *scene), scene->scene));
      },
      py::arg("positions"), py::arg("quaternions"), py::arg("scene"),
      "the paper's per-frame errors of a trajectory ([frames, objects, 3] and [frames, objects, "
      "4], frame 0 first) against the scene's ground truth");
}

}  // namespace topos::python

// Tests of topos/models/hopnet: the frozenset edge direction, features, incidences and outputs
// of the first two rollout steps against the reference's golden arrays (MOVi-A scene 8,
// modela_seed2_e39), the 102-step rollout's metrics, native mode, normalisation statistics,
// checkpoints (import, topos save/load, every error), and the role-mixing buffer.
#include "support/torch_prelude.hpp"

#include "support/reference.hpp"
#include "topos/data/npy.hpp"
#include "topos/models/hopnet/rollout.hpp"

#include <filesystem>
#include <random>

using namespace topos;
using namespace topos::hopnet;
namespace fs = std::filesystem;

namespace {

struct Golden {
  fs::path ref, dir;
  Scene scene;
  Golden(const char* what) : ref(test::reference_dir(what)), dir(ref / "data" / "golden" / "movi-a-8") {
    MeshLibrary lib(ref / "data" / "kubasic");
    scene = make_scene(data::read_kubric_metadata(ref / "data" / "movi-a" / "8"), lib);
  }
  std::vector<double> array(const std::string& rel, std::vector<std::int64_t>* shape = nullptr) const {
    const auto a = data::read_npy((dir / rel).string());
    if (shape) *shape = a.shape;
    return a.as<double>();
  }
  Normalizer normalizer() const { return Normalizer(read_stats_json((ref / "data" / "normalization" / "movia.json").string())); }
  Hopnet model() const { return load_hopnet((ref / "data" / "checkpoints" / "modela_seed2_e39.pt").string()); }
  std::string checkpoint() const { return (ref / "data" / "checkpoints" / "modela_seed2_e39.pt").string(); }
};

// Max |a-b| / max(|b|, floor) over all entries, with the shapes checked.
void require_close(const torch::Tensor& got, const std::vector<double>& want, const std::vector<std::int64_t>& shape, double rel, double abs, const std::string& what) {
  INFO(what);
  REQUIRE(got.dim() == static_cast<std::int64_t>(shape.size()));
  for (std::size_t d = 0; d < shape.size(); ++d) REQUIRE(got.size(static_cast<std::int64_t>(d)) == shape[d]);
  const auto g = got.to(torch::kDouble).contiguous();
  const double* p = g.data_ptr<double>();
  std::int64_t bad = 0;
  double worst = 0;
  for (std::size_t i = 0; i < want.size(); ++i) {
    const double err = std::abs(p[i] - want[i]);
    if (err > abs && err > rel * std::abs(want[i])) ++bad, worst = std::max(worst, err);
  }
  INFO(bad << " entries out of tolerance, worst abs error " << worst);
  REQUIRE(bad == 0);
}

Poses poses_from(const std::vector<double>& pos, const std::vector<double>& quat, std::int64_t O) {
  Poses p;
  p.positions = Eigen::Map<const RowMatrix>(pos.data(), O, 3);
  p.quaternions = Eigen::Map<const RowMatrix>(quat.data(), O, 4);
  return p;
}

void check_incidence(const Golden& G, const std::string& step, const std::string& name, const nn::TensorNeighborhood& n, bool rank_x_is_source) {
  std::vector<std::int64_t> shape;
  const auto idx = G.array(step + "/" + name + "_indices.npy", &shape);
  const auto vals = G.array(step + "/" + name + "_values.npy");
  const auto sz = G.array(step + "/" + name + "_shape.npy");
  INFO(step << " " << name);
  REQUIRE(static_cast<std::int64_t>(sz[0]) == (rank_x_is_source ? n.num_source : n.num_target));
  REQUIRE(static_cast<std::int64_t>(sz[1]) == (rank_x_is_source ? n.num_target : n.num_source));
  std::set<std::tuple<std::int64_t, std::int64_t, int>> want, got;
  const auto nnz = shape[1];
  for (std::int64_t k = 0; k < nnz; ++k) want.insert({static_cast<std::int64_t>(idx[static_cast<std::size_t>(k)]), static_cast<std::int64_t>(idx[static_cast<std::size_t>(nnz + k)]), static_cast<int>(vals[static_cast<std::size_t>(k)])});
  for (std::int64_t k = 0; k < n.nnz(); ++k) {
    const auto s = n.source[k].item<std::int64_t>(), t = n.target[k].item<std::int64_t>();
    const int v = n.roles.defined() ? n.roles[k].item<int>() : 1;
    got.insert(rank_x_is_source ? std::make_tuple(s, t, v) : std::make_tuple(t, s, v));
  }
  REQUIRE((got == want));
}

}  // namespace

TEST_CASE("the frozenset rule gives the reference's edge directions and order on MOVi-A scene 8", "[hopnet][reference]") {
  Golden G("hopnet edge directions");
  const auto g = make_geometry(G.scene, FeatureMode::reference);
  std::vector<std::int64_t> shape;
  const auto e = G.array("geometry/edges_directed.npy", &shape);
  REQUIRE(shape == std::vector<std::int64_t>{524, 2});
  REQUIRE(g.num_edges() == 524);
  REQUIRE(g.num_nodes() == 183);
  int swapped = 0;
  for (std::size_t i = 0; i < 524; ++i) {
    REQUIRE(g.edges[i][0] == static_cast<std::int64_t>(e[2 * i]));
    REQUIRE(g.edges[i][1] == static_cast<std::int64_t>(e[2 * i + 1]));
    swapped += g.edges[i][0] > g.edges[i][1];
  }
  REQUIRE(swapped == 225);
  // Native mode keeps the mesh's own (first-seen) direction.
  const auto n = make_geometry(G.scene, FeatureMode::native);
  for (std::size_t i = 0; i < 524; ++i) REQUIRE(std::set<std::int64_t>{n.edges[i][0], n.edges[i][1]} == std::set<std::int64_t>{g.edges[i][0], g.edges[i][1]});
}

TEST_CASE("the published MOVi-A model has 707,078 parameters and loads by the reference's names", "[hopnet][reference]") {
  Golden G("hopnet checkpoint import");
  REQUIRE(Hopnet()->num_parameters() == 707078);
  auto model = G.model();
  REQUIRE(model->num_parameters() == 707078);
  REQUIRE(model->options.hidden() == 128);
  REQUIRE(model->options.num_layers() == 1);
  REQUIRE(model->options.mlp_layers() == 2);
  const auto dict = nn::read_tensor_dict(G.checkpoint());
  REQUIRE(dict.size() == 116);
  REQUIRE(torch::equal(model->module("layer0_2to3")->named_parameters()["0.weight"], dict.at("_HOPNet__layers.0._HOPNet_Layer__mlp_processor_2to3.0.weight")));

  Hopnet fresh;
  auto missing = dict;
  missing.erase("_HOPNet__mlp_encoder_3.2.bias");
  REQUIRE_THROWS_WITH(load_checkpoint(*fresh, missing, "x.pt"), Catch::Contains("missing tensor '_HOPNet__mlp_encoder_3.2.bias'"));
  auto extra = dict;
  extra["_HOPNet__mlp_encoder_9.0.weight"] = torch::zeros({1});
  REQUIRE_THROWS_WITH(load_checkpoint(*fresh, extra, "x.pt"), Catch::Contains("unexpected tensor '_HOPNet__mlp_encoder_9.0.weight'"));
  auto bad = dict;
  bad["_HOPNet__mlp_decoder_4.2.weight"] = torch::zeros({4, 128});
  REQUIRE_THROWS_WITH(load_checkpoint(*fresh, bad, "x.pt"), Catch::Contains("'_HOPNet__mlp_decoder_4.2.weight' has shape"));

  // topos's own checkpoint round trip keeps every tensor and the configuration.
  const auto path = (fs::temp_directory_path() / "topos_hopnet_roundtrip.pt").string();
  save_hopnet(*model, path);
  auto back = load_hopnet(path);
  REQUIRE(back->options.to_json() == model->options.to_json());
  for (const auto& p : model->named_parameters()) REQUIRE(torch::equal(p.value(), back->named_parameters()[p.key()]));
  fs::remove(path);
}

TEST_CASE("step000 and step001 of the reference rollout: features, incidences and outputs match the golden arrays", "[hopnet][reference]") {
  Golden G("hopnet golden steps");
  const auto g = make_geometry(G.scene, FeatureMode::reference);
  const auto norm = G.normalizer();
  auto model = G.model();
  model->eval();
  const auto collisions = read_collisions_json((G.ref / "data" / "movi-a" / "8" / "collisions.json").string());
  const Poses first = scene_poses(G.scene, 0);
  std::vector<Poses> p{first, scene_poses(G.scene, 1), scene_poses(G.scene, 2), scene_poses(G.scene, 3)};

  for (int step = 0; step < 2; ++step) {
    const std::string dir = step == 0 ? "step000" : "step001";
    const std::size_t t = p.size() - 1;
    const auto contacts = step == 0 ? collisions.at(3) : detect_contacts(g, pose_objects(g, p[t]), 0.1);
    HopnetFrame frame;
    const Poses next = predict_next(*model, norm, g, first, p[t - 2], p[t - 1], p[t], contacts, &frame);
    const HopnetBatch batch = make_batch({{&g, &frame}}, norm);
    std::vector<std::int64_t> shape;
    const std::map<std::string, const RowMatrix*> raw{{"x0", &frame.x0}, {"x1", &frame.x1}, {"x2", &frame.x2}, {"x3", &frame.x3}, {"x4", &frame.x4}};
    for (const auto& [k, m] : raw) {
      // The reference computes in double and stores float32.
      const auto want_raw = G.array(dir + "/" + k + "_raw.npy", &shape);
      require_close(Normalizer::to_tensor(*m), want_raw, shape, 1e-6, 1e-7, dir + " " + k + "_raw");
      const auto want = G.array(dir + "/" + k + ".npy", &shape);
      require_close(batch.inputs.at(k), want, shape, 1e-6, 1e-6, dir + " " + k + " (normalised)");
    }
    check_incidence(G, dir, "b04", batch.complex.neighborhood("B04"), true);
    check_incidence(G, dir, "b02", batch.complex.neighborhood("B02"), true);
    check_incidence(G, dir, "b12", batch.complex.neighborhood("B12"), true);
    check_incidence(G, dir, "b24", batch.complex.neighborhood("B24"), true);
    check_incidence(G, dir, "b23", batch.complex.neighborhood("B32"), false);

    torch::NoGradGuard ng;
    const auto out = model->forward(batch, norm);
    require_close(out.a0, G.array(dir + "/out0.npy", &shape), shape, 1e-4, 2e-6, dir + " out0");
    require_close(out.a4, G.array(dir + "/out4.npy", &shape), shape, 1e-4, 2e-6, dir + " out4");
    std::vector<std::int64_t> s2;
    const auto pos = G.array(dir + "/pred_obj_pos.npy", &s2);
    const auto quat = G.array(dir + "/pred_obj_quat.npy");
    const Poses want_next = poses_from(pos, quat, 4);
    for (int o = 0; o < 3; ++o) {
      REQUIRE((next.positions.row(o) - want_next.positions.row(o)).norm() < 1e-6);
      const double dot = std::abs(next.quaternions.row(o).dot(want_next.quaternions.row(o)));
      REQUIRE(dot > 1 - 1e-9);
    }
    p.push_back(next);
  }
}

TEST_CASE("the 102-step reference rollout of MOVi-A scene 8 lands within 2% of the golden metrics", "[hopnet][reference][rollout]") {
  Golden G("hopnet golden rollout");
  const auto g = make_geometry(G.scene, FeatureMode::reference);
  const auto norm = G.normalizer();
  auto model = G.model();
  model->eval();
  RolloutOptions opt;
  opt.first_contacts = read_collisions_json((G.ref / "data" / "movi-a" / "8" / "collisions.json").string()).at(3);
  const auto r = rollout(*model, norm, G.scene, g, opt);
  REQUIRE(r.num_frames() == 106);
  const auto m = rollout_metrics(r.poses, G.scene);
  const std::map<int, std::pair<double, double>> golden{{25, {0.026131, 0.979}}, {50, {0.083279, 2.321}}, {75, {0.144398, 4.496}}, {100, {0.271126, 6.382}}};
  for (const auto& [f, want] : golden) {
    INFO("frame " << f << ": pos RMSE " << m.pos_rmse[static_cast<std::size_t>(f)] << " (golden " << want.first << "), ori MAE " << m.ori_mae[static_cast<std::size_t>(f)] << " (golden " << want.second << ")");
    CHECK(std::abs(m.pos_rmse[static_cast<std::size_t>(f)] / want.first - 1) < 0.02);
    CHECK(std::abs(m.ori_mae[static_cast<std::size_t>(f)] / want.second - 1) < 0.02);
  }
  // Frames 0..3 are the ground truth.
  for (int f = 0; f < 4; ++f) REQUIRE(m.pos_rmse[static_cast<std::size_t>(f)] == 0.0);
}

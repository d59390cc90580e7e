// Tests of topos/models/hopnet: the frozenset edge direction, features, incidences and outputs
// of the first two rollout steps against the reference's golden arrays (MOVi-A scene 8,
// modela_seed2_e39), the 102-step rollout's metrics, native mode (with bfloat16 products too),
// normalisation statistics, checkpoints (import, topos save/load, every error), the role-mixing
// buffer, and training:
// chunked gradients, and the reference's loss, gradient and Adam steps (train-golden).
#include "support/torch_prelude.hpp"

#include "support/fast_paths.hpp"
#include "support/reference.hpp"
#include "support/scenes.hpp"
#include "topos/data/npy.hpp"
#include "topos/models/hopnet/training.hpp"
#include "topos/models/hopnet/variants.hpp"

#include <filesystem>
#include <numeric>
#include <random>

using namespace topos;
using namespace topos::models::hopnet;
namespace fs = std::filesystem;

namespace {

struct Golden {
  fs::path ref, dir;
  Scene scene;
  Golden(const char* what)
      : ref(test::reference_dir(what)), dir(ref / "data" / "golden" / "movi-a-8") {
    MeshLibrary lib(ref / "data" / "kubasic");
    scene = make_scene(data::read_kubric_metadata(ref / "data" / "movi-a" / "8"), lib);
  }
  std::vector<double> array(const std::string& rel,
                            std::vector<std::int64_t>* shape = nullptr) const {
    const auto a = data::read_npy((dir / rel).string());
    if (shape) *shape = a.shape;
    return a.as<double>();
  }
  Normalizer normalizer() const {
    return Normalizer(read_stats_json((ref / "data" / "normalization" / "movia.json").string()));
  }
  std::string checkpoint() const {
    return (ref / "data" / "checkpoints" / "modela_seed2_e39.pt").string();
  }
  /// The published modela weights, in eval mode.
  Hopnet model() const {
    auto m = load_hopnet(checkpoint());
    m->eval();
    return m;
  }
};

// Max |a-b| / max(|b|, floor) over all entries, with the shapes checked.
void require_close(const torch::Tensor& got, const std::vector<double>& want,
                   const std::vector<std::int64_t>& shape, double rel, double abs,
                   const std::string& what) {
  INFO(what);
  REQUIRE(got.dim() == static_cast<std::int64_t>(shape.size()));
  for (std::size_t d = 0; d < shape.size(); ++d)
    REQUIRE(got.size(static_cast<std::int64_t>(d)) == shape[d]);
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

void check_incidence(const Golden& G, const std::string& step, const std::string& name,
                     const nn::TensorNeighborhood& n, bool rank_x_is_source) {
  std::vector<std::int64_t> shape;
  const auto idx = G.array(step + "/" + name + "_indices.npy", &shape);
  const auto vals = G.array(step + "/" + name + "_values.npy");
  const auto sz = G.array(step + "/" + name + "_shape.npy");
  INFO(step << " " << name);
  REQUIRE(static_cast<std::int64_t>(sz[0]) == (rank_x_is_source ? n.num_source : n.num_target));
  REQUIRE(static_cast<std::int64_t>(sz[1]) == (rank_x_is_source ? n.num_target : n.num_source));
  std::set<std::tuple<std::int64_t, std::int64_t, int>> want, got;
  const auto nnz = shape[1];
  for (std::int64_t k = 0; k < nnz; ++k)
    want.insert({static_cast<std::int64_t>(idx[static_cast<std::size_t>(k)]),
                 static_cast<std::int64_t>(idx[static_cast<std::size_t>(nnz + k)]),
                 static_cast<int>(vals[static_cast<std::size_t>(k)])});
  for (std::int64_t k = 0; k < n.nnz(); ++k) {
    const auto s = n.source[k].item<std::int64_t>(), t = n.target[k].item<std::int64_t>();
    const int v = n.roles.defined() ? n.roles[k].item<int>() : 1;
    got.insert(rank_x_is_source ? std::make_tuple(s, t, v) : std::make_tuple(t, s, v));
  }
  REQUIRE((got == want));
}

}  // namespace

TEST_CASE("the frozenset rule gives the reference's edge directions and order on MOVi-A scene 8",
          "[hopnet][reference]") {
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
  for (std::size_t i = 0; i < 524; ++i)
    REQUIRE(std::set<std::int64_t>{n.edges[i][0], n.edges[i][1]} ==
            std::set<std::int64_t>{g.edges[i][0], g.edges[i][1]});
}

TEST_CASE("the published MOVi-A model has 707,078 parameters and loads by the reference's names",
          "[hopnet][reference]") {
  Golden G("hopnet checkpoint import");
  REQUIRE(Hopnet()->num_parameters() == 707078);
  auto model = G.model();
  REQUIRE(model->num_parameters() == 707078);
  REQUIRE(model->options.hidden() == 128);
  REQUIRE(model->options.num_layers() == 1);
  REQUIRE(model->options.mlp_layers() == 2);
  const auto dict = nn::read_tensor_dict(G.checkpoint());
  REQUIRE(dict.size() == 116);
  REQUIRE(torch::equal(model->mlp("modules.layer0_2to3")->named_parameters()["0.weight"],
                       dict.at("_HOPNet__layers.0._HOPNet_Layer__mlp_processor_2to3.0.weight")));

  Hopnet fresh;
  auto missing = dict;
  missing.erase("_HOPNet__mlp_encoder_3.2.bias");
  REQUIRE_THROWS_WITH(load_checkpoint(*fresh, missing, "x.pt"),
                      Catch::Contains("missing tensor '_HOPNet__mlp_encoder_3.2.bias'"));
  auto extra = dict;
  extra["_HOPNet__mlp_encoder_9.0.weight"] = torch::zeros({1});
  REQUIRE_THROWS_WITH(load_checkpoint(*fresh, extra, "x.pt"),
                      Catch::Contains("unexpected tensor '_HOPNet__mlp_encoder_9.0.weight'"));
  auto bad = dict;
  bad["_HOPNet__mlp_decoder_4.2.weight"] = torch::zeros({4, 128});
  REQUIRE_THROWS_WITH(load_checkpoint(*fresh, bad, "x.pt"),
                      Catch::Contains("'_HOPNet__mlp_decoder_4.2.weight' has shape"));

  // topos's own checkpoint round trip keeps every tensor and the configuration.
  const auto path = (fs::temp_directory_path() / "topos_hopnet_roundtrip.pt").string();
  save_hopnet(*model, path);
  auto back = load_hopnet(path);
  REQUIRE(back->options.to_json() == model->options.to_json());
  for (const auto& p : model->named_parameters())
    REQUIRE(torch::equal(p.value(), back->named_parameters()[p.key()]));
  fs::remove(path);
}

TEST_CASE(
    "step000 and step001 of the reference rollout: features, incidences and outputs match the "
    "golden arrays",
    "[hopnet][reference]") {
  Golden G("hopnet golden steps");
  const auto g = make_geometry(G.scene, FeatureMode::reference);
  const auto norm = G.normalizer();
  auto model = G.model();
  const auto collisions =
      read_collisions_json((G.ref / "data" / "movi-a" / "8" / "collisions.json").string());
  const Poses first = scene_poses(G.scene, 0);
  std::vector<Poses> p{first, scene_poses(G.scene, 1), scene_poses(G.scene, 2),
                       scene_poses(G.scene, 3)};

  for (int step = 0; step < 2; ++step) {
    const std::string dir = step == 0 ? "step000" : "step001";
    const std::size_t t = p.size() - 1;
    const auto contacts =
        step == 0 ? collisions.at(3) : detect_contacts(g, pose_objects(g, p[t]), 0.1);
    HopnetFrame frame;
    const Poses next =
        predict_next(*model, norm, g, first, p[t - 2], p[t - 1], p[t], contacts, &frame);
    const HopnetBatch batch = make_batch({{&g, &frame}}, norm);
    std::vector<std::int64_t> shape;
    const std::map<std::string, const RowMatrix*> raw{{"x0", &frame.x0},
                                                      {"x1", &frame.x1},
                                                      {"x2", &frame.x2},
                                                      {"x3", &frame.x3},
                                                      {"x4", &frame.x4}};
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

TEST_CASE("the 102-step reference rollout of MOVi-A scene 8 lands within 2% of the golden metrics",
          "[hopnet][reference][rollout]") {
  Golden G("hopnet golden rollout");
  const auto g = make_geometry(G.scene, FeatureMode::reference);
  const auto norm = G.normalizer();
  auto model = G.model();
  RolloutOptions opt;
  opt.first_contacts =
      read_collisions_json((G.ref / "data" / "movi-a" / "8" / "collisions.json").string()).at(3);
  const std::map<int, std::pair<double, double>> golden{{25, {0.026131, 0.979}},
                                                        {50, {0.083279, 2.321}},
                                                        {75, {0.144398, 4.496}},
                                                        {100, {0.271126, 6.382}}};
  // With each library of float32 products (hopnet rollout's --cpu-gemm): the same sums in
  // another order give the same metrics to about five digits.
  struct Restore {  // the setting is process-wide: back to BLAS even if this throws
    ~Restore() { nn::set_cpu_gemm(nn::CpuGemm::blas); }
  } restore;
  std::vector<nn::CpuGemm> gemms{nn::CpuGemm::blas, nn::CpuGemm::topos};
  if (nn::onednn_gemm_available()) gemms.push_back(nn::CpuGemm::onednn);
  std::map<int, double> blas;  // BLAS's position RMSE by frame (the first library run)
  for (const auto gemm : gemms) {
    INFO("cpu gemm " << nn::to_string(gemm));
    nn::set_cpu_gemm(gemm);
    const auto r = rollout(*model, norm, G.scene, g, opt);
    REQUIRE(r.num_frames() == 106);
    const auto m = rollout_metrics(r.poses, G.scene);
    for (const auto& [f, want] : golden) {
      const auto at = static_cast<std::size_t>(f);
      INFO("frame " << f << ": pos RMSE " << m.pos_rmse[at] << " (golden " << want.first
                    << "), ori MAE " << m.ori_mae[at] << " (golden " << want.second << ")");
      CHECK(std::abs(m.pos_rmse[at] / want.first - 1) < 0.02);
      CHECK(std::abs(m.ori_mae[at] / want.second - 1) < 0.02);
      if (gemm == nn::CpuGemm::blas) blas[f] = m.pos_rmse[at];
      CHECK(std::abs(m.pos_rmse[at] / blas.at(f) - 1) < 1e-3);
    }
    // Frames 0..3 are the ground truth.
    for (int f = 0; f < 4; ++f) REQUIRE(m.pos_rmse[static_cast<std::size_t>(f)] == 0.0);
    // Two step threads (a parallel group's steps shared with a helper): the same poses, bit for
    // bit.
    model->step_threads(2);
    const auto two = rollout(*model, norm, G.scene, g, opt);
    model->step_threads(1);
    REQUIRE(two.poses.size() == r.poses.size());
    for (std::size_t f = 0; f < r.poses.size(); ++f) {
      INFO("frame " << f);
      CHECK(two.poses[f].positions == r.poses[f].positions);
      CHECK(two.poses[f].quaternions == r.poses[f].quaternions);
    }
  }
}

TEST_CASE("native rollouts may multiply in bfloat16, close to float32, and reference mode may not",
          "[hopnet][rollout][precision]") {
  Golden G("hopnet bfloat16 rollout");
  const auto norm = G.normalizer();
  struct Restore {  // the setting is process-wide: back to highest even if this throws
    ~Restore() { nn::set_float32_matmul_precision(nn::MatmulPrecision::highest); }
  } restore;
  auto native = load_hopnet(G.checkpoint(), FeatureMode::native);
  native->eval();
  const auto g = make_geometry(G.scene, FeatureMode::native);
  RolloutOptions opt;
  opt.steps = 22;  // frames 4..25
  const auto hi = rollout(*native, norm, G.scene, g, opt);
  nn::set_float32_matmul_precision(nn::MatmulPrecision::medium);
  const auto md = rollout(*native, norm, G.scene, g, opt);
  // Frame 4, one step from the ground truth: it did multiply in bfloat16, and the predicted
  // positions moved by far less than a millimetre (bfloat16 keeps 8 significant bits of a
  // normalised acceleration, which the integration scales by 1/240² s²).
  const auto frame_gap = [&](std::size_t f) {
    return (md.poses[f].positions - hi.poses[f].positions).cwiseAbs().maxCoeff();
  };
  CHECK(frame_gap(4) > 0);
  CHECK(frame_gap(4) < 1e-4);
  // Frame 25: errors compound over 22 steps, the metrics stay within a few per cent.
  const auto m_hi = rollout_metrics(hi.poses, G.scene), m_md = rollout_metrics(md.poses, G.scene);
  INFO("frame 25 pos RMSE: highest " << m_hi.pos_rmse[25] << ", medium " << m_md.pos_rmse[25]
                                     << "; largest position gap " << frame_gap(25) << " m");
  CHECK(std::abs(m_md.pos_rmse[25] / m_hi.pos_rmse[25] - 1) < 0.05);
  CHECK(frame_gap(25) < 5e-3);
  // Reference mode stays the published model's float32 numbers.
  auto reference = G.model();
  const auto gr = make_geometry(G.scene, FeatureMode::reference);
  REQUIRE_THROWS_WITH(rollout(*reference, norm, G.scene, gr, opt),
                      Catch::Contains("reference mode runs in float32 only"));
}

namespace {
NormalizationStats unit_stats() {
  NormalizationStats s;
  for (const auto& [k, n] : NormalizationStats::layout())
    s.mean[k].assign(n, 0.0), s.std[k].assign(n, 1.0);
  s.mean["x4"][8] = s.mean["x4"][9] = s.std["x4"][8] = s.std["x4"][9] =
      0.5;  // type columns, as the reference forces them
  return s;
}
}  // namespace

TEST_CASE("normalisation statistics: population moments with the reference's shared scales",
          "[hopnet][stats]") {
  std::mt19937 rng(5);
  std::normal_distribution<double> nd;
  StatsAccumulator a, b, all;
  std::map<std::string, std::vector<RowMatrix>> seen;
  for (int chunk = 0; chunk < 6; ++chunk) {
    for (const auto& [k, n] : NormalizationStats::layout()) {
      RowMatrix m(7 + chunk, static_cast<Eigen::Index>(n));
      for (Eigen::Index i = 0; i < m.size(); ++i)
        m.data()[i] = 100.0 + (1.0 + static_cast<double>(i % n)) * nd(rng);
      (chunk < 3 ? a : b).add(k, m);
      all.add(k, m);
      seen[k].push_back(m);
    }
  }
  a.merge(b);
  const auto s = a.finalize(), t = all.finalize();
  for (const auto& [k, n] : NormalizationStats::layout()) {
    // Brute force per column.
    std::vector<double> mean(n, 0), sd(n, 0);
    std::int64_t cnt = 0;
    for (const auto& m : seen[k]) {
      cnt += m.rows();
      for (Eigen::Index r = 0; r < m.rows(); ++r)
        for (std::size_t c = 0; c < n; ++c) mean[c] += m(r, static_cast<Eigen::Index>(c));
    }
    for (auto& v : mean) v /= static_cast<double>(cnt);
    for (const auto& m : seen[k])
      for (Eigen::Index r = 0; r < m.rows(); ++r)
        for (std::size_t c = 0; c < n; ++c)
          sd[c] += std::pow(m(r, static_cast<Eigen::Index>(c)) - mean[c], 2);
    for (auto& v : sd) v = std::sqrt(v / static_cast<double>(cnt));
    for (std::size_t c = 0; c < n; ++c) {
      if (!(k == "x4" && (c == 8 || c == 9)))
        REQUIRE(s.mean.at(k)[c] == Approx(mean[c]).epsilon(1e-12));
      REQUIRE(s.mean.at(k)[c] == Approx(t.mean.at(k)[c]).epsilon(1e-12));
      REQUIRE(s.std.at(k)[c] == Approx(t.std.at(k)[c]).epsilon(1e-10));
    }
    const auto max_of = [&](std::initializer_list<std::pair<std::size_t, std::size_t>> blocks) {
      double mx = 0;
      for (auto [b0, e0] : blocks)
        for (std::size_t c = b0; c < e0; ++c) mx = std::max(mx, sd[c]);
      return mx;
    };
    if (k == "x0") {
      REQUIRE(s.std.at(k)[3] == Approx(max_of({{0, 8}})));
      REQUIRE(s.std.at(k)[15] == Approx(max_of({{8, 16}})));
    }
    if (k == "x1" || k == "t0") REQUIRE(s.std.at(k)[0] == Approx(max_of({{0, n}})));
    if (k == "x3") {
      REQUIRE(s.std.at(k)[0] == Approx(max_of({{0, 4}})));
      REQUIRE(s.std.at(k)[4] == Approx(max_of({{4, 8}, {16, 20}})));
      REQUIRE(s.std.at(k)[20] == s.std.at(k)[8]);
      REQUIRE(s.std.at(k)[27] == Approx(max_of({{12, 16}, {24, 28}})));
    }
    if (k == "x4")
      REQUIRE(
          (s.mean.at(k)[8] == 0.5 && s.std.at(k)[9] == 0.5 && s.std.at(k)[12] == Approx(sd[12])));
  }
  // JSON round trip, and its errors.
  const auto path = (fs::temp_directory_path() / "topos_stats.json").string();
  write_stats_json(s, path);
  const auto back = read_stats_json(path);
  REQUIRE(back.mean == s.mean);
  REQUIRE(back.std == s.std);
  fs::remove(path);
  REQUIRE_THROWS_WITH(parse_stats_json("{", "s.json"), Catch::Contains("s.json: malformed JSON"));
  nlohmann::json j = nlohmann::json::object();
  for (const auto& [k, n] : NormalizationStats::layout())
    j[k + "_mean"] = s.mean.at(k), j[k + "_std"] = s.std.at(k);
  auto short_x2 = j;
  short_x2["x2_std"] = std::vector<double>{1, 1};
  REQUIRE_THROWS_WITH(parse_stats_json(short_x2.dump(), "s.json"),
                      Catch::Contains("'x2_std' has 2 entries, expected 3"));
  auto no_t4 = j;
  no_t4.erase("t4_mean");
  REQUIRE_THROWS_WITH(parse_stats_json(no_t4.dump(), "s.json"),
                      Catch::Contains("missing statistics 't4_mean'"));
  auto zero = j;
  zero["x1_std"][0] = 0.0;
  REQUIRE_THROWS_WITH(parse_stats_json(zero.dump(), "s.json"), Catch::Contains("non-positive"));
}

TEST_CASE(
    "the role-mixing buffer: a face that is face0 in one contact and face1 in another feeds both "
    "halves",
    "[hopnet]") {
  const Scene scene = testing::cube_and_sphere();
  for (auto mode : {FeatureMode::reference, FeatureMode::native}) {
    const auto g = make_geometry(scene, mode);
    HopnetFrame f;
    f.faces = {0, 1, g.face_offset[1] + 0};  // face A (obj 0), face B (obj 0), face C (obj 1)
    f.contacts = {{0, 2}, {2, 1}};  // A–C (A is face0), C–B (C is face0 here, face1 above)
    const auto n = hopnet_neighborhoods(g, f);
    const auto& neg = n.at("B23neg");
    const auto& pos = n.at("B23pos");
    REQUIRE(neg.nnz() == 4);
    // Pairs in order: (A,c0), (C,c0), (C,c1), (B,c1).
    const std::vector<double> want_neg = mode == FeatureMode::reference
                                             ? std::vector<double>{1, 1, 1, 0}
                                             : std::vector<double>{1, 0, 1, 0};
    const std::vector<double> want_pos = mode == FeatureMode::reference
                                             ? std::vector<double>{0, 1, 1, 1}
                                             : std::vector<double>{0, 1, 0, 1};
    REQUIRE(neg.values == want_neg);
    REQUIRE(pos.values == want_pos);
    REQUIRE(n.at("B32").roles == std::vector<std::int8_t>{-1, 1, -1, 1});
  }
}

TEST_CASE(
    "HOPNet on built-in shapes: batched frames equal single frames, static forcing, rollout, bad "
    "input",
    "[hopnet]") {
  torch::manual_seed(3);
  const Scene scene = testing::cube_and_sphere();
  const Normalizer norm(unit_stats());
  for (auto mode : {FeatureMode::reference, FeatureMode::native}) {
    INFO(to_string(mode));
    Hopnet net(HopnetOptions().hidden(32).mode(mode));
    net->eval();
    const std::int64_t D = 32;
    const auto mlp = [&](std::int64_t in, std::int64_t out, bool ln) {
      return in * D + D + D * out + out + (ln ? 2 * out : 0);
    };
    std::int64_t want = 0;
    for (std::int64_t in : {16, 8, 3, 28, 13}) want += mlp(in, D, true);
    for (std::int64_t in : {D, D, D, D, D, D, D, 4 * D, 3 * D, 2 * D, 2 * D, 2 * D, 2 * D})
      want += mlp(in, D, true);
    want += 2 * mlp(D, 3, false);
    REQUIRE(net->num_parameters() == want);
    const auto g = make_geometry(scene, mode);
    std::vector<HopnetFrame> frames;
    for (std::int64_t t = 2; t < 10; ++t)
      frames.push_back(build_frame(
          g, scene_poses(scene, 0), scene_poses(scene, t - 2), scene_poses(scene, t - 1),
          scene_poses(scene, t), detect_contacts(g, pose_objects(g, scene_poses(scene, t)), 0.1)));
    std::int64_t with_contacts = 0;
    for (const auto& f : frames) with_contacts += f.num_contacts() > 0;
    REQUIRE(with_contacts > 0);  // the cube sits on the floor
    std::vector<std::pair<const HopnetGeometry*, const HopnetFrame*>> all;
    for (const auto& f : frames) all.push_back({&g, &f});
    torch::NoGradGuard ng;
    const auto batched = net->forward(make_batch(all, norm), norm);
    std::int64_t row = 0;
    for (const auto& f : frames) {
      const auto one = net->forward(make_batch({{&g, &f}}, norm), norm);
      REQUIRE(torch::allclose(one.a0, batched.a0.slice(0, row, row + g.num_nodes()), 1e-5, 1e-6));
      row += g.num_nodes();
      // The floor (last object, last 4 nodes) gets exactly the normalised zero acceleration.
      REQUIRE(torch::equal(one.a4[2], norm.zero_object_acceleration()));
      REQUIRE(torch::equal(one.a0[g.num_nodes() - 1], norm.zero_node_acceleration()));
    }
    RolloutOptions opt;
    opt.steps = 6;
    const auto r = rollout(*net, norm, scene, g, opt);
    REQUIRE(r.num_frames() == 10);
    REQUIRE(r.poses[9].positions.row(2).norm() == 0.0);  // the floor never moves
    const auto m = rollout_metrics(r.poses, scene);
    REQUIRE(m.pos_rmse[3] == 0.0);
    REQUIRE(std::isfinite(m.pos_rmse[9]));
    // Bad input.
    Poses nan_pose = scene_poses(scene, 3);
    nan_pose.positions(0, 1) = std::nan("");
    REQUIRE_THROWS_WITH(pose_objects(g, nan_pose), Catch::Contains("not finite"));
    REQUIRE_THROWS_WITH(
        build_frame(g, scene_poses(scene, 0), scene_poses(scene, 1), scene_poses(scene, 2),
                    scene_poses(scene, 3), {{0, 9999, 1, 0}}),
        Catch::Contains("does not exist"));
    REQUIRE_THROWS_WITH(build_frame(g, scene_poses(scene, 0), scene_poses(scene, 1),
                                    scene_poses(scene, 2), scene_poses(scene, 3), {{0, 0, 0, 1}}),
                        Catch::Contains("not valid"));
    RolloutOptions none;
    none.steps = 0;
    REQUIRE_THROWS(rollout(*net, norm, scene, g, none));
  }
  REQUIRE_THROWS_WITH(feature_mode_from_string("fast"), Catch::Contains("unknown mode 'fast'"));
  // A file that is not a checkpoint, and a dict without HOPNet tensors.
  const auto junk = (fs::temp_directory_path() / "topos_junk.pt").string();
  { std::ofstream(junk) << "not a torch file"; }
  REQUIRE_THROWS_WITH(load_hopnet(junk), Catch::Contains("not a readable torch file"));
  c10::Dict<std::string, torch::Tensor> d;
  d.insert("weight", torch::zeros({2}));
  nn::write_tensor_dict(d, junk);
  REQUIRE_THROWS_WITH(load_hopnet(junk),
                      Catch::Contains("neither a topos nor a reference HOPNet checkpoint"));
  fs::remove(junk);
}

TEST_CASE("the training loss equals the reference's per-step losses on MOVi-A scene 8",
          "[hopnet][reference][training]") {
  Golden G("hopnet training loss");
  const auto g = make_geometry(G.scene, FeatureMode::reference);
  const auto norm = G.normalizer();
  auto model = G.model();
  torch::NoGradGuard ng;
  for (const auto& [t, want] :
       std::vector<std::pair<int, double>>{{2, 0.0150184}, {100, 2.78862}, {300, 0.140924}}) {
    const auto tf = trajectory_frames(G.scene, g, 0.1, 0.0, t, t);
    const auto item = make_training_item(g, tf, norm);
    INFO("t = " << t << ": faces " << tf.frames[0].num_faces() << ", contacts "
                << tf.frames[0].num_contacts());
    REQUIRE(trajectory_loss(*model, item, norm).item<double>() == Approx(want).epsilon(1e-4));
  }
}

TEST_CASE("one batched backward over a trajectory equals the sum of per-timestep gradients",
          "[hopnet][training]") {
  torch::manual_seed(11);
  const Scene scene = testing::cube_and_sphere(12);
  const Normalizer norm(unit_stats());
  Hopnet net(HopnetOptions().hidden(16).mode(FeatureMode::native));
  const auto g = make_geometry(scene, FeatureMode::native);
  const auto tf = trajectory_frames(scene, g, 0.1, 0.0);
  REQUIRE(tf.frames.size() == 9);
  const auto batched = make_training_item(g, tf, norm);
  net->zero_grad();
  trajectory_loss(*net, batched, norm).backward();
  std::map<std::string, torch::Tensor> want;
  for (const auto& p : net->named_parameters()) want[p.key()] = p.value().grad().clone();
  std::map<std::string, torch::Tensor> sum;
  for (std::size_t i = 0; i < tf.frames.size(); ++i) {
    TrajectoryFrames one;
    one.frames = {tf.frames[i]};
    one.t0 = {tf.t0[i]};
    one.t4 = {tf.t4[i]};
    one.mask = {tf.mask[i]};
    net->zero_grad();
    trajectory_loss(*net, make_training_item(g, one, norm), norm).backward();
    for (const auto& p : net->named_parameters())
      sum[p.key()] =
          sum.count(p.key()) ? sum[p.key()] + p.value().grad() : p.value().grad().clone();
  }
  for (const auto& [k, w] : want) {
    INFO(k);
    const double err = (w - sum[k]).abs().max().item<double>(),
                 scale = w.abs().max().item<double>();
    REQUIRE(err <= 1e-5 * std::max(scale, 1e-3));
  }
}

TEST_CASE("chunked training steps give the unchunked gradient", "[hopnet][training]") {
  torch::manual_seed(5);
  // The cube falls onto the floor: the chunk of timesteps 4..7 starts without contacts and has
  // some later (its batch must keep the contact neighbourhoods' values and roles).
  const Scene scene = testing::cube_and_sphere(16, 0.2);
  const Normalizer norm(unit_stats());
  for (const auto mode : {FeatureMode::native, FeatureMode::reference}) {
    INFO(to_string(mode));
    Hopnet net(HopnetOptions().hidden(16).mode(mode));
    const auto g = make_geometry(scene, mode);
    const auto tf = trajectory_frames(scene, g, 0.1, 0.0);
    REQUIRE(tf.frames.size() == 13);
    REQUIRE(tf.frames[0].num_contacts() == 0);
    REQUIRE(tf.frames[4].num_contacts() == 0);
    REQUIRE(tf.frames[7].num_contacts() > 0);
    const auto grads = [&](std::int64_t chunk, int workers) {
      const auto chunks = make_training_chunks(g, tf, norm, chunk);
      REQUIRE(chunks.size() == (chunk <= 0
                                    ? 1
                                    : (tf.frames.size() + static_cast<std::size_t>(chunk) - 1) /
                                          static_cast<std::size_t>(chunk)));
      net->zero_grad();
      std::vector<double> per_timestep;
      const double loss = backward_trajectory(*net, chunks, norm, &per_timestep, workers);
      REQUIRE(per_timestep.size() == tf.frames.size());
      REQUIRE(std::accumulate(per_timestep.begin(), per_timestep.end(), 0.0) ==
              Approx(loss).epsilon(1e-6));
      std::map<std::string, torch::Tensor> out;
      for (const auto& p : net->named_parameters()) out[p.key()] = p.value().grad().clone();
      return std::make_pair(loss, out);
    };
    const auto [whole_loss, whole] = grads(0, 1);
    // Chunks one after the other, and run at once on 2 or 3 worker threads.
    for (const auto& [chunk, workers] :
         std::vector<std::pair<std::int64_t, int>>{{1, 1}, {4, 1}, {4, 2}, {1, 3}}) {
      INFO("chunks of " << chunk << ", " << workers << " workers");
      const auto [loss, got] = grads(chunk, workers);
      REQUIRE(loss == Approx(whole_loss).epsilon(1e-6));
      // The chunks' gradients are the same sum in another float32 order: 1e-6 relative over the
      // whole gradient, and no tensor off by more than float32 summation explains (1e-5 of its
      // norm).
      double diff2 = 0, norm2 = 0;
      for (const auto& [k, w] : whole) {
        INFO(k << ", chunks of " << chunk);
        const double d = (got.at(k) - w).norm().item<double>(), n = w.norm().item<double>();
        diff2 += d * d, norm2 += n * n;
        REQUIRE(d <= 1e-5 * std::max(n, 1e-6));
      }
      INFO("chunks of " << chunk);
      REQUIRE(std::sqrt(diff2) <= 1e-6 * std::sqrt(norm2));
    }
  }
  // The automatic chunk fits the budget from the most expensive timestep, within 1..T.
  const auto g = make_geometry(scene, FeatureMode::native);
  const auto tf = trajectory_frames(scene, g, 0.1, 0.0);
  double worst = 0;
  for (const auto& f : tf.frames) worst = std::max(worst, timestep_activation_bytes(g, f, 128));
  REQUIRE(auto_chunk(g, tf, 128, 3.5 * worst) == 3);
  REQUIRE(auto_chunk(g, tf, 128, 0.1 * worst) == 1);
  REQUIRE(auto_chunk(g, tf, 128, 1e15) == static_cast<std::int64_t>(tf.frames.size()));
}

TEST_CASE(
    "reference backward values: the gradient of a face's message comes back once per duplicate "
    "write",
    "[hopnet][training]") {
  // Two contacts share face 0 as their -1 face: the reference computes its 2-to-3 message twice
  // and writes both copies into one row with index_put_, whose backward gives each copy the
  // row's gradient. Written with index_put_ here and compared with aggregate().
  torch::manual_seed(3);
  const auto x = torch::randn({3, 4}, torch::requires_grad());  // face messages
  nn::TensorNeighborhood n;
  n.source =
      torch::tensor(std::vector<std::int64_t>{0, 1, 0, 2}, torch::kLong);  // (face, contact) pairs
  n.target = torch::tensor(std::vector<std::int64_t>{0, 0, 1, 1}, torch::kLong);
  n.values = torch::tensor(std::vector<float>{1, 0, 1, 0});  // neg(f): faces 1, 2 are +1 faces only
  n.backward_values = torch::tensor(std::vector<float>{2, 0, 2, 0});  // k_neg(f)
  n.num_source = 3;
  n.num_target = 2;
  const auto w = torch::randn({2, 4});
  (nn::aggregate(x, n, nn::AggregateOptions().with_weighted(true)) * w).sum().backward();
  const auto got = x.grad().clone();
  // The reference's construction.
  const auto x2 = x.detach().clone().requires_grad_(true);
  const auto neg_faces =
      torch::tensor(std::vector<std::int64_t>{0, 0}, torch::kLong);  // one row per -1 entry of B23
  auto buffer = torch::zeros({3, 4});
  buffer.index_put_({neg_faces}, x2.index_select(0, neg_faces));
  const auto B =
      torch::tensor(std::vector<float>{1, 1, 0, 1, 0, 1}).reshape({2, 3});  // contacts × faces
  (B.matmul(buffer) * w).sum().backward();
  REQUIRE(torch::allclose(got, x2.grad()));
  REQUIRE(torch::allclose(got[0], 2 * (w[0] + w[1])));
}

namespace {
// A case of the reference's training goldens (train-golden/<case>/, its README): the sample,
// checkpoint and statistics named by meta.json, read from the reference folder.
struct TrainGolden {
  fs::path dir, sample, checkpoint, stats;
  std::string name;
  static std::vector<TrainGolden> all(const fs::path& ref) {
    std::vector<TrainGolden> out;
    for (const auto& e : fs::directory_iterator(ref / "data" / "train-golden")) {
      if (!fs::exists(e.path() / "meta.json")) continue;
      const auto meta = data::read_json_file(e.path() / "meta.json").at("case");
      TrainGolden c;
      c.dir = e.path();
      c.name = e.path().filename().string();
      // "samples/MOVi-A/8 (...)" -> data/movi-a/8; "normalization-movia.npy" ->
      // normalization/movia.json
      std::string sample = meta.at("sample").get<std::string>();
      sample = sample.substr(0, sample.find(' '));
      const auto slash = sample.find('/'), last = sample.rfind('/');
      std::string dataset = sample.substr(slash + 1, last - slash - 1);
      std::transform(dataset.begin(), dataset.end(), dataset.begin(),
                     [](unsigned char ch) { return static_cast<char>(std::tolower(ch)); });
      c.sample = ref / "data" / dataset / sample.substr(last + 1);
      c.checkpoint = ref / "data" / "checkpoints" / meta.at("checkpoint").get<std::string>();
      std::string norm = meta.at("normalization_file").get<std::string>();
      norm = norm.substr(std::string("normalization-").size());
      c.stats = ref / "data" / "normalization" / (norm.substr(0, norm.size() - 4) + ".json");
      out.push_back(c);
    }
    REQUIRE(!out.empty());
    return out;
  }
  torch::Tensor tensor(const std::string& rel) const {
    const auto a = data::read_npy((dir / rel).string());
    const auto v = a.as<double>();
    return torch::tensor(v, torch::kDouble).reshape(a.shape);
  }
  /// The reference's state dict names of `model`'s parameters -> golden tensors of folder `sub`.
  std::map<std::string, torch::Tensor> params(const HopnetImpl& model,
                                              const std::string& sub) const {
    std::map<std::string, torch::Tensor> out;
    for (const auto& p : model.named_parameters())
      out[p.key()] = tensor(sub + "/" + reference_parameter_name(p.key()) + ".npy");
    return out;
  }
};

struct TrainSetup {
  Scene scene;
  HopnetGeometry g;
  Normalizer norm;
  TrajectoryFrames tf;
  explicit TrainSetup(const fs::path& ref, const TrainGolden& c) {
    MeshLibrary lib(ref / "data" / "kubasic");
    scene = make_scene(data::read_kubric_metadata(c.sample), lib);
    g = make_geometry(scene,
                      FeatureMode::reference);  // points into `scene`: TrainSetup is never moved
    norm = Normalizer(read_stats_json(c.stats.string()));
    const auto contacts = read_collisions_json((c.sample / "collisions.json").string());
    tf = trajectory_frames(scene, g, 0.1, 0.0, 2, -1, &contacts);
  }
};
}  // namespace

TEST_CASE(
    "reference mode reproduces the reference's training: loss, gradient and three Adam steps "
    "(train-golden)",
    "[hopnet][reference][training]") {
  const auto ref = test::reference_dir("hopnet training parity");
  for (const auto& c : TrainGolden::all(ref)) {
    INFO("case " << c.name);
    const TrainSetup S(ref, c);
    auto model = load_hopnet(c.checkpoint.string(), FeatureMode::reference);
    model->train();
    const auto counts = c.tensor("complex_counts.npy");
    REQUIRE(static_cast<std::int64_t>(S.tf.frames.size()) == counts.size(0));
    // Inputs first (input_checksums.npy: float64 sums of the normalised x0..x4, t0, t4): the
    // features are computed in float64 from bitwise the reference's node positions, so the sums
    // agree to rounding; a contact whose PhysX branch flips moves x3's sum by ~1e-5 relative.
    const auto checksums = c.tensor("input_checksums.npy");
    double worst_in = 0;
    for (std::size_t t = 0; t < S.tf.frames.size(); ++t) {
      INFO("timestep " << t);
      const auto& f = S.tf.frames[t];
      REQUIRE(f.num_faces() == counts[static_cast<std::int64_t>(t)][0].item<std::int64_t>());
      REQUIRE(f.num_contacts() == counts[static_cast<std::int64_t>(t)][1].item<std::int64_t>());
      const std::pair<const char*, const RowMatrix*> inputs[7] = {
          {"x0", &f.x0}, {"x1", &f.x1},       {"x2", &f.x2},      {"x3", &f.x3},
          {"x4", &f.x4}, {"t0", &S.tf.t0[t]}, {"t4", &S.tf.t4[t]}};
      for (int k = 0; k < 7; ++k) {
        const auto& [key, x] = inputs[k];
        const double got = x->size() == 0
                               ? 0.0
                               : S.norm.normalize(key, *x).to(torch::kDouble).sum().item<double>();
        const double want = checksums[static_cast<std::int64_t>(t)][k].item<double>();
        const double e = std::abs(got - want) / std::max(1.0, std::abs(want));
        worst_in = std::max(worst_in, e);
        INFO(key << ": " << got << " vs " << want);
        CHECK(e <= 1e-12);
      }
    }
    std::cout << c.name << ": inputs, worst relative checksum error " << worst_in << "\n";
    // Chunks of 160 timesteps: the gradients add up (and a test above checks that exactly).
    const auto chunks = make_training_chunks(S.g, S.tf, S.norm, 160);
    std::map<std::string, torch::Tensor> start;
    for (const auto& p : model->named_parameters())
      start[p.key()] = p.value().detach().to(torch::kDouble).clone();
    torch::optim::Adam opt(model->parameters(), torch::optim::AdamOptions(1e-4));
    std::vector<double> per_timestep;
    const double loss = train_step(*model, opt, chunks, S.norm, &per_timestep);

    // Loss: total within 1e-5, every timestep within 5e-5 (README section 5).
    const double want_total = c.tensor("loss_total.npy").item<double>();
    float total32 = 0;
    for (double l : per_timestep) total32 += static_cast<float>(l);
    CHECK(std::abs(loss - want_total) <= 1e-5 * want_total);
    CHECK(std::abs(static_cast<double>(total32) - want_total) <= 1e-5 * want_total);
    const auto want_t = c.tensor("loss_per_timestep.npy");
    REQUIRE(want_t.size(0) == static_cast<std::int64_t>(per_timestep.size()));
    double worst_t = 0;
    for (std::size_t t = 0; t < per_timestep.size(); ++t) {
      const double w = want_t[static_cast<std::int64_t>(t)].item<double>();
      worst_t = std::max(worst_t, std::abs(per_timestep[t] - w) / w);
    }
    std::cout << c.name << ": loss " << loss << " (golden " << want_total
              << "), worst per-timestep relative error " << worst_t << "\n";
    CHECK(worst_t <= 5e-5);

    // Gradient of step 1 (the parameters' .grad still holds it): every tensor within 1e-4 in norm.
    const auto want_g = c.params(*model, "grads");
    double worst_g = 0, num = 0, den = 0;
    for (const auto& p : model->named_parameters()) {
      const auto g = p.value().grad().to(torch::kDouble);
      const auto& w = want_g.at(p.key());
      const double e = (g - w).norm().item<double>(), n = w.norm().item<double>();
      num += e * e, den += n * n;
      worst_g = std::max(worst_g, e / std::max(n, 1e-12));
      INFO(reference_parameter_name(p.key()) << ": relative error " << e / n);
      CHECK(e <= 1e-4 * n);
    }
    std::cout << c.name << ": gradient relative error worst tensor " << worst_g << ", global "
              << std::sqrt(num / den) << "\n";

    // Adam step 1 moves each coordinate by about lr · sign(g): coordinates with |g_ref| >= 1e-4
    // whose gradient has the golden sign are within 1e-6 of after_1_step. A coordinate may still
    // flip (a 2·lr difference) where float32 sums of opposite terms leave the golden value within
    // our gradient's own error of zero: on an AMD EPYC with AVX-512 two of them did, in the last
    // Linear of two MLPs, each with |g_ref - g| under 1e-4 of the tensor's norm.
    const auto after1 = c.params(*model, "after_1_step");
    for (const auto& p : model->named_parameters()) {
      const auto d = (p.value().detach().to(torch::kDouble) - after1.at(p.key())).abs();
      const auto& w = want_g.at(p.key());
      const auto g = p.value().grad().to(torch::kDouble);
      const auto big = w.abs().ge(1e-4), agree = g.sign().eq(w.sign());
      INFO(reference_parameter_name(p.key()));
      CHECK(d.masked_select(big & agree).max().item<double>() <= 1e-6);
      const auto flipped = big & agree.logical_not();
      CHECK(flipped.sum().item<std::int64_t>() <= 2);
      if (flipped.any().item<bool>())
        CHECK((g - w).abs().masked_select(flipped).max().item<double>() <=
              1e-4 * w.norm().item<double>());
      CHECK(d.max().item<double>() <= 2.0001e-4);
    }
    // Steps 2 and 3 along our own trajectory: >= 99.5 % of the coordinates within 1e-6, and the
    // whole difference under 1 % of the three-step move.
    for (int k = 2; k <= 3; ++k) train_step(*model, opt, chunks, S.norm);
    const auto after3 = c.params(*model, "after_3_steps");
    std::int64_t close = 0, total = 0;
    double diff = 0, move = 0;
    for (const auto& p : model->named_parameters()) {
      const auto d = p.value().detach().to(torch::kDouble) - after3.at(p.key());
      close += d.abs().le(1e-6).sum().item<std::int64_t>();
      total += d.numel();
      diff += d.pow(2).sum().item<double>();
      move += (after3.at(p.key()) - start.at(p.key())).pow(2).sum().item<double>();
    }
    const double frac = static_cast<double>(close) / static_cast<double>(total),
                 rel = std::sqrt(diff / move);
    std::cout << c.name << ": after 3 steps " << 100 * frac
              << " % of parameters within 1e-6, difference " << rel << " of the 3-step move\n";
    CHECK(frac >= 0.995);
    CHECK(rel < 1e-2);
  }
}

TEST_CASE(
    "oneDNN's products (hopnet train's cpu gemm) give the reference's loss and gradient on two "
    "workers (train-golden)",
    "[hopnet][reference][training]") {
  if (!nn::onednn_gemm_available()) {
    WARN("this LibTorch has no oneDNN: nothing to compare");
    return;
  }
  const auto ref = test::reference_dir("hopnet training parity");
  struct Restore {  // the setting is process-wide: back to BLAS even if this throws
    ~Restore() { nn::set_cpu_gemm(nn::CpuGemm::blas); }
  } restore;
  for (const auto& c : TrainGolden::all(ref)) {
    INFO("case " << c.name);
    const TrainSetup S(ref, c);
    auto model = load_hopnet(c.checkpoint.string(), FeatureMode::reference);
    model->train();
    const auto chunks = make_training_chunks(S.g, S.tf, S.norm, 120);
    const auto grads = [&](nn::CpuGemm gemm) {
      nn::set_cpu_gemm(gemm);
      model->zero_grad();
      const double loss = backward_trajectory(*model, chunks, S.norm, nullptr, 2);
      std::map<std::string, torch::Tensor> out;
      for (const auto& p : model->named_parameters())
        out[p.key()] = p.value().grad().to(torch::kDouble);
      return std::make_pair(loss, out);
    };
    const auto [loss_blas, g_blas] = grads(nn::CpuGemm::blas);
    const auto [loss, g] = grads(nn::CpuGemm::onednn);
    // The same sums in another float32 order: as close to the golden values as BLAS's.
    const double want_total = c.tensor("loss_total.npy").item<double>();
    CHECK(std::abs(loss - want_total) <= 1e-5 * want_total);
    const auto want_g = c.params(*model, "grads");
    bool differs = false;
    for (const auto& [k, w] : want_g) {
      INFO(reference_parameter_name(k));
      const double n = w.norm().item<double>();
      CHECK((g.at(k) - w).norm().item<double>() <= 1e-4 * n);
      differs = differs || !torch::equal(g.at(k), g_blas.at(k));
    }
    CHECK(differs);  // oneDNN did multiply
    CHECK(std::abs(loss - loss_blas) <= 1e-6 * std::abs(loss_blas));
  }
}

TEST_CASE("LibTorch's Adam fed the reference's gradients reproduces its three steps (train-golden)",
          "[hopnet][reference][training]") {
  const auto ref = test::reference_dir("hopnet Adam parity");
  for (const auto& c : TrainGolden::all(ref)) {
    INFO("case " << c.name);
    auto model = load_hopnet(c.checkpoint.string(), FeatureMode::reference);
    torch::optim::Adam opt(model->parameters(), torch::optim::AdamOptions(1e-4));
    for (const auto& [step, grads, after] : std::vector<std::tuple<int, std::string, std::string>>{
             {1, "grads", "after_1_step"},
             {2, "grads_step2", "after_2_steps"},
             {3, "grads_step3", "after_3_steps"}}) {
      const auto g = c.params(*model, grads);
      for (auto& p : model->named_parameters())
        p.value().mutable_grad() = g.at(p.key()).to(torch::kFloat);
      opt.step();
      const auto want = c.params(*model, after);
      double worst = 0;
      for (const auto& p : model->named_parameters())
        worst = std::max(
            worst,
            (p.value().detach().to(torch::kDouble) - want.at(p.key())).abs().max().item<double>());
      INFO("step " << step);
      CHECK(worst <= 1e-6);
    }
  }
}

// ---- the HOPNet family (docs/hopnet.md) ----------------------------------------------------

TEST_CASE(
    "HOPNet variants: presets compose into the reference's parameter counts, and bad "
    "configurations are errors",
    "[hopnet][variants]") {
  // Counts of the reference classes' constructions (docs/hopnet.md, the HOPNet family).
  for (const auto& [config, want] :
       std::vector<std::pair<std::string, std::int64_t>>{{"standard", 707078},
                                                         {"nox4", 539651},
                                                         {"noseq", 951814},
                                                         {"no-cm-distance", 706054},
                                                         {"mlp3", 1037318},
                                                         {"mp2", 1287174},
                                                         {"hidden64", 181510},
                                                         {"mlp3,no-cm-distance", 1036294},
                                                         {"mp2,no-cm-distance", 1286150},
                                                         {"hidden64,no-cm-distance", 180998},
                                                         {"noseq,hidden64", 951814},
                                                         {"standard,mlp3", 1037318}}) {
    INFO(config);
    const auto o = parse_config(config);
    REQUIRE(Hopnet(o)->num_parameters() == want);
    REQUIRE(parse_config(variant_name(o).substr(0, variant_name(o).find(' '))).to_json() ==
            o.to_json());  // the name is a configuration
  }
  for (const char* act : {"relu", "gelu", "elu", "selu"})
    REQUIRE(Hopnet(parse_config("standard").activation(nn::activation_from_string(act)))
                ->num_parameters() == 707078);
  REQUIRE(parse_config("noseq").hidden() == 64);
  REQUIRE(parse_config("noseq").num_layers() == 3);
  REQUIRE(variant_name(parse_config("nox4").activation(nn::Activation::gelu)) ==
          "nox4 (activation gelu)");
  // The NoObjectCells encoder reads 21 node columns; no-cm-distance 8.
  REQUIRE(Hopnet(parse_config("nox4"))->mlp("modules.encoder_0")->options.in() == 21);
  REQUIRE(Hopnet(parse_config("no-cm-distance"))->mlp("modules.encoder_0")->options.in() == 8);

  REQUIRE_THROWS_WITH(parse_config("nox5"),
                      Catch::Contains("unknown configuration 'nox5': not a preset"));
  REQUIRE_THROWS_WITH(
      parse_config("nox4,noseq"),
      Catch::Contains("conflicting configuration: preset 'nox4' sets architecture"));
  REQUIRE_THROWS_WITH(parse_config("noseq,mp2"), Catch::Contains("num_layers = 3"));
  REQUIRE_THROWS_WITH(parse_config("mlp3,,mp2"), Catch::Contains("empty item"));
  REQUIRE_THROWS_WITH(parse_config("missing.json"), Catch::Contains("no such file"));
  // JSON configuration files: fields, and presets under them.
  const auto file = (fs::temp_directory_path() / "topos_variant.json").string();
  {
    std::ofstream(file)
        << R"({"presets": ["mlp3"], "activation": "gelu", "collision_radius": 0.05})";
  }
  const auto o = parse_config(file + ",no-cm-distance");
  REQUIRE(o.mlp_layers() == 3);
  REQUIRE(o.activation() == nn::Activation::gelu);
  REQUIRE(o.collision_radius() == 0.05);
  REQUIRE(Hopnet(o)->num_parameters() == 1036294);
  { std::ofstream(file) << R"({"hiden": 64})"; }
  REQUIRE_THROWS_WITH(parse_config(file), Catch::Contains("unknown configuration field 'hiden'"));
  { std::ofstream(file) << R"({"collision_radius": -1})"; }
  REQUIRE_THROWS_WITH(parse_config(file),
                      Catch::Contains("collision radius must be a positive number"));
  { std::ofstream(file) << R"({"presets": "mp2", "num_layers": 3})"; }
  REQUIRE_THROWS_WITH(parse_config(file), Catch::Contains("conflicting configuration"));
  fs::remove(file);
}

namespace {
struct VariantGolden {
  Golden G;
  std::map<std::string, torch::Tensor> dict;
  Hopnet model{nullptr};
  Normalizer norm;
  HopnetGeometry g;
  VariantGolden(const char* what, const std::string& checkpoint, const std::string& stats)
      : G(what) {
    const auto path = (G.ref / "data" / "checkpoints" / checkpoint).string();
    dict = nn::read_tensor_dict(path);
    model = load_hopnet(dict, path);
    model->eval();
    const auto s = read_stats_json((G.ref / "data" / "normalization" / stats).string());
    check_stats_fit(model->options, s, stats);
    norm = Normalizer(s);
    g = make_geometry(G.scene, model->options.lifting());
  }
};
double sum_of(const torch::Tensor& t) {
  return t.sum().item<double>();
}
}  // namespace

TEST_CASE(
    "NoObjectCells: the published movia-nox4 weights on MOVi-A scene 8 give the reference's single "
    "steps",
    "[hopnet][variants][reference]") {
  VariantGolden V("hopnet NoObjectCells", "movia-nox4_seed0_e39.pt", "movia-nox4.json");
  REQUIRE(V.model->options.architecture() == Architecture::no_object_cells);
  REQUIRE(V.model->num_parameters() == 539651);
  REQUIRE(V.dict.size() == 88);
  REQUIRE(variant_name(V.model->options) == "nox4");
  // The complex of the ablation golden case (nox4 on MOVi-A scene 8).
  const auto& g = V.g;
  REQUIRE(g.num_rank0() == 187);
  REQUIRE(g.num_rank1() == 707);
  std::int64_t virtual_first = 0;
  for (char c : g.spoke_virtual_first) virtual_first += c;
  REQUIRE(virtual_first == 54);
  // z0 of the nox4 statistics, in float32.
  const auto z0 = V.norm.zero_node_acceleration();
  REQUIRE(z0[0].item<float>() == Approx(-1.2923704e-4f).epsilon(1e-6));
  REQUIRE(z0[1].item<float>() == Approx(4.3692067e-5f).epsilon(1e-6));
  REQUIRE(z0[2].item<float>() == Approx(-1.2546999e-4f).epsilon(1e-6));
  REQUIRE_FALSE(V.norm.stats().has_objects());
  torch::NoGradGuard ng;
  struct Want {
    int t, F, C;
    double loss, sum_all, sum_mesh;
  };
  for (const auto& w : {Want{2, 26, 34, 0.00444751, -15.9626, -15.5869},
                        Want{100, 47, 49, 2.70767, -39.8994, -39.3561},
                        Want{300, 61, 59, 0.119437, -10.8541, -10.4690}}) {
    INFO("t = " << w.t);
    const auto tf = trajectory_frames(V.G.scene, g, 0.1, 0.0, w.t, w.t);
    const auto& f = tf.frames[0];
    REQUIRE(f.num_faces() == w.F);
    REQUIRE(f.num_contacts() == w.C);
    REQUIRE(f.x0.rows() == 187);
    REQUIRE(f.x1.rows() == 707);
    const auto item = make_training_item(g, tf, V.norm);
    REQUIRE(item.batch.complex.neighborhood("A010").nnz() ==
            1601 - 187);  // the reference's explicit diagonal zeros left out
    const auto out = V.model->forward(item.batch, V.norm);
    REQUIRE(out.a0.size(0) == 187);
    REQUIRE_FALSE(out.a4.defined());
    REQUIRE(trajectory_loss(*V.model, item, V.norm).item<double>() == Approx(w.loss).epsilon(2e-4));
    REQUIRE(sum_of(out.a0) == Approx(w.sum_all).epsilon(2e-4));
    REQUIRE(sum_of(out.a0.slice(0, 0, 183)) == Approx(w.sum_mesh).epsilon(2e-4));
    // Static rows: the floor's 4 mesh nodes and its virtual node.
    for (std::int64_t r : {179, 180, 181, 182, 186}) REQUIRE(torch::equal(out.a0[r], z0));
    if (w.t == 100) {
      const auto acc = V.norm.denormalize("t0", out.a0);
      const auto close = [&](std::int64_t row, std::array<double, 3> v) {
        INFO("row " << row);
        for (int c = 0; c < 3; ++c)
          REQUIRE(acc[row][c].item<double>() ==
                  Approx(v[static_cast<std::size_t>(c)]).margin(5e-9).epsilon(2e-3));
      };
      close(0, {1.18782e-5, 5.14045e-5, -8.38266e-5});
      close(183, {9.788e-6, -2.019e-5, -1.74249e-4});
      close(184, {4.568e-5, 1.01074e-4, -1.08692e-4});
      close(185, {5.1888e-5, -4.37754e-4, -2.76162e-4});
      REQUIRE(acc[186].abs().max().item<double>() == 0.0);
    }
  }
  // Node features of the golden case: x0n[0, 16:21] and the cylinder's virtual row at t = 3.
  const auto tf = trajectory_frames(V.G.scene, g, 0.1, 0.0, 3, 3);
  const auto x0n = V.norm.normalize("x0", tf.frames[0].x0);
  const std::array<double, 5> obj{1, -1, 0.071063, 1.008522, 1.012018};
  for (int c = 0; c < 5; ++c)
    REQUIRE(x0n[0][16 + c].item<double>() == Approx(obj[static_cast<std::size_t>(c)]).margin(1e-5));
  const std::array<double, 8> v{-0.003789, -0.007679, -0.000443, 0.008575,
                                -0.003789, -0.007679, -0.000269, 0.008567};
  for (int c = 0; c < 8; ++c)
    REQUIRE(tf.frames[0].x0(183, c) == Approx(v[static_cast<std::size_t>(c)]).margin(1e-6));
  for (int c = 8; c < 16; ++c) REQUIRE(tf.frames[0].x0(183, c) == 0.0);
  REQUIRE(tf.frames[0].x0(186, 17) == 1.0);  // the floor's virtual node: type (0, 1)
  // The standard statistics cannot feed it.
  REQUIRE_THROWS_WITH(
      check_stats_fit(V.model->options, V.G.normalizer().stats(), "movia.json"),
      Catch::Contains("x0 statistics have 16 columns") && Catch::Contains("reads 21"));
}

TEST_CASE(
    "NoSequential: the published movia-noseq weights on MOVi-A scene 8 give the reference's single "
    "steps",
    "[hopnet][variants][reference]") {
  VariantGolden V("hopnet NoSequential", "movia-noseq_seed1_e39.pt", "movia.json");
  REQUIRE(V.model->options.architecture() == Architecture::no_sequential);
  REQUIRE(V.model->options.hidden() == 64);
  REQUIRE(V.model->options.num_layers() == 3);
  REQUIRE(V.model->num_parameters() == 951814);
  REQUIRE(V.dict.size() == 506);
  REQUIRE(variant_name(V.model->options) == "noseq");
  torch::NoGradGuard ng;
  struct Want {
    int t, F, C;
    std::int64_t a232;
    double loss, sum_a0, sum_a4;
  };
  for (const auto& w : {Want{2, 26, 34, 94 - 26, 0.00687097, -23.3120, -0.482267},
                        Want{100, 47, 49, 145 - 47, 2.43256, -59.7767, -2.23047},
                        Want{300, 61, 59, 179 - 61, 0.119727, -14.2289, -0.234775}}) {
    INFO("t = " << w.t);
    const auto tf = trajectory_frames(V.G.scene, V.g, 0.1, 0.0, w.t, w.t);
    REQUIRE(tf.frames[0].num_faces() == w.F);
    REQUIRE(tf.frames[0].num_contacts() == w.C);
    const auto item = make_training_item(V.g, tf, V.norm);
    const auto& cx = item.batch.complex;
    REQUIRE(cx.neighborhood("A232").nnz() == w.a232);
    REQUIRE(cx.neighborhood("A101").nnz() == 5818 - 524);
    REQUIRE(cx.neighborhood("B03").nnz() == 6 * w.C);
    REQUIRE(cx.neighborhood("B13").nnz() == 6 * w.C);
    const auto out = V.model->forward(item.batch, V.norm);
    REQUIRE(trajectory_loss(*V.model, item, V.norm).item<double>() == Approx(w.loss).epsilon(2e-4));
    REQUIRE(sum_of(out.a0) == Approx(w.sum_a0).epsilon(2e-4));
    REQUIRE(sum_of(out.a4) == Approx(w.sum_a4).epsilon(2e-4));
    if (w.t == 100) {
      const auto acc = V.norm.denormalize("t4", out.a4);
      const std::vector<std::array<double, 3>> want{{-5.38867e-6, -1.91431e-7, -1.77391e-4},
                                                    {1.70072e-5, 3.94399e-4, -2.35282e-5},
                                                    {-8.59022e-5, -2.40931e-3, -4.43048e-4}};
      for (std::int64_t o = 0; o < 3; ++o)
        for (int c = 0; c < 3; ++c)
          REQUIRE(acc[o][c].item<double>() ==
                  Approx(want[static_cast<std::size_t>(o)][static_cast<std::size_t>(c)])
                      .margin(5e-9)
                      .epsilon(2e-3));
      REQUIRE(acc[3].abs().max().item<double>() == 0.0);
    }
  }
}

TEST_CASE(
    "the published variant checkpoints are recognised from their keys, and a dict of no variant is "
    "an error",
    "[hopnet][variants][reference]") {
  Golden G("hopnet variant checkpoints");
  const auto ckpt = [&](const char* f) { return (G.ref / "data" / "checkpoints" / f).string(); };
  for (const auto& [file, name, params] :
       std::vector<std::tuple<const char*, const char*, std::int64_t>>{
           {"movia-nox4_seed0_e39.pt", "nox4", 539651},
           {"movia-noseq_seed1_e39.pt", "noseq", 951814},
           {"gelu_seed0_e39.pt", "standard", 707078},
           {"models_seed2_e39.pt", "standard", 707078},
           {"movib-alt_seed0_e39.pt", "standard", 707078}}) {
    INFO(file);
    const auto dict = nn::read_tensor_dict(ckpt(file));
    const auto o = checkpoint_options(dict, file);
    REQUIRE(variant_name(o) == name);
    auto m = load_hopnet(dict, file);
    REQUIRE(m->num_parameters() == params);
    // Exported reference names are the file's own.
    std::set<std::string> names;
    for (const auto& p : m->named_parameters())
      names.insert(reference_parameter_name(p.key(), o.architecture()));
    std::set<std::string> keys;
    for (const auto& [k, v] : dict) keys.insert(k);
    REQUIRE(names == keys);
  }
  // The activation is not in a reference file: an override applies; a topos file records it.
  CheckpointOverrides gelu;
  gelu.activation = nn::Activation::gelu;
  const auto dict = nn::read_tensor_dict(ckpt("gelu_seed0_e39.pt"));
  REQUIRE(load_hopnet(dict, "gelu", gelu)->options.activation() == nn::Activation::gelu);
  // A state dict whose names belong to no variant, and one whose class is known but whose
  // tensors are not the class's.
  std::map<std::string, torch::Tensor> renamed;
  for (const auto& [k, v] : dict) renamed["_HOPNet_Other__" + k.substr(9)] = v;
  REQUIRE_THROWS_WITH(checkpoint_options(renamed, "other.pt"),
                      Catch::Contains("neither a topos nor a reference HOPNet checkpoint"));
  auto mixed = nn::read_tensor_dict(ckpt("movia-nox4_seed0_e39.pt"));
  mixed["_HOPNet__mlp_encoder_4.0.weight"] = torch::zeros({128, 13});
  REQUIRE_THROWS_WITH(load_hopnet(mixed, "mixed.pt"),
                      Catch::Contains("unexpected tensor '_HOPNet__mlp_encoder_4.0.weight'"));
  auto wide = dict;
  wide["_HOPNet__mlp_encoder_0.0.weight"] = torch::zeros({128, 12});
  REQUIRE_THROWS_WITH(checkpoint_options(wide, "wide.pt"),
                      Catch::Contains("reads 12 node features"));
}

TEST_CASE(
    "variants on built-in shapes: batching, rollout, training, statistics and topos checkpoints",
    "[hopnet][variants]") {
  torch::manual_seed(5);
  const Scene scene = testing::cube_and_sphere();
  for (const char* config :
       {"nox4", "noseq,hidden64", "no-cm-distance", "mp2", "nox4,no-cm-distance"}) {
    INFO(config);
    for (auto mode : {FeatureMode::reference, FeatureMode::native}) {
      INFO(to_string(mode));
      HopnetOptions o = parse_config(config, HopnetOptions().mode(mode));
      o.hidden(16);
      Hopnet net(o);
      const auto g = make_geometry(scene, o.lifting());
      // Statistics of the variant's own layout, computed from its features.
      const auto tf = trajectory_frames(scene, g, o.collision_radius(), 0.0);
      StatsAccumulator acc;
      accumulate_stats(acc, tf, o.lifting().object_cells());
      const auto stats = acc.finalize();
      REQUIRE(stats.x0_width() == static_cast<std::size_t>(o.lifting().x0_width()));
      REQUIRE(stats.has_objects() == o.lifting().object_cells());
      check_stats_fit(o, stats, "computed");
      if (!o.lifting().object_cells())
        REQUIRE(stats.mean.at("x0")[o.lifting().x0_width() - 5] == 0.5);
      const auto path = (fs::temp_directory_path() / "topos_variant_stats.json").string();
      write_stats_json(stats, path);
      const Normalizer norm(read_stats_json(path));
      fs::remove(path);
      // One backward over the trajectory; every parameter that the schedule reaches gets a
      // gradient.
      const auto item = make_training_item(g, tf, norm);
      net->zero_grad();
      const auto loss = trajectory_loss(*net, item, norm);
      REQUIRE(std::isfinite(loss.item<double>()));
      loss.backward();
      // Batched frames equal single frames.
      net->eval();
      torch::NoGradGuard ng;
      std::vector<std::pair<const HopnetGeometry*, const HopnetFrame*>> all;
      for (const auto& f : tf.frames) all.push_back({&g, &f});
      const auto batched = net->forward(make_batch(all, norm), norm);
      std::int64_t row = 0;
      for (const auto& f : tf.frames) {
        const auto one = net->forward(make_batch({{&g, &f}}, norm), norm);
        REQUIRE(torch::allclose(one.a0, batched.a0.slice(0, row, row + g.num_rank0()), 1e-4, 1e-5));
        row += g.num_rank0();
        REQUIRE(torch::equal(one.a0[g.num_nodes() - 1],
                             norm.zero_node_acceleration()));  // a floor node
      }
      RolloutOptions opt;
      opt.steps = 5;
      const auto r = rollout(*net, norm, scene, g, opt);
      REQUIRE(r.poses[8].positions.row(2).norm() == 0.0);
      // The topos checkpoint keeps the configuration.
      const auto ck = (fs::temp_directory_path() / "topos_variant.pt").string();
      save_hopnet(*net, ck);
      auto back = load_hopnet(ck);
      REQUIRE(back->options.to_json() == net->options.to_json());
      CheckpointOverrides other;
      other.activation = nn::Activation::selu;
      REQUIRE_THROWS_WITH(load_hopnet(nn::read_tensor_dict(ck), ck, other),
                          Catch::Contains("trained with activation relu, not selu"));
      fs::remove(ck);
    }
  }
}

TEST_CASE("on CUDA, a training step and a rollout step equal the CPU ones", "[hopnet][cuda]") {
  if (!torch::cuda::is_available()) {
    std::cout << "SKIPPED: no CUDA device (this LibTorch has no CUDA support or sees no GPU); "
                 "build against a CUDA LibTorch to run it\n";
    std::exit(TOPOS_SKIP_CODE);
  }
  torch::manual_seed(11);
  const Scene scene = testing::cube_and_sphere(12);
  const Normalizer norm(unit_stats());
  const auto g = make_geometry(scene, FeatureMode::native);
  const auto item = make_training_item(g, trajectory_frames(scene, g, 0.1, 0.0), norm);
  Hopnet cpu(HopnetOptions().hidden(16).mode(FeatureMode::native)),
      gpu(HopnetOptions().hidden(16).mode(FeatureMode::native));
  {
    torch::NoGradGuard ng;
    for (const auto& p : cpu->named_parameters()) gpu->named_parameters()[p.key()].copy_(p.value());
  }
  gpu->to(torch::kCUDA);
  // device() follows the parameters (read from one found at construction): moved, cloned, and a
  // clone moved back leaves the original where it was.
  REQUIRE(cpu->device().is_cpu());
  REQUIRE(gpu->device().is_cuda());
  const auto cloned =
      std::dynamic_pointer_cast<HopnetImpl>(cpu->clone(torch::Device(torch::kCUDA)));
  REQUIRE(cloned->device().is_cuda());
  cloned->to(torch::kCPU);
  REQUIRE(cloned->device().is_cpu());
  REQUIRE(gpu->device().is_cuda());
  const auto l_cpu = trajectory_loss(*cpu, item, norm);
  l_cpu.backward();
  const auto l_gpu = trajectory_loss(*gpu, item.to(torch::kCUDA), norm);
  l_gpu.backward();
  REQUIRE(l_gpu.device().is_cuda());
  REQUIRE(l_gpu.item<double>() == Approx(l_cpu.item<double>()).epsilon(1e-4));
  for (const auto& p : cpu->named_parameters()) {
    INFO(p.key());
    const auto want = p.value().grad(), got = gpu->named_parameters()[p.key()].grad().cpu();
    REQUIRE((want - got).abs().max().item<double>() <=
            1e-3 * std::max(want.abs().max().item<double>(), 1e-3));
  }
  // A rollout step: the model on the GPU, the pose update on the host.
  cpu->eval(), gpu->eval();
  const auto p = [&](int t) { return scene_poses(scene, t); };
  const auto contacts = detect_contacts(g, pose_objects(g, p(3)), 0.1);
  const Poses a = predict_next(*cpu, norm, g, p(0), p(1), p(2), p(3), contacts),
              b = predict_next(*gpu, norm, g, p(0), p(1), p(2), p(3), contacts);
  REQUIRE((a.positions - b.positions).cwiseAbs().maxCoeff() < 1e-5);
  REQUIRE((a.quaternions - b.quaternions).cwiseAbs().maxCoeff() < 1e-4);
}

TEST_CASE("HOPNet gives all-off's loss and gradients with each fast path on alone and all on",
          "[hopnet][training][fast_paths]") {
  torch::manual_seed(11);
  const Scene scene = testing::cube_and_sphere(12);
  const Normalizer norm(unit_stats());
  Hopnet net(HopnetOptions().hidden(16).mode(FeatureMode::native));
  const auto g = make_geometry(scene, FeatureMode::native);
  const auto item = make_training_item(g, trajectory_frames(scene, g, 0.1, 0.0), norm);
  const auto run = [&] {
    net->zero_grad();
    const auto loss = trajectory_loss(*net, item, norm);
    loss.backward();
    std::vector<torch::Tensor> r{loss};
    for (const auto& p : net->parameters()) r.push_back(p.grad());
    return r;
  };
  // float32: sums in another order.
  const auto changed = test::check_fast_paths(*net, run, 1e-4, 1e-6);
  WARN("fast paths that changed some bit on HOPNet: " << test::joined(changed));
  // The loss, then gradients. The encoders' group and the node and object updates split, and
  // the faces' step runs its messages from the nodes and the edges at once.
  const auto split = test::check_step_threads(*net, run, 1, 1e-5, 1e-6);
  CHECK(split.groups > 0);
  CHECK(split.steps > 0);
}

TEST_CASE("a HOPNet's device is its parameters' device", "[hopnet]") {
  // On the CPU here; the CUDA case above moves and clones a model across devices.
  Hopnet net(HopnetOptions().hidden(16));
  REQUIRE(net->device() == net->parameters().front().device());
  net->to(torch::kDouble);
  REQUIRE(net->device() == torch::Device(torch::kCPU));
  REQUIRE(std::dynamic_pointer_cast<HopnetImpl>(net->clone())->device().is_cpu());
}

TEST_CASE("normalising features on the host equals the tensor operations bit for bit",
          "[hopnet][stats]") {
  std::mt19937 rng(12);
  std::uniform_real_distribution<double> u(-1, 1);
  auto s = unit_stats();
  for (auto& [k, v] : s.mean)
    for (std::size_t j = 0; j < v.size(); ++j)
      v[j] = 100 * u(rng), s.std[k][j] = std::pow(10.0, 3 * u(rng));
  const Normalizer norm(s);
  for (const auto& [k, n] : NormalizationStats::layout()) {
    for (const std::int64_t rows : {0, 1, 37}) {
      RowMatrix x(rows, static_cast<Eigen::Index>(n));
      for (Eigen::Index i = 0; i < x.size(); ++i) x.data()[i] = std::pow(10.0, 4 * u(rng)) * u(rng);
      INFO(k << ", " << rows << " rows");
      const auto host = norm.normalize(k, x), ops = norm.normalize(k, Normalizer::to_tensor(x));
      REQUIRE(host.scalar_type() == torch::kFloat);
      REQUIRE(torch::equal(host, ops));
    }
    const RowMatrix wrong(2, static_cast<Eigen::Index>(n) + 1);
    REQUIRE_THROWS_WITH(norm.normalize(k, wrong),
                        Catch::Contains("the features have " + std::to_string(n + 1)));
    REQUIRE_THROWS_WITH(norm.normalize(k, Normalizer::to_tensor(wrong)),
                        Catch::Contains("the features have " + std::to_string(n + 1)));
  }
  REQUIRE(torch::equal(norm.normalize("x3_plus", RowMatrix::Ones(3, 28)),
                       norm.normalize("x3", RowMatrix::Ones(3, 28))));
  REQUIRE_THROWS_WITH(norm.normalize("x9", RowMatrix::Ones(1, 1)),
                      Catch::Contains("have no 'x9' entries"));
}

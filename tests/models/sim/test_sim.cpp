// Tests of topos/sim: open_model on each checkpoint kind (reference HOPNet, topos HOPNet, FIGNet,
// MeshGraphNet) and on files that are none of them; the Simulator rollout against each model's
// own rollout function, pose for pose (bit for bit); make_model's fresh models.
#include "support/torch_prelude.hpp"

#include "support/fresh_dir.hpp"
#include "support/reference.hpp"
#include "support/scenes.hpp"
#include "topos/sim/open_model.hpp"

#include <filesystem>
#include <fstream>

using namespace topos;
namespace fs = std::filesystem;

namespace {

// Every pose of `a` equals `b`'s exactly.
void require_same_poses(const sim::RolloutResult& a, const sim::RolloutResult& b) {
  REQUIRE(a.poses.size() == b.poses.size());
  for (std::size_t t = 0; t < a.poses.size(); ++t) {
    INFO("frame " << t);
    REQUIRE((a.poses[t].positions.array() == b.poses[t].positions.array()).all());
    REQUIRE((a.poses[t].quaternions.array() == b.poses[t].quaternions.array()).all());
  }
  REQUIRE(a.invalid_ratio == b.invalid_ratio);
}

// HOPNet statistics with zero means and unit scales (the type columns as the reference forces).
models::hopnet::NormalizationStats zero_mean_unit_stats() {
  models::hopnet::NormalizationStats s;
  for (const auto& [k, n] : models::hopnet::NormalizationStats::layout())
    s.mean[k].assign(n, 0.0), s.std[k].assign(n, 1.0);
  s.mean["x4"][8] = s.mean["x4"][9] = s.std["x4"][8] = s.std["x4"][9] = 0.5;
  return s;
}

}  // namespace

TEST_CASE(
    "open_model: a topos HOPNet checkpoint rolls out as models::hopnet::rollout does, bit for bit",
    "[sim][hopnet]") {
  const auto dir = testing::fresh_dir("sim_hopnet");
  torch::manual_seed(3);
  models::hopnet::Hopnet net(
      models::hopnet::HopnetOptions().hidden(16).mode(models::hopnet::FeatureMode::native));
  models::hopnet::save_hopnet(*net, (dir / "hopnet.pt").string());
  models::hopnet::write_stats_json(zero_mean_unit_stats(), (dir / "stats.json").string());
  const auto scene = testing::cube_and_sphere();

  sim::OpenOptions o;
  o.stats = (dir / "stats.json").string();
  auto opened = sim::open_model((dir / "hopnet.pt").string(), o);
  CHECK(opened.format == "topos");
  CHECK(opened.notes.empty());
  sim::Simulator& model = *opened.simulator;
  CHECK(model.name() == "hopnet");
  CHECK(model.variant() == models::hopnet::variant_name(net->options));
  CHECK(model.num_parameters() == net->num_parameters());
  CHECK(model.config() == net->options.to_json());

  sim::RolloutOptions opt;
  opt.steps = 6;
  const auto got = sim::rollout(model, scene, opt);
  net->eval();
  const auto g = models::hopnet::make_geometry(scene, net->options.lifting());
  opt.collision_radius = net->options.collision_radius();
  const auto want = models::hopnet::rollout(
      *net, models::hopnet::Normalizer(zero_mean_unit_stats()), scene, g, opt);
  REQUIRE(got.num_frames() == 10);
  require_same_poses(got, want);
  // The predictions moved the sphere: the comparison is not of ground truth with itself.
  CHECK(got.poses.back().positions(1, 2) != scene.position(9, 1).z());
  // A clone (another worker's model) predicts the same.
  require_same_poses(sim::rollout(*model.clone(), scene, opt), want);

  // Without statistics it opens to be described only.
  CHECK_THROWS_WITH(sim::open_model((dir / "hopnet.pt").string()),
                    Catch::Contains("hopnet.pt is a HOPNet checkpoint: --stats is required"));
  sim::OpenOptions describe_only;
  describe_only.require_statistics = false;
  auto bare = sim::open_model((dir / "hopnet.pt").string(), describe_only);
  std::ostringstream text;
  bare.simulator->describe(text);
  CHECK_THAT(text.str(),
             Catch::StartsWith("variant: " + model.variant()) &&
                 Catch::Contains("parameters: " + std::to_string(net->num_parameters())));
  fs::remove_all(dir);
}

TEST_CASE(
    "open_model: FIGNet and MeshGraphNet checkpoints roll out as models::baselines::rollout does",
    "[sim][gns]") {
  const auto dir = testing::fresh_dir("sim_baselines");
  const auto scene = testing::cube_and_sphere();
  for (const std::string text :
       {R"({"model": "mgn", "latent": 8, "steps": 2})", R"({"model": "fignet", "latent": 8,
       "steps": 2, "collision_radius": 0.2})"}) {
    const auto config = models::baselines::BaselineConfig::from_json(nlohmann::json::parse(text));
    INFO(config.model());
    torch::manual_seed(5);
    models::baselines::Baseline b(config);
    const models::baselines::SceneGraphs graphs(config, scene);
    models::gns::StatisticsAccumulator acc(config.spec());
    for (std::int64_t t = 2; t + 1 < scene.num_frames; ++t) acc.add(graphs.frame(scene, t));
    const auto stats = acc.finish();
    const auto path = (dir / (config.model() + ".pt")).string();
    models::baselines::save_baseline(b, stats, path);

    auto opened = sim::open_model(path);  // no --stats: the checkpoint carries them
    CHECK(opened.format == "topos");
    sim::Simulator& model = *opened.simulator;
    CHECK(model.name() == config.model());
    CHECK(model.num_parameters() == b.num_parameters());
    sim::RolloutOptions opt;
    opt.steps = 5;
    const auto got = sim::rollout(model, scene, opt);
    b.net->eval();
    const auto want = models::baselines::rollout(b, stats, scene, graphs, opt);
    REQUIRE(got.num_frames() == 9);
    require_same_poses(got, want);
    CHECK(got.poses.back().positions(1, 2) != scene.position(8, 1).z());
    require_same_poses(sim::rollout(*model.clone(), scene, opt), want);
  }
  fs::remove_all(dir);
}

TEST_CASE("A baseline checkpoint written before hidden_layers (as mlp_layers) still loads",
          "[sim][gns]") {
  const auto dir = testing::fresh_dir("sim_old_baseline");
  const auto scene = testing::cube_and_sphere();
  const auto config = models::baselines::BaselineConfig::from_json(
      {{"model", "mgn"}, {"latent", 8}, {"steps", 1}, {"hidden_layers", 1}});
  torch::manual_seed(7);
  models::baselines::Baseline b(config);
  const models::baselines::SceneGraphs graphs(config, scene);
  models::gns::StatisticsAccumulator acc(config.spec());
  for (std::int64_t t = 2; t + 1 < scene.num_frames; ++t) acc.add(graphs.frame(scene, t));
  const auto path = (dir / "mgn.pt").string();
  models::baselines::save_baseline(b, acc.finish(), path);
  auto dict = nn::read_tensor_dict(path);
  // The configuration as checkpoints recorded it before: the depth under "mlp_layers".
  auto old = models::baselines::checkpoint_config(dict, path);
  REQUIRE(old.at("hidden_layers") == 1);
  old.erase("hidden_layers");
  old["mlp_layers"] = 1;
  const std::string text = old.dump();
  dict["topos.config"] =
      torch::tensor(std::vector<std::uint8_t>(text.begin(), text.end()), torch::kUInt8);
  const auto loaded = models::baselines::load_baseline(dict, path, "mgn");
  CHECK(loaded.model.config.to_json() == config.to_json());
  CHECK(loaded.model.num_parameters() == b.num_parameters());
  const auto want = b.net->named_parameters(), got = loaded.model.net->named_parameters();
  REQUIRE(got.size() == want.size());
  for (const auto& p : want) CHECK(torch::equal(got[p.key()], p.value()));
  fs::remove_all(dir);
}

TEST_CASE("open_model: a file of no known format is an error naming it and the formats", "[sim]") {
  const auto dir = testing::fresh_dir("sim_bad_files");
  const auto plain = (dir / "plain.pt").string();
  c10::Dict<std::string, torch::Tensor> d;
  d.insert("weight", torch::zeros({2, 2}));
  nn::write_tensor_dict(d, plain);
  CHECK_THROWS_WITH(sim::open_model(plain), Catch::Contains("plain.pt: not a model checkpoint") &&
                                                Catch::Contains("a topos checkpoint") &&
                                                Catch::Contains("reference HOPNet state dict"));

  const auto other = (dir / "other.pt").string();
  const std::string cfg = R"({"model": "gcn"})";
  d.insert("topos.config",
           torch::tensor(std::vector<std::uint8_t>(cfg.begin(), cfg.end()), torch::kUInt8));
  nn::write_tensor_dict(d, other);
  CHECK_THROWS_WITH(sim::open_model(other),
                    Catch::Contains("other.pt: a checkpoint of model 'gcn'") &&
                        Catch::Contains("hopnet, fignet or mgn"));

  const auto junk = (dir / "junk.pt").string();
  std::ofstream(junk) << "not a torch file";
  CHECK_THROWS_WITH(sim::open_model(junk), Catch::Contains("junk.pt"));
  fs::remove_all(dir);
}

TEST_CASE("make_model: fresh models of configurations", "[sim]") {
  CHECK(sim::make_model("fignet")->num_parameters() == 5559430);
  CHECK(sim::make_model("mgn")->num_parameters() == 2613507);
  CHECK(sim::make_model("mgn-large-radius")->name() == "mgn-large-radius");
  const auto standard = sim::make_model("");
  CHECK(standard->name() == "hopnet");
  CHECK(standard->variant() == "standard");
  CHECK(standard->num_parameters() == 707078);
  // A fresh baseline has no statistics: it cannot predict.
  auto mgn = sim::make_model("mgn");
  const auto scene = testing::cube_and_sphere();
  mgn->reset(scene);
  std::vector<sim::Poses> window;
  for (int t = 0; t < 4; ++t) window.push_back(sim::scene_poses(scene, t));
  CHECK_THROWS_WITH(mgn->predict(window, {}), Catch::Contains("no normalisation statistics"));
}

TEST_CASE("open_model on the published MOVi-A checkpoint: the reference rollout, bit for bit",
          "[sim][hopnet][reference]") {
  const auto ref = test::reference_dir("open_model on the published checkpoint");
  const auto ckpt = (ref / "data" / "checkpoints" / "modela_seed2_e39.pt").string();
  sim::OpenOptions o;
  o.stats = (ref / "data" / "normalization" / "movia.json").string();
  o.mode = models::hopnet::FeatureMode::reference;
  auto opened = sim::open_model(ckpt, o);
  CHECK_THAT(opened.format,
             Catch::StartsWith("reference (HOPNet authors' state dict, class HOPNet, "));
  CHECK(opened.simulator->num_parameters() == 707078);
  sim::MeshLibrary lib(ref / "data" / "kubasic");
  const auto scene =
      sim::make_scene(data::read_kubric_metadata(ref / "data" / "movi-a" / "8"), lib);
  sim::RolloutOptions opt;
  opt.steps = 8;
  opt.first_contacts = models::hopnet::read_collisions_json(
                           (ref / "data" / "movi-a" / "8" / "collisions.json").string())
                           .at(3);
  const auto got = sim::rollout(*opened.simulator, scene, opt);

  auto net = models::hopnet::load_hopnet(ckpt, models::hopnet::FeatureMode::reference);
  net->eval();
  const auto g = models::hopnet::make_geometry(scene, net->options.lifting());
  const models::hopnet::Normalizer norm(models::hopnet::read_stats_json(o.stats));
  const auto want = models::hopnet::rollout(*net, norm, scene, g, opt);
  require_same_poses(got, want);
}

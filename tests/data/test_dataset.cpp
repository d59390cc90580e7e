// Tests of topos/data/dataset.hpp: seed ranges, the reference split (the published 1200 and 10
// lists, and the fallback's proportions), custom splits and their errors, and the topos dataset
// format: a round trip of every pose, both formats read alike, and clear errors for truncated,
// mismatched or malformed files, never a silent wrong answer.
#include <catch2/catch.hpp>

#include "support/fresh_dir.hpp"

#include "topos/data/dataset.hpp"

#include <fstream>
#include <random>

using namespace topos::data;
namespace fs = std::filesystem;

namespace {

std::vector<KubricScene> random_scenes(int n, std::int64_t frames, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  std::vector<KubricScene> out;
  for (int s = 0; s < n; ++s) {
    KubricScene k;
    k.seed = 10 + 3 * s;
    k.num_frames = frames;
    for (unsigned o = 0; o < 1 + rng() % 4; ++o) {
      KubricInstance in;
      in.asset_id = in.shape = (o % 2) ? "sphere" : "cube";
      in.size = 0.5 + o, in.mass = 1.5 * (o + 1), in.friction = 0.25, in.restitution = 0.75;
      in.positions.resize(frames, 3);
      in.quaternions.resize(frames, 4);
      for (std::int64_t f = 0; f < frames; ++f) {
        for (int c = 0; c < 3; ++c) in.positions(f, c) = u(rng);
        for (int c = 0; c < 4; ++c) in.quaternions(f, c) = u(rng);
      }
      k.instances.push_back(in);
    }
    out.push_back(k);
  }
  return out;
}
}  // namespace

TEST_CASE("seed ranges parse lists and ranges, and reject nonsense", "[data][dataset]") {
  REQUIRE(parse_seed_range("1-3,8,10-11") == std::vector<std::int64_t>{1, 2, 3, 8, 10, 11});
  REQUIRE(parse_seed_range("5,5,4") == std::vector<std::int64_t>{4, 5});
  REQUIRE(parse_seed_range("1-1200").size() == 1200);
  REQUIRE(parse_seed_range("6-8,1-5,3-7,2") == std::vector<std::int64_t>{1, 2, 3, 4, 5, 6, 7, 8});
  // At most 10,000,000 seeds in all, however the parts overlap (found by fuzzing: parts of a
  // few million each used to be inserted one by one into a set).
  REQUIRE(parse_seed_range("0-9999999,5-9999999").size() == 10000000);
  REQUIRE_THROWS_WITH(parse_seed_range("0-9999999,10000000"), Catch::Contains("too many seeds"));
  for (const char* bad : {"", "5-2", "a", "1-", "3-x", "1,,2", "-4"}) {
    INFO(bad);
    REQUIRE_THROWS_AS(parse_seed_range(bad), DataError);
  }
}

TEST_CASE("the reference split gives the published lists", "[data][dataset][split]") {
  const auto s = reference_split(parse_seed_range("1-1200"));
  REQUIRE(s.train.size() == 960);
  REQUIRE(s.val.size() == 120);
  REQUIRE(s.test.size() == 120);
  REQUIRE(s.test.front() == 4);
  REQUIRE(s.test.back() == 1197);
  REQUIRE(s.val.front() == 15);
  const auto ten = reference_split(parse_seed_range("1-10"));
  REQUIRE(ten.val == std::vector<std::int64_t>{8});
  REQUIRE(ten.test == std::vector<std::int64_t>{6});
  // Any other set: ceil(0.8 n) / ceil(0.1 n) / rest, disjoint, covering, deterministic.
  const auto ids = parse_seed_range("3-99");
  const auto a = reference_split(ids), b = reference_split(ids);
  REQUIRE(a.train.size() == 78);
  REQUIRE(a.val.size() == 10);
  REQUIRE(a.test.size() == 9);
  REQUIRE(a.test == b.test);
  std::vector<std::int64_t> all = a.train;
  all.insert(all.end(), a.val.begin(), a.val.end());
  all.insert(all.end(), a.test.begin(), a.test.end());
  std::sort(all.begin(), all.end());
  REQUIRE(all == ids);
}

TEST_CASE("custom splits are read, checked against the dataset, and round-trip",
          "[data][dataset][split]") {
  const auto s = parse_split_json(R"({"train": [3, 1], "test": [7]})", "split.json");
  REQUIRE(s.train == std::vector<std::int64_t>{1, 3});
  REQUIRE(s.val.empty());
  REQUIRE(split_part(s, "test", {1, 3, 7}) == std::vector<std::int64_t>{7});
  REQUIRE(split_part(s, "all", {1, 3, 7}).size() == 3);
  REQUIRE_THROWS_WITH(split_part(s, "test", {1, 3}),
                      Catch::Contains("seed 7, which the dataset does not hold"));
  REQUIRE_THROWS_WITH(split_part(s, "holdout", {1}),
                      Catch::Contains("unknown split part 'holdout'"));
  REQUIRE_THROWS_WITH(parse_split_json(R"({"train": [1, 2], "val": [2]})", "s.json"),
                      Catch::Contains("seed 2 is listed twice"));
  REQUIRE_THROWS_WITH(parse_split_json(R"({"train": [1], "extra": []})", "s.json"),
                      Catch::Contains("unknown part 'extra'"));
  REQUIRE_THROWS_WITH(parse_split_json(R"({"train": [1,)", "s.json"),
                      Catch::Contains("malformed split"));
  REQUIRE_THROWS_WITH(parse_split_json(R"({"train": ["a"]})", "s.json"),
                      Catch::Contains("s.json: a seed of train: expected an integer") &&
                          Catch::Contains("got \"a\""));
  REQUIRE_THROWS_WITH(parse_split_json(R"({"train": [3.5e97]})", "s.json"),
                      Catch::Contains("s.json: a seed of train: expected an integer"));
  const auto back =
      parse_split_json(split_json(reference_split(parse_seed_range("1-10"))).dump(), "x");
  REQUIRE(back.test == std::vector<std::int64_t>{6});
}

TEST_CASE("a topos dataset holds every pose and property exactly", "[data][dataset][format]") {
  const auto dir = topos::testing::fresh_dir("dataset_roundtrip");
  const auto scenes = random_scenes(7, 11, 3);
  write_topos_dataset(scenes, dir);
  const auto d = Dataset::open(dir);
  REQUIRE(d.format() == "topos");
  REQUIRE(d.ids().size() == scenes.size());
  for (const auto& want : scenes) {
    REQUIRE(d.contains(want.seed));
    const auto got = d.scene(want.seed);
    REQUIRE(got.num_frames == want.num_frames);
    REQUIRE(got.instances.size() == want.instances.size());
    for (std::size_t o = 0; o < want.instances.size(); ++o) {
      const auto& a = got.instances[o];
      const auto& b = want.instances[o];
      REQUIRE(a.shape == b.shape);
      REQUIRE(a.size == b.size);
      REQUIRE(a.mass == b.mass);
      REQUIRE(a.friction == b.friction);
      REQUIRE(a.restitution == b.restitution);
      REQUIRE(a.positions == b.positions);  // float64 on disk: bit for bit
      REQUIRE(a.quaternions == b.quaternions);
    }
  }
  REQUIRE_THROWS_WITH(d.scene(999), Catch::Contains("no scene 999"));
  // Never overwritten.
  REQUIRE_THROWS_WITH(write_topos_dataset(scenes, dir),
                      Catch::Contains("already holds a topos dataset"));
  // Scenes of different lengths do not make one dataset.
  auto mixed = random_scenes(2, 5, 4);
  mixed[1] = random_scenes(1, 6, 5)[0];
  REQUIRE_THROWS_WITH(write_topos_dataset(mixed, topos::testing::fresh_dir("dataset_mixed")),
                      Catch::Contains("frames"));
}

TEST_CASE("a Kubric folder and its packed topos dataset read alike", "[data][dataset][format]") {
  const auto kub = topos::testing::fresh_dir("dataset_kubric");
  const auto scenes = random_scenes(3, 4, 9);
  for (const auto& s : scenes) {
    nlohmann::json j{
        {"metadata",
         {{"num_frames", s.num_frames}, {"num_instances", s.instances.size()}, {"seed", s.seed}}},
        {"instances", nlohmann::json::array()}};
    for (const auto& in : s.instances) {
      nlohmann::json p = nlohmann::json::array(), q = nlohmann::json::array();
      for (std::int64_t f = 0; f < s.num_frames; ++f) {
        p.push_back({in.positions(f, 0), in.positions(f, 1), in.positions(f, 2)});
        q.push_back({in.quaternions(f, 0), in.quaternions(f, 1), in.quaternions(f, 2),
                     in.quaternions(f, 3)});
      }
      j["instances"].push_back({{"asset_id", in.asset_id},
                                {"shape", in.shape},
                                {"size", in.size},
                                {"mass", in.mass},
                                {"friction", in.friction},
                                {"restitution", in.restitution},
                                {"positions", p},
                                {"quaternions", q}});
    }
    fs::create_directories(kub / std::to_string(s.seed));
    std::ofstream(kub / std::to_string(s.seed) / "metadata.json") << j.dump();
  }
  const auto k = Dataset::open(kub);
  REQUIRE(k.format() == "kubric");
  std::vector<KubricScene> read;
  for (auto id : k.ids()) read.push_back(k.scene(id));
  const auto packed = topos::testing::fresh_dir("dataset_packed");
  write_topos_dataset(read, packed);
  const auto t = Dataset::open(packed);
  REQUIRE(t.ids() == k.ids());
  for (auto id : k.ids()) {
    const auto a = k.scene(id), b = t.scene(id);
    REQUIRE(a.instances.size() == b.instances.size());
    for (std::size_t o = 0; o < a.instances.size(); ++o)
      REQUIRE(a.instances[o].positions == b.instances[o].positions);
  }
}

TEST_CASE("damaged topos datasets are clear errors", "[data][dataset][format][errors]") {
  const auto good = topos::testing::fresh_dir("dataset_good");
  write_topos_dataset(random_scenes(3, 6, 1), good);
  const auto damaged = [&](const std::string& name,
                           const std::function<void(const fs::path&)>& damage) {
    const auto d = topos::testing::fresh_dir("dataset_" + name);
    for (const auto& f : {"dataset.json", "positions.npy", "quaternions.npy"})
      fs::copy_file(good / f, d / f);
    damage(d);
    return d;
  };
  const auto truncate = [](const fs::path& f, std::uintmax_t keep) { fs::resize_file(f, keep); };
  REQUIRE_THROWS_WITH(Dataset::open(damaged("trunc",
                                            [&](const fs::path& d) {
                                              truncate(d / "positions.npy",
                                                       fs::file_size(d / "positions.npy") - 8);
                                            })),
                      Catch::Contains("truncated data"));
  REQUIRE_THROWS_WITH(
      Dataset::open(
          damaged("header", [&](const fs::path& d) { truncate(d / "quaternions.npy", 20); })),
      Catch::Contains("quaternions.npy"));
  REQUIRE_THROWS_WITH(
      Dataset::open(damaged("missing", [](const fs::path& d) { fs::remove(d / "positions.npy"); })),
      Catch::Contains("cannot open"));
  REQUIRE_THROWS_WITH(
      Dataset::open(damaged(
          "json", [](const fs::path& d) { std::ofstream(d / "dataset.json") << "{\"format\": "; })),
      Catch::Contains("malformed JSON"));
  const auto edit = [](const fs::path& d, const std::function<void(nlohmann::json&)>& f) {
    nlohmann::json j;
    std::ifstream(d / "dataset.json") >> j;
    f(j);
    std::ofstream(d / "dataset.json") << j.dump();
  };
  REQUIRE_THROWS_WITH(
      Dataset::open(damaged(
          "frames", [&](const fs::path& d) { edit(d, [](auto& j) { j["num_frames"] = 7; }); })),
      Catch::Contains("as dataset.json says"));
  REQUIRE_THROWS_WITH(
      Dataset::open(damaged(
          "format", [&](const fs::path& d) { edit(d, [](auto& j) { j["format"] = "other"; }); })),
      Catch::Contains("not 'topos-movi'"));
  REQUIRE_THROWS_WITH(
      Dataset::open(damaged(
          "offset",
          [&](const fs::path& d) { edit(d, [](auto& j) { j["scenes"][1]["offset"] = 0; }); })),
      Catch::Contains("offset"));
  REQUIRE_THROWS_WITH(Dataset::open(damaged("dup",
                                            [&](const fs::path& d) {
                                              edit(d, [](auto& j) {
                                                j["scenes"][1]["seed"] = j["scenes"][0]["seed"];
                                              });
                                            })),
                      Catch::Contains("appears twice"));
  REQUIRE_THROWS_WITH(Dataset::open(damaged("field",
                                            [&](const fs::path& d) {
                                              edit(d, [](auto& j) {
                                                j["scenes"][0]["instances"][0].erase("mass");
                                              });
                                            })),
                      Catch::Contains("malformed dataset index"));
  REQUIRE_THROWS_WITH(Dataset::open(topos::testing::fresh_dir("dataset_empty")),
                      Catch::Contains("no scene folders"));
}

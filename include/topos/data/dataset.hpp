// topos/data/dataset.hpp
// Datasets of MOVi scenes on disk, in two formats (docs/datasets.md):
//  - kubric: a folder of numeric scene folders, `<root>/<seed>/metadata.json` (Kubric's layout,
//    which the reference code reads too);
//  - topos: `<root>/dataset.json` (every scene's objects and properties) beside
//    `positions.npy` (float64, objects × frames × 3) and `quaternions.npy` (objects × frames × 4,
//    w x y z), all scenes' objects stacked; two reads load a whole dataset, and NumPy opens it.
// Seed ranges, the reference's 80/10/10 split (data/movi_dataset.py: the exact lists for seeds
// 1..1200 and 1..10; other sets get a documented deterministic split) and custom splits as JSON.
// std + nlohmann-json.
#pragma once

#include "topos/data/kubric.hpp"
#include "topos/data/npy.hpp"

#include <algorithm>
#include <map>
#include <cmath>
#include <filesystem>
#include <random>
#include <set>
#include <string>
#include <vector>

namespace topos::data {

/// Parses "1-1200", "8", or "1,3,10-12" into ascending unique seeds (at most 10,000,000; the
/// parts are merged as ranges first, so overlapping parts cost nothing).
inline std::vector<std::int64_t> parse_seed_range(const std::string& text) {
  constexpr long long max_seeds = 10000000;
  std::vector<std::pair<long long, long long>> parts;
  std::size_t pos = 0;
  const auto fail = [&](const std::string& why) {
    throw DataError("seed range '" + text + "': " + why);
  };
  if (text.empty()) fail("empty");
  while (pos <= text.size()) {
    const auto comma = text.find(',', pos);
    const std::string part =
        text.substr(pos, comma == std::string::npos ? std::string::npos : comma - pos);
    const auto dash = part.find('-', 1);
    try {
      std::size_t used = 0;
      const long long a = std::stoll(part.substr(0, dash), &used);
      if (used != (dash == std::string::npos ? part.size() : dash))
        fail("'" + part + "' is not a number or a range");
      long long b = a;
      if (dash != std::string::npos) {
        const std::string rest = part.substr(dash + 1);
        b = std::stoll(rest, &used);
        if (used != rest.size()) fail("'" + part + "' is not a range");
      }
      if (a < 0 || b < a) fail("'" + part + "' is empty or negative");
      if (b - a >= max_seeds) fail("too many seeds");
      parts.emplace_back(a, b);
    } catch (const std::logic_error&) {
      fail("'" + part + "' is not a number or a range");
    }
    if (comma == std::string::npos) break;
    pos = comma + 1;
  }
  std::sort(parts.begin(), parts.end());
  std::vector<std::pair<long long, long long>> merged;
  long long total = 0;
  for (const auto& [a, b] : parts) {
    if (!merged.empty() && a <= merged.back().second + 1) {
      if (b > merged.back().second) total += b - merged.back().second, merged.back().second = b;
    } else {
      merged.emplace_back(a, b);
      total += b - a + 1;
    }
    if (total > max_seeds) fail("too many seeds");
  }
  std::vector<std::int64_t> out;
  out.reserve(static_cast<std::size_t>(total));
  for (const auto& [a, b] : merged)
    for (long long s = a; s <= b; ++s) out.push_back(s);
  return out;
}

/// Numeric scene folders holding metadata.json, ascending (the reference's sample list).
inline std::vector<std::int64_t> list_scenes(const std::filesystem::path& root) {
  if (!std::filesystem::is_directory(root))
    throw DataError(root.string() + ": dataset folder does not exist");
  std::vector<std::int64_t> ids;
  for (const auto& e : std::filesystem::directory_iterator(root)) {
    const std::string n = e.path().filename().string();
    if (!e.is_directory() || n.empty() || n.size() > 9 ||
        !std::all_of(n.begin(), n.end(), ::isdigit))
      continue;
    if (std::filesystem::exists(e.path() / "metadata.json")) ids.push_back(std::stoll(n));
  }
  std::sort(ids.begin(), ids.end());
  if (ids.empty()) throw DataError(root.string() + ": no scene folders (<seed>/metadata.json)");
  return ids;
}

struct Split {
  std::vector<std::int64_t> train, val, test;
};

/// The reference's split. For exactly the seeds 1..1200 and 1..10 it is the published lists
/// (numpy default_rng(0) choices); otherwise train/val/test take ceil(0.8n)/ceil(0.1n)/rest of
/// a std::mt19937(0) shuffle, sorted.
inline Split reference_split(const std::vector<std::int64_t>& ids) {
  static const std::vector<std::int64_t> val1200{
      15,   16,   26,   27,   37,   39,   45,   46,   50,   52,   67,   74,   80,   87,   91,
      95,   98,   101,  123,  129,  132,  154,  159,  173,  176,  183,  188,  197,  207,  217,
      222,  226,  256,  260,  261,  263,  265,  306,  311,  319,  350,  354,  379,  380,  383,
      416,  433,  445,  460,  463,  466,  479,  480,  489,  490,  494,  509,  522,  532,  587,
      588,  598,  602,  607,  613,  623,  624,  646,  647,  667,  669,  675,  676,  677,  687,
      691,  693,  701,  703,  713,  775,  796,  802,  811,  829,  835,  837,  846,  851,  855,
      863,  866,  868,  870,  879,  887,  896,  902,  904,  917,  946,  961,  977,  1027, 1031,
      1044, 1049, 1051, 1059, 1064, 1072, 1074, 1083, 1085, 1093, 1131, 1158, 1164, 1184, 1192};
  static const std::vector<std::int64_t> test1200{
      4,    40,   47,   54,   55,   72,   78,   82,   93,   124,  126,  131,  140,  143,  152,
      172,  180,  203,  236,  255,  264,  271,  273,  281,  290,  301,  309,  315,  316,  327,
      330,  342,  348,  349,  381,  391,  415,  419,  423,  437,  469,  482,  487,  491,  499,
      504,  507,  542,  545,  547,  551,  553,  595,  599,  616,  626,  641,  652,  655,  672,
      694,  716,  724,  729,  731,  747,  755,  764,  772,  794,  804,  809,  812,  817,  826,
      830,  849,  854,  860,  883,  905,  908,  924,  926,  944,  959,  969,  975,  982,  1000,
      1011, 1019, 1021, 1028, 1033, 1034, 1039, 1042, 1060, 1061, 1073, 1092, 1102, 1103, 1104,
      1106, 1111, 1118, 1121, 1124, 1136, 1139, 1144, 1150, 1167, 1169, 1175, 1179, 1190, 1197};
  Split s;
  const auto consecutive = [&](std::int64_t n) {
    if (static_cast<std::int64_t>(ids.size()) != n) return false;
    for (std::int64_t i = 0; i < n; ++i)
      if (ids[static_cast<std::size_t>(i)] != i + 1) return false;
    return true;
  };
  std::set<std::int64_t> val, test;
  if (consecutive(1200)) {
    val.insert(val1200.begin(), val1200.end());
    test.insert(test1200.begin(), test1200.end());
  } else if (consecutive(10)) {
    val = {8};
    test = {6};
  } else {
    std::vector<std::int64_t> order = ids;
    std::mt19937 rng(0);
    std::shuffle(order.begin(), order.end(), rng);
    const auto n = order.size(),
               ntrain = static_cast<std::size_t>(std::ceil(0.8 * static_cast<double>(n))),
               nval = std::min(n - ntrain,
                               static_cast<std::size_t>(std::ceil(0.1 * static_cast<double>(n))));
    val.insert(order.begin() + static_cast<std::ptrdiff_t>(ntrain),
               order.begin() + static_cast<std::ptrdiff_t>(ntrain + nval));
    test.insert(order.begin() + static_cast<std::ptrdiff_t>(ntrain + nval), order.end());
  }
  for (auto id : ids) (val.count(id) ? s.val : test.count(id) ? s.test : s.train).push_back(id);
  return s;
}

inline nlohmann::json split_json(const Split& s) {
  return {{"train", s.train}, {"val", s.val}, {"test", s.test}};
}

/// A custom split: {"train": [...], "val": [...], "test": [...]} (any part may be missing). A seed
/// in two parts is an error.
inline Split parse_split_json(const std::string& text, const std::string& source) {
  Split s;
  std::set<std::int64_t> seen;
  try {
    const auto j = nlohmann::json::parse(text);
    if (!j.is_object())
      throw DataError(source + ": a split is a JSON object with train/val/test seed lists");
    for (auto& [key, part] : std::vector<std::pair<const char*, std::vector<std::int64_t>*>>{
             {"train", &s.train}, {"val", &s.val}, {"test", &s.test}}) {
      if (!j.contains(key)) continue;
      const auto& list = j.at(key);
      if (!list.is_array()) throw DataError(source + ": '" + key + "' must be a list of seeds");
      part->clear();
      for (const auto& v : list) part->push_back(get_integer(v, source + ": a seed of " + key));
      for (auto id : *part)
        if (!seen.insert(id).second)
          throw DataError(source + ": seed " + std::to_string(id) + " is listed twice");
      std::sort(part->begin(), part->end());
    }
    for (const auto& [k, v] : j.items())
      if (k != "train" && k != "val" && k != "test")
        throw DataError(source + ": unknown part '" + k + "' (train, val, test)");
  } catch (const nlohmann::json::exception& e) {
    throw DataError(source + ": malformed split: " + e.what());
  }
  return s;
}

inline Split read_split_json(const std::filesystem::path& path) {
  return parse_split_json(read_text_file(path), path.string());
}

/// The seeds of `part` ("train", "val", "test" or "all") that a dataset must hold; a listed seed
/// the dataset lacks is an error naming it.
inline std::vector<std::int64_t> split_part(const Split& s, const std::string& part,
                                            const std::vector<std::int64_t>& available) {
  std::vector<std::int64_t> ids;
  if (part == "all")
    ids = available;
  else if (part == "train")
    ids = s.train;
  else if (part == "val")
    ids = s.val;
  else if (part == "test")
    ids = s.test;
  else
    throw DataError("unknown split part '" + part + "' (train, val, test, all)");
  for (auto id : ids)
    if (!std::binary_search(available.begin(), available.end(), id))
      throw DataError("the " + part + " split lists seed " + std::to_string(id) +
                      ", which the dataset does not hold");
  return ids;
}

/// A dataset in either format, opened by its folder. Kubric scenes are read when asked for; a
/// topos dataset is read whole at open.
class Dataset {
 public:
  static Dataset open(const std::filesystem::path& root) {
    Dataset d;
    d.root_ = root;
    if (std::filesystem::exists(root / "dataset.json")) {
      d.format_ = "topos";
      d.load_topos();
    } else {
      d.format_ = "kubric";
      d.ids_ = list_scenes(root);
    }
    return d;
  }
  const std::vector<std::int64_t>& ids() const { return ids_; }
  const std::string& format() const { return format_; }
  const std::filesystem::path& root() const { return root_; }
  bool contains(std::int64_t id) const { return std::binary_search(ids_.begin(), ids_.end(), id); }

  /// The reference's contacts of every frame of a scene (collisions.json: beside the scene's
  /// metadata.json, or collisions/<seed>.json in a topos dataset), or "" when there are none.
  std::string collisions_path(std::int64_t id) const {
    const auto p = format_ == "kubric" ? root_ / std::to_string(id) / "collisions.json"
                                       : root_ / "collisions" / (std::to_string(id) + ".json");
    return std::filesystem::exists(p) ? p.string() : std::string();
  }

  KubricScene scene(std::int64_t id) const {
    if (format_ == "kubric") return read_kubric_metadata(root_ / std::to_string(id));
    auto it = scenes_.find(id);
    if (it == scenes_.end())
      throw DataError((root_ / "dataset.json").string() + ": no scene " + std::to_string(id));
    return it->second;
  }

 private:
  std::filesystem::path root_;
  std::string format_;
  std::vector<std::int64_t> ids_;
  std::map<std::int64_t, KubricScene> scenes_;

  void load_topos() {
    const nlohmann::json j = read_json_file(root_ / "dataset.json");
    NpyArray pos, quat;
    try {
      pos = read_npy((root_ / "positions.npy").string());
      quat = read_npy((root_ / "quaternions.npy").string());
    } catch (const std::runtime_error& e) {
      throw DataError(e.what());
    }
    load_topos(j, pos, quat);
  }

 public:
  /// A topos dataset from its index and arrays as read from `root` (what open does after
  /// reading the three files); every inconsistency is a DataError naming the file.
  static Dataset from_topos(const std::filesystem::path& root, const nlohmann::json& index,
                            const NpyArray& positions, const NpyArray& quaternions) {
    Dataset d;
    d.root_ = root;
    d.format_ = "topos";
    d.load_topos(index, positions, quaternions);
    return d;
  }

 private:
  void load_topos(const nlohmann::json& j, const NpyArray& pos, const NpyArray& quat) {
    const auto index_path = (root_ / "dataset.json").string();
    try {
      if (j.at("format").get<std::string>() != "topos-movi")
        throw DataError(index_path + ": format is not 'topos-movi'");
      if (get_integer(j.at("version"), index_path + ": version") != 1)
        throw DataError(index_path + ": unsupported version " + j.at("version").dump());
      const std::int64_t frames = get_integer(j.at("num_frames"), index_path + ": num_frames"),
                         total = get_integer(j.at("num_objects"), index_path + ": num_objects");
      if (frames <= 0 || total <= 0)
        throw DataError(index_path + ": num_frames and num_objects must be positive");
      const auto check = [&](const NpyArray& a, const char* name, std::int64_t cols) {
        if (a.dtype != "f8" || a.shape != std::vector<std::int64_t>{total, frames, cols})
          throw DataError((root_ / name).string() + ": expected float64 of shape (" +
                          std::to_string(total) + ", " + std::to_string(frames) + ", " +
                          std::to_string(cols) + ") as dataset.json says");
      };
      check(pos, "positions.npy", 3);
      check(quat, "quaternions.npy", 4);
      const auto* P = reinterpret_cast<const double*>(pos.bytes.data());
      const auto* Q = reinterpret_cast<const double*>(quat.bytes.data());
      std::int64_t next = 0;
      for (const auto& js : j.at("scenes")) {
        KubricScene s;
        s.seed = get_integer(js.at("seed"), index_path + ": a scene's seed");
        s.num_frames = frames;
        s.source = index_path + " (seed " + std::to_string(s.seed) + ")";
        if (get_integer(js.at("offset"), s.source + ": offset") != next)
          throw DataError(s.source + ": offset " + js.at("offset").dump() + ", expected " +
                          std::to_string(next));
        for (const auto& ji : js.at("instances")) {
          if (next >= total) throw DataError(s.source + ": more objects than num_objects");
          KubricInstance k;
          k.asset_id = ji.at("asset_id").get<std::string>();
          k.shape = ji.value("shape", k.asset_id);
          k.size = ji.at("size").get<double>(), k.mass = ji.at("mass").get<double>();
          k.friction = ji.at("friction").get<double>(),
          k.restitution = ji.at("restitution").get<double>();
          k.positions = Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>>(
              P + next * frames * 3, frames, 3);
          k.quaternions =
              Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, 4, Eigen::RowMajor>>(
                  Q + next * frames * 4, frames, 4);
          if (!k.positions.allFinite() || !k.quaternions.allFinite())
            throw DataError(s.source + ": non-finite pose of object " +
                            std::to_string(s.instances.size()));
          s.instances.push_back(std::move(k));
          ++next;
        }
        if (s.instances.empty()) throw DataError(s.source + ": the scene has no instances");
        if (!scenes_.emplace(s.seed, s).second)
          throw DataError(index_path + ": seed " + std::to_string(s.seed) + " appears twice");
        ids_.push_back(s.seed);
      }
      if (next != total)
        throw DataError(index_path + ": the scenes hold " + std::to_string(next) +
                        " objects, num_objects is " + std::to_string(total));
    } catch (const nlohmann::json::exception& e) {
      throw DataError(index_path + ": malformed dataset index: " + e.what());
    }
    std::sort(ids_.begin(), ids_.end());
    if (ids_.empty()) throw DataError(index_path + ": the dataset holds no scenes");
  }
};

/// Writes scenes (all with the same number of frames) as a topos dataset in `root`: the arrays
/// first, then dataset.json, each atomically, so a reader never sees a half-written dataset.
/// An existing dataset in `root` is never overwritten (that is an error).
inline void write_topos_dataset(const std::vector<KubricScene>& scenes,
                                const std::filesystem::path& root) {
  if (scenes.empty()) throw DataError(root.string() + ": no scenes to write");
  if (std::filesystem::exists(root / "dataset.json"))
    throw DataError(root.string() +
                    ": already holds a topos dataset (dataset.json); remove it or write elsewhere");
  const std::int64_t frames = scenes.front().num_frames;
  std::int64_t total = 0;
  for (const auto& s : scenes) {
    if (s.num_frames != frames)
      throw DataError(s.source + ": has " + std::to_string(s.num_frames) + " frames, the dataset " +
                      std::to_string(frames));
    total += static_cast<std::int64_t>(s.instances.size());
  }
  std::vector<double> P(static_cast<std::size_t>(total * frames * 3)),
      Q(static_cast<std::size_t>(total * frames * 4));
  nlohmann::json index{{"format", "topos-movi"},
                       {"version", 1},
                       {"num_frames", frames},
                       {"num_objects", total},
                       {"scenes", nlohmann::json::array()}};
  std::int64_t next = 0;
  for (const auto& s : scenes) {
    nlohmann::json js{{"seed", s.seed}, {"offset", next}, {"instances", nlohmann::json::array()}};
    for (const auto& k : s.instances) {
      js["instances"].push_back({{"asset_id", k.asset_id},
                                 {"shape", k.shape},
                                 {"size", k.size},
                                 {"mass", k.mass},
                                 {"friction", k.friction},
                                 {"restitution", k.restitution}});
      Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>>(
          P.data() + next * frames * 3, frames, 3) = k.positions;
      Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, 4, Eigen::RowMajor>>(
          Q.data() + next * frames * 4, frames, 4) = k.quaternions;
      ++next;
    }
    index["scenes"].push_back(js);
  }
  std::filesystem::create_directories(root);
  write_npy((root / "positions.npy").string(), {total, frames, 3}, P.data());
  write_npy((root / "quaternions.npy").string(), {total, frames, 4}, Q.data());
  io::write_file_atomic((root / "dataset.json").string(), index.dump() + "\n");
}

}  // namespace topos::data

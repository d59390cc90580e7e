// Python interop where users are: every torch file topos writes opens in Python's
// torch.load(..., weights_only=True) with the same tensors, and a state_dict saved by Python's
// torch.save(model.state_dict()) loads in topos and computes what Python computed. Needs
// /usr/bin/python3 with torch (Debian's python3-torch, installed by scripts/setup.sh); skipped
// with a message only when that is missing.
#include "support/torch_prelude.hpp"

#include "topos/models/hopnet/model.hpp"
#include "topos/nn/mlp.hpp"
#include "topos/nn/serialization.hpp"

#include <nlohmann/json.hpp>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>

#include <unistd.h>

namespace {

const char* kPython = "/usr/bin/python3";

void require_python_torch() {
  const std::string probe = std::string(kPython) + " -c 'import torch' >/dev/null 2>&1";
  if (std::system(probe.c_str()) != 0) {
    std::cout << "SKIPPED: Python interop needs " << kPython
              << " with torch (apt-get install python3-torch; scripts/setup.sh installs it)\n";
    std::exit(TOPOS_SKIP_CODE);
  }
}

std::filesystem::path work_dir(const std::string& name) {
  const auto d = std::filesystem::temp_directory_path() /
                 ("topos_interop_" + name + "_" + std::to_string(::getpid()));
  std::filesystem::remove_all(d);
  std::filesystem::create_directories(d);
  return d;
}

/// Runs a Python script (given as text) with arguments; requires exit status 0.
void run_python(const std::filesystem::path& dir, const std::string& script,
                const std::string& args) {
  const auto file = dir / "script.py";
  std::ofstream(file) << script;
  const std::string cmd = std::string(kPython) + " " + file.string() + " " + args + " > " +
                          (dir / "python.log").string() + " 2>&1";
  const int rc = std::system(cmd.c_str());
  std::ifstream log(dir / "python.log");
  const std::string out((std::istreambuf_iterator<char>(log)), std::istreambuf_iterator<char>());
  INFO("python output:\n" << out);
  REQUIRE(rc == 0);
}

// Loads each file with torch.load(weights_only=True) and writes, per tensor, its dtype, shape
// and values (as Python floats/ints: exact for float32, float64 and integers) to <file>.json.
const char* kLoadScript = R"(
import json, sys, torch
for path in sys.argv[1:]:
    d = torch.load(path, map_location="cpu", weights_only=True)
    out = {k: {"dtype": str(v.dtype).replace("torch.", ""), "shape": list(v.shape),
               "values": v.reshape(-1).tolist()} for k, v in d.items()}
    with open(path + ".json", "w") as f:
        json.dump(out, f)
)";

void require_same_as_python(const std::map<std::string, torch::Tensor>& mine,
                            const std::string& json_path) {
  std::ifstream in(json_path);
  const auto j = nlohmann::json::parse(in);
  REQUIRE(j.size() == mine.size());
  for (const auto& [name, t] : mine) {
    INFO("tensor " << name);
    REQUIRE(j.contains(name));
    const auto& e = j[name];
    const std::string want_dtype = t.scalar_type() == torch::kFloat    ? "float32"
                                   : t.scalar_type() == torch::kDouble ? "float64"
                                   : t.scalar_type() == torch::kLong   ? "int64"
                                                                       : "uint8";
    CHECK(e["dtype"].get<std::string>() == want_dtype);
    REQUIRE(e["shape"].get<std::vector<std::int64_t>>() == t.sizes().vec());
    const auto values = e["values"].get<std::vector<double>>();
    const auto flat = t.to(torch::kDouble).contiguous().reshape({-1});
    REQUIRE(static_cast<std::int64_t>(values.size()) == flat.numel());
    for (std::int64_t i = 0; i < flat.numel(); ++i)
      REQUIRE(values[static_cast<std::size_t>(i)] == flat[i].item<double>());
  }
}

}  // namespace

TEST_CASE(
    "every torch file topos writes opens in Python's torch.load(weights_only=True) with the same "
    "tensors",
    "[nn][interop]") {
  require_python_torch();
  const auto dir = work_dir("export");
  torch::manual_seed(3);
  // A HOPNet checkpoint (save_hopnet: parameters + topos.config), plain parameters
  // (save_parameters, with buffers), and a dict of mixed dtypes and a non-contiguous view.
  topos::models::hopnet::Hopnet net(topos::models::hopnet::HopnetOptions().hidden(4));
  topos::models::hopnet::save_hopnet(*net, (dir / "hopnet.pt").string());
  torch::nn::Sequential seq(torch::nn::Linear(3, 4), torch::nn::BatchNorm1d(4));
  seq->train();
  seq->forward(torch::randn({5, 3}));  // running statistics and num_batches_tracked move
  topos::nn::save_parameters(*seq, (dir / "params.pt").string());
  c10::Dict<std::string, torch::Tensor> mixed;
  mixed.insert("f64", torch::randn({2, 3}, torch::kDouble));
  mixed.insert("i64", torch::arange(5, torch::kLong));
  mixed.insert("u8", torch::tensor(std::vector<std::uint8_t>{0, 7, 255}, torch::kUInt8));
  mixed.insert("view", torch::arange(12, torch::kFloat).reshape({3, 4}).slice(1, 1, 3));
  mixed.insert("scalar", torch::tensor(2.5f));
  topos::nn::write_tensor_dict(mixed, (dir / "mixed.pt").string());
  run_python(dir, kLoadScript,
             (dir / "hopnet.pt").string() + " " + (dir / "params.pt").string() + " " +
                 (dir / "mixed.pt").string());

  std::map<std::string, torch::Tensor> hop;
  for (const auto& p : net->named_parameters()) hop[p.key()] = p.value().detach();
  const std::string cfg = net->options.to_json().dump();
  hop["topos.config"] =
      torch::tensor(std::vector<std::uint8_t>(cfg.begin(), cfg.end()), torch::kUInt8);
  require_same_as_python(hop, (dir / "hopnet.pt.json").string());
  std::map<std::string, torch::Tensor> params;
  for (const auto& p : seq->named_parameters()) params[p.key()] = p.value().detach();
  for (const auto& b : seq->named_buffers()) params[b.key()] = b.value();
  REQUIRE(params.count("1.num_batches_tracked"));
  require_same_as_python(params, (dir / "params.pt.json").string());
  std::map<std::string, torch::Tensor> m;
  for (const auto& kv : mixed) m[kv.key()] = kv.value();
  require_same_as_python(m, (dir / "mixed.pt.json").string());
  std::filesystem::remove_all(dir);
}

TEST_CASE(
    "a state_dict saved by Python's torch.save loads in topos and computes what Python computed",
    "[nn][interop]") {
  require_python_torch();
  const auto dir = work_dir("import");
  // Python: a Linear-ReLU-Linear-BatchNorm model, trained one step so the BatchNorm buffers
  // move, saved with torch.save(model.state_dict()); its eval output on fixed inputs to JSON.
  const char* script = R"(
import json, sys, torch
torch.manual_seed(7)
model = torch.nn.Sequential(torch.nn.Linear(3, 5), torch.nn.ReLU(), torch.nn.Linear(5, 2),
                            torch.nn.BatchNorm1d(2))
opt = torch.optim.SGD(model.parameters(), lr=0.1)
model(torch.randn(8, 3)).pow(2).sum().backward()
opt.step()
model.eval()
torch.save(model.state_dict(), sys.argv[1])
x = torch.linspace(-1, 1, 12).reshape(4, 3)
with torch.no_grad():
    y = model(x)
json.dump({"x": x.reshape(-1).tolist(), "y": y.reshape(-1).tolist()}, open(sys.argv[2], "w"))
)";
  const auto pt = (dir / "python_state_dict.pt").string(),
             expect = (dir / "expected.json").string();
  run_python(dir, script, pt + " " + expect);
  const auto dict = topos::nn::read_tensor_dict(pt);
  CHECK(dict.size() == 9);  // 3 Linear/BatchNorm weights and biases, 3 BatchNorm buffers
  REQUIRE(dict.at("3.num_batches_tracked").item<std::int64_t>() == 1);
  torch::nn::Sequential model(torch::nn::Linear(3, 5), torch::nn::ReLU(), torch::nn::Linear(5, 2),
                              torch::nn::BatchNorm1d(2));
  topos::nn::load_parameters(*model, dict, pt);
  model->eval();
  std::ifstream in(expect);
  const auto j = nlohmann::json::parse(in);
  const auto xs = j["x"].get<std::vector<float>>(), ys = j["y"].get<std::vector<float>>();
  const auto x = torch::tensor(xs).reshape({4, 3});
  const auto y = model->forward(x).reshape({-1});
  for (std::size_t i = 0; i < ys.size(); ++i)
    CHECK(y[static_cast<std::int64_t>(i)].item<float>() ==
          Approx(ys[i]).epsilon(1e-6).margin(1e-6));
  std::filesystem::remove_all(dir);
}

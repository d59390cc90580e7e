// Tests of topos/models/gns, fignet/model.hpp and mgn/model.hpp: FIGNet's and MeshGraphNet's
// parameter names, shapes and counts derived from the FIGNet reimplementation's construction,
// one Graph-Network block against an independent index_select / index_add implementation (the
// slot-interleaved hyperedge input, per-slot sums at the receivers, sums not means, the node
// input order, residuals after aggregating the pre-residual messages), collation, statistics and
// configuration errors.
#include "support/torch_prelude.hpp"
#include "support/fast_paths.hpp"

#include "topos/models/fignet/model.hpp"
#include "topos/models/mgn/model.hpp"

#include <random>

using namespace topos;

namespace {

std::map<std::string, std::vector<std::int64_t>> shapes(torch::nn::Module& m) {
  std::map<std::string, std::vector<std::int64_t>> out;
  for (const auto& p : m.named_parameters()) out[p.key()] = p.value().sizes().vec();
  return out;
}

std::int64_t count(torch::nn::Module& m) {
  std::int64_t n = 0;
  for (const auto& p : m.parameters()) n += p.numel();
  return n;
}

// The reimplementation's names, written from its code (graph_networks.py): an encoder is
// Sequential(build_mlp(in, [L, L], out), LayerNorm(out)) with build_mlp's Linear layers named
// NN-0..NN-2; a processor function is the same pair at gnn_stacks.<k>.<fn>.{0,1}; a decoder is
// the bare build_mlp at <decoder>.node_fn.
void expect_encoder_like(std::map<std::string, std::vector<std::int64_t>>& expected,
                         const std::string& mlp, const std::string& norm, std::int64_t in,
                         std::int64_t out, std::int64_t L = 128) {
  expected[mlp + "NN-0.weight"] = {L, in};
  expected[mlp + "NN-0.bias"] = {L};
  expected[mlp + "NN-1.weight"] = {L, L};
  expected[mlp + "NN-1.bias"] = {L};
  expected[mlp + "NN-2.weight"] = {out, L};
  expected[mlp + "NN-2.bias"] = {out};
  if (!norm.empty()) {
    expected[norm + ".weight"] = {out};
    expected[norm + ".bias"] = {out};
  }
}

std::map<std::string, std::vector<std::int64_t>> fignet_reference_shapes(bool mesh_edges) {
  std::map<std::string, std::vector<std::int64_t>> e;
  const std::string root = "_encode_process_decode.";
  auto encoder = [&](const std::string& name, std::int64_t in, std::int64_t out) {
    expect_encoder_like(e, root + name + ".mlp.0.", root + name + ".mlp.1", in, out);
  };
  encoder("_m_encoder", 12, 128);
  encoder("_o_encoder", 12, 128);
  encoder("_emo_encoder", 8, 128);
  encoder("_eom_encoder", 8, 128);
  if (mesh_edges) encoder("_emm_encoder", 8, 128);
  encoder("_eff_encoder", 34, 384);  // one 128-wide latent per receiver slot
  for (int k = 0; k < 10; ++k) {
    const std::string p = root + "_processor.gnn_stacks." + std::to_string(k) + ".";
    auto fn = [&](const std::string& name, std::int64_t in, std::int64_t out) {
      expect_encoder_like(e, p + name + ".0.", p + name + ".1", in, out);
    };
    fn("mesh_node_fn", mesh_edges ? 512 : 384, 128);  // [x, Σ om, (Σ mm,) Σ ff]
    fn("obj_node_fn", 256, 128);                      // [x, Σ mo]
    fn("mo_edge_fn", 384, 128);                       // [e, x_s, x_r]
    fn("om_edge_fn", 384, 128);
    if (mesh_edges) fn("mm_edge_fn", 384, 128);
    fn("ff_edge_fn", 1152, 384);  // 3 × [e_k, x_sk, x_rk]
  }
  expect_encoder_like(e, root + "_m_decoder.node_fn.", "", 128, 3);
  expect_encoder_like(e, root + "_o_decoder.node_fn.", "", 128, 3);
  return e;
}

}  // namespace

TEST_CASE("FIGNet has the reimplementation's parameters: names, shapes, 5,559,430 in 452",
          "[gns]") {
  for (bool mm : {false, true}) {
    models::fignet::FignetOptions o;
    o.mesh_edges = mm;
    auto net = models::fignet::make_fignet(o);
    const auto got = shapes(*net);
    const auto expected = fignet_reference_shapes(mm);
    for (const auto& [name, shape] : expected) {
      INFO(name);
      REQUIRE(got.count(name) == 1);
      CHECK(got.at(name) == shape);
    }
    CHECK(got.size() == expected.size());
    // Part 2 of docs/design/baselines.md: encoders 210,048 + 10 × 528,256 + decoders 66,822;
    // mm edges add 34,432 + 10 × (82,560 + 16,384).
    CHECK(count(*net) == (mm ? 6583302 : 5559430));
    CHECK(got.size() == (mm ? 540u : 452u));
  }
}

TEST_CASE("MeshGraphNet: 2,613,507 parameters at 10 steps, 3,851,907 at 15", "[gns]") {
  models::mgn::MgnOptions o;
  auto net = models::mgn::make_mgn(o);
  // node encoder 34,944 + mesh-edge 34,432 + world-edge 33,920 + steps × 3 × 82,560 + 33,411
  CHECK(count(*net) == 2613507);
  CHECK(shapes(*net).size() == 270u);
  CHECK(shapes(*net).at("_encode_process_decode._processor.gnn_stacks.9.node_fn.0.NN-0.weight") ==
        std::vector<std::int64_t>{128, 384});
  o.network.steps = 15;
  CHECK(count(*models::mgn::make_mgn(o)) == 3851907);
  o.network.steps = 10;
  o.world_edge_radius = 0.3;  // the large-radius baseline: the radius is not a parameter
  CHECK(count(*models::mgn::make_mgn(o)) == 2613507);
}

namespace {

// A FIGNet-shaped spec small enough to check by hand: 5 mesh nodes in 2 objects, 1 block.
models::gns::GraphNetworkSpec tiny_spec(std::int64_t L) {
  models::fignet::FignetOptions o;
  o.network.latent = L;
  o.network.steps = 1;
  o.network.hidden_layers = 1;
  return models::fignet::fignet_spec(o);
}

models::gns::GraphFrame tiny_frame(std::mt19937& rng) {
  std::normal_distribution<double> n(0, 1);
  auto random = [&](Eigen::Index r, Eigen::Index c) {
    models::gns::RowMatrix m(r, c);
    for (Eigen::Index i = 0; i < m.size(); ++i) m.data()[i] = n(rng);
    return m;
  };
  models::gns::GraphFrame f;
  f.nodes["mesh"].features = random(5, 12);
  f.nodes["object"].features = random(2, 12);
  const std::vector<std::int64_t> object{0, 0, 0, 1, 1};
  auto& mo = f.edges["mo"];
  auto& om = f.edges["om"];
  mo.features = random(5, 8);
  om.features = random(5, 8);
  mo.senders.resize(5, 1), mo.receivers.resize(5, 1), om.senders.resize(5, 1),
      om.receivers.resize(5, 1);
  for (int v = 0; v < 5; ++v)
    mo.senders(v, 0) = v, mo.receivers(v, 0) = object[static_cast<std::size_t>(v)],
                  om.senders(v, 0) = object[static_cast<std::size_t>(v)], om.receivers(v, 0) = v;
  // Two hyperedges: face (0,1,2) -> face (3,4,3) and back, slots permuted.
  auto& ff = f.edges["ff"];
  ff.features = random(2, 34);
  ff.senders.resize(2, 3), ff.receivers.resize(2, 3);
  ff.senders << 0, 1, 2, 4, 3, 3;
  ff.receivers << 3, 4, 3, 2, 0, 1;
  f.target = random(5, 3);
  f.dynamic = {1, 1, 1, 0, 0};
  f.node_object = object;
  return f;
}

models::gns::Statistics unit_statistics(const models::gns::GraphNetworkSpec& spec) {
  models::gns::Statistics s;
  auto unit = [&](const std::string& k, std::int64_t w) {
    s.mean[k].assign(static_cast<std::size_t>(w), 0.0);
    s.std[k].assign(static_cast<std::size_t>(w), 1.0);
  };
  for (const auto& n : spec.nodes) unit(n.statistics, n.features);
  for (const auto& e : spec.edges) unit(e.statistics, e.features);
  unit("acceleration", 3);
  return s;
}

torch::Tensor as_tensor(const models::gns::RowMatrix& m) {
  return torch::from_blob(const_cast<double*>(m.data()), {m.rows(), m.cols()}, torch::kDouble)
      .to(torch::kFloat);
}

torch::Tensor as_index(const models::gns::IndexMatrix& m, int slot) {
  std::vector<std::int64_t> v;
  for (Eigen::Index i = 0; i < m.rows(); ++i) v.push_back(m(i, slot));
  return torch::tensor(v);
}

}  // namespace

TEST_CASE("One Graph-Network block equals an index_select / index_add implementation", "[gns]") {
  torch::manual_seed(3);
  std::mt19937 rng(5);
  const std::int64_t L = 4;
  const auto spec = tiny_spec(L);
  auto net = models::gns::GraphNetwork(spec, "_encode_process_decode");
  const auto frame = tiny_frame(rng);
  const auto stats = unit_statistics(spec);
  const auto batch = models::gns::collate(spec, {&frame}, stats);
  const auto out = net->forward(batch);

  // The same network by hand, reading the parameters by their reference names.
  const auto P = net->named_parameters();
  auto mlp = [&](const std::string& prefix, const std::string& norm, torch::Tensor x) {
    x = torch::relu(
        torch::nn::functional::linear(x, P[prefix + "NN-0.weight"], P[prefix + "NN-0.bias"]));
    x = torch::nn::functional::linear(x, P[prefix + "NN-1.weight"], P[prefix + "NN-1.bias"]);
    if (norm.empty()) return x;
    return torch::layer_norm(x, {x.size(1)}, P[norm + ".weight"], P[norm + ".bias"]);
  };
  const std::string r = "_encode_process_decode.";
  auto enc = [&](const std::string& name, const torch::Tensor& x) {
    return mlp(r + name + ".mlp.0.", r + name + ".mlp.1", x);
  };
  auto fn = [&](const std::string& name, const torch::Tensor& x) {
    return mlp(r + "_processor.gnn_stacks.0." + name + ".0.",
               r + "_processor.gnn_stacks.0." + name + ".1", x);
  };
  auto xm = enc("_m_encoder", as_tensor(frame.nodes.at("mesh").features));
  auto xo = enc("_o_encoder", as_tensor(frame.nodes.at("object").features));
  auto emo = enc("_emo_encoder", as_tensor(frame.edges.at("mo").features));
  auto eom = enc("_eom_encoder", as_tensor(frame.edges.at("om").features));
  auto eff = enc("_eff_encoder", as_tensor(frame.edges.at("ff").features));
  REQUIRE(eff.size(1) == 3 * L);
  const auto& mo = frame.edges.at("mo");
  const auto& om = frame.edges.at("om");
  const auto& ff = frame.edges.at("ff");
  auto msg_mo = fn("mo_edge_fn", torch::cat({emo, xm.index_select(0, as_index(mo.senders, 0)),
                                             xo.index_select(0, as_index(mo.receivers, 0))},
                                            1));
  auto msg_om = fn("om_edge_fn", torch::cat({eom, xo.index_select(0, as_index(om.senders, 0)),
                                             xm.index_select(0, as_index(om.receivers, 0))},
                                            1));
  std::vector<torch::Tensor> blocks;  // [e_0, s_0, r_0, e_1, s_1, r_1, e_2, s_2, r_2]
  for (int k = 0; k < 3; ++k) {
    blocks.push_back(eff.narrow(1, k * L, L));
    blocks.push_back(xm.index_select(0, as_index(ff.senders, k)));
    blocks.push_back(xm.index_select(0, as_index(ff.receivers, k)));
  }
  auto msg_ff = fn("ff_edge_fn", torch::cat(blocks, 1));
  auto sum_om = torch::zeros({5, L}).index_add(0, as_index(om.receivers, 0), msg_om);
  auto sum_mo = torch::zeros({2, L}).index_add(0, as_index(mo.receivers, 0), msg_mo);
  auto sum_ff = torch::zeros({5, L});
  for (int k = 0; k < 3; ++k)
    sum_ff = sum_ff.index_add(0, as_index(ff.receivers, k), msg_ff.narrow(1, k * L, L));
  auto xm2 = xm + fn("mesh_node_fn", torch::cat({xm, sum_om, sum_ff}, 1));
  auto xo2 = xo + fn("obj_node_fn", torch::cat({xo, sum_mo}, 1));
  auto am = mlp(r + "_m_decoder.node_fn.", "", xm2);
  auto ao = mlp(r + "_o_decoder.node_fn.", "", xo2);
  CHECK(torch::allclose(out.at("mesh"), am, 1e-5, 1e-5));
  CHECK(torch::allclose(out.at("object"), ao, 1e-5, 1e-5));

  // Two copies of the frame in one batch give the same rows twice.
  const auto twice = net->forward(models::gns::collate(spec, {&frame, &frame}, stats));
  CHECK(torch::allclose(twice.at("mesh").narrow(0, 0, 5), am, 1e-5, 1e-5));
  CHECK(torch::allclose(twice.at("mesh").narrow(0, 5, 5), am, 1e-5, 1e-5));
  CHECK(torch::allclose(twice.at("object").narrow(0, 2, 2), ao, 1e-5, 1e-5));

  // A clone computes the same, with parameters of its own under the same names.
  const auto copy = std::dynamic_pointer_cast<models::gns::GraphNetworkImpl>(net->clone());
  REQUIRE(copy != nullptr);
  CHECK(torch::equal(copy->forward(batch).at("mesh"), out.at("mesh")));
  CHECK(copy->named_parameters().keys() == net->named_parameters().keys());
  CHECK(copy->parameters()[0].data_ptr() != net->parameters()[0].data_ptr());

  // The loss: squared error over the dynamic nodes only, divided by their number.
  const auto loss = models::gns::acceleration_loss(out.at("mesh"), batch);
  const auto t = as_tensor(frame.target);
  const auto expected = (am - t).pow(2).narrow(0, 0, 3).sum() / 3;
  CHECK(loss.item<double>() == Approx(expected.item<double>()).epsilon(1e-5));
}

TEST_CASE("FIGNet's graph network gives all-off's numbers with each fast path on alone",
          "[gns][fast_paths]") {
  // The baselines' schedule (models::gns::graph_network_schedule), FIGNet-shaped, two blocks.
  torch::manual_seed(5);
  std::mt19937 rng(9);
  auto spec = tiny_spec(16);
  spec.steps = 2;
  auto net = models::gns::GraphNetwork(spec, "_encode_process_decode");
  auto a = tiny_frame(rng), b = tiny_frame(rng);
  const auto batch = models::gns::collate(spec, {&a, &b}, unit_statistics(spec));
  const auto run = [&] {
    net->zero_grad();
    const auto out = net->forward(batch);
    std::vector<torch::Tensor> r;
    torch::Tensor loss = torch::zeros({});
    for (const auto& [name, y] : out) {
      r.push_back(y);
      loss = loss + y.sin().sum();
    }
    loss.backward();
    for (const auto& p : net->parameters()) r.push_back(p.grad());
    return r;
  };
  const auto changed = test::check_fast_paths(*net, run, 1e-4, 1e-6);  // float32
  WARN("fast paths that changed some bit on FIGNet's network: " << test::joined(changed));
  const auto split = test::check_step_threads(*net, run, net->forward(batch).size(), 1e-5, 1e-6);
  CHECK(split.groups > 0);
  WARN("FIGNet's steps that ran their terms at once: " << split.steps);
}

TEST_CASE("Graph networks: statistics, collation and configuration errors", "[gns]") {
  std::mt19937 rng(7);
  const auto spec = tiny_spec(4);
  const auto frame = tiny_frame(rng);

  SECTION("statistics are population moments per column, constant columns get std 1") {
    models::gns::StatisticsAccumulator acc(spec);
    auto f2 = frame;
    f2.nodes["mesh"].features.col(3).setConstant(0.25);
    f2.nodes["object"].features.col(3).setConstant(0.25);
    acc.add(f2);
    const auto s = acc.finish();
    s.check_fits(spec, "test");
    // "node" pools the 5 mesh and 2 object rows.
    double sum = 0, sum2 = 0;
    for (const auto* set : {&f2.nodes["mesh"].features, &f2.nodes["object"].features})
      for (Eigen::Index i = 0; i < set->rows(); ++i)
        sum += (*set)(i, 0), sum2 += (*set)(i, 0) * (*set)(i, 0);
    CHECK(s.mean.at("node")[0] == Approx(sum / 7));
    CHECK(s.std.at("node")[0] == Approx(std::sqrt(sum2 / 7 - sum * sum / 49)));
    CHECK(s.mean.at("node")[3] == Approx(0.25));
    CHECK(s.std.at("node")[3] == 1.0);
    // Targets of dynamic nodes only (the first 3).
    CHECK(s.mean.at("acceleration")[1] == Approx(f2.target.col(1).head(3).sum() / 3).margin(1e-12));
    const auto back = models::gns::Statistics::from_json(s.to_json(), "round trip");
    CHECK(back.mean == s.mean);
    CHECK(back.std == s.std);
    auto missing = s;
    missing.mean.erase("face_edge");
    CHECK_THROWS_WITH(missing.check_fits(spec, "stats.json"),
                      Catch::Contains("stats.json") && Catch::Contains("face_edge"));
    auto wrong = s;
    wrong.std["edge"].pop_back();
    CHECK_THROWS_WITH(wrong.check_fits(spec, "stats.json"), Catch::Contains("'edge' have 7"));
  }
  SECTION("a hyperedge naming a node outside its set is refused") {
    auto bad = frame;
    bad.edges["ff"].receivers(1, 2) = 5;
    CHECK_THROWS_WITH(models::gns::collate(spec, {&bad}, unit_statistics(spec)),
                      Catch::Contains("'ff'") && Catch::Contains("node 5"));
    bad = frame;
    bad.edges["ff"].senders.resize(2, 2);
    CHECK_THROWS_WITH(models::gns::collate(spec, {&bad}, unit_statistics(spec)),
                      Catch::Contains("'ff' has 2 x 2 senders"));
  }
  SECTION("a configuration of another model, or an unknown field, names both") {
    models::mgn::MgnOptions m;
    CHECK_THROWS_WITH(models::fignet::FignetOptions::from_json(m.to_json()),
                      Catch::Contains("a mgn configuration") && Catch::Contains("fignet"));
    CHECK_THROWS_WITH(models::mgn::MgnOptions::from_json({{"model", "hopnet"}}),
                      Catch::Contains("hopnet") && Catch::Contains("mgn"));
    CHECK_THROWS_WITH(models::mgn::MgnOptions::from_json({{"model", "mgn"}, {"radius", 1}}),
                      Catch::Contains("unknown field 'radius'"));
    CHECK_THROWS_WITH(
        models::mgn::MgnOptions::from_json({{"model", "mgn"}, {"world_edge_radius", -1}}),
        Catch::Contains("world_edge_radius"));
    CHECK_THROWS_WITH(models::fignet::FignetOptions::from_json({{"model", "fignet"}, {"steps", 0}}),
                      Catch::Contains("steps"));
    models::fignet::FignetOptions f;
    f.mesh_edges = true;
    f.collision_radius = 0.2;
    const auto g = models::fignet::FignetOptions::from_json(f.to_json());
    CHECK(g.mesh_edges);
    CHECK(g.collision_radius == 0.2);
    // The MLP depth is written as hidden_layers; mlp_layers, its name before, is still read.
    f.network.hidden_layers = 1;
    const auto written = f.to_json();
    CHECK(written.at("hidden_layers") == 1);
    CHECK(!written.contains("mlp_layers"));
    auto old = written;
    old.erase("hidden_layers");
    old["mlp_layers"] = 3;
    CHECK(models::fignet::FignetOptions::from_json(old).network.hidden_layers == 3);
    old["hidden_layers"] = 3;  // both names, one value: accepted
    CHECK(models::fignet::FignetOptions::from_json(old).network.hidden_layers == 3);
    old["hidden_layers"] = 1;
    CHECK_THROWS_WITH(models::fignet::FignetOptions::from_json(old),
                      Catch::Contains("hidden_layers 1 and its old name mlp_layers 3 differ"));
    models::gns::GraphNetworkSpec s = spec;
    s.edges[0].receiver = "objects";
    CHECK_THROWS_WITH(models::gns::graph_network_schedule(s),
                      Catch::Contains("'mo'") && Catch::Contains("'objects'"));
  }
}

TEST_CASE("A graph network fits one batch: the loss falls by orders of magnitude", "[gns]") {
  // A network that cannot overfit a handful of timesteps has a broken gradient path.
  torch::manual_seed(11);
  std::mt19937 rng(13);
  auto spec = tiny_spec(32);
  spec.steps = 2;
  auto net = models::gns::GraphNetwork(spec, "_encode_process_decode");
  auto a = tiny_frame(rng), b = tiny_frame(rng);
  b.dynamic = {1, 1, 1, 1, 1};
  const auto batch = models::gns::collate(spec, {&a, &b}, unit_statistics(spec));
  torch::optim::Adam opt(net->parameters(), torch::optim::AdamOptions(1e-3));
  double first = 0, last = 0;
  for (int i = 0; i < 300; ++i) {
    opt.zero_grad();
    const auto loss = models::gns::acceleration_loss(net->forward(batch).at("mesh"), batch);
    loss.backward();
    opt.step();
    (i == 0 ? first : last) = loss.item<double>();
  }
  INFO("loss " << first << " -> " << last);
  CHECK(last < 1e-2 * first);
}

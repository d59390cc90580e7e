// The reference for a user's compile time (bench/compile_time.sh, docs/benchmarks.md): a plain
// LibTorch translation unit that trains an MLP, torch/torch.h only.
#include <torch/torch.h>

#include <cstdio>

struct MLPImpl : torch::nn::Module {
  MLPImpl(std::int64_t in, std::int64_t hidden, std::int64_t out)
      : l1(register_module("l1", torch::nn::Linear(in, hidden))),
        l2(register_module("l2", torch::nn::Linear(hidden, out))) {}
  torch::Tensor forward(const torch::Tensor& x) { return l2->forward(torch::relu(l1->forward(x))); }
  torch::nn::Linear l1, l2;
};
TORCH_MODULE(MLP);

int main() {
  torch::manual_seed(0);
  const auto x = torch::randn({256, 8});
  const auto y = (x.sum(1) > 0).to(torch::kLong);
  MLP net(8, 32, 2);
  torch::optim::Adam opt(net->parameters(), torch::optim::AdamOptions(1e-2));
  for (int epoch = 0; epoch < 100; ++epoch) {
    const auto loss = torch::nn::functional::cross_entropy(net->forward(x), y);
    opt.zero_grad();
    loss.backward();
    opt.step();
    if (epoch % 20 == 0) std::printf("epoch %d loss %.4f\n", epoch, loss.item<double>());
  }
  return 0;
}

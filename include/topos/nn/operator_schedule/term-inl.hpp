// topos/nn/operator_schedule/term-inl.hpp
// One term of a step evaluated: its cochain read through the network's operators, its operations
// applied in order (products fused with the activation that follows, attention, aggregation over
// a neighbourhood), with the checks that name the step. interpreter-inl.hpp runs the steps.
// Compiled into topos::nn, or inline with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/nn/operator_schedule/parameters-inl.hpp"  // detail::shape_str
#include "topos/nn/operator_schedule/network.hpp"
#include "topos/nn/operator_schedule/printer-inl.hpp"   // detail::ops_str
#include "topos/nn/operator_schedule/products-inl.hpp"  // detail::check_fits, multiply

#include <algorithm>
#include <cstdint>
#include <exception>
#include <functional>
#include <set>

namespace topos::nn {

namespace detail {

/// An operation other than an aggregation applied to a batch's neighbourhood.
[[noreturn]] TOPOS_INLINE void not_an_aggregation(const std::string& where,
                                                  const std::string& name) {
  throw ScheduleError(where + ": '" + name +
                      "' is a neighbourhood of the batch: only via (without row normalisation) "
                      "and an untransposed pattern apply to it");
}

/// A neighbourhood must read as many source rows as the cochain (`source`, if named) has.
TOPOS_INLINE void check_reads(const std::string& where, const std::string& name,
                              std::int64_t num_source, std::int64_t rows,
                              const std::string& source = "") {
  if (num_source != rows)
    throw ScheduleError(where + ": neighbourhood '" + name + "' reads " +
                        std::to_string(num_source) + " source rows but the cochain " +
                        (source.empty() ? "" : source + " ") + "has " + std::to_string(rows));
}

}  // namespace detail

/// A term's value; or, for a term that ends on an aggregation over a batch neighbourhood and
/// whose caller can apply a linear map first, the rows and the aggregation still to apply.
struct OperatorNetworkImpl::TermValue {
  bool handled = false;  // false: the term is not one of these, evaluate it the general way
  torch::Tensor value;
  torch::Tensor x;
  TensorNeighborhood n;  // sources renumbered to x's rows
  AggregateOptions agg;
  bool deferred = false;
  std::exception_ptr error;  // evaluated ahead on another thread, where it threw this
};

struct OperatorNetworkImpl::Operators {
  const std::map<std::string, SparseOperator>* given;
  const ComplexBatch* batch = nullptr;  // its neighbourhoods, where no operator is given
  std::map<std::string, SparseOperator> transposed;
  std::set<std::string> absent;                  // optional operators this forward lacks
  std::map<std::string, torch::Tensor> scratch;  // RunContext::scratch: kept for this run
  bool shared = false;  // steps on several threads now: `transposed`, `scratch` under the lock
  std::mutex lock;
  // step_threads: helpers a step may hand its terms to now (run_group sets it while it holds
  // them for a group that runs on one thread), whether a step did, and the terms evaluated
  // ahead on them, each taken by evaluate_term when its step reaches it in order.
  std::size_t term_helpers = 0;
  bool split_terms = false;
  std::map<const PlannedTerm*, TermValue> ahead;
  const SparseOperator& at(const std::string& where, const std::string& name) const {
    auto it = given->find(name);
    if (it == given->end()) {
      if (neighborhood(name)) detail::not_an_aggregation(where, name);
      throw ScheduleError(where + ": operator '" + name + "' was not given" +
                          (batch ? " and the batch has no neighbourhood of that name" : ""));
    }
    return it->second;
  }
  const SparseOperator& t(const std::string& where, const std::string& name) {
    std::unique_lock<std::mutex> guard(lock, std::defer_lock);
    if (shared) guard.lock();  // a map's elements stay where they are as others are added
    auto it = transposed.find(name);
    if (it == transposed.end()) it = transposed.emplace(name, at(where, name).t()).first;
    return it->second;
  }
  /// The batch's neighbourhood `name`, when no operator of that name is given.
  const TensorNeighborhood* neighborhood(const std::string& name) const {
    if (batch == nullptr || given->count(name) || !batch->has_neighborhood(name)) return nullptr;
    return &batch->neighborhood(name);
  }
};

namespace detail {

/// What a user operation sees of a running step (operation.hpp).
class NetworkRunContext final : public RunContext {
 public:
  NetworkRunContext(OperatorNetworkImpl& net, const std::string& where, const CochainKey& target,
                    OperatorNetworkImpl::Operators& ops, const Cochains& h)
      : net_(net), where_(where), target_(target), ops_(ops), h_(h) {}
  const std::string& where() const override { return where_; }
  const CochainKey& target() const override { return target_; }
  const SparseOperator& op(const std::string& name) override { return ops_.at(where_, name); }
  const SparseOperator& op_transposed(const std::string& name) override {
    return ops_.t(where_, name);
  }
  const torch::Tensor& parameter(const std::string& path) const override {
    auto it = net_.params_.find(path);
    if (it == net_.params_.end()) fail("no parameter '" + path + "'");
    return it->second;
  }
  const torch::Tensor& cochain(const CochainKey& key) const override {
    if (!h_.has(key.rank, key.state)) fail("no cochain " + key.str() + " before the step");
    return h_.at(key.rank, key.state);
  }
  bool is_training() const override { return net_.is_training(); }
  torch::Tensor& scratch(const std::string& key) override {
    std::unique_lock<std::mutex> guard(ops_.lock, std::defer_lock);
    if (ops_.shared) guard.lock();  // steps on several threads (step_threads, eval only)
    return ops_.scratch[key];
  }
  const FastPaths& fast_paths() const override { return net_.fast_paths(); }

 protected:
  std::shared_ptr<torch::nn::Module> module_at(const std::string& path) const override {
    auto it = net_.modules_.find(path);
    if (it == net_.modules_.end()) fail("no module '" + path + "'");
    return it->second;
  }

 private:
  OperatorNetworkImpl& net_;
  const std::string& where_;
  const CochainKey& target_;
  OperatorNetworkImpl::Operators& ops_;
  const Cochains& h_;
};

TOPOS_INLINE AggregateOptions aggregate_options(const OperatorProduct& p, const FastPaths& fast) {
  AggregateOptions o;
  o.csr = fast.csr_aggregation();
  o.role = p.role;
  o.weighted = p.weighted;
  o.reduce = p.weighted ? Aggr::sum : p.reduce;
  return o;
}

/// The rows of `rows` that `source` names, ascending (torch::_unique's sorted values): marked in
/// a mask, linear in the pairs where the sort of _unique is not (1 % of HOPNet's training step).
/// On the CPU in one loop each way: as torch's five operations these two took 8 % of a HOPNet
/// rollout step, whose tensors are small.
TOPOS_INLINE torch::Tensor used_rows(const torch::Tensor& source, std::int64_t rows) {
  if (!source.device().is_cpu() || source.scalar_type() != torch::kLong) {
    auto mask = torch::zeros({rows}, source.options().dtype(torch::kBool));
    mask.index_fill_(0, source, true);
    return mask.nonzero().squeeze(1);
  }
  const auto s = source.contiguous();
  const auto* p = s.data_ptr<std::int64_t>();
  std::vector<char> mark(static_cast<std::size_t>(rows), 0);
  for (std::int64_t k = 0; k < s.numel(); ++k) {
    TORCH_CHECK(p[k] >= 0 && p[k] < rows, "index ", p[k], " is out of bounds for ", rows, " rows");
    mark[static_cast<std::size_t>(p[k])] = 1;
  }
  std::int64_t n = 0;
  for (const char m : mark) n += m;
  auto used = torch::empty({n}, source.options());
  auto* u = used.data_ptr<std::int64_t>();
  for (std::int64_t r = 0; r < rows; ++r)
    if (mark[static_cast<std::size_t>(r)]) *u++ = r;
  return used;
}

/// Each of `rows` cells' position among the sorted `used` ones, or -1.
TOPOS_INLINE torch::Tensor compact_rows(const torch::Tensor& used, std::int64_t rows) {
  auto row = torch::full({rows}, -1, used.options());
  if (!used.device().is_cpu() || used.scalar_type() != torch::kLong) {
    row.index_put_({used}, torch::arange(used.size(0), used.options()));
    return row;
  }
  auto* out = row.data_ptr<std::int64_t>();
  const auto u = used.contiguous();
  const auto* p = u.data_ptr<std::int64_t>();
  for (std::int64_t i = 0; i < u.numel(); ++i) {
    TORCH_CHECK(p[i] >= 0 && p[i] < rows, "index ", p[i], " is out of bounds for ", rows, " rows");
    out[p[i]] = i;
  }
  return row;
}

/// The cache key of a term's first `k` operations from `source`: their printed form, and an
/// Operation's identity (OperationTraits::identity, else the object's address).
TOPOS_INLINE std::string prefix_key(const CochainKey& source, const std::vector<TermOp>& list,
                                    std::size_t k) {
  std::string key = ops_str(source.str(), {list.begin(), list.begin() + static_cast<long>(k)});
  for (std::size_t i = 0; i < k; ++i) {
    const auto& id = list[i].traits.identity;
    key += "|" + (id.empty()
                      ? std::to_string(reinterpret_cast<std::uintptr_t>(list[i].operation.get()))
                      : id);
  }
  return key;
}

/// A clear error naming the step and the operation when an Operation's forward gives something
/// else than its `infer` said: (cells × channels) with x's dtype and device, x's rows when the
/// rank is kept, else the rows of `same_rank` when that is defined.
TOPOS_INLINE void check_result(const std::string& where, const Operation& op, int rank_in,
                               TermShape out, const torch::Tensor& x, const torch::Tensor& y,
                               const torch::Tensor& same_rank) {
  const auto fail = [&](const std::string& why) {
    throw ScheduleError(where + ": operation " + op.str("x") + " " + why);
  };
  if (!y.defined()) fail("returned an undefined tensor: forward must return (cells × channels)");
  if (y.dim() != 2 || x.dim() != 2) {
    if (x.dim() == 2)
      fail("returned a tensor of shape " + shape_str(y) + ": forward must return (cells × " +
           std::to_string(out.channels) + ")");
    return;
  }
  if (y.size(1) != out.channels)
    fail("returned " + std::to_string(y.size(1)) + " channels, but its infer said " +
         std::to_string(out.channels) + ": return TermShape{" + std::to_string(out.rank) + ", " +
         std::to_string(y.size(1)) + "} from infer, or " + std::to_string(out.channels) +
         " columns from forward");
  if (y.scalar_type() != x.scalar_type())
    fail(std::string("returned ") + c10::toString(y.scalar_type()) + ", but it was given " +
         c10::toString(x.scalar_type()) + ": return the operand's dtype (.to(x.scalar_type()))");
  if (y.device() != x.device())
    fail("returned a tensor on " + y.device().str() + ", but it was given one on " +
         x.device().str() + ": return it on x's device (.to(x.device()))");
  const auto rows = out.rank == rank_in ? x.size(0) : same_rank.defined() ? same_rank.size(0) : -1;
  if (rows >= 0 && y.size(0) != rows)
    fail("returned " + std::to_string(y.size(0)) + " rows, but rank " + std::to_string(out.rank) +
         " has " + std::to_string(rows) + " cells here" +
         (out.rank == rank_in ? " (as many as the rows it was given)" : "") +
         ": return one row per cell of the rank its infer returned");
}

/// A term's operations over a batch neighbourhood: the aggregation, checked against x's rows.
TOPOS_INLINE torch::Tensor aggregate_over(const std::string& where, const OperatorProduct& p,
                                          const TensorNeighborhood& n, const torch::Tensor& x,
                                          const FastPaths& fast) {
  if (!p.aggregation()) not_an_aggregation(where, p.op);
  check_reads(where, p.op, n.num_source, x.size(0));
  return aggregate(x, n, aggregate_options(p, fast));
}

/// The leading dimensions of inputs given as (..., cells, channels): the same for every input of
/// the schedule, empty when all are matrices.
TOPOS_INLINE std::vector<std::int64_t> leading_dims(
    const std::vector<OperatorSchedule::Port>& ports,
    const std::map<std::string, torch::Tensor>& inputs) {
  std::vector<std::int64_t> lead;
  std::string first;
  for (const auto& port : ports) {
    auto it = inputs.find(port.name);
    if (it == inputs.end() || it->second.dim() < 2) continue;  // input_cochains says why
    const auto sizes = it->second.sizes();
    std::vector<std::int64_t> l(sizes.begin(), sizes.end() - 2);
    if (first.empty()) {
      lead = std::move(l);
      first = port.name;
    } else if (l != lead) {
      throw ScheduleError("input '" + port.name + "' has leading dimensions " +
                          shape_str(torch::empty(l)) + " but input '" + first + "' has " +
                          shape_str(torch::empty(lead)));
    }
  }
  return lead;
}

/// `run` on each element of the leading dimensions, the outputs stacked back into them.
TOPOS_INLINE std::map<std::string, torch::Tensor> over_leading(
    const std::vector<OperatorSchedule::Port>& ports,
    const std::map<std::string, torch::Tensor>& inputs, const std::vector<std::int64_t>& lead,
    const std::function<
        std::map<std::string, torch::Tensor>(const std::map<std::string, torch::Tensor>&)>& run) {
  std::int64_t n = 1;
  for (auto d : lead) n *= d;
  std::map<std::string, torch::Tensor> flat = inputs;
  for (const auto& port : ports)
    if (auto it = flat.find(port.name); it != flat.end())
      it->second = it->second.reshape({n, it->second.size(-2), it->second.size(-1)});
  std::map<std::string, std::vector<torch::Tensor>> outs;
  for (std::int64_t b = 0; b < n; ++b) {
    auto in = flat;
    for (const auto& port : ports)
      if (auto it = in.find(port.name); it != in.end()) it->second = it->second.select(0, b);
    for (auto& [name, y] : run(in)) outs[name].push_back(std::move(y));
  }
  std::map<std::string, torch::Tensor> out;
  for (auto& [name, ys] : outs) {
    auto shape = lead;
    const auto inner = ys[0].sizes();
    shape.insert(shape.end(), inner.begin(), inner.end());
    out[name] = torch::stack(ys).reshape(shape);
  }
  return out;
}

}  // namespace detail

namespace detail {
/// The pattern reorder_products and fuse_products work on at list[i]: a weight (a right factor)
/// next to a weighted product by a sparse operator (role 0; `is_neighborhood(name)` says which
/// operators are a batch's neighbourhoods instead), in either order. The interpreter and the
/// planner both read it here.
struct WeightNextToProduct {
  const OperatorProduct* product = nullptr;  ///< null: no such pair at i
  const std::string* weight = nullptr;       ///< the weight's parameter path
  bool weight_first = false;                 ///< the order in the schedule
  const Activation* activation = nullptr;    ///< list[i + 2] when it is a fusable activation
};
/// The weighted product by a sparse operator (role 0, not a batch's neighbourhood) that `o` is,
/// or null.
template <class IsNeighborhood>
const OperatorProduct* sparse_product_of(const TermOp& o, const IsNeighborhood& is_neighborhood) {
  const auto* p = product_of(o);
  return p != nullptr && p->weighted && p->role == 0 && !is_neighborhood(p->op) ? p : nullptr;
}
template <class IsNeighborhood>
WeightNextToProduct weight_next_to_product(const OperationSeq& list, std::size_t i,
                                           const IsNeighborhood& is_neighborhood) {
  WeightNextToProduct w;
  if (i + 1 >= list.size()) return w;
  const auto sparse_product = [&](const TermOp& o) {
    return sparse_product_of(o, is_neighborhood);
  };
  const auto &t = list[i], &next = list[i + 1];
  if (!t.traits.right_factor.empty() && (w.product = sparse_product(next)) != nullptr) {
    w.weight = &t.traits.right_factor;
    w.weight_first = true;
  } else if (!next.traits.right_factor.empty() && (w.product = sparse_product(t)) != nullptr) {
    w.weight = &next.traits.right_factor;
  }
  if (w.product != nullptr && i + 2 < list.size()) {
    const auto& act = activation_of(list[i + 2]);
    if (act && fusable(*act)) w.activation = &*act;
  }
  return w;
}
}  // namespace detail

TOPOS_INLINE std::size_t OperatorNetworkImpl::apply_fused(const std::string& where,
                                                          const CochainKey& target,
                                                          const detail::OperationSeq& list,
                                                          std::size_t i, torch::Tensor& x,
                                                          Operators& ops, const Cochains& h) {
  const auto& t = list[i];
  const auto is_neighborhood = [&](const std::string& name) {
    return ops.neighborhood(name) != nullptr;
  };
  // A right factor next to a sparse product: A (x W) = (A x) W, so the dense product runs on the
  // side with fewer rows (SCCN's tetrahedra to triangles: the weight after the sum, on a quarter
  // of the rows). Sparse entries are weighted as 4 dense multiply-adds (their gather is slower).
  // With fuse_products, the pair (and the activation after it) is one autograd node.
  if ((fast_.reorder_products() || fast_.fuse_products()) && x.dim() == 2) {
    const auto pair = detail::weight_next_to_product(list, i, is_neighborhood);
    const auto* p = pair.product;
    const bool weight_first = pair.weight_first;
    const auto* W = p ? &params_.at(*pair.weight) : nullptr;
    const auto* A = p ? &(p->transposed ? ops.t(where, p->op) : ops.at(where, p->op)) : nullptr;
    if (p != nullptr && W->dim() == 2 && A->cols == x.size(0)) {
      const double n = static_cast<double>(x.size(0)), m = static_cast<double>(A->rows),
                   nnz = 4.0 * static_cast<double>(A->nnz()),
                   c_in = static_cast<double>(W->size(0)), c_out = static_cast<double>(W->size(1));
      const double cost_weight_first = n * c_in * c_out + nnz * c_out,
                   cost_via_first = nnz * c_in + m * c_in * c_out;
      const bool swap =
          fast_.reorder_products() && (weight_first ? cost_via_first < 0.8 * cost_weight_first
                                                    : cost_weight_first < 0.8 * cost_via_first);
      bool run_weight_first = weight_first != swap;
      const auto name = operator_label(p->op, p->transposed);
      if (fast_.fuse_products() && !p->row_norm) {
        // With an activation, and both orders as costly within 5 % (SCN's square Laplacians): the
        // weight last, so that the backward takes the activation's derivative inside the dense
        // kernel's row blocks instead of in a pass of its own.
        if (pair.activation != nullptr && run_weight_first && fast_.reorder_products() &&
            cost_via_first < 1.05 * cost_weight_first)
          run_weight_first = false;
        detail::check_fits(where, name, *A, x);
        x = sparse_linear_act(*A, x, *W, run_weight_first,
                              pair.activation ? epilogue_of(*pair.activation) : Epilogue::none);
        return pair.activation ? i + 2 : i + 1;
      }
      if (swap) {
        x = run_weight_first
                ? detail::multiply(where, name, *A, linear_act(x, W->t(), {}), p->row_norm)
                : linear_act(detail::multiply(where, name, *A, x, p->row_norm), W->t(), {});
        return i + 1;
      }
    }
  }
  // A bias and the operation after it that adds it in its kernel (a layer norm), with its
  // activation.
  if (fast_.fuse_residuals() && !t.traits.row_offset.empty() && i + 1 < list.size() &&
      list[i + 1].traits.fuses_residual && x.dim() == 2) {
    const auto offset = params_.find(t.traits.row_offset);
    if (offset == params_.end())
      throw ScheduleError(where + ": " + t.operation->str("x") + " declares the row offset '" +
                          t.traits.row_offset + "', which is no parameter of the network");
    const auto* act = fusable_activation_at(list, i + 2);
    x = run_operation(where, target, list[i + 1], x, ops, h, act, offset->second.reshape({-1}));
    return act ? i + 2 : i + 1;
  }
  // A product and the activation after it in one kernel: a sparse product without row sums, or
  // an operation whose traits say it fuses one.
  const auto* product = detail::sparse_product_of(t, is_neighborhood);
  const bool fuses = t.traits.fuses_activation || (product != nullptr && !product->row_norm);
  const auto* act = fuses ? fusable_activation_at(list, i + 1) : nullptr;
  if (act == nullptr) {
    x = apply(where, target, t, x, ops, h);
    return i;
  }
  if (product == nullptr) {
    x = run_operation(where, target, t, x, ops, h, act);
  } else {
    const auto& A = product->transposed ? ops.t(where, product->op) : ops.at(where, product->op);
    x = detail::multiply(where, operator_label(product->op, product->transposed), A, x, false,
                         epilogue_of(*act->traits.activation));
  }
  return i + 1;
}

TOPOS_INLINE const TermOp* OperatorNetworkImpl::fusable_activation_at(
    const detail::OperationSeq& list, std::size_t j) const {
  if (!fast_.fuse_activations() || j >= list.size()) return nullptr;
  const auto& a = detail::activation_of(list[j]);
  return a && fusable(*a) ? &list[j] : nullptr;
}

TOPOS_INLINE torch::Tensor OperatorNetworkImpl::apply(const std::string& where,
                                                      const CochainKey& target, const TermOp& t,
                                                      torch::Tensor x, Operators& ops,
                                                      const Cochains& h) {
  if (const auto* p = detail::product_of(t))
    if (const auto* n = ops.neighborhood(p->op))
      return detail::aggregate_over(where, *p, *n, x, fast_);
  return run_operation(where, target, t, x, ops, h, nullptr);
}

// An Operation's forward, or with `activation` (an activation operation after it, which its
// traits say it fuses) its forward_activated; the result checked against what its infer said.
TOPOS_INLINE torch::Tensor OperatorNetworkImpl::run_operation(
    const std::string& where, const CochainKey& target, const TermOp& t, const torch::Tensor& x,
    Operators& ops, const Cochains& h, const TermOp* activation, const torch::Tensor& residual) {
  detail::NetworkRunContext ctx(*this, where, target, ops, h);
  const double slope = activation ? activation->traits.negative_slope : 0.0;
  auto y =
      residual.defined()
          ? t.operation->forward_residual(
                ctx, x, residual,
                activation ? activation->traits.activation : std::optional<Activation>(), slope)
      : activation == nullptr
          ? t.operation->forward(ctx, x)
          : t.operation->forward_activated(ctx, x, *activation->traits.activation, slope);
  if (auto it = inferred_.find(&t); it != inferred_.end()) {
    const auto& [rank_in, out] = it->second;
    // The target before the step, whole, has a row per cell of its rank.
    const bool whole =
        out.rank == target.rank && h.has(target.rank, target.state) && !h.rows(target).defined();
    detail::check_result(where, *t.operation, rank_in, out, x, y,
                         whole ? h.at(target.rank, target.state) : torch::Tensor());
  }
  return y;
}

TOPOS_INLINE OperatorNetworkImpl::TermValue OperatorNetworkImpl::evaluate_term(
    const std::string& where, const CochainKey& target, const PlannedTerm& planned,
    const Cochains& h, Operators& ops, PrefixCache& cache, bool may_defer) {
  if (!ops.ahead.empty()) {
    const auto it = ops.ahead.find(&planned);
    if (it != ops.ahead.end()) {
      auto ahead = std::move(it->second);
      ops.ahead.erase(it);
      if (ahead.error) std::rethrow_exception(ahead.error);  // in the one-thread order
      return ahead;
    }
  }
  TermValue v;
  if (planned.neighborhood.empty()) return v;  // not handled here
  const auto& term = *planned.term;
  const auto& list = term.operations();
  const std::size_t k = planned.row_wise_prefix;  // the first operation that is not row-wise
  const TensorNeighborhood* nb = ops.neighborhood(planned.neighborhood);
  v.handled = true;
  torch::Tensor x = h.at(term.source.rank, term.source.state);
  TensorNeighborhood n = *nb;
  const auto rows = h.rows(term.source);  // defined for a compact cochain: each cell's row
  const auto& product = *detail::product_of(list[k]);
  detail::check_reads(where, product.op, n.num_source, rows.defined() ? rows.size(0) : x.size(0),
                      term.source.str());
  if (rows.defined()) {
    n.source = rows.index_select(0, n.source);
    n.num_source = x.size(0);
  }
  if (k > 0) {
    const auto& key = planned.prefix_key;
    const bool share = !key.empty();
    const auto cached = share ? cache.find(key) : cache.end();
    torch::Tensor used;
    if (cached == cache.end() && fast_.row_subset()) {
      used = detail::used_rows(n.source, x.size(0));
      if (used.size(0) >= x.size(0)) used = torch::Tensor();
    }
    if (cached != cache.end()) {
      x = cached->second;
    } else if (used.defined()) {
      // Some source rows send nothing here: the row-wise prefix runs on the others only, and
      // the pairs' sources are renumbered.
      x = x.index_select(0, used);
      for (std::size_t i = 0; i < k; ++i) i = apply_fused(where, target, list, i, x, ops, h);
      n.source = detail::compact_rows(used, n.num_source).index_select(0, n.source);
      n.num_source = used.size(0);
    } else {
      for (std::size_t i = 0; i < k; ++i) i = apply_fused(where, target, list, i, x, ops, h);
      if (share) cache.emplace(key, x);
    }
  }
  v.agg = detail::aggregate_options(product, fast_);
  if (may_defer && k + 1 == list.size()) {
    v.deferred = true;
    v.x = std::move(x);
    v.n = std::move(n);
    return v;
  }
  x = aggregate(x, n, v.agg);
  for (std::size_t i = k + 1; i < list.size(); ++i)
    i = apply_fused(where, target, list, i, x, ops, h);
  v.value = std::move(x);
  return v;
}

}  // namespace topos::nn

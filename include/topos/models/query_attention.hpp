// topos/models/query_attention.hpp
// The checks shared by the model attentions that score an operator's entries against a cochain of
// its target rank (models::HmcAttention, CanAttention, SanFilterAttention): when the network is
// built, that the cochain sits on the target rank; when it runs, that the operator fits both the
// messages and that cochain. Errors name the step, through the contexts.
#pragma once

#include "topos/nn/operator_schedule.hpp"

#include <string>

namespace topos::models {

/// The width of `queries`, which must be a cochain of `target_rank`; otherwise the build fails
/// with `who` (e.g. "CAN attention over 'A'") and what the scores need.
inline std::int64_t query_width(nn::BuildContext& ctx, const nn::CochainKey& queries,
                                int target_rank, const std::string& who) {
  if (queries.rank != target_rank)
    ctx.fail(who + " scores against " + queries.str() + ", which needs a cochain of rank " +
             std::to_string(target_rank));
  return ctx.cochain_width(queries);
}

/// The `queries` cochain at run time, after checking that `A` (named `name`) maps the messages'
/// rows to the queries' rows.
inline const torch::Tensor& query_rows(nn::RunContext& ctx, const nn::SparseOperator& A,
                                       const torch::Tensor& messages, const nn::CochainKey& queries,
                                       const std::string& name) {
  const auto& q = ctx.cochain(queries);
  if (A.cols != messages.size(0) || A.rows != q.size(0))
    ctx.fail("operator '" + name + "' is " + std::to_string(A.rows) + " x " +
             std::to_string(A.cols) + " but its messages have " + std::to_string(messages.size(0)) +
             " rows and its queries " + queries.str() + " " + std::to_string(q.size(0)));
  return q;
}

}  // namespace topos::models

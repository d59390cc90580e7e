// topos/core/spectral-inl.hpp
// The definitions of spectral.hpp's functions: compiled once in topos::core_compiled
// (src/core.cpp), or inline in every translation unit with topos::core alone.
#pragma once

#include "topos/core/operators.hpp"
#include "topos/core/spectral.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/SVD>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

namespace topos {

TOPOS_CORE_INLINE double largest_magnitude_eigenvalue(const SparseMatrix& m) {
  if (m.rows() != m.cols()) throw ComplexError("largest eigenvalue: the matrix is not square");
  const Eigen::Index n = m.rows();
  if (n == 0) throw ComplexError("largest eigenvalue: the matrix is empty");
  const auto pick = [](const Eigen::VectorXd& ev) {
    double best = 0;
    for (Eigen::Index i = 0; i < ev.size(); ++i)
      if (std::abs(ev[i]) > std::abs(best)) best = ev[i];
    return best;
  };
  if (n <= 1500) {
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(Eigen::MatrixXd(m), Eigen::EigenvaluesOnly);
    return pick(es.eigenvalues());
  }
  const Eigen::Index steps = std::min<Eigen::Index>(n, 300);
  Eigen::MatrixXd q(n, steps + 1);
  Eigen::VectorXd alpha(steps), beta(steps);
  std::mt19937_64 rng(12345);
  std::normal_distribution<double> g;
  Eigen::VectorXd v(n);
  for (Eigen::Index i = 0; i < n; ++i) v[i] = g(rng);
  q.col(0) = v.normalized();
  double previous = std::numeric_limits<double>::quiet_NaN();
  for (Eigen::Index k = 0; k < steps; ++k) {
    Eigen::VectorXd w = m * q.col(k);
    alpha[k] = q.col(k).dot(w);
    for (int pass = 0; pass < 2; ++pass)
      w -= q.leftCols(k + 1) * (q.leftCols(k + 1).transpose() * w);
    beta[k] = w.norm();
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es;
    Eigen::MatrixXd t = Eigen::MatrixXd::Zero(k + 1, k + 1);
    for (Eigen::Index i = 0; i <= k; ++i) {
      t(i, i) = alpha[i];
      if (i < k) t(i, i + 1) = t(i + 1, i) = beta[i];
    }
    es.compute(t, Eigen::EigenvaluesOnly);
    const double now = pick(es.eigenvalues());
    if (beta[k] < 1e-12 * std::max(1.0, std::abs(now)) ||
        (k > 5 && std::abs(now - previous) <= 1e-14 * std::abs(now)))
      return now;
    previous = now;
    q.col(k + 1) = w / beta[k];
  }
  return previous;
}

TOPOS_CORE_INLINE Eigen::MatrixXd pinv(const Eigen::MatrixXd& a, double rcond) {
  if (a.size() == 0) return Eigen::MatrixXd::Zero(a.cols(), a.rows());
  if (a.rows() == a.cols() && a.isApprox(a.transpose(), 0.0)) {
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(a);
    const Eigen::VectorXd& ev = es.eigenvalues();
    const double cut = rcond * ev.cwiseAbs().maxCoeff();
    Eigen::VectorXd inv(ev.size());
    for (Eigen::Index i = 0; i < ev.size(); ++i) inv[i] = std::abs(ev[i]) > cut ? 1.0 / ev[i] : 0.0;
    return es.eigenvectors() * inv.asDiagonal() * es.eigenvectors().transpose();
  }
  Eigen::BDCSVD<Eigen::MatrixXd> svd(a, Eigen::ComputeThinU | Eigen::ComputeThinV);
  const Eigen::VectorXd& s = svd.singularValues();
  const double cut = rcond * (s.size() ? s.maxCoeff() : 0.0);
  Eigen::VectorXd inv(s.size());
  for (Eigen::Index i = 0; i < s.size(); ++i) inv[i] = s[i] > cut ? 1.0 / s[i] : 0.0;
  return svd.matrixV() * inv.asDiagonal() * svd.matrixU().transpose();
}

TOPOS_CORE_INLINE Eigen::MatrixXd harmonic_basis(const SparseMatrix& l, double tol) {
  if (l.rows() != l.cols()) throw ComplexError("harmonic_basis: the Laplacian is not square");
  if (l.rows() == 0) return Eigen::MatrixXd(0, 0);
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es{Eigen::MatrixXd(l)};
  const Eigen::VectorXd& ev = es.eigenvalues();
  const double cut = tol * std::max(1.0, ev.cwiseAbs().maxCoeff());
  Eigen::Index k = 0;
  while (k < ev.size() && std::abs(ev[k]) <= cut) ++k;
  return es.eigenvectors().leftCols(k);
}

TOPOS_CORE_INLINE Eigen::MatrixXd harmonic_projector(const SparseMatrix& l, double tol) {
  const Eigen::MatrixXd u = harmonic_basis(l, tol);
  return u * u.transpose();
}

TOPOS_CORE_INLINE HodgeDecomposition hodge_decomposition(const SparseMatrix& b_k,
                                                         const SparseMatrix& b_next,
                                                         const Eigen::VectorXd& x) {
  const Eigen::Index n = x.size();
  if ((b_k.size() && b_k.cols() != n) || (b_next.size() && b_next.rows() != n)) {
    throw ComplexError("hodge_decomposition: the cochain has " + std::to_string(n) +
                       " entries, the incidence matrices do not fit");
  }
  // Projection of x onto the column space of A by least squares (pseudo-inverse of the normal
  // equations' matrix, which handles rank deficiency).
  const auto project = [&](const Eigen::MatrixXd& a) -> Eigen::VectorXd {
    if (a.cols() == 0) return Eigen::VectorXd::Zero(n);
    const Eigen::MatrixXd gram = a.transpose() * a;
    return a * (pinv(gram, 1e-12) * (a.transpose() * x));
  };
  HodgeDecomposition h;
  h.gradient = b_k.size() ? project(Eigen::MatrixXd(b_k).transpose()) : Eigen::VectorXd::Zero(n);
  h.curl = b_next.size() ? project(Eigen::MatrixXd(b_next)) : Eigen::VectorXd::Zero(n);
  h.harmonic = x - h.gradient - h.curl;
  return h;
}

}  // namespace topos

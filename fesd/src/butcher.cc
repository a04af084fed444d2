#include "bflow/fesd/butcher.h"

#include <cmath>
#include <vector>

#include <Eigen/LU>

#include "bflow/core/errors.h"

namespace bflow {

namespace {

using Real = long double;
using RealMatrix = Eigen::Matrix<Real, Eigen::Dynamic, Eigen::Dynamic>;
using RealVector = Eigen::Matrix<Real, Eigen::Dynamic, 1>;

// P_n(x) by the three-term recurrence.
Real legendre(int n, Real x) {
  if (n == 0) return 1;
  Real previous = 1, current = x;
  for (int k = 1; k < n; ++k) {
    const Real next = ((2 * k + 1) * x * current - k * previous) / (k + 1);
    previous = current;
    current = next;
  }
  return current;
}

// The node polynomial in c on [0, 1].
Real node_polynomial(CollocationScheme scheme, int s, Real c) {
  const Real x = 2 * c - 1;
  return scheme == CollocationScheme::kGaussLegendre ? legendre(s, x)
                                                     : legendre(s, x) - legendre(s - 1, x);
}

// Roots in (0, 1): sign changes on a grid fine enough to separate them (the closest two nodes
// of a 9-stage scheme are ~0.016 apart), each bisected to the last bit of a long double.
std::vector<Real> interior_roots(CollocationScheme scheme, int s) {
  std::vector<Real> roots;
  constexpr int kGrid = 4096;
  Real left = 0, f_left = node_polynomial(scheme, s, left);
  for (int k = 1; k < kGrid; ++k) {  // stops short of c = 1, a Radau root
    const Real right = static_cast<Real>(k) / kGrid;
    const Real f_right = node_polynomial(scheme, s, right);
    if ((f_left < 0) != (f_right < 0)) {
      Real lo = left, hi = right, f_lo = f_left;
      for (int it = 0; it < 200 && hi - lo > 0; ++it) {
        const Real mid = (lo + hi) / 2;
        if (mid <= lo || mid >= hi) break;
        const Real f_mid = node_polynomial(scheme, s, mid);
        if ((f_mid < 0) == (f_lo < 0)) {
          lo = mid;
          f_lo = f_mid;
        } else {
          hi = mid;
        }
      }
      roots.push_back((lo + hi) / 2);
    }
    left = right;
    f_left = f_right;
  }
  return roots;
}

}  // namespace

const char* to_string(CollocationScheme scheme) {
  return scheme == CollocationScheme::kRadauIIA ? "radau" : "gauss";
}

CollocationScheme parse_collocation_scheme(const std::string& text) {
  if (text == "radau") return CollocationScheme::kRadauIIA;
  if (text == "gauss") return CollocationScheme::kGaussLegendre;
  throw InvalidArgument("unknown collocation scheme \"" + text + "\": use radau or gauss");
}

ButcherTableau collocation_tableau(CollocationScheme scheme, int stages) {
  if (stages < 1 || stages > kMaxCollocationStages) {
    throw InvalidArgument(std::string(to_string(scheme)) + " tableau: stages must be in [1, " +
                          std::to_string(kMaxCollocationStages) + "], got " +
                          std::to_string(stages));
  }
  const int s = stages;
  std::vector<Real> c = interior_roots(scheme, s);
  if (scheme == CollocationScheme::kRadauIIA) c.push_back(1);
  BFLOW_ASSERT(static_cast<int>(c.size()) == s);

  // V(k, j) = c_j^k, k = 0..s-1: A^T solves V A^T = R with R(k, i) = c_i^(k+1) / (k+1).
  RealMatrix vandermonde(s, s), rhs_a(s, s);
  RealVector rhs_b(s);
  for (int k = 0; k < s; ++k) {
    for (int j = 0; j < s; ++j) {
      vandermonde(k, j) = std::pow(c[static_cast<std::size_t>(j)], static_cast<Real>(k));
      rhs_a(k, j) = std::pow(c[static_cast<std::size_t>(j)], static_cast<Real>(k + 1)) / (k + 1);
    }
    rhs_b(k) = static_cast<Real>(1) / (k + 1);
  }
  const Eigen::FullPivLU<RealMatrix> lu(vandermonde);
  const RealMatrix a_transposed = lu.solve(rhs_a);
  const RealVector b = lu.solve(rhs_b);

  ButcherTableau tableau;
  tableau.scheme = scheme;
  tableau.stages = s;
  tableau.a = a_transposed.transpose().cast<double>();
  tableau.b = b.cast<double>();
  tableau.c.resize(s);
  for (int i = 0; i < s; ++i) tableau.c(i) = static_cast<double>(c[static_cast<std::size_t>(i)]);
  tableau.order = scheme == CollocationScheme::kGaussLegendre ? 2 * s : 2 * s - 1;

  // The derivative form: D = A^-1 = (A^T)^-1^T, D_0 = -D 1, e = b^T D, e_0 = 1 - sum e.
  const RealMatrix derivative = Eigen::FullPivLU<RealMatrix>(a_transposed).inverse().transpose();
  RealVector end = derivative.transpose() * b;
  Real end_0 = 1;
  if (scheme == CollocationScheme::kRadauIIA) {
    end.setZero();  // b is A's last row: e is the unit vector of X_s, exactly
    end(s - 1) = 1;
    end_0 = 0;
  } else {
    for (int k = 0; k < s; ++k) end_0 -= end(k);
  }
  tableau.derivative = derivative.cast<double>();
  tableau.derivative_0 = (-derivative.rowwise().sum()).cast<double>();
  tableau.end = end.cast<double>();
  tableau.end_0 = static_cast<double>(end_0);
  return tableau;
}

const char* to_string(CollocationForm form) {
  return form == CollocationForm::kDerivative ? "derivative" : "integral";
}

CollocationForm parse_collocation_form(const std::string& text) {
  if (text == "integral") return CollocationForm::kIntegral;
  if (text == "derivative") return CollocationForm::kDerivative;
  throw InvalidArgument("unknown collocation form \"" + text + "\": use integral or derivative");
}

CollocationRows collocation_rows(const ButcherTableau& tableau, CollocationForm form) {
  const int s = tableau.stages;
  CollocationRows rows;
  rows.form = form;
  if (form == CollocationForm::kDerivative) {
    rows.state = tableau.derivative;
    rows.start = tableau.derivative_0;
    rows.rate = Eigen::MatrixXd::Identity(s, s);
    rows.end_start = tableau.end_0;
    rows.end_state = tableau.end;
    rows.end_rate = Eigen::VectorXd::Zero(s);
  } else {
    rows.state = Eigen::MatrixXd::Identity(s, s);
    rows.start = Eigen::VectorXd::Constant(s, -1.0);
    rows.rate = tableau.a;
    rows.end_start = 1.0;
    rows.end_state = Eigen::VectorXd::Zero(s);
    rows.end_rate = tableau.b;
  }
  return rows;
}

}  // namespace bflow

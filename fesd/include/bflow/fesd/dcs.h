// The algebraic part of the DCS at one collocation point, for FESD's element equations (element.h):
// its variables z, equalities, the field it gives, its complementarity pairs and bounds. Three
// formulations ([F] Section 2.5-2.6, 6.3):
//
//   step      z = [a | lambda^p | lambda^n]            (nc each), eq c - lambda^p + lambda^n;
//             field f(x, a); pairs (a_j, lambda^n_j) and (1 - a_j, lambda^p_j).
//   lifted    z = [a | lambda^p | lambda^n | theta | beta], eq as step plus beta and theta
//             from the lifted products of SignMatrix::lifting (Algorithm 1); field
//             sum_i theta_i f_i(x), f_i(x) = f(x, vertex of mode i).
//   stewart   z = [theta | lambda | mu]                (n_f = 2^nc each, mu scalar),
//             eq g(x) - lambda - mu e (g = -S c, S dense), e'theta - 1; field sum_i theta_i f_i;
//             pairs (theta_i, lambda_i).
//
// The lifted and Stewart fields equal f(x, a) for models multi-affine in a (every
// PiecewiseSmoothAsStep, IRMA, the switching cases).
//
// A pair (u, v) has u = z[u] or 1 - z[u] (flipped) and v = z[v] >= 0. Its "group" is the
// switching function (step) or the mode (Stewart) it belongs to; the step equilibration and the
// active sides are computed per group.
#ifndef BFLOW_FESD_DCS_H_
#define BFLOW_FESD_DCS_H_

#include <algorithm>
#include <limits>
#include <string>
#include <vector>

#include "bflow/core/errors.h"
#include "bflow/core/filippov.h"
#include "bflow/fesd/fesd.h"

namespace bflow {
namespace fesd {

struct Pair {
  int u;
  bool flipped;
  int v;
  int group;
};

// Which member of a pair is zero on an element.
enum class PairState { kUZero, kVZero };

class PointDcs {
 public:
  enum class Kind { kStep, kLifted, kStewart };

  PointDcs(const StepModel& model, DcsFormulation formulation, int lifting_depth)
      : model_(model), d_(model.states()), nc_(model.switches()) {
    if (formulation == DcsFormulation::kStewart) {
      kind_ = Kind::kStewart;
      signs_ = SignMatrix::dense(nc_);
    } else if (lifting_depth != 0) {
      kind_ = Kind::kLifted;
      signs_ = model.sign_matrix() != nullptr ? *model.sign_matrix() : SignMatrix::dense(nc_);
      lifting_ = signs_.lifting(lifting_depth);
    } else {
      kind_ = Kind::kStep;
    }
    const double inf = std::numeric_limits<double>::infinity();
    if (kind_ == Kind::kStewart) {
      nf_ = signs_.modes();
      size_ = 2 * nf_ + 1;
      equations_ = nf_ + 1;
      lower_.assign(static_cast<std::size_t>(size_), 0.0);
      upper_.assign(static_cast<std::size_t>(size_), inf);
      lower_[static_cast<std::size_t>(2 * nf_)] = -inf;  // mu
      for (int i = 0; i < nf_; ++i) pairs_.push_back({i, false, nf_ + i, i});
      groups_ = nf_;
    } else {
      nf_ = kind_ == Kind::kLifted ? signs_.modes() : 0;
      const int betas = kind_ == Kind::kLifted ? lifting_.betas() : 0;
      size_ = 3 * nc_ + nf_ + betas;
      equations_ = nc_ + nf_ + betas;
      lower_.assign(static_cast<std::size_t>(size_), -inf);
      upper_.assign(static_cast<std::size_t>(size_), inf);
      for (int k = 0; k < 3 * nc_; ++k) lower_[static_cast<std::size_t>(k)] = 0.0;
      for (int j = 0; j < nc_; ++j) upper_[static_cast<std::size_t>(j)] = 1.0;
      for (int j = 0; j < nc_; ++j) pairs_.push_back({j, false, 2 * nc_ + j, j});  // (a, l^n)
      for (int j = 0; j < nc_; ++j) pairs_.push_back({j, true, nc_ + j, j});       // (1-a, l^p)
      groups_ = nc_;
    }
    if (kind_ != Kind::kStep) {
      // One vertex per mode (any row of the mode).
      vertices_.assign(static_cast<std::size_t>(nf_), {});
      for (int r = signs_.rows() - 1; r >= 0; --r) {
        vertices_[static_cast<std::size_t>(signs_.mode_of_row()[static_cast<std::size_t>(r)])] =
            signs_.vertex(r);
      }
      // A piecewise-smooth model gives all its modes in one call: the field at vertex i is
      // sum_j theta_j(vertex_i) f_j, with these weights.
      const SignMatrix* own = model.sign_matrix();
      if (model.modes() > 0 && own != nullptr && own->modes() == model.modes()) {
        model_modes_ = model.modes();
        mix_.assign(static_cast<std::size_t>(nf_ * model_modes_), 0.0);
        for (int i = 0; i < nf_; ++i) {
          own->multipliers(vertices_[static_cast<std::size_t>(i)].data(),
                           mix_.data() + static_cast<std::size_t>(i * model_modes_));
        }
      }
    }
  }

  Kind kind() const { return kind_; }
  int size() const { return size_; }
  int equations() const { return equations_; }
  int modes() const { return nf_; }
  const std::vector<Pair>& pairs() const { return pairs_; }
  int groups() const { return groups_; }
  double lower(int k) const { return lower_[static_cast<std::size_t>(k)]; }
  double upper(int k) const { return upper_[static_cast<std::size_t>(k)]; }

  template <typename T>
  static T member_u(const Pair& pair, const T* z) {
    return pair.flipped ? T(1.0) - z[pair.u] : z[pair.u];
  }
  // The value z[pair.u] takes when u = 0.
  static double u_zero(const Pair& pair) { return pair.flipped ? 1.0 : 0.0; }

  // The entries of z that field() reads: [field_first(), field_first() + field_count()) (alpha
  // for the step formulation, theta for Stewart's and the lifted one).
  int field_first() const { return kind_ == Kind::kLifted ? 3 * nc_ : 0; }
  int field_count() const { return kind_ == Kind::kStep ? nc_ : nf_; }

  // x' at a point.
  template <typename T>
  void field(const T* x, const T* z, T* xdot) const {
    if (kind_ == Kind::kStep) {
      model_.field(x, z, xdot);
      return;
    }
    const T* theta = z + (kind_ == Kind::kStewart ? 0 : 3 * nc_);
    if (model_modes_ > 0) {
      thread_local std::vector<T> modes;
      modes.resize(static_cast<std::size_t>(model_modes_ * d_));
      model_.mode_fields(x, modes.data());
      for (int k = 0; k < d_; ++k) xdot[k] = T(0.0);
      for (int j = 0; j < model_modes_; ++j) {
        T weight(0.0);
        bool used = false;
        for (int i = 0; i < nf_; ++i) {
          const double m = mix_[static_cast<std::size_t>(i * model_modes_ + j)];
          if (m == 0.0) continue;
          weight += m == 1.0 ? theta[i] : T(m) * theta[i];
          used = true;
        }
        if (!used) continue;
        const T* fj = modes.data() + static_cast<std::size_t>(j * d_);
        for (int k = 0; k < d_; ++k) xdot[k] += weight * fj[k];
      }
      return;
    }
    thread_local std::vector<T> vertex, f;
    vertex.resize(static_cast<std::size_t>(nc_));
    f.resize(static_cast<std::size_t>(d_));
    for (int k = 0; k < d_; ++k) xdot[k] = T(0.0);
    for (int i = 0; i < nf_; ++i) {
      const std::vector<double>& v = vertices_[static_cast<std::size_t>(i)];
      for (int j = 0; j < nc_; ++j)
        vertex[static_cast<std::size_t>(j)] = T(v[static_cast<std::size_t>(j)]);
      model_.field(x, vertex.data(), f.data());
      for (int k = 0; k < d_; ++k) xdot[k] += theta[i] * f[static_cast<std::size_t>(k)];
    }
  }

  // The algebraic equalities at a point (equations() values).
  template <typename T>
  void algebraic(const T* x, const T* z, T* eq) const {
    thread_local std::vector<T> c;
    c.resize(static_cast<std::size_t>(nc_));
    model_.switching(x, c.data());
    if (kind_ == Kind::kStewart) {
      const T* theta = z;
      const T* lambda = z + nf_;
      const T& mu = z[2 * nf_];
      thread_local std::vector<T> g;
      g.resize(static_cast<std::size_t>(nf_));
      signs_.indicator(c.data(), g.data());
      T sum(-1.0);
      for (int i = 0; i < nf_; ++i) {
        eq[i] = g[static_cast<std::size_t>(i)] - lambda[i] - mu;
        sum += theta[i];
      }
      eq[nf_] = sum;
      return;
    }
    const T* a = z;
    const T* p = z + nc_;
    const T* q = z + 2 * nc_;
    for (int j = 0; j < nc_; ++j) eq[j] = c[static_cast<std::size_t>(j)] - p[j] + q[j];
    if (kind_ != Kind::kLifted) return;
    const T* theta = z + 3 * nc_;
    const T* beta = theta + nf_;
    T* eq_beta = eq + nc_;
    T* eq_theta = eq_beta + lifting_.betas();
    for (int k = 0; k < lifting_.betas(); ++k) {
      eq_beta[k] = beta[k] - SignMatrix::Lifting::product(
                                 lifting_.beta_products[static_cast<std::size_t>(k)], a, beta);
    }
    for (int i = 0; i < nf_; ++i) eq_theta[i] = theta[i];
    for (int r = 0; r < signs_.rows(); ++r) {
      eq_theta[signs_.mode_of_row()[static_cast<std::size_t>(r)]] -=
          SignMatrix::Lifting::product(lifting_.row_products[static_cast<std::size_t>(r)], a, beta);
    }
  }

  // The pairs' v at a state x, from the LP's KKT conditions ((17); Stewart: lambda = g - min g).
  void start(const double* x, double* v) const {
    std::vector<double> z(static_cast<std::size_t>(size_));
    initial(x, z.data());
    for (std::size_t k = 0; k < pairs_.size(); ++k) v[k] = z[static_cast<std::size_t>(pairs_[k].v)];
  }

  // A consistent point at x: the selections of x's sides (on a surface: a = 1/2, Stewart: theta
  // shared by the minimisers of g).
  void initial(const double* x, double* z) const {
    std::vector<double> c(static_cast<std::size_t>(nc_));
    model_.switching(x, c.data());
    if (kind_ == Kind::kStewart) {
      std::vector<double> g(static_cast<std::size_t>(nf_));
      signs_.indicator(c.data(), g.data());
      const double mu = *std::min_element(g.begin(), g.end());
      int ties = 0;
      for (double gi : g) ties += gi == mu ? 1 : 0;
      for (int i = 0; i < nf_; ++i) {
        const double gi = g[static_cast<std::size_t>(i)];
        z[i] = gi == mu ? 1.0 / ties : 0.0;
        z[nf_ + i] = gi - mu;
      }
      z[2 * nf_] = mu;
      return;
    }
    for (int j = 0; j < nc_; ++j) {
      const double cj = c[static_cast<std::size_t>(j)];
      z[j] = cj > 0 ? 1.0 : cj < 0 ? 0.0 : 0.5;
      z[nc_ + j] = std::max(cj, 0.0);
      z[2 * nc_ + j] = std::max(-cj, 0.0);
    }
    if (kind_ != Kind::kLifted) return;
    double* theta = z + 3 * nc_;
    double* beta = theta + nf_;
    lifting_.betas(z, beta);
    signs_.multipliers(z, theta);
  }

  // A guess that favours no side: a = 1/2 and lambda+- = 1/2 with the lifted theta and beta
  // consistent with a (nosnoc's initialisation); Stewart: theta = 1/n_f with lambda = 1 and
  // mu = 0 (kNeutral), or nosnoc's theta = lambda = sigma_0 / n_f and mu = 1 at its sigma_0 = 1
  // (kNosnoc).
  void neutral(double* z, AlgebraicGuess guess = AlgebraicGuess::kNeutral) const {
    if (kind_ == Kind::kStewart) {
      const bool nosnoc = guess == AlgebraicGuess::kNosnoc;
      for (int i = 0; i < nf_; ++i) {
        z[i] = 1.0 / nf_;
        z[nf_ + i] = nosnoc ? 1.0 / nf_ : 1.0;
      }
      z[2 * nf_] = nosnoc ? 1.0 : 0.0;
      return;
    }
    for (int j = 0; j < nc_; ++j) z[j] = z[nc_ + j] = z[2 * nc_ + j] = 0.5;
    if (kind_ != Kind::kLifted) return;
    double* theta = z + 3 * nc_;
    double* beta = theta + nf_;
    lifting_.betas(z, beta);
    signs_.multipliers(z, theta);
  }

  // Sides of the switching functions (+1, -1, 0 = on the surface) on an element whose pairs'
  // largest v are vmax: v > tol marks the other member zero.
  std::vector<int> sides(const std::vector<double>& vmax, double tol) const {
    std::vector<int> out(static_cast<std::size_t>(nc_), 0);
    if (kind_ == Kind::kStewart) {
      std::vector<bool> active(static_cast<std::size_t>(nf_));
      for (int i = 0; i < nf_; ++i)
        active[static_cast<std::size_t>(i)] = !(vmax[static_cast<std::size_t>(i)] > tol);
      for (int j = 0; j < nc_; ++j) {
        int plus = 0, minus = 0;
        for (int i = 0; i < nf_; ++i) {
          if (!active[static_cast<std::size_t>(i)]) continue;
          (signs_.matrix()(i, j) > 0 ? plus : minus) += 1;
        }
        out[static_cast<std::size_t>(j)] = plus > 0 && minus == 0   ? 1
                                           : minus > 0 && plus == 0 ? -1
                                                                    : 0;
      }
      return out;
    }
    for (int j = 0; j < nc_; ++j) {
      const double q = vmax[static_cast<std::size_t>(j)],
                   p = vmax[static_cast<std::size_t>(nc_ + j)];
      out[static_cast<std::size_t>(j)] = p > tol && p >= q ? 1 : q > tol ? -1 : 0;
    }
    return out;
  }

  // The member of each pair that is zero on an element with these sides.
  std::vector<PairState> states(const std::vector<int>& sides) const {
    std::vector<PairState> out(pairs_.size());
    if (kind_ == Kind::kStewart) {
      for (int i = 0; i < nf_; ++i) {
        bool active = true;
        for (int j = 0; j < nc_; ++j) {
          const int side = sides[static_cast<std::size_t>(j)];
          if (side != 0 && signs_.matrix()(i, j) != side) active = false;
        }
        out[static_cast<std::size_t>(i)] = active ? PairState::kVZero : PairState::kUZero;
      }
      return out;
    }
    for (int j = 0; j < nc_; ++j) {
      const int side = sides[static_cast<std::size_t>(j)];
      out[static_cast<std::size_t>(j)] = side < 0 ? PairState::kUZero : PairState::kVZero;
      out[static_cast<std::size_t>(nc_ + j)] = side > 0 ? PairState::kUZero : PairState::kVZero;
    }
    return out;
  }

  // Whether group g leaves a sliding arc between elements with sides `prior` and `next` (its
  // selection must then be continuous): a surface it slid on is left, and (Stewart) the mode
  // lies on the side that is left.
  bool leaves_sliding(const std::vector<int>& prior, const std::vector<int>& next,
                      int group) const {
    if (kind_ != Kind::kStewart) {
      return prior[static_cast<std::size_t>(group)] == 0 &&
             next[static_cast<std::size_t>(group)] != 0;
    }
    for (int j = 0; j < nc_; ++j) {
      const int before = prior[static_cast<std::size_t>(j)];
      const int after = next[static_cast<std::size_t>(j)];
      if (before == 0 && after != 0 && signs_.matrix()(group, j) != after) return true;
    }
    return false;
  }

 private:
  const StepModel& model_;
  int d_, nc_;
  Kind kind_ = Kind::kStep;
  SignMatrix signs_ = SignMatrix::dense(1);
  SignMatrix::Lifting lifting_;
  int nf_ = 0, size_ = 0, equations_ = 0, groups_ = 0;
  std::vector<double> lower_, upper_;
  std::vector<Pair> pairs_;
  std::vector<std::vector<double>> vertices_;
  int model_modes_ = 0;      // > 0: the model's modes in one call (mode_fields), mixed by mix_
  std::vector<double> mix_;  // nf x model_modes_: theta of the model's modes at each vertex
};

}  // namespace fesd
}  // namespace bflow

#endif  // BFLOW_FESD_DCS_H_

#include "bflow/integrators/fesd.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <deque>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/LU>
#include <Eigen/QR>
#include <IpIpoptApplication.hpp>
#include <IpSolveStatistics.hpp>
#include <IpTNLP.hpp>

#include "bflow/core/errors.h"

namespace bflow {

const char* to_string(FesdStatus status) {
  switch (status) {
    case FesdStatus::kConverged:
      return "converged";
    case FesdStatus::kStepFailed:
      return "step failed";
    case FesdStatus::kInvalidModel:
      return "invalid model";
  }
  return "unknown";
}

namespace {

constexpr double kInfinity = 1e19;  // IPOPT's default nlp_upper_bound_inf

// Where each unknown of one integration step lives. Per finite element n (0-based):
//   [h | X_1..X_s (s d) | x_{n+1} (d) | a (P nc) | lambda^p (P nc) | lambda^n (P nc)]
// with P = s points (Radau IIA: the last stage is the element's end) or s + 1 (Gauss-Legendre:
// the stages and the end point of (42)). An element's "local" vector puts its start in front:
//   [x_n (d) | lambda^p_{n,0} (nc) | lambda^n_{n,0} (nc) | its own block].
struct Layout {
  int d = 0, nc = 0, s = 0, points = 0, elements = 0;
  bool end_point = false;  // Gauss-Legendre: an extra point at the element's end
  int off_x = 0, off_a = 0, off_p = 0, off_q = 0, block = 0;
  int equalities = 0;  // per element
  int local = 0;

  Layout(int states, int switches, const ButcherTableau& tableau, int n_fe)
      : d(states), nc(switches), s(tableau.stages), elements(n_fe) {
    end_point = !tableau.stiffly_accurate();
    points = s + (end_point ? 1 : 0);
    off_x = 1 + s * d;
    off_a = off_x + d;
    off_p = off_a + points * nc;
    off_q = off_p + points * nc;
    block = off_q + points * nc;
    equalities = s * d + d + points * nc;
    local = d + 2 * nc + block;
  }
  int variables() const { return elements * block; }
  int rows_per_element() const { return equalities + 2 * nc; }
  int constraints() const { return elements * rows_per_element() + 1; }
  int var(int n, int offset) const { return n * block + offset; }
  // Global index of local input k of element n, or -1 for a constant (the step's start).
  int global(int n, int k) const {
    if (k >= d + 2 * nc) return var(n, k - d - 2 * nc);
    if (n == 0) return -1;
    if (k < d) return var(n - 1, off_x + k);
    if (k < d + nc) return var(n - 1, off_p + (points - 1) * nc + (k - d));
    return var(n - 1, off_q + (points - 1) * nc + (k - d - nc));
  }
};

// Equalities and aggregated complementarity products of one element from its local vector.
template <typename T>
void element_residual(const StepModel& model, const ButcherTableau& tab, const Layout& l,
                      bool standard, const T* in, T* out) {
  const int d = l.d, nc = l.nc, s = l.s;
  const T* xn = in;
  const T* p0 = in + d;
  const T* q0 = in + d + nc;
  const T* blk = in + d + 2 * nc;
  const T& h = blk[0];
  const T* stage = blk + 1;
  const T* xnext = blk + l.off_x;
  const T* a = blk + l.off_a;
  const T* p = blk + l.off_p;
  const T* q = blk + l.off_q;
  // Scratch kept per thread and scalar type: this runs for every Jacobian chunk and every IPOPT
  // evaluation, so it allocates only when the sizes grow.
  thread_local std::vector<T> f, c;
  f.resize(static_cast<std::size_t>(s * d));
  c.resize(static_cast<std::size_t>(nc));
  for (int m = 0; m < s; ++m) model.field(stage + m * d, a + m * nc, f.data() + m * d);
  T* eq = out;
  for (int m = 0; m < s; ++m) {
    for (int i = 0; i < d; ++i) {
      T sum(0.0);
      for (int k = 0; k < s; ++k) sum += tab.a(m, k) * f[static_cast<std::size_t>(k * d + i)];
      eq[m * d + i] = stage[m * d + i] - xn[i] - h * sum;
    }
  }
  for (int i = 0; i < d; ++i) {
    T sum(0.0);
    for (int k = 0; k < s; ++k) sum += tab.b(k) * f[static_cast<std::size_t>(k * d + i)];
    eq[s * d + i] = xnext[i] - xn[i] - h * sum;
  }
  T* alg = eq + s * d + d;
  for (int m = 0; m < l.points; ++m) {
    model.switching(m < s ? stage + m * d : xnext, c.data());
    for (int j = 0; j < nc; ++j) {
      alg[m * nc + j] = c[static_cast<std::size_t>(j)] - p[m * nc + j] + q[m * nc + j];
    }
  }
  T* comp = eq + l.equalities;
  for (int j = 0; j < nc; ++j) {
    if (standard) {
      // (34): each point's own pair only.
      T sa(0.0), sb(0.0);
      for (int m = 0; m < l.points; ++m) {
        sa += a[m * nc + j] * q[m * nc + j];
        sb += (1.0 - a[m * nc + j]) * p[m * nc + j];
      }
      comp[j] = sa;
      comp[nc + j] = sb;
    } else {
      // (35) and (37) summed over all pairs of points of the element, the start included:
      // sum_m sum_m' a_m q_m' = (sum_m a_m)(sum_m' q_m').
      T sum_a(0.0), sum_1a(0.0), sum_p = p0[j], sum_q = q0[j];
      for (int m = 0; m < l.points; ++m) {
        sum_a += a[m * nc + j];
        sum_1a += 1.0 - a[m * nc + j];
        sum_p += p[m * nc + j];
        sum_q += q[m * nc + j];
      }
      comp[j] = sum_a * sum_q;
      comp[nc + j] = sum_1a * sum_p;
    }
  }
}

// Step equilibration between elements n - 1 and n ((39) with the indicator of Section 4.4):
// inputs [h_{n-1}, h_n, start p, q of n - 1 (2 nc), p, q of n - 1 (2 P nc), p, q of n (2 P nc),
// a at the last point of n - 1 (nc), a at the first point of n (nc)].
template <typename T>
T equilibration_term(const Layout& l, double h_ref, const T* in) {
  const int nc = l.nc, pts = l.points;
  const T* start_p = in + 2;
  const T* start_q = start_p + nc;
  const T* back_p = start_q + nc;
  const T* back_q = back_p + pts * nc;
  const T* fwd_p = back_q + pts * nc;
  const T* fwd_q = fwd_p + pts * nc;
  T eta(1.0);
  for (int j = 0; j < nc; ++j) {
    T bp = start_p[j], bq = start_q[j], fp(0.0), fq(0.0);
    for (int m = 0; m < pts; ++m) {
      bp += back_p[m * nc + j];
      bq += back_q[m * nc + j];
      fp += fwd_p[m * nc + j];
      fq += fwd_q[m * nc + j];
    }
    fp += back_p[(pts - 1) * nc + j];  // the forward element starts where the back one ends
    fq += back_q[(pts - 1) * nc + j];
    const T nu = bq * fq + bp * fp;
    eta *= nu / (nu + 1e-6);
  }
  const T dh = (in[1] - in[0]) / h_ref;
  T value = (eta + 1e-3) * dh * dh;
  // Leaving a sliding arc: the selection is continuous where a trajectory leaves the surface (it
  // reaches its bound exactly there), so a jump of a_j after an element that slides on c_j is
  // penalised. This picks the exact leaving time among the boundaries the collocation conditions
  // allow (they admit any within O(h) of it), and keeps a trajectory on the surface when leaving
  // is optional (the spontaneous case).
  const T* back_a = fwd_q + pts * nc;
  const T* fwd_a = back_a + nc;
  for (int j = 0; j < nc; ++j) {
    T lambda(0.0);
    for (int m = 0; m < pts; ++m) lambda += back_p[m * nc + j] + back_q[m * nc + j];
    const T sliding = 1e-6 / (1e-6 + lambda);
    const T jump = fwd_a[j] - back_a[j];
    value += 1e3 * sliding * jump * jump;
  }
  return value;
}

// Global indices of the inputs of equilibration_term at boundary n (1 <= n < N): -1 = constant.
std::vector<int> equilibration_inputs(const Layout& l, int n) {
  std::vector<int> idx;
  idx.push_back(l.var(n - 1, 0));
  idx.push_back(l.var(n, 0));
  for (int which = 0; which < 2; ++which) {  // start p, then start q of element n - 1
    for (int j = 0; j < l.nc; ++j) {
      idx.push_back(l.global(n - 1, l.d + which * l.nc + j));
    }
  }
  for (int e : {n - 1, n}) {
    for (int off : {l.off_p, l.off_q}) {
      for (int k = 0; k < l.points * l.nc; ++k) idx.push_back(l.var(e, off + k));
    }
  }
  for (int j = 0; j < l.nc; ++j) idx.push_back(l.var(n - 1, l.off_a + (l.points - 1) * l.nc + j));
  for (int j = 0; j < l.nc; ++j) idx.push_back(l.var(n, l.off_a + j));
  return idx;
}

// One integration step as an IPOPT problem at relaxation sigma.
class StepNlp final : public Ipopt::TNLP {
 public:
  StepNlp(const StepModel& model, const ButcherTableau& tab, const Layout& layout,
          const FesdOptions& options, Eigen::VectorXd x_start, double step)
      : model_(model),
        tab_(tab),
        l_(layout),
        options_(options),
        x_start_(std::move(x_start)),
        step_(step) {
    const int nc = l_.nc;
    Eigen::VectorXd c(nc);
    model_.switching(x_start_.data(), c.data());
    p_start_ = c.cwiseMax(0.0);  // (17)
    q_start_ = (-c).cwiseMax(0.0);
    // Initial guess: the state held, the selections of the start's sides.
    w_.setZero(l_.variables());
    for (int n = 0; n < l_.elements; ++n) {
      w_[l_.var(n, 0)] = step_ / l_.elements;
      for (int m = 0; m < l_.s; ++m) {
        w_.segment(l_.var(n, 1 + m * l_.d), l_.d) = x_start_;
      }
      w_.segment(l_.var(n, l_.off_x), l_.d) = x_start_;
      for (int m = 0; m < l_.points; ++m) {
        for (int j = 0; j < nc; ++j) {
          w_[l_.var(n, l_.off_a + m * nc + j)] = c[j] > 0 ? 1.0 : c[j] < 0 ? 0.0 : 0.5;
          w_[l_.var(n, l_.off_p + m * nc + j)] = p_start_[j];
          w_[l_.var(n, l_.off_q + m * nc + j)] = q_start_[j];
        }
      }
    }
    for (int n = 1; n < l_.elements; ++n)
      equilibration_index_.push_back(equilibration_inputs(l_, n));
    // Jacobian structure: each element's rows against its non-constant local inputs.
    for (int n = 0; n < l_.elements; ++n) {
      for (int r = 0; r < l_.rows_per_element(); ++r) {
        for (int k = 0; k < l_.local; ++k) {
          const int col = l_.global(n, k);
          if (col < 0) continue;
          jac_rows_.push_back(n * l_.rows_per_element() + r);
          jac_cols_.push_back(col);
        }
      }
    }
    for (int n = 0; n < l_.elements; ++n) {
      jac_rows_.push_back(l_.elements * l_.rows_per_element());
      jac_cols_.push_back(l_.var(n, 0));
    }
  }

  void set_sigma(double sigma) { sigma_ = sigma; }
  void set_solution(const Eigen::VectorXd& w) { w_ = w; }
  // The last converged iterate, kept so that a failed solve can be retried from it.
  void save() { saved_ = {w_, z_l_, z_u_, lambda_}; }
  void restore() {
    w_ = saved_[0];
    z_l_ = saved_[1];
    z_u_ = saved_[2];
    lambda_ = saved_[3];
  }
  const Eigen::VectorXd& solution() const { return w_; }
  double start_p(int j) const { return p_start_[j]; }
  double start_q(int j) const { return q_start_[j]; }
  Ipopt::SolverReturn last_status() const { return status_; }

  // Local input vector of element n from w (constants from the step's start).
  template <typename T>
  void local_inputs(const double* w, int n, std::vector<T>& in) const {
    in.resize(static_cast<std::size_t>(l_.local));
    for (int k = 0; k < l_.local; ++k) {
      const int g = l_.global(n, k);
      double value;
      if (g >= 0) {
        value = w[g];
      } else if (k < l_.d) {
        value = x_start_[k];
      } else if (k < l_.d + l_.nc) {
        value = p_start_[k - l_.d];
      } else {
        value = q_start_[k - l_.d - l_.nc];
      }
      in[static_cast<std::size_t>(k)] = T(value);
    }
  }

  // Dense Jacobian of element n's rows against its local inputs, by Jet chunks.
  Eigen::MatrixXd element_jacobian(const double* w, int n, Eigen::VectorXd* values) const {
    const int rows = l_.rows_per_element();
    Eigen::MatrixXd jac(rows, l_.local);
    std::vector<JetChunk> in, out(static_cast<std::size_t>(rows));
    local_inputs(w, n, in);
    for (int first = 0; first < l_.local; first += kTangentChunk) {
      for (int k = 0; k < l_.local; ++k) in[static_cast<std::size_t>(k)].v.setZero();
      const int width = std::min(kTangentChunk, l_.local - first);
      for (int c = 0; c < width; ++c) in[static_cast<std::size_t>(first + c)].v[c] = 1.0;
      element_residual(model_, tab_, l_, options_.standard, in.data(), out.data());
      for (int r = 0; r < rows; ++r) {
        for (int c = 0; c < width; ++c) jac(r, first + c) = out[static_cast<std::size_t>(r)].v[c];
      }
    }
    if (values != nullptr) {
      values->resize(rows);
      for (int r = 0; r < rows; ++r) (*values)[r] = out[static_cast<std::size_t>(r)].a;
    }
    return jac;
  }

  bool get_nlp_info(Ipopt::Index& n, Ipopt::Index& m, Ipopt::Index& nnz_jac, Ipopt::Index& nnz_hess,
                    IndexStyleEnum& style) override {
    n = l_.variables();
    m = l_.constraints();
    nnz_jac = static_cast<Ipopt::Index>(jac_rows_.size());
    nnz_hess = 0;
    style = C_STYLE;
    return true;
  }

  bool get_bounds_info(Ipopt::Index n, Ipopt::Number* x_l, Ipopt::Number* x_u, Ipopt::Index m,
                       Ipopt::Number* g_l, Ipopt::Number* g_u) override {
    for (int k = 0; k < n; ++k) {
      x_l[k] = -kInfinity;
      x_u[k] = kInfinity;
    }
    const double h0 = step_ / l_.elements;
    for (int e = 0; e < l_.elements; ++e) {
      x_l[l_.var(e, 0)] = options_.standard ? h0 : 0.0;
      x_u[l_.var(e, 0)] = options_.standard ? h0 : 2.0 * h0;
      for (int k = 0; k < l_.points * l_.nc; ++k) {
        x_l[l_.var(e, l_.off_a + k)] = 0.0;
        x_u[l_.var(e, l_.off_a + k)] = 1.0;
        x_l[l_.var(e, l_.off_p + k)] = 0.0;
        x_l[l_.var(e, l_.off_q + k)] = 0.0;
      }
      for (int r = 0; r < l_.rows_per_element(); ++r) {
        const int row = e * l_.rows_per_element() + r;
        g_l[row] = r < l_.equalities ? 0.0 : -kInfinity;
        g_u[row] = r < l_.equalities ? 0.0 : sigma_;
      }
    }
    g_l[m - 1] = g_u[m - 1] = step_;
    return true;
  }

  bool get_starting_point(Ipopt::Index n, bool init_x, Ipopt::Number* x, bool init_z,
                          Ipopt::Number* z_l, Ipopt::Number* z_u, Ipopt::Index m, bool init_lambda,
                          Ipopt::Number* lambda) override {
    if (init_x) std::copy(w_.data(), w_.data() + n, x);
    if (init_z) {
      if (z_l_.size() != n) return false;
      std::copy(z_l_.data(), z_l_.data() + n, z_l);
      std::copy(z_u_.data(), z_u_.data() + n, z_u);
    }
    if (init_lambda) {
      if (lambda_.size() != m) return false;
      std::copy(lambda_.data(), lambda_.data() + m, lambda);
    }
    return true;
  }

  bool eval_f(Ipopt::Index, const Ipopt::Number* x, bool, Ipopt::Number& value) override {
    value = 0.0;
    if (options_.standard) return true;
    std::vector<double> in;
    for (const std::vector<int>& idx : equilibration_index_) {
      gather(x, idx, in);
      value += equilibration_term(l_, step_ / l_.elements, in.data());
    }
    return true;
  }

  bool eval_grad_f(Ipopt::Index n, const Ipopt::Number* x, bool, Ipopt::Number* grad) override {
    std::fill(grad, grad + n, 0.0);
    if (options_.standard) return true;
    std::vector<double> values;
    for (const std::vector<int>& idx : equilibration_index_) {
      gather(x, idx, values);
      const int size = static_cast<int>(idx.size());
      std::vector<JetChunk> in(static_cast<std::size_t>(size));
      for (int first = 0; first < size; first += kTangentChunk) {
        for (int k = 0; k < size; ++k)
          in[static_cast<std::size_t>(k)] = JetChunk(values[static_cast<std::size_t>(k)]);
        const int width = std::min(kTangentChunk, size - first);
        for (int c = 0; c < width; ++c) in[static_cast<std::size_t>(first + c)].v[c] = 1.0;
        const JetChunk term = equilibration_term(l_, step_ / l_.elements, in.data());
        for (int c = 0; c < width; ++c) {
          const int g = idx[static_cast<std::size_t>(first + c)];
          if (g >= 0) grad[g] += term.v[c];
        }
      }
    }
    return true;
  }

  bool eval_g(Ipopt::Index, const Ipopt::Number* x, bool, Ipopt::Index m,
              Ipopt::Number* g) override {
    std::vector<double> in;
    for (int n = 0; n < l_.elements; ++n) {
      local_inputs(x, n, in);
      element_residual(model_, tab_, l_, options_.standard, in.data(),
                       g + n * l_.rows_per_element());
    }
    double sum = 0;
    for (int n = 0; n < l_.elements; ++n) sum += x[l_.var(n, 0)];
    g[m - 1] = sum;
    return true;
  }

  bool eval_jac_g(Ipopt::Index, const Ipopt::Number* x, bool, Ipopt::Index, Ipopt::Index nele,
                  Ipopt::Index* rows, Ipopt::Index* cols, Ipopt::Number* values) override {
    if (values == nullptr) {
      for (Ipopt::Index k = 0; k < nele; ++k) {
        rows[k] = jac_rows_[static_cast<std::size_t>(k)];
        cols[k] = jac_cols_[static_cast<std::size_t>(k)];
      }
      return true;
    }
    Ipopt::Index k = 0;
    for (int n = 0; n < l_.elements; ++n) {
      const Eigen::MatrixXd jac = element_jacobian(x, n, nullptr);
      for (int r = 0; r < l_.rows_per_element(); ++r) {
        for (int c = 0; c < l_.local; ++c) {
          if (l_.global(n, c) < 0) continue;
          values[k++] = jac(r, c);
        }
      }
    }
    for (int n = 0; n < l_.elements; ++n) values[k++] = 1.0;
    return true;
  }

  void finalize_solution(Ipopt::SolverReturn status, Ipopt::Index n, const Ipopt::Number* x,
                         const Ipopt::Number* z_l, const Ipopt::Number* z_u, Ipopt::Index m,
                         const Ipopt::Number*, const Ipopt::Number* lambda, Ipopt::Number,
                         const Ipopt::IpoptData*, Ipopt::IpoptCalculatedQuantities*) override {
    status_ = status;
    w_ = Eigen::Map<const Eigen::VectorXd>(x, n);
    z_l_ = Eigen::Map<const Eigen::VectorXd>(z_l, n);
    z_u_ = Eigen::Map<const Eigen::VectorXd>(z_u, n);
    lambda_ = Eigen::Map<const Eigen::VectorXd>(lambda, m);
  }

  // Largest aggregated complementarity product at w.
  double complementarity(const Eigen::VectorXd& w) const {
    double worst = 0;
    std::vector<double> in, out(static_cast<std::size_t>(l_.rows_per_element()));
    for (int n = 0; n < l_.elements; ++n) {
      local_inputs(w.data(), n, in);
      element_residual(model_, tab_, l_, options_.standard, in.data(), out.data());
      for (int r = l_.equalities; r < l_.rows_per_element(); ++r) {
        worst = std::max(worst, std::abs(out[static_cast<std::size_t>(r)]));
      }
    }
    return worst;
  }

 private:
  static void gather(const double* x, const std::vector<int>& idx, std::vector<double>& out) {
    out.resize(idx.size());
    for (std::size_t k = 0; k < idx.size(); ++k) out[k] = idx[k] >= 0 ? x[idx[k]] : 0.0;
  }

  const StepModel& model_;
  const ButcherTableau& tab_;
  const Layout& l_;
  const FesdOptions& options_;
  Eigen::VectorXd x_start_, p_start_, q_start_;
  double step_;
  double sigma_ = 1.0;
  Eigen::VectorXd w_, z_l_, z_u_, lambda_;
  std::array<Eigen::VectorXd, 4> saved_;
  std::vector<std::vector<int>> equilibration_index_;
  std::vector<Ipopt::Index> jac_rows_, jac_cols_;
  Ipopt::SolverReturn status_ = Ipopt::SUCCESS;
};

// Side of switching function j on element n: +1 (lambda^p > 0), -1 (lambda^n > 0), 0 (both 0).
int element_side(const Layout& l, const Eigen::VectorXd& w, int n, int j, double tol) {
  double p = 0, q = 0;
  for (int m = 0; m < l.points; ++m) {
    p = std::max(p, w[l.var(n, l.off_p + m * l.nc + j)]);
    q = std::max(q, w[l.var(n, l.off_q + m * l.nc + j)]);
  }
  if (p > tol && p >= q) return 1;
  if (q > tol) return -1;
  return 0;
}

// One integration step's FESD equations with the active set fixed: the element equalities, each
// fixed complementarity variable (index, value), sum h_n = H, and h_n = h_{n-1} at the listed
// boundaries n. assemble() writes the residual and the Jacobians in w and in the step's start x.
struct FixedActiveSet {
  std::vector<std::pair<int, double>> fixed;
  std::vector<int> equal_lengths;

  int rows(const Layout& l) const {
    return l.elements * l.equalities + static_cast<int>(fixed.size()) + 1 +
           static_cast<int>(equal_lengths.size());
  }

  void assemble(const StepNlp& nlp, const Layout& l, const Eigen::VectorXd& w, double step,
                Eigen::MatrixXd& jac_w, Eigen::MatrixXd& jac_x, Eigen::VectorXd& residual) const {
    const int count = rows(l);
    jac_w.setZero(count, l.variables());
    jac_x.setZero(count, l.d);
    residual.resize(count);
    int row = 0;
    Eigen::VectorXd values;
    for (int n = 0; n < l.elements; ++n) {
      const Eigen::MatrixXd local = nlp.element_jacobian(w.data(), n, &values);
      for (int r = 0; r < l.equalities; ++r, ++row) {
        residual[row] = values[r];
        for (int k = 0; k < l.local; ++k) {
          const int g = l.global(n, k);
          if (g >= 0) {
            jac_w(row, g) += local(r, k);
          } else if (k < l.d) {
            jac_x(row, k) += local(r, k);
          }
        }
      }
    }
    for (const auto& [index, value] : fixed) {
      residual[row] = w[index] - value;
      jac_w(row++, index) = 1.0;
    }
    double sum = 0;
    for (int n = 0; n < l.elements; ++n) {
      sum += w[l.var(n, 0)];
      jac_w(row, l.var(n, 0)) = 1.0;
    }
    residual[row++] = sum - step;
    for (int n : equal_lengths) {
      residual[row] = w[l.var(n, 0)] - w[l.var(n - 1, 0)];
      jac_w(row, l.var(n, 0)) = 1.0;
      jac_w(row++, l.var(n - 1, 0)) = -1.0;
    }
  }
};

// dx_end/dx_start by the implicit function theorem on the converged active set, or an empty
// matrix with *why set when the fixed-active-set system is not square or is singular.
Eigen::MatrixXd step_sensitivity(const StepNlp& nlp, const Layout& l, const Eigen::VectorXd& w,
                                 double step, double tol, std::string* why) {
  const int nv = l.variables();
  FixedActiveSet active;
  for (int n = 0; n < l.elements; ++n) {
    for (int m = 0; m < l.points; ++m) {
      for (int j = 0; j < l.nc; ++j) {
        const int ia = l.var(n, l.off_a + m * l.nc + j);
        if (w[ia] <= tol) active.fixed.push_back({ia, 0.0});
        if (w[ia] >= 1.0 - tol) active.fixed.push_back({ia, 1.0});
        for (int off : {l.off_p, l.off_q}) {
          const int idx = l.var(n, off + m * l.nc + j);
          if (w[idx] <= tol) active.fixed.push_back({idx, 0.0});
        }
      }
    }
  }
  for (int n = 1; n < l.elements; ++n) {
    bool same = true;
    for (int j = 0; j < l.nc; ++j) {
      same = same && element_side(l, w, n - 1, j, tol) == element_side(l, w, n, j, tol);
    }
    if (same) active.equal_lengths.push_back(n);
  }
  // A switch that falls on the step's end, or a pair that is degenerate at the solution (both
  // members zero), adds an equation that the others already imply: the system is then tall but
  // consistent, and its least-squares solution is the derivative.
  const int count = active.rows(l);
  if (count < nv) {
    *why = "the fixed-active-set system has " + std::to_string(count) + " equations for " +
           std::to_string(nv) + " unknowns (no switch condition for a free element length)";
    return {};
  }
  Eigen::MatrixXd gw, gx;
  Eigen::VectorXd residual;
  active.assemble(nlp, l, w, step, gw, gx, residual);
  const Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(gw);
  if (qr.rank() < nv) {
    *why = "the fixed-active-set system is singular (rank " + std::to_string(qr.rank()) + " of " +
           std::to_string(nv) + ")";
    return {};
  }
  const Eigen::MatrixXd dw = qr.solve(-gx);
  const double inconsistency = (gw * dw + gx).norm();
  if (!(inconsistency <= 1e-8 * std::max(1.0, gx.norm()))) {
    *why = "the fixed-active-set system is inconsistent (residual " + format_number(inconsistency) +
           ")";
    return {};
  }
  return dw.middleRows(l.var(l.elements - 1, l.off_x), l.d);
}

// A step without a switch, solved by Newton's method on the FESD equations with the active set
// predicted from the step's start (`sides`: +1, -1 or 0 per switching function, for every point
// of every element): a = 1 and lambda^n = 0 on +, a = 0 and lambda^p = 0 on -, lambda^p =
// lambda^n = 0 when sliding, and equal element lengths. The system is square; its solution is an
// FESD solution (every complementarity product exactly 0) if the free members come out
// nonnegative and the free selections inside [0, 1]. Returns false otherwise (a switch inside
// the step, or no convergence): the caller then solves the step's NLPs.
bool newton_step(const StepNlp& nlp, const Layout& l, const std::vector<int>& sides, double step,
                 Eigen::VectorXd& w, int* iterations) {
  FixedActiveSet active;
  for (int n = 0; n < l.elements; ++n) {
    if (n > 0) active.equal_lengths.push_back(n);
    for (int m = 0; m < l.points; ++m) {
      for (int j = 0; j < l.nc; ++j) {
        const int ia = l.var(n, l.off_a + m * l.nc + j);
        const int ip = l.var(n, l.off_p + m * l.nc + j);
        const int iq = l.var(n, l.off_q + m * l.nc + j);
        const int side = sides[static_cast<std::size_t>(j)];
        if (side > 0) {
          active.fixed.push_back({ia, 1.0});
          active.fixed.push_back({iq, 0.0});
        } else if (side < 0) {
          active.fixed.push_back({ia, 0.0});
          active.fixed.push_back({ip, 0.0});
        } else {
          active.fixed.push_back({ip, 0.0});
          active.fixed.push_back({iq, 0.0});
        }
      }
    }
  }
  BFLOW_ASSERT(active.rows(l) == l.variables());
  for (const auto& [index, value] : active.fixed) w[index] = value;
  Eigen::MatrixXd jac, jac_x;
  Eigen::VectorXd residual;
  for (int it = 0; it < 20; ++it) {
    active.assemble(nlp, l, w, step, jac, jac_x, residual);
    const Eigen::PartialPivLU<Eigen::MatrixXd> lu(jac);
    const Eigen::VectorXd delta = lu.solve(-residual);
    if (!delta.allFinite()) return false;
    w += delta;
    *iterations = it + 1;
    if (delta.lpNorm<Eigen::Infinity>() <= 1e-14 * (1.0 + w.lpNorm<Eigen::Infinity>())) break;
    if (it == 19) return false;
  }
  // The predicted active set is right only if the free members are feasible.
  for (int n = 0; n < l.elements; ++n) {
    for (int k = 0; k < l.points * l.nc; ++k) {
      const double a = w[l.var(n, l.off_a + k)];
      if (w[l.var(n, l.off_p + k)] < 0.0 || w[l.var(n, l.off_q + k)] < 0.0 || a < 0.0 || a > 1.0) {
        return false;
      }
    }
  }
  return true;
}

void check_options(const StepModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                   double t_end, const FesdOptions& o) {
  if (x0.size() != model.states()) {
    throw InvalidArgument("fesd: x0 has " + std::to_string(x0.size()) + " entries, the model " +
                          std::to_string(model.states()) + " states");
  }
  if (!x0.allFinite()) throw InvalidArgument("fesd: x0 is not finite: " + format_vector(x0));
  if (!(t_end > 0.0) || !std::isfinite(t_end)) {
    throw InvalidArgument("fesd: T must be finite and > 0, got " + format_number(t_end));
  }
  if (o.elements < 1 || o.steps < 1) {
    throw InvalidArgument("fesd: need N_FE >= 1 and N_sim >= 1, got N_FE = " +
                          std::to_string(o.elements) + ", N_sim = " + std::to_string(o.steps));
  }
  if (!(o.sigma_initial > 0.0) || !(o.sigma_final > 0.0) || o.sigma_final > o.sigma_initial ||
      !(o.sigma_factor > 0.0 && o.sigma_factor < 1.0)) {
    throw InvalidArgument(
        "fesd: need 0 < sigma_final <= sigma_initial and 0 < sigma_factor < 1, "
        "got sigma_initial = " +
        format_number(o.sigma_initial) + ", sigma_final = " + format_number(o.sigma_final) +
        ", sigma_factor = " + format_number(o.sigma_factor));
  }
}

}  // namespace

FesdResult fesd_simulate(const StepModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                         double t_end, const FesdOptions& options) {
  check_options(model, x0, t_end, options);
  const ButcherTableau tab = collocation_tableau(options.scheme, options.stages);
  const Layout l(model.states(), model.switches(), tab, options.elements);
  const double step = t_end / options.steps;
  // Active-set decisions: a complementarity variable counts as zero below this.
  // A complementarity variable counts as zero below this: with products <= sigma_final, the zero
  // member of a pair whose other member is O(1e-3) or more is below sqrt(sigma_final).
  const double active_tol = std::clamp(std::sqrt(options.sigma_final), 1e-9, 1e-4);

  Ipopt::SmartPtr<Ipopt::IpoptApplication> app = IpoptApplicationFactory();
  app->RethrowNonIpoptException(false);
  app->Options()->SetIntegerValue("print_level", options.print_level);
  app->Options()->SetStringValue("sb", "yes");
  app->Options()->SetStringValue("hessian_approximation", "limited-memory");
  app->Options()->SetNumericValue("tol", options.nlp_tolerance);
  app->Options()->SetNumericValue("acceptable_tol", 1e3 * options.nlp_tolerance);
  app->Options()->SetIntegerValue("max_iter", options.max_nlp_iterations);
  app->Options()->SetStringValue("mu_strategy", "adaptive");
  app->Options()->SetNumericValue("bound_relax_factor", 0.0);
  if (app->Initialize() != Ipopt::Solve_Succeeded) {
    throw InvalidArgument("fesd: IPOPT failed to initialise");
  }

  FesdResult result;
  Eigen::VectorXd x = x0;
  result.grid.push_back(0.0);
  std::vector<Eigen::VectorXd> states{x};
  Eigen::MatrixXd sensitivity = Eigen::MatrixXd::Identity(l.d, l.d);
  bool sensitivities = options.sensitivities;
  std::vector<int> previous_sides;
  // Integration steps still to take, as (length, times halved); a step whose homotopy fails is
  // replaced by its two halves, at most kMaxHalvings times.
  constexpr int kMaxHalvings = 4;
  std::deque<std::pair<double, int>> pending(static_cast<std::size_t>(options.steps),
                                             std::make_pair(step, 0));
  double t0 = 0.0;
  while (!pending.empty()) {
    const auto [length, halvings] = pending.front();
    pending.pop_front();
    Ipopt::SmartPtr<StepNlp> nlp = new StepNlp(model, tab, l, options, x, length);
    int iterations = 0;
    double sigma = options.sigma_initial, last_sigma = sigma;
    bool first = true;
    int retries = 0;
    // Predicted sides: from c(x) where it is clearly nonzero, else the last element's.
    bool solved_by_newton = false;
    if (options.newton && !options.standard) {
      Eigen::VectorXd c(l.nc);
      model.switching(x.data(), c.data());
      std::vector<int> sides(static_cast<std::size_t>(l.nc));
      bool known = true;
      for (int j = 0; j < l.nc; ++j) {
        if (std::abs(c[j]) > active_tol) {
          sides[static_cast<std::size_t>(j)] = c[j] > 0 ? 1 : -1;
        } else if (!previous_sides.empty()) {
          sides[static_cast<std::size_t>(j)] = previous_sides[static_cast<std::size_t>(j)];
        } else {
          known = false;
        }
      }
      Eigen::VectorXd w = nlp->solution();
      int newton_iterations = 0;
      if (known && newton_step(*nlp, l, sides, length, w, &newton_iterations)) {
        nlp->set_solution(w);
        solved_by_newton = true;
        ++result.newton_steps;
      } else if (known && w.allFinite()) {
        // A switch inside the step: the no-switch solution still follows the trajectory up to
        // it, a better start for the homotopy than the held state.
        for (int n = 0; n < l.elements; ++n) {
          w[l.var(n, 0)] = length / l.elements;
          for (int i = 0; i < l.points * l.nc; ++i) {
            double& a = w[l.var(n, l.off_a + i)];
            a = std::clamp(a, 0.0, 1.0);
            w[l.var(n, l.off_p + i)] = std::max(w[l.var(n, l.off_p + i)], 0.0);
            w[l.var(n, l.off_q + i)] = std::max(w[l.var(n, l.off_q + i)], 0.0);
          }
        }
        nlp->set_solution(w);
      }
    }
    while (!solved_by_newton) {
      nlp->set_sigma(sigma);
      // Intermediate problems only need to be solved to the accuracy sigma allows.
      const double tol = sigma <= options.sigma_final
                             ? options.nlp_tolerance
                             : std::max(options.nlp_tolerance, 1e-2 * sigma);
      app->Options()->SetNumericValue("tol", tol);
      // The objective (step equilibration) only selects among the FESD solutions; when IPOPT
      // crawls along its flat directions (lengths inside a sliding arc), a point that satisfies
      // the constraints to the tolerance is the answer.
      app->Options()->SetNumericValue("acceptable_tol", 1e-4);
      app->Options()->SetNumericValue("acceptable_constr_viol_tol", std::max(tol, 1e-12));
      app->Options()->SetNumericValue("acceptable_compl_inf_tol", 1e-4);
      app->Options()->SetIntegerValue("acceptable_iter", 5);
      app->Options()->SetStringValue("warm_start_init_point", first ? "no" : "yes");
      if (!first) {
        app->Options()->SetNumericValue("mu_init", std::max(1e-12, 1e-2 * sigma));
        app->Options()->SetNumericValue("warm_start_bound_push", 1e-9);
        app->Options()->SetNumericValue("warm_start_mult_bound_push", 1e-9);
        app->Options()->SetNumericValue("warm_start_slack_bound_push", 1e-9);
      } else {
        app->Options()->SetNumericValue("mu_init", 0.1);
      }
      const Ipopt::ApplicationReturnStatus status = app->OptimizeTNLP(nlp);
      if (Ipopt::IsValid(app->Statistics())) iterations += app->Statistics()->IterationCount();
      const bool solved =
          status == Ipopt::Solve_Succeeded || status == Ipopt::Solved_To_Acceptable_Level;
      if (!solved && !first && retries < 6) {
        // Too large a step in sigma: back to the last solution, half the step (in log sigma).
        ++retries;
        nlp->restore();
        sigma = std::sqrt(sigma * last_sigma);
        continue;
      }
      if (!solved && halvings < kMaxHalvings) {
        pending.push_front({length / 2, halvings + 1});
        pending.push_front({length / 2, halvings + 1});
        ++result.halved_steps;
        break;
      }
      if (!solved) {
        result.status = FesdStatus::kStepFailed;
        result.message = "fesd: the integration step at t = " + format_number(t0) + " of length " +
                         format_number(length) + " (halved " + std::to_string(halvings) +
                         " times) did not converge at sigma = " + format_number(sigma) +
                         ": IPOPT status " + std::to_string(static_cast<int>(status)) +
                         ", complementarity residual " +
                         format_number(nlp->complementarity(nlp->solution()));
        result.x_end = x;
        result.nlp_iterations.push_back(iterations);
        return result;
      }
      first = false;
      nlp->save();
      last_sigma = sigma;
      if (sigma <= options.sigma_final) break;
      double next = options.sigma_factor * sigma;
      if (options.superlinear) next = std::min(next, std::pow(sigma, 1.5));
      sigma = std::max(next, options.sigma_final);
    }
    if (!solved_by_newton && last_sigma > options.sigma_final) continue;  // halved
    const Eigen::VectorXd& w = nlp->solution();
    result.nlp_iterations.push_back(iterations);
    result.max_complementarity = std::max(result.max_complementarity, nlp->complementarity(w));
    double t = t0;
    for (int n = 0; n < l.elements; ++n) {
      const double h = w[l.var(n, 0)];
      t += h;
      result.step_sizes.push_back(h);
      result.grid.push_back(n + 1 == l.elements ? t0 + length : t);
      states.push_back(w.segment(l.var(n, l.off_x), l.d));
      std::vector<int> sides(static_cast<std::size_t>(l.nc));
      for (int j = 0; j < l.nc; ++j)
        sides[static_cast<std::size_t>(j)] = element_side(l, w, n, j, active_tol);
      if (!previous_sides.empty() && sides != previous_sides) {
        result.switch_times.push_back(result.grid[result.grid.size() - 2]);
      }
      previous_sides = sides;
      result.active_sets.push_back(std::move(sides));
    }
    if (sensitivities) {
      std::string why;
      const Eigen::MatrixXd s = step_sensitivity(*nlp, l, w, length, active_tol, &why);
      if (s.size() == 0) {
        sensitivities = false;
        result.message =
            "fesd: no sensitivity at the step from t = " + format_number(t0) + ": " + why;
      } else {
        sensitivity = s * sensitivity;
      }
    }
    x = w.segment(l.var(l.elements - 1, l.off_x), l.d);
    t0 += length;
  }
  result.x_end = x;
  result.states.resize(l.d, static_cast<Eigen::Index>(states.size()));
  for (std::size_t k = 0; k < states.size(); ++k)
    result.states.col(static_cast<Eigen::Index>(k)) = states[k];
  if (sensitivities) result.sensitivity = sensitivity;
  return result;
}

}  // namespace bflow

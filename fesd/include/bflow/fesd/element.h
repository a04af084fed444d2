// One FESD finite element, written once for simulation (fesd_simulate, one integration step per
// NLP) and optimal control (ocp_solve, all control stages in one NLP): its unknowns, its
// equations ([F] (33), (36)-(43)), the step equilibration between two elements ((39)) and the
// assembly of exact second derivatives by pieces (hessian_blocks.h).
//
// An element's own unknowns ("block"):
//   [h | X_1..X_s (s d) | z_1..z_P (P nz)]             Radau IIA (the default)
//   [h | X_1..X_s (s d) | x_{n+1} (d) | z_1..z_P (P nz)]  Gauss-Legendre, or Radau IIA asked to
//                                                         keep the end apart (shared_end false)
// with z a point's algebraic variables (dcs.h) and P = s points (Radau IIA: c_s = 1 and b is A's
// last row, so the last stage value is the element's end x_{n+1} and its collocation rows are the
// end rows; the end is then that stage, with no unknowns or rows of its own, as nosnoc lays the
// element out) or s + 1 (Gauss-Legendre: the stages and the end point of (42)). Its
// "local" vector puts what it reads from elsewhere in front:
//   [x_n (d) | v of every pair at the start (npairs) | u (nu) | T (1 if time-scaled) | block]
// u is the control of the element's stage (the model then sees the point [X; u]); with time
// scaling the element's physical length is T h.
#ifndef BFLOW_FESD_ELEMENT_H_
#define BFLOW_FESD_ELEMENT_H_

#include <algorithm>
#include <cstdint>
#include <map>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "bflow/core/errors.h"
#include "bflow/fesd/butcher.h"
#include "bflow/fesd/dcs.h"
#include "bflow/fesd/fesd.h"
#include "bflow/fesd/hessian_blocks.h"

namespace bflow {
namespace fesd {

struct ElementShape {
  const PointDcs* dcs = nullptr;
  int d = 0, nc = 0, s = 0, points = 0;
  int nu = 0;           // controls read by the element (0 in simulation)
  bool scaled = false;  // a time-scaling variable T multiplies h
  int nz = 0, neq = 0, npairs = 0;
  bool end_point = false;  // Gauss-Legendre: an extra point at the element's end
  /** Radau IIA: x_{n+1} is the last stage value X_s (no end unknowns, no end rows). */
  bool shared_end = false;
  int off_x = 0, off_z = 0, block = 0;
  int dynamics = 0;    // collocation (and end) rows per element: the first rows
  int equalities = 0;  // per element
  int params = 0;      // nu + (scaled ? 1 : 0)
  int local = 0;
  /** The rows of the cross complementarity (fesd.h); set before the rows are counted. */
  CrossComplementarity cross = CrossComplementarity::kElementSums;
  /** The collocation rows' weights in the form the layout writes them (butcher.h). */
  CollocationRows rows;

  /** end_apart keeps a Radau IIA element's end as unknowns of its own (d more unknowns and d
      more rows per element, the same solutions); Gauss-Legendre always has them. */
  ElementShape(const PointDcs& point, int states, int switches, const ButcherTableau& tableau,
               int controls = 0, bool time_scaled = false, bool end_apart = false,
               CollocationForm form = CollocationForm::kIntegral)
      : dcs(&point),
        d(states),
        nc(switches),
        s(tableau.stages),
        nu(controls),
        scaled(time_scaled),
        rows(collocation_rows(tableau, form)) {
    nz = point.size();
    neq = point.equations();
    npairs = static_cast<int>(point.pairs().size());
    end_point = !tableau.stiffly_accurate();
    shared_end = !end_point && !end_apart;
    points = s + (end_point ? 1 : 0);
    off_x = shared_end ? 1 + (s - 1) * d : 1 + s * d;
    off_z = 1 + s * d + (shared_end ? 0 : d);
    block = off_z + points * nz;
    dynamics = s * d + (shared_end ? 0 : d);
    equalities = dynamics + points * neq;
    params = nu + (scaled ? 1 : 0);
    local = d + npairs + params + block;
  }
  /** Complementarity rows per pair: 1, P (P + 1) point pairs or P point sums. */
  int comp_per_pair() const {
    if (cross == CrossComplementarity::kPointSums) return points;
    return cross == CrossComplementarity::kPointPairs ? points * (points + 1) : 1;
  }
  int comp_rows() const { return npairs * comp_per_pair(); }
  int rows_per_element() const { return equalities + comp_rows(); }
  // Offset in the local vector of the element's own block.
  int own() const { return d + npairs + params; }
};

// The complementarity rows of one element (l.comp_rows() values) from the v of every pair at
// its start and the z of its points. kPointPairs: pair k's rows are u_r v_m, row
// k P (P + 1) + m P + r for point r of u and m of v (m = 0 the start, m = 1..P the points).
// kPointSums: pair k's row k P + r is u_r (v_start + sum_m v_m).
template <typename T>
void complementarity_rows(const ElementShape& l, bool standard, const T* v0, const T* z, T* comp) {
  const PointDcs& dcs = *l.dcs;
  const int nz = l.nz, P = l.points;
  for (int k = 0; k < l.npairs; ++k) {
    const Pair& pair = dcs.pairs()[static_cast<std::size_t>(k)];
    if (!standard && l.cross == CrossComplementarity::kPointPairs) {
      T* row = comp + k * P * (P + 1);
      for (int m = 0; m <= P; ++m) {
        const T v = m == 0 ? v0[k] : z[(m - 1) * nz + pair.v];
        for (int r = 0; r < P; ++r) row[m * P + r] = PointDcs::member_u(pair, z + r * nz) * v;
      }
      continue;
    }
    if (!standard && l.cross == CrossComplementarity::kPointSums) {
      T sum_v = v0[k];
      for (int m = 0; m < P; ++m) sum_v += z[m * nz + pair.v];
      for (int r = 0; r < P; ++r) comp[k * P + r] = PointDcs::member_u(pair, z + r * nz) * sum_v;
      continue;
    }
    if (standard) {
      // (34): each point's own pair only.
      T sum(0.0);
      for (int m = 0; m < l.points; ++m) {
        sum += PointDcs::member_u(pair, z + m * nz) * z[m * nz + pair.v];
      }
      comp[k] = sum;
    } else {
      // (35) and (37) summed over all pairs of points of the element, the start included:
      // sum_m sum_m' u_m v_m' = (sum_m u_m)(sum_m' v_m').
      T sum_u(0.0), sum_v = v0[k];
      for (int m = 0; m < l.points; ++m) {
        sum_u += PointDcs::member_u(pair, z + m * nz);
        sum_v += z[m * nz + pair.v];
      }
      comp[k] = sum_u * sum_v;
    }
  }
}

// Equalities and aggregated complementarity products of one element from its local vector.
template <typename T>
void element_residual(const ElementShape& l, bool standard, const T* in, T* out) {
  const PointDcs& dcs = *l.dcs;
  const int d = l.d, s = l.s, nz = l.nz, nu = l.nu;
  const T* xn = in;
  const T* v0 = in + d;
  const T* u = in + d + l.npairs;
  const T* blk = in + l.own();
  const T h = l.scaled ? blk[0] * u[nu] : blk[0];
  const T* stage = blk + 1;
  const T* xnext = blk + l.off_x;
  const T* z = blk + l.off_z;
  // Scratch kept per thread and scalar type: this runs for every Jacobian chunk and every IPOPT
  // evaluation, so it allocates only when the sizes grow.
  thread_local std::vector<T> f, point, rate;
  f.resize(static_cast<std::size_t>(s * d));
  // The model sees [x; u] at a point (d + nu values; its rates of u are ignored).
  const auto at = [&](const T* x) -> const T* {
    if (nu == 0) return x;
    point.resize(static_cast<std::size_t>(d + nu));
    std::copy(x, x + d, point.begin());
    std::copy(u, u + nu, point.begin() + d);
    return point.data();
  };
  for (int m = 0; m < s; ++m) {
    if (nu == 0) {
      dcs.field(stage + m * d, z + m * nz, f.data() + m * d);
    } else {
      rate.resize(static_cast<std::size_t>(d + nu));
      dcs.field(at(stage + m * d), z + m * nz, rate.data());
      std::copy(rate.begin(), rate.begin() + d, f.begin() + m * d);
    }
  }
  // Collocation row (m, i) and end row i (apart) with the weights of l.rows (butcher.h),
  // leaving out the weights that are exactly 0:
  //   start(m) x_n,i + sum_k state(m, k) X_k,i - h sum_k rate(m, k) f_i(X_k),
  //   (x_{n+1},i - (end_start x_n,i + sum_k end_state(k) X_k,i)) - h sum_k end_rate(k) f_i(X_k).
  const CollocationRows& w = l.rows;
  const auto rates = [&](int i, const auto& weight) {
    T sum(0.0);
    for (int k = 0; k < s; ++k) {
      if (weight(k) != 0.0) sum += weight(k) * f[static_cast<std::size_t>(k * d + i)];
    }
    return sum;
  };
  T* eq = out;
  for (int m = 0; m < s; ++m) {
    for (int i = 0; i < d; ++i) {
      T sum = w.start(m) * xn[i];
      for (int k = 0; k < s; ++k) {
        if (w.state(m, k) != 0.0) sum += w.state(m, k) * stage[k * d + i];
      }
      eq[m * d + i] = sum - h * rates(i, [&](int k) { return w.rate(m, k); });
    }
  }
  for (int i = 0; !l.shared_end && i < d; ++i) {
    T sum = w.end_start * xn[i];
    for (int k = 0; k < s; ++k) {
      if (w.end_state(k) != 0.0) sum += w.end_state(k) * stage[k * d + i];
    }
    eq[s * d + i] = (xnext[i] - sum) - h * rates(i, [&](int k) { return w.end_rate(k); });
  }
  T* alg = eq + l.dynamics;
  for (int m = 0; m < l.points; ++m) {
    dcs.algebraic(at(m < s ? stage + m * d : xnext), z + m * nz, alg + m * l.neq);
  }
  complementarity_rows(l, standard, v0, z, eq + l.equalities);
}

// The second derivatives of complementarity_rows: every row is a sum of products of an affine
// member u (z_u, or 1 - z_u for a flipped pair) and a v (at the start, v0, or at a point), so its
// Hessian is the constant +1 or -1 (the sign of z_u in u) at each pair of a u and a v it
// multiplies, and no AD is needed. For the complementarity piece's locals [v0 (npairs), z_1 ..
// z_P (P nz)] (element_hessian_pieces) it lists every such pair with the row and the sign; a pair
// of locals appears once per row that multiplies it.
struct ComplementarityHessian {
  std::vector<std::pair<int, int>> pairs;  // (u, v) local indices in the piece
  std::vector<int> rows;                   // the row of complementarity_rows
  std::vector<double> signs;
};

inline void complementarity_hessian(const ElementShape& l, bool standard,
                                    ComplementarityHessian& out) {
  out.pairs.clear();
  out.rows.clear();
  out.signs.clear();
  const PointDcs& dcs = *l.dcs;
  const int nz = l.nz, P = l.points, z0 = l.npairs;
  const auto add = [&](int u, int v, int row, const Pair& pair) {
    out.pairs.emplace_back(u, v);
    out.rows.push_back(row);
    out.signs.push_back((pair.flipped ? -1.0 : 1.0) * (u == v ? 2.0 : 1.0));  // z^2: 2
  };
  for (int k = 0; k < l.npairs; ++k) {
    const Pair& pair = dcs.pairs()[static_cast<std::size_t>(k)];
    const auto u_at = [&](int r) { return z0 + r * nz + pair.u; };
    const auto v_at = [&](int m) { return m == 0 ? k : z0 + (m - 1) * nz + pair.v; };  // m = 0: v0
    if (!standard && l.cross == CrossComplementarity::kPointPairs) {
      for (int m = 0; m <= P; ++m) {
        for (int r = 0; r < P; ++r) add(u_at(r), v_at(m), k * P * (P + 1) + m * P + r, pair);
      }
    } else if (!standard && l.cross == CrossComplementarity::kPointSums) {
      for (int r = 0; r < P; ++r) {
        for (int m = 0; m <= P; ++m) add(u_at(r), v_at(m), k * P + r, pair);
      }
    } else if (standard) {
      for (int m = 0; m < P; ++m) add(u_at(m), v_at(m + 1), k, pair);
    } else {
      for (int r = 0; r < P; ++r) {
        for (int m = 0; m <= P; ++m) add(u_at(r), v_at(m), k, pair);
      }
    }
  }
}

// The local inputs each row of element_residual reads, by construction (whatever the model):
//   collocation and end rows, integral form: by blocks, x_n, the parameters (u, T), h, the stage
//     values X, x_{n+1} and the entries of z the field reads at the stage points (the structure
//     the integral form's homotopy paths were measured on);
//   collocation and end rows, derivative form: exactly what each reads, x_n's entry i (a nonzero
//     start weight), the parameters and h (a nonzero rate weight), all of X_k and the entries of
//     z_k the field reads where rate(m, k) is nonzero, X_k's entry i where only state(m, k) is,
//     and x_{n+1}'s entry i in the end row i (for Radau IIA apart, x_{n+1},i and X_s,i alone);
//   algebraic rows of point m: X_m (x_{n+1} at Gauss-Legendre's end point), u and z_m;
//   complementarity rows: their pairs' members (u and v at the points, v at the start).
// Everything else in a row's Jacobian is exactly zero, so a sparse Jacobian lists only these.
// Each row's inputs are increasing.
inline std::vector<std::vector<int>> element_jacobian_pattern(const ElementShape& l,
                                                              bool standard) {
  const int d = l.d, s = l.s, own = l.own(), u0 = d + l.npairs;
  const auto range = [](std::vector<int>& v, int first, int count) {
    for (int k = 0; k < count; ++k) v.push_back(first + k);
  };
  std::vector<std::vector<int>> rows(static_cast<std::size_t>(l.rows_per_element()));
  const CollocationRows& w = l.rows;
  if (w.form == CollocationForm::kIntegral) {
    std::vector<int> dynamics;
    range(dynamics, 0, d);
    range(dynamics, u0, l.params);
    range(dynamics, own, l.off_z);  // h, X, x_{n+1} (when apart)
    for (int m = 0; m < s; ++m) {
      range(dynamics, own + l.off_z + m * l.nz + l.dcs->field_first(), l.dcs->field_count());
    }
    for (int r = 0; r < l.dynamics; ++r) rows[static_cast<std::size_t>(r)] = dynamics;
  } else {
    // Row i of a block whose x_n weight is `start`, X_k weights state(k), rate weights rate(k).
    const auto dynamics_row = [&](std::vector<int>& row, int i, double start, const auto& state,
                                  const auto& rate, bool end) {
      bool rates = false;
      for (int k = 0; k < s; ++k) rates = rates || rate(k) != 0.0;
      if (start != 0.0) row.push_back(i);
      if (rates) {
        range(row, u0, l.params);
        row.push_back(own);  // h
      }
      for (int k = 0; k < s; ++k) {
        if (rate(k) != 0.0) {
          range(row, own + 1 + k * d, d);  // the field reads all of X_k
        } else if (state(k) != 0.0) {
          row.push_back(own + 1 + k * d + i);
        }
      }
      if (end) row.push_back(own + l.off_x + i);
      for (int k = 0; k < s; ++k) {
        if (rate(k) != 0.0) {
          range(row, own + l.off_z + k * l.nz + l.dcs->field_first(), l.dcs->field_count());
        }
      }
    };
    for (int m = 0; m < s; ++m) {
      for (int i = 0; i < d; ++i) {
        dynamics_row(
            rows[static_cast<std::size_t>(m * d + i)], i, w.start(m),
            [&](int k) { return w.state(m, k); }, [&](int k) { return w.rate(m, k); }, false);
      }
    }
    for (int i = 0; !l.shared_end && i < d; ++i) {
      dynamics_row(
          rows[static_cast<std::size_t>(s * d + i)], i, w.end_start,
          [&](int k) { return w.end_state(k); }, [&](int k) { return w.end_rate(k); }, true);
    }
  }
  for (int m = 0; m < l.points; ++m) {
    std::vector<int> alg;
    range(alg, m < l.s ? own + 1 + m * d : own + l.off_x, d);
    range(alg, u0, l.nu);
    range(alg, own + l.off_z + m * l.nz, l.nz);
    for (int r = 0; r < l.neq; ++r) {
      rows[static_cast<std::size_t>(l.dynamics + m * l.neq + r)] = alg;
    }
  }
  if (!standard && l.cross == CrossComplementarity::kPointPairs) {
    // Each row reads one v (at the start or a point) and one u.
    const int P = l.points, z0 = own + l.off_z;
    for (int k = 0; k < l.npairs; ++k) {
      const Pair& pair = l.dcs->pairs()[static_cast<std::size_t>(k)];
      for (int m = 0; m <= P; ++m) {
        const int v = m == 0 ? d + k : z0 + (m - 1) * l.nz + pair.v;
        for (int r = 0; r < P; ++r) {
          rows[static_cast<std::size_t>(l.equalities + k * P * (P + 1) + m * P + r)] = {
              std::min(v, z0 + r * l.nz + pair.u), std::max(v, z0 + r * l.nz + pair.u)};
        }
      }
    }
    return rows;
  }
  if (!standard && l.cross == CrossComplementarity::kPointSums) {
    // Row k P + r reads every v of pair k (the start and the points) and u at point r.
    const int P = l.points, z0 = own + l.off_z;
    for (int k = 0; k < l.npairs; ++k) {
      const Pair& pair = l.dcs->pairs()[static_cast<std::size_t>(k)];
      for (int r = 0; r < P; ++r) {
        std::vector<int> row = {d + k, z0 + r * l.nz + pair.u};
        for (int m = 0; m < P; ++m) row.push_back(z0 + m * l.nz + pair.v);
        std::sort(row.begin(), row.end());
        row.erase(std::unique(row.begin(), row.end()), row.end());
        rows[static_cast<std::size_t>(l.equalities + k * P + r)] = std::move(row);
      }
    }
    return rows;
  }
  // One row per pair: pair k's u and v at every point, and its v at the start (not read by the
  // standard rows, whose products are each point's own).
  const int z0 = own + l.off_z;
  for (int k = 0; k < l.npairs; ++k) {
    const Pair& pair = l.dcs->pairs()[static_cast<std::size_t>(k)];
    std::vector<int> row;
    if (!standard) row.push_back(d + k);
    for (int m = 0; m < l.points; ++m) {
      row.push_back(z0 + m * l.nz + std::min(pair.u, pair.v));
      row.push_back(z0 + m * l.nz + std::max(pair.u, pair.v));
    }
    rows[static_cast<std::size_t>(l.equalities + k)] = std::move(row);
  }
  return rows;
}

// The element's Lagrangian sum_r lambda_r residual_r is linear in everything but a few small
// pieces, and its second derivatives are theirs:
//   field piece k (stage point k < s):  -h sum_i w_ki f_i([X_k; u], z_k),
//        w_ki = sum_m lambda_(m,i) rate(m, k) + lambda_(end,i) end_rate(k) (butcher.h: in the
//        integral form A's column k and b_k, in the derivative form lambda_(k,i) alone),
//        over [X_k, u, the entries of z_k the field reads, h, T (time-scaled)];
//   algebraic piece m (point m < P):     lambda_alg(m) . algebraic([X_m or x_{n+1}; u], z_m),
//        over [X_m or x_{n+1}, u, z_m];
//   complementarity piece:               lambda_comp . comp(v0, z), over [v0, z_1..z_P].
// Each piece's unknowns are listed as local indices (element_hessian_pieces); second derivatives
// then cost a pass over a piece's few unknowns instead of over the whole element.
inline std::vector<std::vector<int>> element_hessian_pieces(const ElementShape& l) {
  std::vector<std::vector<int>> pieces;
  const int own = l.own(), u0 = l.d + l.npairs;
  const auto range = [](std::vector<int>& v, int first, int count) {
    for (int k = 0; k < count; ++k) v.push_back(first + k);
  };
  for (int k = 0; k < l.s; ++k) {
    // h (and T) last: the length is a factor of the piece (add_element_hessian hands them to
    // HessianBlocks::add_scaled, which takes their second derivatives in closed form).
    std::vector<int> v;
    range(v, own + 1 + k * l.d, l.d);
    range(v, u0, l.nu);
    range(v, own + l.off_z + k * l.nz + l.dcs->field_first(), l.dcs->field_count());
    v.push_back(own);  // h
    if (l.scaled) v.push_back(u0 + l.nu);
    pieces.push_back(std::move(v));
  }
  for (int m = 0; m < l.points; ++m) {
    std::vector<int> v;
    range(v, m < l.s ? own + 1 + m * l.d : own + l.off_x, l.d);
    range(v, u0, l.nu);
    range(v, own + l.off_z + m * l.nz, l.nz);
    pieces.push_back(std::move(v));
  }
  std::vector<int> comp;
  range(comp, l.d, l.npairs);
  range(comp, own + l.off_z, l.points * l.nz);
  pieces.push_back(std::move(comp));
  return pieces;
}

// A cost at an element's stage points, sum_k weight_k h L(X_k, u) (h the element's length, times
// T when time-scaled): add_element_hessian adds its second derivatives in the passes of the field
// pieces, which have the same factor and inputs, instead of in passes of its own.
class StageCostTerm {
 public:
  virtual ~StageCostTerm() = default;
  virtual JetChunk value(const JetChunk* x, const JetChunk* u) const = 0;
  virtual HessianScalar value(const HessianScalar* x, const HessianScalar* u) const = 0;
};

// Adds the Hessian of the element's Lagrangian sum_r lambda[r] residual_r at its local values
// `local` (globals: the unknown of each local entry, -1 for a constant) to `values`, and with
// `cost` that of the stage cost sum_k cost_weights[k] h L(X_k, u). `pieces` and `comp` are the
// element's element_hessian_pieces and complementarity_hessian, found once.
//
// One pass per stage point k covers field piece k, the cost at X_k and, where z enters them
// linearly (step, Stewart), the algebraic rows of point k, all functions of [X_k, u, z_k]; the
// algebraic rows of the other points (Gauss-Legendre's end) and of the lifted formulation have
// passes of their own.
template <typename Blocks>
void add_element_hessian(const ElementShape& l, const std::vector<std::vector<int>>& pieces,
                         const ComplementarityHessian& comp, const std::vector<int>& globals,
                         const std::vector<double>& local, const double* lambda, Blocks& hessian,
                         double* values, const StageCostTerm* cost = nullptr,
                         const double* cost_weights = nullptr) {
  const PointDcs& dcs = *l.dcs;
  const int d = l.d, nu = l.nu, nz = l.nz, own = l.own();
  // Scratch kept per thread: this runs for every element of every Hessian evaluation.
  thread_local std::vector<int> piece_globals;
  thread_local std::vector<double> piece_base, weights, piece_weights;
  const auto gather = [&](const std::vector<int>& piece) {
    piece_globals.resize(piece.size());
    piece_base.resize(piece.size());
    for (std::size_t k = 0; k < piece.size(); ++k) {
      piece_globals[k] = globals[static_cast<std::size_t>(piece[k])];
      piece_base[k] = local[static_cast<std::size_t>(piece[k])];
    }
  };
  const CollocationRows& cr = l.rows;
  const double* alg = lambda + l.dynamics;
  // The step and Stewart equalities are the model's switching functions of [x; u] plus terms
  // linear in z (dcs.h): z enters them as constants, which leaves their (exactly zero)
  // second derivatives out of the AD. The lifted products of z are not linear.
  const bool linear_in_z = dcs.kind() != PointDcs::Kind::kLifted;
  const int merged = linear_in_z ? std::min(l.s, l.points) : 0;  // points whose rows join
  weights.resize(static_cast<std::size_t>(d));
  for (int k = 0; k < l.s; ++k) {
    // w_ki = lambda_(end,i) end_rate(k) + sum_m lambda_(m,i) rate(m, k), the weights exactly 0
    // left out (the derivative form: lambda_(k,i)).
    for (int i = 0; i < d; ++i) {
      double sum =
          l.shared_end || cr.end_rate(k) == 0.0 ? 0.0 : cr.end_rate(k) * lambda[l.s * d + i];
      for (int m = 0; m < l.s; ++m) {
        if (cr.rate(m, k) != 0.0) sum += lambda[m * d + i] * cr.rate(m, k);
      }
      weights[static_cast<std::size_t>(i)] = sum;
    }
    const int rows = k < merged ? l.neq : 0;
    const int with_cost = cost != nullptr ? 1 : 0;
    // The outputs f_1 ... f_d (weights -w_ki), L (weight c_k) and the algebraic rows: the
    // multipliers are weights, not constants of `eval`, so that eval is a function of its
    // inputs alone (HessianBlocks may run it as a traced program, hessian_tape.h).
    piece_weights.resize(static_cast<std::size_t>(d + with_cost));
    for (int i = 0; i < d; ++i)
      piece_weights[static_cast<std::size_t>(i)] = -weights[static_cast<std::size_t>(i)];
    if (with_cost > 0) piece_weights[static_cast<std::size_t>(d)] = cost_weights[k];
    piece_weights.insert(piece_weights.end(), alg + k * l.neq, alg + k * l.neq + rows);
    const double* zk = local.data() + own + l.off_z + k * nz;
    const int nf = dcs.field_count(), zf = dcs.field_first();
    gather(pieces[static_cast<std::size_t>(k)]);
    // The point's other z entries (read by the algebraic rows, where z enters linearly) as
    // constant inputs before the factors: no lanes, but inputs of eval.
    const std::size_t factors = l.scaled ? 2 : 1;
    const auto at = static_cast<std::ptrdiff_t>(piece_globals.size() - factors);
    for (int j = nz - 1; j >= 0; --j) {
      if (j >= zf && j < zf + nf) continue;
      piece_globals.insert(piece_globals.begin() + at, -1);
      piece_base.insert(piece_base.begin() + at, zk[j]);
    }
    // -h sum_i w_ki f_i + c h L: the length (h, or h and T) as add_scaled's factors of the first
    // d + 1 outputs, HessianJet's lanes on [X_k, u, z_k's field entries] alone; the algebraic
    // rows after them.
    hessian.add_scaled(
        piece_globals, piece_base, static_cast<int>(factors), d + with_cost + rows,
        piece_weights.data(),
        [&](const auto* in, auto* out) {
          using T = std::remove_const_t<std::remove_pointer_t<decltype(in)>>;
          thread_local std::vector<T> rate, z;
          rate.resize(static_cast<std::size_t>(d + nu));  // an OCP's u has rates (zero) too
          // The model sees [X_k; u] (contiguous here) and the point's z: the entries the field
          // reads from the lanes, the others from the constant inputs after them.
          z.resize(static_cast<std::size_t>(nz));
          const T* other = in + d + nu + nf;
          for (int j = 0; j < nz; ++j) {
            z[static_cast<std::size_t>(j)] =
                j >= zf && j < zf + nf ? in[d + nu + j - zf] : other[j < zf ? j : j - nf];
          }
          dcs.field(in, z.data(), rate.data());
          for (int i = 0; i < d; ++i) out[i] = rate[static_cast<std::size_t>(i)];
          if (with_cost > 0) out[d] = cost->value(in, in + d);
          if (rows > 0) dcs.algebraic(in, z.data(), out + d + with_cost);
        },
        values, d + with_cost);
  }
  for (int m = merged; m < l.points; ++m) {
    gather(pieces[static_cast<std::size_t>(l.s + m)]);
    if (linear_in_z) std::fill(piece_globals.begin() + d + nu, piece_globals.end(), -1);
    hessian.add(
        piece_globals, piece_base, l.neq, alg + m * l.neq,
        [&](const auto* in, auto* out) { dcs.algebraic(in, in + d + nu, out); }, values);
  }
  // The complementarity rows' second derivatives are constants (complementarity_hessian).
  gather(pieces.back());
  thread_local std::vector<double> terms;
  terms.resize(comp.rows.size());
  const double* comp_lambda = lambda + l.equalities;
  for (std::size_t t = 0; t < terms.size(); ++t) {
    terms[t] = comp.signs[t] * comp_lambda[comp.rows[t]];
  }
  hessian.add_constant(piece_globals, comp.pairs, terms, values);
}

// Step equilibration between elements n - 1 and n ((39) with the indicator of Section 4.4):
// inputs [h_{n-1}, h_n, v of every pair at the start of n - 1 (npairs), z of n - 1 (P nz),
// z of n (P nz)].
template <typename T>
T equilibration_term(const ElementShape& l, double h_ref, const T* in) {
  const PointDcs& dcs = *l.dcs;
  const int nz = l.nz, pts = l.points;
  const T* v0 = in + 2;
  const T* back = v0 + l.npairs;
  const T* fwd = back + pts * nz;
  const T* back_last = back + (pts - 1) * nz;
  const bool stewart = dcs.kind() == PointDcs::Kind::kStewart;
  // nu per group: products of backward and forward sums of the v members (for Stewart also the
  // u members, theta); zero exactly where the group's active set changes.
  thread_local std::vector<T> nu;
  nu.assign(static_cast<std::size_t>(dcs.groups()), T(0.0));
  for (int k = 0; k < l.npairs; ++k) {
    const Pair& pair = dcs.pairs()[static_cast<std::size_t>(k)];
    T bv = v0[k], fv = back_last[pair.v];  // the forward element starts where the back one ends
    T bu(0.0), fu(0.0);
    for (int m = 0; m < pts; ++m) {
      bv += back[m * nz + pair.v];
      fv += fwd[m * nz + pair.v];
      if (stewart) {
        bu += back[m * nz + pair.u];
        fu += fwd[m * nz + pair.u];
      }
    }
    nu[static_cast<std::size_t>(pair.group)] += bv * fv + bu * fu;
  }
  T eta(1.0);
  for (const T& value : nu) eta *= value / (value + 1e-6);
  const T dh = (in[1] - in[0]) / h_ref;
  T value = (eta + 1e-3) * dh * dh;
  // Leaving a sliding arc (step formulation): the selection is continuous where a trajectory
  // leaves the surface (it reaches its bound exactly there), so a jump of a_j after an element
  // that slides on c_j is penalised. This picks the exact leaving time among the boundaries the
  // collocation conditions allow (they admit any within O(h) of it), and keeps a trajectory on
  // the surface when leaving is optional (the spontaneous case). Stewart's homotopy goes without
  // it: a penalty on the jumps of theta, weighted by the number of active modes, made IPOPT
  // fail at every switch; the Newton path imposes the continuity exactly in both formulations.
  if (stewart) return value;
  for (int j = 0; j < l.nc; ++j) {
    const Pair& q = dcs.pairs()[static_cast<std::size_t>(j)];
    const Pair& p = dcs.pairs()[static_cast<std::size_t>(l.nc + j)];
    T lambda(0.0);
    for (int m = 0; m < pts; ++m) lambda += back[m * nz + p.v] + back[m * nz + q.v];
    const T sliding = 1e-6 / (1e-6 + lambda);
    const T jump = fwd[q.u] - back_last[q.u];
    value += 1e3 * sliding * jump * jump;
  }
  return value;
}

// Adds weight * the gradient of f(in) over the unknowns `globals` (-1 for a constant) into grad,
// f evaluated at `base` by `eval` (JetChunk in, JetChunk out), kTangentChunk directions at once.
template <typename Eval>
void add_gradient(const std::vector<int>& globals, const std::vector<double>& base, double weight,
                  Eval eval, double* grad) {
  const int size = static_cast<int>(globals.size());
  thread_local std::vector<JetChunk> in;
  in.resize(globals.size());
  for (int first = 0; first < size; first += kTangentChunk) {
    for (int k = 0; k < size; ++k)
      in[static_cast<std::size_t>(k)] = JetChunk(base[static_cast<std::size_t>(k)]);
    const int width = std::min(kTangentChunk, size - first);
    for (int c = 0; c < width; ++c) in[static_cast<std::size_t>(first + c)].v[c] = 1.0;
    const JetChunk value = eval(in.data());
    for (int c = 0; c < width; ++c) {
      const int g = globals[static_cast<std::size_t>(first + c)];
      if (g >= 0) grad[g] += weight * value.v[c];
    }
  }
}

// The dense Jacobian (rows x inputs) of the `rows` outputs of f at `base`, by Jet chunks of
// kTangentChunk directions; `values`, when given, receives f(base).
template <typename F>
void dense_jacobian(const std::vector<double>& base, int rows, Eigen::MatrixXd& jac, F f,
                    Eigen::VectorXd* values = nullptr) {
  const int size = static_cast<int>(base.size());
  jac.resize(rows, size);
  thread_local std::vector<JetChunk> in, out;
  in.resize(base.size());
  out.resize(static_cast<std::size_t>(rows));
  for (int first = 0; first < size; first += kTangentChunk) {
    for (int k = 0; k < size; ++k)
      in[static_cast<std::size_t>(k)] = JetChunk(base[static_cast<std::size_t>(k)]);
    const int width = std::min(kTangentChunk, size - first);
    for (int c = 0; c < width; ++c) in[static_cast<std::size_t>(first + c)].v[c] = 1.0;
    f(in.data(), out.data());
    for (int r = 0; r < rows; ++r) {
      for (int c = 0; c < width; ++c) jac(r, first + c) = out[static_cast<std::size_t>(r)].v[c];
    }
  }
  if (values != nullptr) {
    values->resize(rows);
    for (int r = 0; r < rows; ++r) (*values)[r] = out[static_cast<std::size_t>(r)].a;
  }
}

// The dense Jacobian of element_residual (rows_per_element() x local) at `local`, by its
// pieces: the field at each stage by Jets over [X_k, u, the entries of z_k the field reads],
// the algebraic rows of each point by Jets over [X_m, u, z_m], the rest (x_n, h, T, x_{n+1}, the
// complementarity products of affine members) in closed form. Every entry is the number
// dense_jacobian(element_residual) gives, computed by the same operations in the same order
// (a Jet's directions are independent, so a direction seeded in a narrower pass gets the same
// arithmetic), for the s + P narrow passes of the pieces instead of local / kTangentChunk
// passes over the whole element. `values`, when given, receives the residual.
//
// element_jacobian_into writes through `jac(r, c)` (a double&, = and +=) into any view whose
// entries start at zero: the dense matrix, or IPOPT's value array itself (the transcription's
// JacobianSlots: each entry of the declared pattern at its position, the others checked).
template <typename Matrix>
void element_jacobian_into(const ElementShape& l, bool standard, const std::vector<double>& local,
                           Matrix& jac, Eigen::VectorXd* values = nullptr);
inline void element_jacobian(const ElementShape& l, bool standard, const std::vector<double>& local,
                             Eigen::MatrixXd& jac, Eigen::VectorXd* values = nullptr) {
  jac.setZero(l.rows_per_element(), l.local);
  element_jacobian_into(l, standard, local, jac, values);
}
template <typename Matrix>
void element_jacobian_into(const ElementShape& l, bool standard, const std::vector<double>& local,
                           Matrix& jac, Eigen::VectorXd* values) {
  const PointDcs& dcs = *l.dcs;
  const int d = l.d, s = l.s, nu = l.nu, nz = l.nz, P = l.points;
  const int own = l.own(), u0 = d + l.npairs, zf = dcs.field_first(), nf = dcs.field_count();
  const double* in = local.data();
  const double* xn = in;
  const double* blk = in + own;
  const double hb = blk[0];
  const double T = l.scaled ? in[u0 + nu] : 1.0;
  const double h = l.scaled ? hb * T : hb;
  const double* z = blk + l.off_z;
  const int rows = l.rows_per_element();
  thread_local Eigen::VectorXd out;
  out.resize(rows);
  // f_k and its derivatives by [X_k, u, z_k's field entries] (d x (d + nu + nf)), per stage.
  const int wf = d + nu + nf;
  thread_local std::vector<double> f, df;
  f.resize(static_cast<std::size_t>(s * d));
  df.resize(static_cast<std::size_t>(s * d * wf));
  thread_local std::vector<JetChunk> point, zj, rate, alg;
  point.resize(static_cast<std::size_t>(d + nu));
  zj.resize(static_cast<std::size_t>(nz));
  rate.resize(static_cast<std::size_t>(d + nu));
  alg.resize(static_cast<std::size_t>(std::max(l.neq, 1)));
  const auto load = [&](const double* x, const double* zm) {
    for (int i = 0; i < d; ++i) point[static_cast<std::size_t>(i)] = JetChunk(x[i]);
    for (int j = 0; j < nu; ++j) point[static_cast<std::size_t>(d + j)] = JetChunk(in[u0 + j]);
    for (int k = 0; k < nz; ++k) zj[static_cast<std::size_t>(k)] = JetChunk(zm[k]);
  };
  // The inputs of a piece, in order: the point [x; u] then z from zfirst.
  const auto seed = [&](int count_point, int zfirst, int count_z, auto eval) {
    thread_local std::vector<JetChunk*> lanes;
    lanes.clear();
    for (int i = 0; i < count_point; ++i) lanes.push_back(&point[static_cast<std::size_t>(i)]);
    for (int k = 0; k < count_z; ++k) lanes.push_back(&zj[static_cast<std::size_t>(zfirst + k)]);
    const int count = static_cast<int>(lanes.size());
    for (int chunk = 0; chunk < count; chunk += kTangentChunk) {
      const int width = std::min(kTangentChunk, count - chunk);
      for (int c = 0; c < width; ++c) lanes[static_cast<std::size_t>(chunk + c)]->v[c] = 1.0;
      eval(chunk, width);
      for (int c = 0; c < width; ++c) lanes[static_cast<std::size_t>(chunk + c)]->v[c] = 0.0;
    }
  };
  for (int k = 0; k < s; ++k) {
    load(blk + 1 + k * d, z + k * nz);
    double* dfk = df.data() + static_cast<std::size_t>(k * d * wf);
    seed(d + nu, zf, nf, [&](int chunk, int width) {
      dcs.field(point.data(), zj.data(), rate.data());
      for (int i = 0; i < d; ++i) {
        for (int c = 0; c < width; ++c) {
          dfk[i * wf + chunk + c] = rate[static_cast<std::size_t>(i)].v[c];
        }
      }
    });
    for (int i = 0; i < d; ++i)
      f[static_cast<std::size_t>(k * d + i)] = rate[static_cast<std::size_t>(i)].a;
  }
  // Collocation rows and the end rows when apart, with l.rows' weights, by element_residual's
  // operations in its order (the weights exactly 0 left out).
  const CollocationRows& w = l.rows;
  // Row r (entry i of its block) less h sum_k weight(k) f_i(X_k): its rate terms' derivatives.
  const auto rate_terms = [&](int r, int i, const auto& weight) {
    double sum = 0.0;
    bool any = false;
    for (int k = 0; k < s; ++k) {
      if (weight(k) == 0.0) continue;
      any = true;
      sum += weight(k) * f[static_cast<std::size_t>(k * d + i)];
    }
    if (!any) return 0.0;
    jac(r, own) = -((l.scaled ? T : 1.0) * sum);
    if (l.scaled) jac(r, u0 + nu) = -(hb * sum);
    for (int k = 0; k < s; ++k) {
      const double wk = weight(k);
      if (wk == 0.0) continue;
      const double* dfk = df.data() + static_cast<std::size_t>(k * d * wf + i * wf);
      for (int j = 0; j < d; ++j) jac(r, own + 1 + k * d + j) -= h * (dfk[j] * wk);
      for (int q = 0; q < nf; ++q)
        jac(r, own + l.off_z + k * nz + zf + q) = -(h * (dfk[d + nu + q] * wk));
    }
    for (int j = 0; j < nu; ++j) {
      double sum_u = 0.0;
      for (int k = 0; k < s; ++k) {
        if (weight(k) != 0.0) {
          sum_u += df[static_cast<std::size_t>(k * d * wf + i * wf + d + j)] * weight(k);
        }
      }
      jac(r, u0 + j) = -(h * sum_u);
    }
    return h * sum;
  };
  for (int m = 0; m < s; ++m) {
    for (int i = 0; i < d; ++i) {
      const int r = m * d + i;
      double sum = w.start(m) * xn[i];
      jac(r, i) = w.start(m);
      for (int k = 0; k < s; ++k) {
        if (w.state(m, k) == 0.0) continue;
        sum += w.state(m, k) * blk[1 + k * d + i];
        jac(r, own + 1 + k * d + i) += w.state(m, k);
      }
      out[r] = sum - rate_terms(r, i, [&](int k) { return w.rate(m, k); });
    }
  }
  for (int i = 0; !l.shared_end && i < d; ++i) {
    const int r = s * d + i;
    double sum = w.end_start * xn[i];
    jac(r, i) = -w.end_start;
    for (int k = 0; k < s; ++k) {
      if (w.end_state(k) == 0.0) continue;
      sum += w.end_state(k) * blk[1 + k * d + i];
      jac(r, own + 1 + k * d + i) -= w.end_state(k);
    }
    jac(r, own + l.off_x + i) += 1.0;
    out[r] = (blk[l.off_x + i] - sum) - rate_terms(r, i, [&](int k) { return w.end_rate(k); });
  }
  // Algebraic rows of each point: Jets over [X_m (x_{n+1} at Gauss-Legendre's end), u, z_m].
  for (int m = 0; m < P; ++m) {
    const int at = m < s ? 1 + m * d : l.off_x;
    load(blk + at, z + m * nz);
    const int row = l.dynamics + m * l.neq;
    seed(d + nu, 0, nz, [&](int chunk, int width) {
      dcs.algebraic(point.data(), zj.data(), alg.data());
      for (int c = 0; c < width; ++c) {
        const int lane = chunk + c;
        const int col = lane < d        ? own + at + lane
                        : lane < d + nu ? u0 + lane - d
                                        : own + l.off_z + m * nz + lane - d - nu;
        for (int e = 0; e < l.neq; ++e) jac(row + e, col) = alg[static_cast<std::size_t>(e)].v[c];
      }
    });
    for (int e = 0; e < l.neq; ++e) out[row + e] = alg[static_cast<std::size_t>(e)].a;
  }
  // Complementarity rows: products U V of an affine member U (z_u or 1 - z_u) and a V (one v or
  // a sum of them), so d(UV) = sign V at u's column and U at each of V's.
  const int z0 = own + l.off_z;
  const auto product = [&](int r, int ucol, double sign, double U, const int* vcols, int nv,
                           double V) {
    jac(r, ucol) += sign * V;
    for (int k = 0; k < nv; ++k) jac(r, vcols[k]) += U;
    return U * V;
  };
  thread_local std::vector<int> vcols;
  for (int k = 0; k < l.npairs; ++k) {
    const Pair& pair = dcs.pairs()[static_cast<std::size_t>(k)];
    const double sign = pair.flipped ? -1.0 : 1.0;
    const auto U = [&](int r) { return PointDcs::member_u(pair, z + r * nz); };
    const auto vcol = [&](int m) { return m == 0 ? d + k : z0 + (m - 1) * nz + pair.v; };
    const auto vval = [&](int m) { return in[vcol(m)]; };
    const int base = l.equalities;
    if (!standard && l.cross == CrossComplementarity::kPointPairs) {
      for (int m = 0; m <= P; ++m) {
        const int vc = vcol(m);
        for (int r = 0; r < P; ++r) {
          const int row = base + k * P * (P + 1) + m * P + r;
          out[row] = product(row, z0 + r * nz + pair.u, sign, U(r), &vc, 1, vval(m));
        }
      }
      continue;
    }
    vcols.clear();
    double sum_v = standard ? 0.0 : vval(0);
    if (!standard) vcols.push_back(vcol(0));
    for (int m = 1; m <= P; ++m) {
      sum_v += vval(m);
      vcols.push_back(vcol(m));
    }
    if (!standard && l.cross == CrossComplementarity::kPointSums) {
      for (int r = 0; r < P; ++r) {
        const int row = base + k * P + r;
        out[row] = product(row, z0 + r * nz + pair.u, sign, U(r), vcols.data(),
                           static_cast<int>(vcols.size()), sum_v);
      }
    } else if (standard) {
      const int row = base + k;
      double sum = 0.0;
      for (int m = 0; m < P; ++m) {
        const int vc = vcol(m + 1);
        sum += product(row, z0 + m * nz + pair.u, sign, U(m), &vc, 1, vval(m + 1));
      }
      out[row] = sum;
    } else {
      const int row = base + k;
      double sum_u = 0.0;
      for (int m = 0; m < P; ++m) sum_u += U(m);
      for (int m = 0; m < P; ++m) jac(row, z0 + m * nz + pair.u) += sign * sum_v;
      for (int c : vcols) jac(row, c) += sum_u;
      out[row] = sum_u * sum_v;
    }
  }
  if (values != nullptr) *values = out;
}

}  // namespace fesd
}  // namespace bflow

#endif  // BFLOW_FESD_ELEMENT_H_

// Jet bridge: derivatives of user code by forward-mode automatic differentiation with
// ceres::Jet, in fixed-width chunks of directions.
//
// A function is any callable f(const T* in, T* out) that accepts T = double and
// T = ceres::Jet<double, N>; a C++17 generic lambda is the usual way to write one:
//
//   struct Pendulum {                       // a bflow model (see bflow/core/model.h)
//     static constexpr int kStates = 2;
//     static constexpr int kSurfaces = 1;
//     template <typename T> void field(const T* x, bflow::Signs b, T* xdot) const {
//       xdot[0] = x[1];
//       xdot[1] = -sin(x[0]) - (b.plus(0) ? T(0.1) : T(0.3)) * x[1];
//     }
//     template <typename T> void surfaces(const T* x, T* h) const { h[0] = x[1]; }
//   };
//
//   Pendulum model;
//   Eigen::Vector2d x(0.3, -1.0);
//   bflow::Signs b = bflow::Signs::parse("-");
//   Eigen::MatrixXd df = bflow::ad::field_jacobian(model, x, b);   // DF_b(x), 2 x 2
//   Eigen::MatrixXd eta = bflow::ad::normals(model, x);            // Dh(x), 1 x 2
//
//   auto f = [&](const auto* in, auto* out) { model.field(in, b, out); };
//   Eigen::MatrixXd v(2, 3);  v << 1, 0, 2,  0, 1, 3;
//   Eigen::MatrixXd dfv = bflow::ad::jacobian_times(f, 2, x, v);   // DF_b(x) * V, 2 x 3
//
// Chunks. A Jacobian of a function of d inputs is evaluated in ceil(d / Stride) passes of
// ceres::Jet<double, Stride>, each seeding Stride unit directions (the last pass is partial),
// so d is a run-time size and never limited by a compile-time Jet width. Each distinct
// Stride instantiates the user function once more: keep to the default unless measured.
//
// Scalar templates. Code templated on the scalar must branch on values (x[0] < T(0)), never
// on derivative parts: the derivative is then the derivative of the branch taken.
//
// Errors. Every function throws bflow::InvalidArgument (naming the function, the problem and
// the values) for a wrong size, a non-finite input, or a non-finite output or derivative of
// the user function (quoting the output row and x).
#ifndef BFLOW_AD_JET_BRIDGE_H_
#define BFLOW_AD_JET_BRIDGE_H_

#include <algorithm>
#include <cmath>
#include <string>
#include <type_traits>
#include <vector>

#include <ceres/jet.h>
#include <Eigen/Core>

#include "bflow/core/errors.h"
#include "bflow/core/model.h"
#include "bflow/core/signs.h"

namespace bflow {
namespace ad {

/** Default number of directions per Jet pass. */
inline constexpr int kDefaultStride = 8;

namespace internal {

// What is being differentiated, for error messages; strings are built only on failure.
struct Context {
  const char* caller;           // public function name, e.g. "field_jacobian"
  const char* output;           // name of the function's value, e.g. "f" or "F_b"
  const Signs* word = nullptr;  // the sign word of a model field, if any
};

inline std::string describe_word(const Context& ctx) {
  return ctx.word == nullptr ? std::string() : " (b = \"" + ctx.word->str() + "\")";
}

inline void check_count(const Context& ctx, const char* name, int count) {
  if (count < 0) {
    throw InvalidArgument(std::string(ctx.caller) + ": " + name + " must be >= 0, got " +
                          std::to_string(count));
  }
}

// Throws unless v has `size` entries, all finite.
inline void check_input(const Context& ctx, const char* name,
                        const Eigen::Ref<const Eigen::VectorXd>& v, Eigen::Index size,
                        const char* size_meaning) {
  if (v.size() != size) {
    throw InvalidArgument(std::string(ctx.caller) + ": " + name + " has " +
                          std::to_string(v.size()) + " entries, expected " + std::to_string(size) +
                          " (" + size_meaning + ")");
  }
  for (Eigen::Index i = 0; i < v.size(); ++i) {
    if (!std::isfinite(v[i])) {
      throw InvalidArgument(std::string(ctx.caller) + ": " + name + " is not finite (entry " +
                            std::to_string(i) + " is " + format_number(v[i]) + "): " + name +
                            " = " + format_vector(v));
    }
  }
}

inline void check_matrix_input(const Context& ctx, const char* name,
                               const Eigen::Ref<const Eigen::MatrixXd>& m, Eigen::Index rows) {
  if (m.rows() != rows) {
    throw InvalidArgument(std::string(ctx.caller) + ": " + name + " has " +
                          std::to_string(m.rows()) + " rows, expected d = " + std::to_string(rows));
  }
  for (Eigen::Index j = 0; j < m.cols(); ++j) {
    for (Eigen::Index i = 0; i < m.rows(); ++i) {
      if (!std::isfinite(m(i, j))) {
        throw InvalidArgument(std::string(ctx.caller) + ": " + name + " is not finite (entry (" +
                              std::to_string(i) + ", " + std::to_string(j) + ") is " +
                              format_number(m(i, j)) + ")");
      }
    }
  }
}

inline void check_output_shape(const Context& ctx, const char* name, Eigen::Index rows,
                               Eigen::Index cols, Eigen::Index want_rows, Eigen::Index want_cols) {
  if (rows != want_rows || cols != want_cols) {
    throw InvalidArgument(std::string(ctx.caller) + ": " + name + " is " + std::to_string(rows) +
                          " x " + std::to_string(cols) + ", expected " + std::to_string(want_rows) +
                          " x " + std::to_string(want_cols));
  }
}

[[noreturn]] inline void throw_nonfinite_value(const Context& ctx, int row, double value,
                                               const Eigen::Ref<const Eigen::VectorXd>& x) {
  throw InvalidArgument(std::string(ctx.caller) + ": " + ctx.output + "(x) row " +
                        std::to_string(row) + " is non-finite (" + format_number(value) +
                        ") at x = " + format_vector(x) + describe_word(ctx));
}

[[noreturn]] inline void throw_nonfinite_derivative(const Context& ctx, bool unit_directions,
                                                    int row, int col, double value,
                                                    const Eigen::Ref<const Eigen::VectorXd>& x) {
  const std::string what = unit_directions ? std::string("the Jacobian D") + ctx.output + "(x)"
                                           : std::string("D") + ctx.output + "(x) * V";
  throw InvalidArgument(std::string(ctx.caller) + ": row " + std::to_string(row) + " of " + what +
                        " is non-finite (column " + std::to_string(col) + " is " +
                        format_number(value) + ") at x = " + format_vector(x) + describe_word(ctx));
}

// Evaluates f and its derivatives along k directions, Stride directions per Jet pass.
// directions == nullptr seeds the unit vectors e_0 .. e_{d-1} (k = d); otherwise column c of
// the d x k block at `directions` (column stride ld_dir) is direction c. Writes the value to
// `value` (if not null; from the first pass) and derivative column c to out + c * ld_out.
// x, directions and the sizes are already checked by the caller.
template <int Stride, typename Function>
void evaluate_directions(const Function& f, int n_out, const Eigen::Ref<const Eigen::VectorXd>& x,
                         const double* directions, Eigen::Index ld_dir, Eigen::Index k,
                         double* value, double* out, Eigen::Index ld_out, const Context& ctx) {
  static_assert(Stride >= 1, "bflow::ad: Stride must be at least 1");
  using JetT = ceres::Jet<double, Stride>;
  static_assert(std::is_invocable_v<const Function&, const JetT*, JetT*>,
                "bflow::ad: the function must be callable as f(const T* in, T* out) with "
                "T = ceres::Jet<double, Stride> (write it as a template or a generic lambda)");
  const Eigen::Index d = x.size();
  std::vector<JetT> in(static_cast<std::size_t>(d));
  std::vector<JetT> result(static_cast<std::size_t>(n_out));
  // One pass even for k == 0, so that the value is still computed.
  for (Eigen::Index c0 = 0; c0 < k || c0 == 0; c0 += Stride) {
    const int width = static_cast<int>(std::min<Eigen::Index>(Stride, k - c0));
    for (Eigen::Index i = 0; i < d; ++i) {
      JetT& xi = in[static_cast<std::size_t>(i)];
      xi.a = x[i];
      xi.v.setZero();
      for (int m = 0; m < width; ++m) {
        xi.v[m] =
            directions == nullptr ? (i == c0 + m ? 1.0 : 0.0) : directions[i + (c0 + m) * ld_dir];
      }
    }
    for (JetT& y : result) y = JetT(0.0);
    f(static_cast<const JetT*>(in.data()), result.data());
    for (int r = 0; r < n_out; ++r) {
      const JetT& y = result[static_cast<std::size_t>(r)];
      if (!std::isfinite(y.a)) throw_nonfinite_value(ctx, r, y.a, x);
      if (c0 == 0 && value != nullptr) value[r] = y.a;
      for (int m = 0; m < width; ++m) {
        if (!std::isfinite(y.v[m])) {
          throw_nonfinite_derivative(ctx, directions == nullptr, r, static_cast<int>(c0 + m),
                                     y.v[m], x);
        }
        out[r + (c0 + m) * ld_out] = y.v[m];
      }
    }
  }
}

// Evaluates f with doubles, checking the outputs.
template <typename Function>
void evaluate_value(const Function& f, int n_out, const Eigen::Ref<const Eigen::VectorXd>& x,
                    double* value, const Context& ctx) {
  static_assert(std::is_invocable_v<const Function&, const double*, double*>,
                "bflow::ad: the function must be callable as f(const double* in, double* out)");
  for (int r = 0; r < n_out; ++r) value[r] = 0.0;
  f(x.data(), value);
  for (int r = 0; r < n_out; ++r) {
    if (!std::isfinite(value[r])) throw_nonfinite_value(ctx, r, value[r], x);
  }
}

template <typename Model>
void check_model_point(const Model& model, const Context& ctx,
                       const Eigen::Ref<const Eigen::VectorXd>& x, const char* name = "x") {
  check_input(ctx, name, x, model_states(model), "the model's number of states d");
}

// F_b(x) with doubles into `value` (d numbers), checking the outputs; x and b already checked.
template <typename Model>
void model_field_value(const Model& model, const Context& ctx,
                       const Eigen::Ref<const Eigen::VectorXd>& x, Signs b, double* value) {
  evaluate_value([&model, b](const auto* in, auto* out) { model.field(in, b, out); },
                 model_states(model), x, value, ctx);
}

template <typename Model>
void check_model_word(const Model& model, const Context& ctx, Signs b) {
  if (b.size() != model_surfaces(model)) {
    throw InvalidArgument(std::string(ctx.caller) + ": sign word \"" + b.str() + "\" has " +
                          std::to_string(b.size()) + " surfaces, the model has " +
                          std::to_string(model_surfaces(model)));
  }
}

}  // namespace internal

// ---------------------------------------------------------------------------------------------
// Generic functions f(const T* in, T* out): d = x.size() inputs, n_out outputs.

/** Jacobian J = Df(x) (n_out x d) and value f(x) (n_out), in ceil(d / Stride) passes of
    ceres::Jet<double, Stride>.
    @throws InvalidArgument if n_out < 0, x is not finite, `value` or `jac` has the wrong size,
    or f(x) or J has a non-finite entry (the message quotes the row and x). */
template <int Stride = kDefaultStride, typename Function>
void jacobian(const Function& f, int n_out, const Eigen::Ref<const Eigen::VectorXd>& x,
              Eigen::Ref<Eigen::VectorXd> value, Eigen::Ref<Eigen::MatrixXd> jac) {
  const internal::Context ctx{"jacobian", "f", nullptr};
  internal::check_count(ctx, "n_out", n_out);
  internal::check_input(ctx, "x", x, x.size(), "d");
  internal::check_output_shape(ctx, "value", value.rows(), 1, n_out, 1);
  internal::check_output_shape(ctx, "jac", jac.rows(), jac.cols(), n_out, x.size());
  internal::evaluate_directions<Stride>(f, n_out, x, nullptr, 0, x.size(), value.data(), jac.data(),
                                        jac.outerStride(), ctx);
}

/** Jacobian Df(x) (n_out x d) written to `jac`, without the value.
    @throws InvalidArgument as jacobian() above. */
template <int Stride = kDefaultStride, typename Function>
void jacobian(const Function& f, int n_out, const Eigen::Ref<const Eigen::VectorXd>& x,
              Eigen::Ref<Eigen::MatrixXd> jac) {
  const internal::Context ctx{"jacobian", "f", nullptr};
  internal::check_count(ctx, "n_out", n_out);
  internal::check_input(ctx, "x", x, x.size(), "d");
  internal::check_output_shape(ctx, "jac", jac.rows(), jac.cols(), n_out, x.size());
  internal::evaluate_directions<Stride>(f, n_out, x, nullptr, 0, x.size(), nullptr, jac.data(),
                                        jac.outerStride(), ctx);
}

/** Returns the Jacobian Df(x) (n_out x d). @throws InvalidArgument as jacobian() above. */
template <int Stride = kDefaultStride, typename Function>
Eigen::MatrixXd jacobian(const Function& f, int n_out, const Eigen::Ref<const Eigen::VectorXd>& x) {
  internal::check_count(internal::Context{"jacobian", "f", nullptr}, "n_out", n_out);
  Eigen::MatrixXd jac(n_out, x.size());
  jacobian<Stride>(f, n_out, x, jac);
  return jac;
}

/** A value and its Jacobian. */
struct Linearization {
  Eigen::VectorXd value;     ///< f(x), n_out entries
  Eigen::MatrixXd jacobian;  ///< Df(x), n_out x d
};

/** Returns f(x) and Df(x) from one set of Jet passes. @throws InvalidArgument as jacobian(). */
template <int Stride = kDefaultStride, typename Function>
Linearization linearize(const Function& f, int n_out, const Eigen::Ref<const Eigen::VectorXd>& x) {
  internal::check_count(internal::Context{"jacobian", "f", nullptr}, "n_out", n_out);
  Linearization result{Eigen::VectorXd(n_out), Eigen::MatrixXd(n_out, x.size())};
  jacobian<Stride>(f, n_out, x, result.value, result.jacobian);
  return result;
}

/** Jacobian-vector product Df(x) v (n_out) and value f(x), one pass of ceres::Jet<double, 1>.
    @throws InvalidArgument if n_out < 0, x or v is not finite, v.size() != x.size(), an output
    has the wrong size, or f(x) or Df(x) v has a non-finite entry. */
template <typename Function>
void jvp(const Function& f, int n_out, const Eigen::Ref<const Eigen::VectorXd>& x,
         const Eigen::Ref<const Eigen::VectorXd>& v, Eigen::Ref<Eigen::VectorXd> value,
         Eigen::Ref<Eigen::VectorXd> out) {
  const internal::Context ctx{"jvp", "f", nullptr};
  internal::check_count(ctx, "n_out", n_out);
  internal::check_input(ctx, "x", x, x.size(), "d");
  internal::check_input(ctx, "v", v, x.size(), "d = x.size()");
  internal::check_output_shape(ctx, "value", value.rows(), 1, n_out, 1);
  internal::check_output_shape(ctx, "out", out.rows(), 1, n_out, 1);
  internal::evaluate_directions<1>(f, n_out, x, v.data(), v.size(), 1, value.data(), out.data(),
                                   n_out, ctx);
}

/** Jacobian-vector product Df(x) v written to `out` (n_out). @throws InvalidArgument as jvp(). */
template <typename Function>
void jvp(const Function& f, int n_out, const Eigen::Ref<const Eigen::VectorXd>& x,
         const Eigen::Ref<const Eigen::VectorXd>& v, Eigen::Ref<Eigen::VectorXd> out) {
  const internal::Context ctx{"jvp", "f", nullptr};
  internal::check_count(ctx, "n_out", n_out);
  internal::check_input(ctx, "x", x, x.size(), "d");
  internal::check_input(ctx, "v", v, x.size(), "d = x.size()");
  internal::check_output_shape(ctx, "out", out.rows(), 1, n_out, 1);
  internal::evaluate_directions<1>(f, n_out, x, v.data(), v.size(), 1, nullptr, out.data(), n_out,
                                   ctx);
}

/** Returns Df(x) v. @throws InvalidArgument as jvp(). */
template <typename Function>
Eigen::VectorXd jvp(const Function& f, int n_out, const Eigen::Ref<const Eigen::VectorXd>& x,
                    const Eigen::Ref<const Eigen::VectorXd>& v) {
  internal::check_count(internal::Context{"jvp", "f", nullptr}, "n_out", n_out);
  Eigen::VectorXd out(n_out);
  jvp(f, n_out, x, v, out);
  return out;
}

/** Df(x) V (n_out x k) for a block of k directions V (d x k), and the value f(x), in
    ceil(k / Stride) passes of ceres::Jet<double, Stride>.
    @throws InvalidArgument if n_out < 0, x or V is not finite, V.rows() != x.size(), an
    output has the wrong size, or f(x) or Df(x) V has a non-finite entry. */
template <int Stride = kDefaultStride, typename Function>
void jacobian_times(const Function& f, int n_out, const Eigen::Ref<const Eigen::VectorXd>& x,
                    const Eigen::Ref<const Eigen::MatrixXd>& directions,
                    Eigen::Ref<Eigen::VectorXd> value, Eigen::Ref<Eigen::MatrixXd> out) {
  const internal::Context ctx{"jacobian_times", "f", nullptr};
  internal::check_count(ctx, "n_out", n_out);
  internal::check_input(ctx, "x", x, x.size(), "d");
  internal::check_matrix_input(ctx, "V", directions, x.size());
  internal::check_output_shape(ctx, "value", value.rows(), 1, n_out, 1);
  internal::check_output_shape(ctx, "out", out.rows(), out.cols(), n_out, directions.cols());
  internal::evaluate_directions<Stride>(f, n_out, x, directions.data(), directions.outerStride(),
                                        directions.cols(), value.data(), out.data(),
                                        out.outerStride(), ctx);
}

/** Df(x) V written to `out` (n_out x k). @throws InvalidArgument as jacobian_times(). */
template <int Stride = kDefaultStride, typename Function>
void jacobian_times(const Function& f, int n_out, const Eigen::Ref<const Eigen::VectorXd>& x,
                    const Eigen::Ref<const Eigen::MatrixXd>& directions,
                    Eigen::Ref<Eigen::MatrixXd> out) {
  const internal::Context ctx{"jacobian_times", "f", nullptr};
  internal::check_count(ctx, "n_out", n_out);
  internal::check_input(ctx, "x", x, x.size(), "d");
  internal::check_matrix_input(ctx, "V", directions, x.size());
  internal::check_output_shape(ctx, "out", out.rows(), out.cols(), n_out, directions.cols());
  internal::evaluate_directions<Stride>(f, n_out, x, directions.data(), directions.outerStride(),
                                        directions.cols(), nullptr, out.data(), out.outerStride(),
                                        ctx);
}

/** Returns Df(x) V (n_out x k). @throws InvalidArgument as jacobian_times(). */
template <int Stride = kDefaultStride, typename Function>
Eigen::MatrixXd jacobian_times(const Function& f, int n_out,
                               const Eigen::Ref<const Eigen::VectorXd>& x,
                               const Eigen::Ref<const Eigen::MatrixXd>& directions) {
  internal::check_count(internal::Context{"jacobian_times", "f", nullptr}, "n_out", n_out);
  Eigen::MatrixXd out(n_out, directions.cols());
  jacobian_times<Stride>(f, n_out, x, directions, out);
  return out;
}

// ---------------------------------------------------------------------------------------------
// Models (bflow/core/model.h): d = model_states(model), n = model_surfaces(model).

/** F_b(x) (d numbers), evaluated with doubles.
    @throws InvalidArgument if x.size() != d, x is not finite, b.size() != n, or F_b(x) has a
    non-finite entry (quoting the row, x and b). */
template <typename Model>
Eigen::VectorXd field_value(const Model& model, const Eigen::Ref<const Eigen::VectorXd>& x,
                            Signs b) {
  const internal::Context ctx{"field_value", "F_b", &b};
  internal::check_model_point(model, ctx, x);
  internal::check_model_word(model, ctx, b);
  Eigen::VectorXd value(model_states(model));
  internal::model_field_value(model, ctx, x, b, value.data());
  return value;
}

/** F_b(x) (d) and its Jacobian DF_b(x) (d x d) from one set of Jet passes.
    @throws InvalidArgument as field_value(), for wrongly sized outputs, or a non-finite entry
    of DF_b(x) (quoting the row, x and b). */
template <int Stride = kDefaultStride, typename Model>
void field_jacobian(const Model& model, const Eigen::Ref<const Eigen::VectorXd>& x, Signs b,
                    Eigen::Ref<Eigen::VectorXd> value, Eigen::Ref<Eigen::MatrixXd> jac) {
  const internal::Context ctx{"field_jacobian", "F_b", &b};
  internal::check_model_point(model, ctx, x);
  internal::check_model_word(model, ctx, b);
  const int d = model_states(model);
  internal::check_output_shape(ctx, "value", value.rows(), 1, d, 1);
  internal::check_output_shape(ctx, "jac", jac.rows(), jac.cols(), d, d);
  internal::evaluate_directions<Stride>(
      [&model, b](const auto* in, auto* out) { model.field(in, b, out); }, d, x, nullptr, 0, d,
      value.data(), jac.data(), jac.outerStride(), ctx);
}

/** Returns DF_b(x) (d x d). @throws InvalidArgument as field_jacobian() above. */
template <int Stride = kDefaultStride, typename Model>
Eigen::MatrixXd field_jacobian(const Model& model, const Eigen::Ref<const Eigen::VectorXd>& x,
                               Signs b) {
  const int d = model_states(model);
  Eigen::VectorXd value(d);
  Eigen::MatrixXd jac(d, d);
  field_jacobian<Stride>(model, x, b, value, jac);
  return jac;
}

/** F_b(x) (d) and DF_b(x) V (d x k) for tangents V (d x k): the right-hand side of the
    variational equation. Passes of ceres::Jet<double, Stride> over the columns of V.
    @throws InvalidArgument as field_jacobian(), or if V is not finite or not d x k. */
template <int Stride = kDefaultStride, typename Model>
void field_jacobian_times(const Model& model, const Eigen::Ref<const Eigen::VectorXd>& x, Signs b,
                          const Eigen::Ref<const Eigen::MatrixXd>& directions,
                          Eigen::Ref<Eigen::VectorXd> value, Eigen::Ref<Eigen::MatrixXd> out) {
  const internal::Context ctx{"field_jacobian_times", "F_b", &b};
  internal::check_model_point(model, ctx, x);
  internal::check_model_word(model, ctx, b);
  const int d = model_states(model);
  internal::check_matrix_input(ctx, "V", directions, d);
  internal::check_output_shape(ctx, "value", value.rows(), 1, d, 1);
  internal::check_output_shape(ctx, "out", out.rows(), out.cols(), d, directions.cols());
  internal::evaluate_directions<Stride>(
      [&model, b](const auto* in, auto* y) { model.field(in, b, y); }, d, x, directions.data(),
      directions.outerStride(), directions.cols(), value.data(), out.data(), out.outerStride(),
      ctx);
}

/** h(x) (n numbers), evaluated with doubles.
    @throws InvalidArgument if x.size() != d, x is not finite, or h(x) has a non-finite entry. */
template <typename Model>
Eigen::VectorXd surface_values(const Model& model, const Eigen::Ref<const Eigen::VectorXd>& x) {
  const internal::Context ctx{"surface_values", "h", nullptr};
  internal::check_model_point(model, ctx, x);
  const int n = model_surfaces(model);
  Eigen::VectorXd value(n);
  internal::evaluate_value([&model](const auto* in, auto* out) { model.surfaces(in, out); }, n, x,
                           value.data(), ctx);
  return value;
}

/** The surface normals Dh(x) (n x d, row j = Dh_j(x)), not normalised and not oriented (the
    orientation by the flow is done by jump_map_at() in bflow/ad/model_jump.h).
    @throws InvalidArgument if x.size() != d, x is not finite, or h(x) or Dh(x) has a
    non-finite entry (quoting the row and x). */
template <int Stride = kDefaultStride, typename Model>
Eigen::MatrixXd normals(const Model& model, const Eigen::Ref<const Eigen::VectorXd>& x) {
  const internal::Context ctx{"normals", "h", nullptr};
  internal::check_model_point(model, ctx, x);
  const int n = model_surfaces(model);
  const int d = model_states(model);
  Eigen::MatrixXd eta(n, d);
  internal::evaluate_directions<Stride>(
      [&model](const auto* in, auto* out) { model.surfaces(in, out); }, n, x, nullptr, 0, d,
      nullptr, eta.data(), eta.outerStride(), ctx);
  return eta;
}

}  // namespace ad
}  // namespace bflow

#endif  // BFLOW_AD_JET_BRIDGE_H_

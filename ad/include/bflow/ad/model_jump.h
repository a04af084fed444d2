// jump_map_at: the JumpMap of a model at a point rho where some of its surfaces meet.
//
// The normals are the AD gradients Dh_j(rho) of the chosen surfaces, oriented by the flow: the
// flow crosses surface j in the direction s_j = sign(Dh_j(rho) . F_b(rho)), which must be the
// same for every sign word b of the chosen surfaces, and eta_j = s_j Dh_j(rho) so that the
// JumpMap sees every crossing as `-` to `+` (DESIGN.md, Orientation). The limits are
// Gamma(w) = F_b(rho), evaluated lazily, where the JumpMap word w ("before"/"after" crossing,
// bit clear = before) becomes the model's full word b by
//   * placing bit k of w at the model index surfaces[k],
//   * flipping it when s = -1 (that surface is crossed from + to -, so "before" is +),
//   * and taking the model's other surfaces from `others` (or from the sign of h_k(rho)).
//
// Worked example, the piecewise-constant field of [B] (3.1) with d = n = 2, h(x) = x and
// Delta(b) = -delta * b, where the B-derivative is (1-delta)/(1+delta) I ([B] (3.2)):
//
//   struct PiecewiseConstant {
//     static constexpr int kStates = 2;
//     static constexpr int kSurfaces = 2;
//     double delta = 0.5;
//     template <typename T> void field(const T*, bflow::Signs b, T* xdot) const {
//       for (int i = 0; i < 2; ++i) xdot[i] = T(1.0 - delta * b.sign(i));
//     }
//     template <typename T> void surfaces(const T* x, T* h) const { h[0] = x[0]; h[1] = x[1]; }
//   };
//
//   bflow::JumpMap jump = bflow::ad::jump_map_at(PiecewiseConstant{}, Eigen::Vector2d::Zero(),
//                                                {0, 1});
//   Eigen::VectorXd image = jump.apply(dx);   // == (1 - 0.5) / (1 + 0.5) * dx
#ifndef BFLOW_AD_MODEL_JUMP_H_
#define BFLOW_AD_MODEL_JUMP_H_

#include <cmath>
#include <cstdint>
#include <optional>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "bflow/ad/jet_bridge.h"
#include "bflow/core/errors.h"
#include "bflow/core/field_limits.h"
#include "bflow/core/jump_map.h"
#include "bflow/core/model.h"
#include "bflow/core/signs.h"

namespace bflow {
namespace ad {

/** Up to this many chosen surfaces, jump_map_at() checks the crossing direction for all 2^n
    words; above it, only -...-, +...+ and the words one flip away from either. */
inline constexpr int kCheckAllWordsMaxSurfaces = 12;

namespace internal {

inline std::string format_indices(const std::vector<int>& indices) {
  std::string s = "{";
  for (std::size_t k = 0; k < indices.size(); ++k) {
    if (k > 0) s += ", ";
    s += std::to_string(indices[k]);
  }
  return s + "}";
}

// Maps a JumpMap word (bit k: chosen surface k crossed) to the model's full word.
struct WordMap {
  std::vector<int> surfaces;  // model index of chosen surface k
  std::uint64_t flip = 0;     // bit k set when s_k = -1
  std::uint64_t base = 0;     // the other surfaces' bits; chosen bits clear
  int model_surfaces = 0;

  Signs operator()(std::uint64_t w) const {
    std::uint64_t bits = base;
    const std::uint64_t raw = w ^ flip;
    for (std::size_t k = 0; k < surfaces.size(); ++k) {
      if ((raw >> k) & 1u) bits |= std::uint64_t{1} << surfaces[k];
    }
    return Signs(model_surfaces, bits);
  }
};

}  // namespace internal

/** The JumpMap at rho for the model's surfaces `surfaces` (indices into h, in the JumpMap's
    order: JumpMap surface k is model surface surfaces[k]).

    `others` fixes the sides of the model's surfaces that are not chosen; it is a full word of
    the model's n surfaces whose characters at the chosen surfaces are ignored. Without it, the
    side of each other surface k is the sign of h_k(rho), which must be nonzero. The chosen
    h_j(rho) are not checked (an event locator gives rho only to a tolerance).

    The crossing direction s_j = sign(Dh_j(rho) . F_b(rho)) is checked for every word b of the
    chosen surfaces when there are at most kCheckAllWordsMaxSurfaces of them; for more, only for
    the words -...-, +...+ and those one flip away from either (in the JumpMap's orientation).
    The JumpMap itself checks eta_j . Gamma(w) > 0 for every word it evaluates, so a violation
    in an unchecked word throws from the JumpMap call that needs that word.

    The returned JumpMap evaluates Gamma lazily through a FieldLimitFunction that holds a COPY
    of the model (and of rho): the JumpMap stays valid after `model` is gone, and later changes
    to `model` do not affect it. Model must be copy constructible.

    @throws InvalidArgument if rho has the wrong size or is not finite; `surfaces` is empty, has
    an index outside [0, n) or a repeated index; `others` is not a word of n surfaces; a
    non-chosen h_k(rho) is zero and `others` is not given; F_b(rho) or Dh(rho) is not finite;
    a chosen surface is not crossed transversally (Dh_j . F_b is zero, or changes sign between
    words; the message quotes the surface, the words and the values); or as the JumpMap
    constructor (rank-deficient normals, more surfaces than states). */
template <int Stride = kDefaultStride, typename Model>
JumpMap jump_map_at(const Model& model, const Eigen::Ref<const Eigen::VectorXd>& rho,
                    const std::vector<int>& surfaces, std::optional<Signs> others = {},
                    JumpMapOptions options = {}) {
  static_assert(std::is_copy_constructible_v<Model>,
                "bflow::ad::jump_map_at copies the model into the JumpMap: Model must be copy "
                "constructible");
  const internal::Context ctx{"jump_map_at", "F_b", nullptr};
  internal::check_model_point(model, ctx, rho, "rho");
  const int n_model = model_surfaces(model);
  const int n = static_cast<int>(surfaces.size());
  const std::string chosen = internal::format_indices(surfaces);
  if (n == 0) throw InvalidArgument("jump_map_at: no surfaces chosen");
  std::uint64_t chosen_mask = 0;
  for (int j : surfaces) {
    if (j < 0 || j >= n_model) {
      throw InvalidArgument("jump_map_at: surface index " + std::to_string(j) +
                            " is out of range [0, " + std::to_string(n_model) + ") in surfaces " +
                            chosen);
    }
    const std::uint64_t bit = std::uint64_t{1} << j;
    if (chosen_mask & bit) {
      throw InvalidArgument("jump_map_at: surface index " + std::to_string(j) +
                            " appears more than once in surfaces " + chosen);
    }
    chosen_mask |= bit;
  }

  internal::WordMap word_map;
  word_map.surfaces = surfaces;
  word_map.model_surfaces = n_model;
  if (others.has_value()) {
    if (others->size() != n_model) {
      throw InvalidArgument("jump_map_at: others = \"" + others->str() + "\" has " +
                            std::to_string(others->size()) + " surfaces, the model has " +
                            std::to_string(n_model));
    }
    word_map.base = others->bits() & ~chosen_mask;
  } else if (chosen_mask != low_bits(n_model)) {
    const Eigen::VectorXd h = surface_values(model, rho);
    for (int k = 0; k < n_model; ++k) {
      if (chosen_mask & (std::uint64_t{1} << k)) continue;
      if (h[k] == 0.0) {
        throw InvalidArgument("jump_map_at: surface " + std::to_string(k) +
                              " is not among the chosen surfaces " + chosen + " but h_" +
                              std::to_string(k) + "(rho) = 0 at rho = " + format_vector(rho) +
                              ", so its side is unknown: pass `others`");
      }
      if (h[k] > 0.0) word_map.base |= std::uint64_t{1} << k;
    }
  }

  const Eigen::MatrixXd dh = normals<Stride>(model, rho);

  // Dh_j . F_b for the chosen surfaces, at the model word b.
  Eigen::VectorXd rates(n);
  Eigen::VectorXd f(model_states(model));
  auto crossing_rates = [&](Signs b) {
    const internal::Context field_ctx{"jump_map_at", "F_b", &b};
    internal::model_field_value(model, field_ctx, rho, b, f.data());
    for (int k = 0; k < n; ++k) rates[k] = dh.row(surfaces[k]).dot(f);
  };
  auto not_transversal = [&](int k, Signs b) {
    return "jump_map_at: surface " + std::to_string(surfaces[k]) +
           " is not crossed transversally at rho = " + format_vector(rho) + ": Dh_" +
           std::to_string(surfaces[k]) + "(rho) . F_b(rho) = " + format_number(rates[k]) +
           " for b = \"" + b.str() + "\"";
  };

  // The direction of each crossing, from the word with every chosen surface on its - side.
  const Signs first_word(n_model, word_map.base);
  crossing_rates(first_word);
  Eigen::VectorXd first_rates = rates;
  for (int k = 0; k < n; ++k) {
    if (rates[k] == 0.0) {
      throw InvalidArgument(not_transversal(k, first_word) + " (the flow is tangent to it)");
    }
    if (rates[k] < 0.0) word_map.flip |= std::uint64_t{1} << k;
  }

  auto check_word = [&](std::uint64_t w) {
    const Signs b = word_map(w);
    crossing_rates(b);
    for (int k = 0; k < n; ++k) {
      const bool same_side = (rates[k] > 0.0) == (first_rates[k] > 0.0);
      if (rates[k] == 0.0 || !same_side) {
        throw InvalidArgument(not_transversal(k, b) + " but " + format_number(first_rates[k]) +
                              " for b = \"" + first_word.str() +
                              "\" (the flow must cross in the same direction for every word "
                              "of the chosen surfaces " +
                              chosen + ")");
      }
    }
  };
  const std::uint64_t all = low_bits(n);
  if (n <= kCheckAllWordsMaxSurfaces) {
    for (std::uint64_t w = 0; w <= all; ++w) check_word(w);
  } else {
    check_word(0);
    check_word(all);
    for (int k = 0; k < n; ++k) {
      check_word(std::uint64_t{1} << k);
      check_word(all ^ (std::uint64_t{1} << k));
    }
  }

  const int d = model_states(model);
  Eigen::MatrixXd eta(n, d);
  for (int k = 0; k < n; ++k) {
    eta.row(k) = (word_map.flip >> k) & 1u ? Eigen::RowVectorXd(-dh.row(surfaces[k]))
                                           : Eigen::RowVectorXd(dh.row(surfaces[k]));
  }

  FieldLimitFunction limits = [model_copy = model, point = Eigen::VectorXd(rho),
                               map = std::move(word_map)](Signs w,
                                                          Eigen::Ref<Eigen::VectorXd> out) {
    const Signs b = map(w.bits());
    model_copy.field(point.data(), b, out.data());
    for (Eigen::Index i = 0; i < out.size(); ++i) {
      if (!std::isfinite(out[i])) {
        throw InvalidArgument("jump_map_at: F_b(rho) row " + std::to_string(i) +
                              " is non-finite (" + format_number(out[i]) +
                              ") at rho = " + format_vector(point) + " for b = \"" + b.str() +
                              "\" (JumpMap word \"" + w.str() + "\")");
      }
    }
  };
  return JumpMap(eta, std::move(limits), options);
}

}  // namespace ad
}  // namespace bflow

#endif  // BFLOW_AD_MODEL_JUMP_H_

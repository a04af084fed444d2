// JumpMap from NumPy: normals (n x d) and field limits (d x 2^n, column b.bits() is F_b(rho)),
// or from a model at a point, its limits evaluated lazily (n + 1 words per apply).
#include <string>
#include <vector>

#include <nanobind/eigen/dense.h>
#include <nanobind/nanobind.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include "bflow/core/errors.h"
#include "bflow/core/jump_map.h"
#include "bflow/core/triangulation.h"
#include "bindings.h"
#include "model_handle.h"

namespace nb = nanobind;
using namespace nb::literals;

namespace bflow::python {

using ConstMatrix = Eigen::Ref<const Eigen::MatrixXd>;
using ConstVector = Eigen::Ref<const Eigen::VectorXd>;

void bind_jump(nb::module_& m) {
  nb::class_<CrossingOrder>(m, "CrossingOrder",
                            "Which surface a perturbation crosses first, and when.")
      .def_ro("order", &CrossingOrder::order, "surface indices, first crossed first")
      .def_ro("times", &CrossingOrder::times,
              "times[k]: when surface order[k] is crossed (0: dx itself, on the F_{-...-} line)")
      .def("__repr__", [](const CrossingOrder& o) {
        std::string s = "CrossingOrder(order=[";
        for (std::size_t k = 0; k < o.order.size(); ++k)
          s += (k ? ", " : "") + std::to_string(o.order[k]);
        return s + "])";
      });

  // The JumpMap of `model` at rho across the chosen surfaces: eta_k = orient_k Dh_{chosen[k]}(rho)
  // and Gamma(w) = F_b(rho), b the word `base` (the other surfaces' sides, the chosen ones -)
  // with bit chosen[k] set where w_k is "after" for orient_k = +1, "before" for -1. Gamma is
  // evaluated lazily, so that any n up to 64 costs n + 1 field calls per direction.
  m.def(
      "_jump_map_at",
      [](const Model& model, ConstVector rho, const std::vector<int>& chosen,
         const std::string& base, const std::vector<int>& orient) {
        const std::shared_ptr<const SegmentModel> field = model.model;
        const int d = field->states(), surfaces = field->surfaces();
        const Signs sides = Signs::parse(base);
        if (rho.size() != d || sides.size() != surfaces || orient.size() != chosen.size()) {
          throw InvalidArgument(
              "JumpMap.at: rho, the sign word and the orientations must match "
              "the model's " +
              std::to_string(d) + " states and " + std::to_string(surfaces) + " surfaces");
        }
        const Eigen::VectorXd x = rho;
        const Eigen::MatrixXd all = field->surface_normals(x);
        Eigen::MatrixXd eta(static_cast<Eigen::Index>(chosen.size()), d);
        for (std::size_t k = 0; k < chosen.size(); ++k) {
          if (chosen[k] < 0 || chosen[k] >= surfaces) {
            throw InvalidArgument("JumpMap.at: surface " + std::to_string(chosen[k]) +
                                  " is out of range [0, " + std::to_string(surfaces) + ")");
          }
          eta.row(static_cast<Eigen::Index>(k)) = orient[k] * all.row(chosen[k]);
        }
        auto limits = [field, x, chosen, sides, orient](Signs w, Eigen::Ref<Eigen::VectorXd> out) {
          Signs b = sides;
          for (std::size_t k = 0; k < chosen.size(); ++k) {
            const bool after = w.plus(static_cast<int>(k));
            b = (orient[k] > 0 ? after : !after) ? b.with_plus(chosen[k]) : b.with_minus(chosen[k]);
          }
          field->field(x.data(), b, out.data());  // (a Ref<VectorXd> is contiguous)
        };
        return JumpMap(eta, limits);
      },
      "model"_a, "rho"_a, "chosen"_a, "base"_a, "orient"_a);

  nb::class_<JumpMap>(m, "JumpMap")
      .def("_limits_table",
           [](const JumpMap& j) {
             // Every word's limit, column b.bits() (the table from_limits takes).
             if (j.surfaces() > kMaxTableSurfaces) {
               throw InvalidArgument("JumpMap: " + std::to_string(j.surfaces()) +
                                     " surfaces, more than a table holds (" +
                                     std::to_string(kMaxTableSurfaces) + ")");
             }
             Eigen::MatrixXd table(j.dim(), Eigen::Index{1} << j.surfaces());
             for (Eigen::Index b = 0; b < table.cols(); ++b)
               table.col(b) = j.limit(Signs(j.surfaces(), static_cast<std::uint64_t>(b)));
             return table;
           })
      .def(nb::init<ConstMatrix, ConstMatrix>(), "normals"_a, "field_limits"_a,
           nb::call_guard<nb::gil_scoped_release>())
      .def_prop_ro("surfaces", &JumpMap::surfaces)
      .def_prop_ro("dim", &JumpMap::dim)
      .def_prop_ro("normals", &JumpMap::normals, nb::rv_policy::copy)
      .def(
          "_apply_vector",
          [](const JumpMap& j, ConstVector dx) { return Eigen::VectorXd(j.apply(dx)); }, "dx"_a)
      .def(
          "_apply_into",
          [](const JumpMap& j, ConstVector dx, Eigen::Ref<Eigen::VectorXd> out) {
            if (out.size() != j.dim()) {
              throw InvalidArgument("apply: out has " + std::to_string(out.size()) +
                                    " entries, expected d = " + std::to_string(j.dim()));
            }
            j.apply(dx, out);
          },
          "dx"_a, "out"_a.noconvert())
      .def(
          "_apply_block",
          [](const JumpMap& j, ConstMatrix dx) { return Eigen::MatrixXd(j.apply_block(dx)); },
          "dx"_a, nb::call_guard<nb::gil_scoped_release>())
      .def("order", &JumpMap::order, "dx"_a)
      .def("active_jacobian", &JumpMap::active_jacobian, "dx"_a)
      .def("saltation", &JumpMap::saltation, "order"_a)
      .def("_pieces",
           [](const JumpMap& j) {
             nb::list out;
             const Pieces pieces = j.pieces();
             for (std::size_t i = 0; i < pieces.size(); ++i) {
               out.append(nb::make_tuple(pieces.order(i), Eigen::MatrixXd(pieces.matrix(i))));
             }
             return out;
           })
      .def("_triangulation", [](const JumpMap& j) {
        // (zeta, zeta_image, lineality basis, simplices as (order, words)), zeta in the scale
        // 2^scale_exponent.
        const Triangulation t = j.triangulation();
        nb::list simplices;
        for (const Simplex& s : t.simplices()) {
          std::vector<std::string> words;
          for (const Signs& w : s.words) words.push_back(w.str());
          simplices.append(nb::make_tuple(s.order, words));
        }
        return nb::make_tuple(Eigen::MatrixXd(t.zeta()), Eigen::MatrixXd(t.zeta_image()),
                              Eigen::MatrixXd(t.lineality_basis()), t.scale_exponent(), simplices);
      });
}

}  // namespace bflow::python

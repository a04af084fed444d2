// The sparse lower triangle of a Lagrangian's Hessian assembled from small dense blocks, each
// the second derivatives of a function of a few unknowns (fesd element pieces, equilibration
// terms, an OCP's costs and constraints).
#ifndef BFLOW_FESD_HESSIAN_BLOCKS_H_
#define BFLOW_FESD_HESSIAN_BLOCKS_H_

#include <algorithm>
#include <cstddef>
#include <map>
#include <utility>
#include <vector>

#include "bflow/core/errors.h"
#include "bflow/fesd/step_model.h"

namespace bflow {
namespace fesd {

// The lower triangle of a Lagrangian's Hessian assembled from blocks: each block is a function of
// a few unknowns (`globals`, -1 for a constant), and its second derivatives come from nested
// forward AD (HessianScalar), kHessianChunk x kHessianChunk per evaluation.
class HessianBlocks {
 public:
  // Registers every pair of the block's unknowns (call for every block before values are added).
  void add_block(const std::vector<int>& globals) {
    for (int a : globals) {
      for (int b : globals) {
        if (a < 0 || b < 0 || a < b) continue;
        if (position_.emplace(std::make_pair(a, b), static_cast<int>(position_.size())).second) {
          rows_.push_back(a);
          cols_.push_back(b);
        }
      }
    }
    index_ready_ = false;
  }
  std::size_t size() const { return rows_.size(); }
  const std::vector<int>& rows() const { return rows_; }
  const std::vector<int>& cols() const { return cols_; }

  // Adds the Hessian of sum_r weights[r] f_r(in) (f = `eval`, `outputs` values) at `base` into
  // the lower-triangle values.
  template <typename Eval>
  void add(const std::vector<int>& globals, const std::vector<double>& base, int outputs,
           const double* weights, Eval eval, double* values) {
    if (!index_ready_) build_index();
    std::vector<int> free;
    for (std::size_t k = 0; k < globals.size(); ++k) {
      if (globals[k] >= 0) free.push_back(static_cast<int>(k));
    }
    const int count = static_cast<int>(free.size());
    std::vector<HessianScalar> in(globals.size()), out(static_cast<std::size_t>(outputs));
    for (int first_a = 0; first_a < count; first_a += kHessianChunk) {
      for (int first_b = first_a; first_b < count; first_b += kHessianChunk) {
        for (std::size_t k = 0; k < globals.size(); ++k)
          in[k] = HessianScalar(HessianInner(base[k]));
        const int width_a = std::min(kHessianChunk, count - first_a);
        const int width_b = std::min(kHessianChunk, count - first_b);
        for (int i = 0; i < width_a; ++i) {
          in[static_cast<std::size_t>(free[static_cast<std::size_t>(first_a + i)])]
              .value()
              .derivatives()[i] = 1.0;
        }
        for (int j = 0; j < width_b; ++j) {
          in[static_cast<std::size_t>(free[static_cast<std::size_t>(first_b + j)])]
              .derivatives()[j] = HessianInner(1.0);
        }
        eval(in.data(), out.data());
        for (int i = 0; i < width_a; ++i) {
          const int ga =
              globals[static_cast<std::size_t>(free[static_cast<std::size_t>(first_a + i)])];
          for (int j = 0; j < width_b; ++j) {
            const int gb =
                globals[static_cast<std::size_t>(free[static_cast<std::size_t>(first_b + j)])];
            // Diagonal blocks hold both (a, b) and (b, a): take each once.
            if (first_a == first_b && ga < gb) continue;
            double h = 0.0;
            for (int r = 0; r < outputs; ++r) {
              h += weights[r] * out[static_cast<std::size_t>(r)].derivatives()[j].derivatives()[i];
            }
            values[position(std::max(ga, gb), std::min(ga, gb))] += h;
          }
        }
      }
    }
  }

 private:
  // Row-wise sorted columns and positions (a std::map lookup per entry was a few per cent of an
  // IPOPT iteration).
  void build_index() {
    int rows = 0;
    for (int a : rows_) rows = std::max(rows, a + 1);
    row_begin_.assign(static_cast<std::size_t>(rows) + 1, 0);
    for (int a : rows_) ++row_begin_[static_cast<std::size_t>(a) + 1];
    for (std::size_t a = 0; a < static_cast<std::size_t>(rows); ++a)
      row_begin_[a + 1] += row_begin_[a];
    index_cols_.resize(rows_.size());
    index_positions_.resize(rows_.size());
    for (const auto& [key, pos] : position_) {  // ordered by (row, column)
      const auto at = static_cast<std::size_t>(row_begin_[static_cast<std::size_t>(key.first)]++);
      index_cols_[at] = key.second;
      index_positions_[at] = pos;
    }
    for (std::size_t a = static_cast<std::size_t>(rows); a > 0; --a)
      row_begin_[a] = row_begin_[a - 1];
    row_begin_[0] = 0;
    index_ready_ = true;
  }
  // The position of the registered pair (a, b), a >= b.
  std::size_t position(int a, int b) const {
    const auto first = index_cols_.begin() + row_begin_[static_cast<std::size_t>(a)];
    const auto last = index_cols_.begin() + row_begin_[static_cast<std::size_t>(a) + 1];
    const auto it = std::lower_bound(first, last, b);
    BFLOW_ASSERT(it != last && *it == b);
    return static_cast<std::size_t>(
        index_positions_[static_cast<std::size_t>(it - index_cols_.begin())]);
  }

  std::map<std::pair<int, int>, int> position_;
  std::vector<int> rows_, cols_;
  bool index_ready_ = false;
  std::vector<int> row_begin_, index_cols_, index_positions_;
};

}  // namespace fesd
}  // namespace bflow

#endif  // BFLOW_FESD_HESSIAN_BLOCKS_H_

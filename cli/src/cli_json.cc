#include "cli_json.h"

#include <algorithm>
#include <cstddef>

namespace bflow::cli {
namespace {

bool is_primitive_array(const OrderedJson& v) {
  return v.is_array() &&
         std::all_of(v.begin(), v.end(), [](const OrderedJson& e) { return e.is_primitive(); });
}

// A vector, or a small matrix, fits on one line.
bool fits_one_line(const OrderedJson& v) {
  if (is_primitive_array(v)) return true;
  if (!v.is_array()) return false;
  std::size_t count = 0;
  for (const auto& e : v) {
    if (!is_primitive_array(e)) return false;
    count += e.size();
  }
  return count <= 16;
}

// An object of a few numbers or strings, such as {"alpha": 0.01, "one_sided_error": 3e-14}.
bool is_flat_object(const OrderedJson& v) {
  return v.is_object() && !v.empty() && v.size() <= 4 &&
         std::all_of(v.begin(), v.end(), [](const OrderedJson& e) { return e.is_primitive(); });
}

void write_inline(std::ostream& out, const OrderedJson& v) {
  if (v.is_object()) {
    out << '{';
    bool first = true;
    for (auto it = v.begin(); it != v.end(); ++it) {
      out << (first ? "" : ", ") << scalar_text(OrderedJson(it.key())) << ": ";
      write_inline(out, it.value());
      first = false;
    }
    out << '}';
    return;
  }
  if (!v.is_array()) {
    out << scalar_text(v);
    return;
  }
  out << '[';
  for (std::size_t i = 0; i < v.size(); ++i) {
    if (i > 0) out << ", ";
    write_inline(out, v[i]);
  }
  out << ']';
}

void write_pretty(std::ostream& out, const OrderedJson& v, int level) {
  const std::string pad(static_cast<std::size_t>(2 * (level + 1)), ' ');
  const std::string close_pad(static_cast<std::size_t>(2 * level), ' ');
  if (v.is_object() && !v.empty() && !is_flat_object(v)) {
    out << "{\n";
    bool first = true;
    for (auto it = v.begin(); it != v.end(); ++it) {
      out << (first ? "" : ",\n") << pad << scalar_text(OrderedJson(it.key())) << ": ";
      write_pretty(out, it.value(), level + 1);
      first = false;
    }
    out << '\n' << close_pad << '}';
  } else if (v.is_array() && !v.empty() && !fits_one_line(v)) {
    out << "[\n";
    for (std::size_t i = 0; i < v.size(); ++i) {
      out << (i == 0 ? "" : ",\n") << pad;
      write_pretty(out, v[i], level + 1);
    }
    out << '\n' << close_pad << ']';
  } else {
    write_inline(out, v);
  }
}

}  // namespace

OrderedJson vector_json(const Eigen::Ref<const Eigen::VectorXd>& v) {
  OrderedJson out = OrderedJson::array();
  for (Eigen::Index i = 0; i < v.size(); ++i) out.push_back(v[i]);
  return out;
}

OrderedJson rows_json(const Eigen::Ref<const Eigen::MatrixXd>& m) {
  OrderedJson out = OrderedJson::array();
  for (Eigen::Index r = 0; r < m.rows(); ++r) out.push_back(vector_json(m.row(r).transpose()));
  return out;
}

OrderedJson columns_json(const Eigen::Ref<const Eigen::MatrixXd>& m) {
  OrderedJson out = OrderedJson::array();
  for (Eigen::Index c = 0; c < m.cols(); ++c) out.push_back(vector_json(m.col(c)));
  return out;
}

// nlohmann prints a double in the shortest form that reads back to the same double.
std::string scalar_text(const OrderedJson& v) {
  return v.dump(-1, ' ', false, OrderedJson::error_handler_t::replace);
}

void write_json(std::ostream& out, const OrderedJson& v, bool compact) {
  write_json(out, v, compact, 0);
}

void write_json(std::ostream& out, const OrderedJson& v, bool compact, int level) {
  if (compact) {
    out << v.dump(-1, ' ', false, OrderedJson::error_handler_t::replace);
  } else {
    write_pretty(out, v, level);
  }
}

}  // namespace bflow::cli

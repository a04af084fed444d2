// JSON output shared by the commands: Eigen values as JSON arrays, and the indented layout
// with vectors and small matrices on one line. Numbers print in the shortest form that reads
// back to the same double, so the output is exact.
#ifndef BFLOW_CLI_CLI_JSON_H_
#define BFLOW_CLI_CLI_JSON_H_

#include <ostream>
#include <string>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

namespace bflow::cli {

/** Output keeps the documented key order. */
using OrderedJson = nlohmann::ordered_json;

/** [v_0, v_1, ...]. */
OrderedJson vector_json(const Eigen::Ref<const Eigen::VectorXd>& v);
/** The rows of m, each an array. */
OrderedJson rows_json(const Eigen::Ref<const Eigen::MatrixXd>& m);
/** The columns of m, each an array. */
OrderedJson columns_json(const Eigen::Ref<const Eigen::MatrixXd>& m);

/** A scalar in the shortest round-trip form ("0.1", "1.0", "\"text\""). */
std::string scalar_text(const OrderedJson& v);

/** Indented JSON, but vectors, matrices of at most 16 numbers and objects of at most 4
    numbers or strings on one line; with `compact` one line. No trailing newline. */
void write_json(std::ostream& out, const OrderedJson& v, bool compact);
/** As write_json, for a value nested `level` containers deep (its inner lines are indented
    for that depth), so that a large document can be written piece by piece. */
void write_json(std::ostream& out, const OrderedJson& v, bool compact, int level);

}  // namespace bflow::cli

#endif  // BFLOW_CLI_CLI_JSON_H_

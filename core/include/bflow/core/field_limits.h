// Field limits Gamma(b) = F_b(rho): the limits of the vector field at a point where n
// surfaces meet, one vector per sign word b ([B] (2.9)).
//
// A JumpMap takes them either as a table of all 2^n words (a d x 2^n matrix whose column
// b.bits() is Gamma(b)) or as a FieldLimitFunction evaluated lazily. This header converts
// the text form used by files and the command line into the table:
//
//   std::map<std::string, Eigen::VectorXd> words = {{"--", a}, {"+-", b}, {"-+", c}, {"++", e}};
//   Eigen::MatrixXd table = bflow::limits_table_from_words(2, 3, words);  // 3 x 4
#ifndef BFLOW_CORE_FIELD_LIMITS_H_
#define BFLOW_CORE_FIELD_LIMITS_H_

#include <functional>
#include <map>
#include <string>

#include <Eigen/Core>

#include "bflow/core/signs.h"

namespace bflow {

/** Writes Gamma(b) (d numbers) into `out`. Must not depend on anything but b. */
using FieldLimitFunction = std::function<void(Signs b, Eigen::Ref<Eigen::VectorXd> out)>;

/** Largest n for which a full table (2^n columns) is accepted. */
inline constexpr int kMaxTableSurfaces = 24;

/** Builds the d x 2^n table from sign words.
    @throws InvalidArgument naming the word for: a word of the wrong length or with a
    character other than '-'/'+', a repeated word, a vector of the wrong size, non-finite
    numbers, or a missing word (the first missing one in binary order is quoted). */
Eigen::MatrixXd limits_table_from_words(int surfaces, int dim,
                                        const std::map<std::string, Eigen::VectorXd>& words);

}  // namespace bflow

#endif  // BFLOW_CORE_FIELD_LIMITS_H_

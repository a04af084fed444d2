// The size of the FESD problem in 64 bits ([F] Table 4 times the elements of a step), the limits
// fesd_simulate checks before it allocates anything, and a failed step's one message.
#include <sys/resource.h>

#include <cstdint>
#include <fstream>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include "bflow/core/filippov.h"
#include "bflow/examples/irma.h"
#include "bflow/examples/switching_cases.h"
#include "bflow/fesd/fesd.h"
#include "support/error_message.h"

namespace bflow {
namespace {

using ::testing::HasSubstr;
using ::testing::StartsWith;

constexpr std::int64_t kTwoTo30 = std::int64_t{1} << 30;
constexpr int kMaxInt = 2147483647;

// The scalar crossing case x' in 2 - sign(x): d = 1, n_c = 1, so with Radau IIA 2 (2 points) an
// element has 1 + 3 d + 2 * 3 n_c = 10 unknowns and 3 d + 2 n_c + 2 n_c = 7 rows; an element
// after the first reads 3 more inputs (the previous end and its 2 pairs' v), so the Jacobian has
// 7 * 10 + (N - 1) 7 * 13 + N (the row sum h_n = H) = 92 N - 21 nonzeros.
TEST(FesdLimitsTest, StepSizesAbove2To31AreExactIn64Bits) {
  FesdOptions o;
  o.elements = static_cast<int>(kTwoTo30);
  const FesdProblemSize size = fesd_problem_size(adapt_step(examples::CrossingCase{}), o);
  EXPECT_EQ(size.point_variables, 3);
  EXPECT_EQ(size.points, 2);
  EXPECT_EQ(size.unknowns, 10 * kTwoTo30);  // 10737418240
  EXPECT_EQ(size.constraints, 7 * kTwoTo30 + 1);
  EXPECT_EQ(size.jacobian_nonzeros, 92 * kTwoTo30 - 21);
  EXPECT_EQ(size.hessian_nonzeros, 0);
  EXPECT_EQ(size.total_elements, kTwoTo30);
  EXPECT_EQ(size.step_excess(),
            "10737418240 NLP unknowns per integration step, above IPOPT's limit of 2147483647");
}

// Stewart's formulation on IRMA (n_c = 7, d = 5): a point is exactly [F] Table 4's n_alg = 257,
// n_eq = 129, n_comp = 128; Gauss-Legendre 9 has 10 points per element (the end point). With
// N_FE = 2^31 - 1: block = 1 + 10 * 5 + 10 * 257 = 2621, rows = 10 * 5 + 10 * 129 + 128 = 1468,
// inputs after the first element 5 + 128 + 2621 = 2754 (numbers by hand, then multiplied out).
TEST(FesdLimitsTest, StewartSizesFollowTable4) {
  const DcsSize table = dcs_size_dense(7, DcsFormulation::kStewart);
  ASSERT_EQ(table.algebraic, 257);
  FesdOptions o;
  o.formulation = DcsFormulation::kStewart;
  o.scheme = CollocationScheme::kGaussLegendre;
  o.stages = 9;
  o.elements = kMaxInt;
  o.exact_hessian = true;
  const FesdProblemSize size = fesd_problem_size(adapt_step(examples::Irma{}), o);
  EXPECT_EQ(size.point_variables, table.algebraic);
  EXPECT_EQ(size.point_equalities, table.equalities);
  EXPECT_EQ(size.point_pairs, table.complementarity);
  EXPECT_EQ(size.points, 10);
  EXPECT_EQ(size.unknowns, 5628554638787);
  EXPECT_EQ(size.constraints, 3152505993797);
  EXPECT_EQ(size.jacobian_nonzeros, 8682003654202587);
  // Element blocks 2621 (2621 + 1) / 2 + (N - 1) 2754 (2754 + 1) / 2, equilibration terms
  // (N - 1) k (k + 1) / 2 with k = 2 + 128 + 2 * 10 * 257 = 5270: 3.8e16 in all.
  const std::int64_t n = kMaxInt;
  EXPECT_EQ(size.hessian_nonzeros,
            std::int64_t{2621} * 2622 / 2 + (n - 1) * (2754 * 2755 / 2 + 5270 * 5271 / 2));
}

// The lifted step formulation of a model without its own S uses the dense S's Table 4.
TEST(FesdLimitsTest, LiftedStepSizesFollowTable4) {
  FesdOptions o;
  o.lifting_depth = 2;
  o.elements = 5;
  const FesdProblemSize size = fesd_problem_size(adapt_step(examples::Irma{}), o);
  const DcsSize table = dcs_size_dense(7, DcsFormulation::kStep, 2);
  EXPECT_EQ(size.point_variables, 273);  // [F] Table 4, IRMA with bilinear lifting
  EXPECT_EQ(size.point_variables, table.algebraic);
  EXPECT_EQ(size.point_equalities, table.equalities);
  EXPECT_EQ(size.unknowns, 5 * (1 + 3 * 5 + 2 * 273));
}

#if defined(__SANITIZE_ADDRESS__)
constexpr bool kAddressSanitizer = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
constexpr bool kAddressSanitizer = true;
#else
constexpr bool kAddressSanitizer = false;
#endif
#else
constexpr bool kAddressSanitizer = false;
#endif

// The address space this process may still grow by during `call`: an allocation the size of the
// refused problem fails there (std::bad_alloc) instead of succeeding. AddressSanitizer maps its
// own memory in ways a limit would break, so there `call` runs unlimited.
template <typename Call>
void with_address_space_limit(std::int64_t extra_bytes, Call&& call) {
  if (kAddressSanitizer) {
    call();
    return;
  }
  std::ifstream statm("/proc/self/statm");
  std::int64_t pages = 0;
  statm >> pages;
  ASSERT_GT(pages, 0);
  rlimit old{};
  ASSERT_EQ(getrlimit(RLIMIT_AS, &old), 0);
  rlimit tight = old;
  tight.rlim_cur = static_cast<rlim_t>(pages * sysconf(_SC_PAGESIZE) + extra_bytes);
  if (old.rlim_cur != RLIM_INFINITY && old.rlim_cur < tight.rlim_cur) tight.rlim_cur = old.rlim_cur;
  ASSERT_EQ(setrlimit(RLIMIT_AS, &tight), 0);
  call();
  ASSERT_EQ(setrlimit(RLIMIT_AS, &old), 0);
}

// Refused before anything of the problem is allocated: under a 256 MB allowance, each of these
// would otherwise fail with std::bad_alloc (or overflow its int indices). N_FE = 1700 on the
// crossing case passes IPOPT's Index (17000 unknowns) but its dense Newton Jacobian alone is
// 2.3 GB.
TEST(FesdLimitsTest, TooLargeProblemsAreRefusedBeforeAllocating) {
  const auto model = adapt_step(examples::CrossingCase{});
  const Eigen::VectorXd x0 = Eigen::VectorXd::Constant(1, -1.0);
  std::string huge, dense, steps;
  with_address_space_limit(std::int64_t{256} << 20, [&] {
    FesdOptions o;
    o.elements = static_cast<int>(kTwoTo30);
    huge = testing::message_of([&] { fesd_simulate(model, x0, 1.0, o); });
    o.elements = 1700;
    dense = testing::message_of([&] { fesd_simulate(model, x0, 1.0, o); });
    o.elements = 3;
    o.steps = kMaxInt;
    steps = testing::message_of([&] { fesd_simulate(model, x0, 1.0, o); });
  });
  EXPECT_EQ(huge,
            "fesd: N_FE = 1073741824 finite elements of n_s = 2 stages give 10737418240 NLP "
            "unknowns per integration step, above IPOPT's limit of 2147483647 (see docs/fesd.md)");
  EXPECT_EQ(dense,
            "fesd: N_FE = 1700 finite elements of n_s = 2 stages give 17000 NLP unknowns per "
            "integration step, needing about 4.6e+09 bytes, above the limit of 4 GiB = 4294967296 "
            "bytes (see docs/fesd.md)");
  EXPECT_THAT(steps, StartsWith("fesd: N_sim = 2147483647 integration steps of N_FE = 3 finite "
                                "elements give 6442450941 finite elements in all, needing about "));
  // The largest that fits runs (1636 elements on this model; measured by bisection).
  FesdOptions o;
  o.elements = 1636;
  EXPECT_EQ(fesd_problem_size(model, o).step_excess(), "");
  o.elements = 1637;
  EXPECT_THAT(fesd_problem_size(model, o).step_excess(), HasSubstr("above the limit"));
}

TEST(FesdLimitsTest, OptionsWithoutASizeAreNamed) {
  const auto model = adapt_step(examples::CrossingCase{});
  using testing::message_of;
  FesdOptions o;
  o.elements = 0;
  EXPECT_EQ(message_of([&] { fesd_problem_size(model, o); }),
            "fesd: need N_FE >= 1 and N_sim >= 1, got N_FE = 0, N_sim = 1");
  o.elements = 3;
  o.lifting_depth = -7;
  EXPECT_EQ(message_of([&] { fesd_problem_size(model, o); }),
            "fesd: the lifting depth n_d must be 0 (none) or >= 2, got -7");
  o.lifting_depth = 0;
  o.stages = 10;
  EXPECT_EQ(message_of([&] { fesd_problem_size(model, o); }),
            "radau tableau: stages must be in [1, 9], got 10");
}

// IPOPT stopped after one iteration fails every NLP: the step is halved 4 times and the run
// ends with one message, prefixed once, and IPOPT prints nothing (print_level 0, sb yes).
TEST(FesdLimitsTest, AFailedStepEndsWithOneMessageAndIpoptIsSilent) {
  FesdOptions o;
  o.newton = false;
  o.solver.ipopt_integer_options = {{"max_iter", 1}};
  const auto exact = examples::exact_switching_case("crossing");
  ::testing::internal::CaptureStdout();
  ::testing::internal::CaptureStderr();
  const FesdResult r =
      fesd_simulate(adapt_step(examples::CrossingCase{}), exact.x0, exact.t_end, o);
  const std::string printed = ::testing::internal::GetCapturedStdout();
  const std::string warned = ::testing::internal::GetCapturedStderr();
  EXPECT_EQ(printed, "");
  EXPECT_EQ(warned, "");
  EXPECT_EQ(r.status, FesdStatus::kStepFailed);
  EXPECT_EQ(r.halved_steps, 4);
  EXPECT_THAT(r.message, StartsWith("fesd: the integration step at t = 0 of length 0.0625 "
                                    "(halved 4 times) did not converge at sigma = 1: IPOPT "
                                    "status Maximum_Iterations_Exceeded, complementarity "
                                    "residual "));
  EXPECT_EQ(r.message.find("fesd:", 1), std::string::npos) << r.message;
  EXPECT_EQ(r.message.find('\n'), std::string::npos);
}

}  // namespace
}  // namespace bflow

// IPOPT's linear solver: unknown names refused with the list, HSL's solvers refused with the
// loader's reason when libhsl.so is missing (as on a stock Debian), before IPOPT runs (which
// would end the process for HSL_MA97), and an option IPOPT refuses at the solve reported as
// such rather than as a failed step.
#include "bflow/fesd/linear_solver.h"

#include <dlfcn.h>

#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "bflow/examples/switching_cases.h"
#include "bflow/fesd/fesd.h"
#include "support/error_message.h"

namespace bflow {
namespace {

using ::testing::StartsWith;

// What the dynamic loader says about `library`, independently of bflow ("" when it loads).
std::string loader_error(const char* library) {
  void* handle = dlopen(library, RTLD_NOW | RTLD_LOCAL);
  if (handle != nullptr) {
    dlclose(handle);
    return "";
  }
  return dlerror();
}

FesdResult simulate_crossing(const FesdOptions& options) {
  const auto exact = examples::exact_switching_case("crossing");
  return fesd_simulate(adapt_step(examples::CrossingCase{}), exact.x0, exact.t_end, options);
}

TEST(LinearSolverTest, UnknownNamesAreRefusedWithTheKnownOnes) {
  EXPECT_EQ(linear_solver_list(), "mumps, ma27, ma57, ma77, ma86, ma97 or pardiso");
  for (const char* name : {"ma99", "MUMPS", "", "wsmp", "custom"}) {
    bool unavailable = false;
    const std::string message = testing::message_of([&] {
      try {
        check_linear_solver(name, "fesd");
      } catch (const LinearSolverUnavailable&) {
        unavailable = true;
        throw;
      }
    });
    EXPECT_EQ(message, std::string("fesd: unknown linear solver \"") + name +
                           "\"; use mumps, ma27, ma57, ma77, ma86, ma97 or pardiso");
    EXPECT_FALSE(unavailable) << name << ": an unknown name is not a missing library";
  }
  FesdOptions o;
  o.linear_solver = "ma28";
  EXPECT_EQ(testing::message_of([&] { simulate_crossing(o); }),
            "fesd: unknown linear solver \"ma28\"; use mumps, ma27, ma57, ma77, ma86, ma97 or "
            "pardiso");
}

TEST(LinearSolverTest, EachSolverNamesItsLibrary) {
  EXPECT_EQ(linear_solver_library("mumps", "fesd"), "");
  for (const char* hsl : {"ma27", "ma57", "ma77", "ma86", "ma97"}) {
    EXPECT_EQ(linear_solver_library(hsl, "fesd"), "libhsl.so") << hsl;
  }
  EXPECT_EQ(linear_solver_library("pardiso", "fesd"), "libpardiso.so");
  EXPECT_NO_THROW(check_linear_solver("mumps", "fesd"));
  EXPECT_EQ(linear_solver_load_error("mumps", "libhsl.so"), "");
}

// A file that loads but lacks the solver (the C library stands in for a libhsl.so built
// without HSL_MA97), and a path that does not exist.
TEST(LinearSolverTest, TheLoadErrorNamesTheMissingRoutineOrTheLoadersReason) {
  EXPECT_EQ(linear_solver_load_error("ma97", "libc.so.6"),
            "libc.so.6 has no routine ma97_default_control_d (nor ma97_default_control_d_): it "
            "was built without HSL_MA97");
  EXPECT_EQ(linear_solver_load_error("ma27", "libc.so.6"),
            "libc.so.6 has no routine ma27ad (nor ma27ad_): it was built without MA27");
  EXPECT_EQ(linear_solver_load_error("ma27", "/nonexistent/libhsl.so"),
            "/nonexistent/libhsl.so: cannot open shared object file: No such file or directory");
}

// Without libhsl.so every HSL solver is refused up front, naming the solver, the file, the
// loader's reason and where to get HSL; fesd_simulate refuses it before any step (IPOPT itself
// would end the process for ma97).
TEST(LinearSolverTest, AMissingLibhslIsReportedBeforeIpoptRuns) {
  const std::string reason = loader_error("libhsl.so");
  if (reason.empty()) GTEST_SKIP() << "libhsl.so is installed here";
  EXPECT_THAT(reason, StartsWith("libhsl.so: "));
  for (const char* name : {"ma27", "ma57", "ma77", "ma86", "ma97"}) {
    EXPECT_EQ(linear_solver_load_error(name, "libhsl.so"), reason) << name;
    EXPECT_THROW(check_linear_solver(name, "fesd"), LinearSolverUnavailable) << name;
  }
  FesdOptions o;
  o.linear_solver = "ma97";
  o.newton = false;
  std::string message;
  try {
    simulate_crossing(o);
    ADD_FAILURE() << "expected LinearSolverUnavailable";
  } catch (const LinearSolverUnavailable& e) {
    message = e.what();
  }
  EXPECT_EQ(message,
            "fesd: linear solver \"ma97\" needs HSL's libhsl.so, which cannot be loaded (" +
                reason +
                "); get Coin-HSL (https://licences.stfc.ac.uk/product/coin-hsl), build "
                "libhsl.so and put the directory holding libhsl.so on LD_LIBRARY_PATH "
                "(docs/ocp.md, \"Linear solvers: MUMPS and HSL\"), or use mumps");
  // The caller's string option wins over linear_solver, and is checked the same way.
  o.linear_solver = "mumps";
  o.ipopt_string_options = {{"linear_solver", "ma27"}};
  EXPECT_THROW(simulate_crossing(o), LinearSolverUnavailable);
}

TEST(LinearSolverTest, AMissingPardisoLibraryIsReportedToo) {
  const std::string reason = loader_error("libpardiso.so");
  if (reason.empty()) GTEST_SKIP() << "libpardiso.so is installed here";
  const std::string message = testing::message_of([] { check_linear_solver("pardiso", "ocp"); });
  EXPECT_EQ(message,
            "ocp: linear solver \"pardiso\" needs PARDISO's libpardiso.so, which cannot "
            "be loaded (" +
                reason +
                "); put the directory holding libpardiso.so on LD_LIBRARY_PATH "
                "(docs/ocp.md, \"Linear solvers: MUMPS and HSL\"), or use mumps");
}

// MUMPS explicitly is the default.
TEST(LinearSolverTest, MumpsExplicitlyIsTheDefault) {
  FesdOptions o;
  o.newton = false;
  const FesdResult by_default = simulate_crossing(o);
  o.linear_solver = "mumps";
  const FesdResult explicit_mumps = simulate_crossing(o);
  ASSERT_TRUE(by_default.ok()) << by_default.message;
  ASSERT_TRUE(explicit_mumps.ok()) << explicit_mumps.message;
  EXPECT_EQ(explicit_mumps.x_end, by_default.x_end);
  EXPECT_EQ(explicit_mumps.switch_times, by_default.switch_times);
  EXPECT_EQ(explicit_mumps.nlp_iterations, by_default.nlp_iterations);
}

// An option IPOPT takes but refuses at the solve (MC19 scaling without libhsl.so) ends the run
// with InvalidArgument, not as a step that failed to converge (halved four times).
TEST(LinearSolverTest, InvalidOptionAtTheSolveIsRefusedNotAFailedStep) {
  if (loader_error("libhsl.so").empty()) GTEST_SKIP() << "libhsl.so is installed here";
  FesdOptions o;
  o.newton = false;
  o.ipopt_string_options = {{"linear_system_scaling", "mc19"}};
  const std::string message = testing::message_of([&] { simulate_crossing(o); });
  EXPECT_EQ(message,
            "fesd: IPOPT refused its options (Invalid_Option) with linear solver \"mumps\"; "
            "print_level 5 shows IPOPT's reason");
}

}  // namespace
}  // namespace bflow

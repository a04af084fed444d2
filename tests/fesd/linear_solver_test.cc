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

#if defined(__has_feature)
#if __has_feature(address_sanitizer)
#define BFLOW_TEST_ADDRESS_SANITIZER 1
#endif
#endif
#if defined(__SANITIZE_ADDRESS__)
#define BFLOW_TEST_ADDRESS_SANITIZER 1
#endif

namespace bflow {
namespace {

#ifdef BFLOW_TEST_ADDRESS_SANITIZER
constexpr bool kAddressSanitizer = true;
#else
constexpr bool kAddressSanitizer = false;
#endif

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
  EXPECT_EQ(linear_solver_list(),
            "mumps, spral, ma27, ma57, ma77, ma86, ma97, pardiso or pardisomkl");
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
    EXPECT_EQ(message,
              std::string("fesd: unknown linear solver \"") + name +
                  "\"; use mumps, spral, ma27, ma57, ma77, ma86, ma97, pardiso or pardisomkl");
    EXPECT_FALSE(unavailable) << name << ": an unknown name is not a missing library";
  }
  FesdOptions o;
  o.solver.linear_solver = "ma28";
  EXPECT_EQ(testing::message_of([&] { simulate_crossing(o); }),
            "fesd: unknown linear solver \"ma28\"; use mumps, spral, ma27, ma57, ma77, ma86, ma97, "
            "pardiso or pardisomkl");
}

// IPOPT 3.14 names the HSL library by option (hsllib): bflow tries Coin-HSL's own file name
// first; IPOPT 3.11 loads only libhsl.so.
bool ipopt_3_14() { return std::string(BFLOW_TEST_IPOPT_VERSION).rfind("3.14", 0) == 0; }

TEST(LinearSolverTest, EachSolverNamesItsLibrary) {
  for (const char* linked : {"mumps", "spral", "pardisomkl"}) {
    EXPECT_EQ(linear_solver_library(linked, "fesd"), "") << linked;
  }
  for (const char* hsl : {"ma27", "ma57", "ma77", "ma86", "ma97"}) {
    EXPECT_EQ(linear_solver_library(hsl, "fesd"),
              ipopt_3_14() ? "libcoinhsl.so libhsl.so" : "libhsl.so")
        << hsl;
  }
  EXPECT_EQ(linear_solver_library("pardiso", "fesd"), "libpardiso.so");
  EXPECT_EQ(check_linear_solver("mumps", "fesd"), "");
  EXPECT_EQ(linear_solver_load_error("mumps", "libhsl.so"), "");
  // A linked solver takes no library.
  EXPECT_EQ(testing::message_of([] { check_linear_solver("mumps", "libcoinhsl.so", "ocp"); }),
            "ocp: linear solver \"mumps\" is linked into IPOPT; it takes no library "
            "(\"libcoinhsl.so\")");
}

// The stack the results name is the one configure found in IPOPT's and MUMPS's headers.
TEST(LinearSolverTest, ResultsNameTheIpoptAndTheLinearSolverWithTheirVersions) {
  EXPECT_EQ(ipopt_description(), std::string("IPOPT ") + BFLOW_TEST_IPOPT_VERSION);
  EXPECT_EQ(linear_solver_description("mumps", ""),
            std::string("mumps ") + BFLOW_TEST_MUMPS_VERSION);
  EXPECT_EQ(linear_solver_description("ma57", "libcoinhsl.so"), "ma57 (libcoinhsl.so)");
  EXPECT_EQ(mumps_interposed(), BFLOW_TEST_MUMPS_INTERPOSER != 0);
  FesdOptions o;
  o.newton = false;
  const FesdResult r = simulate_crossing(o);
  ASSERT_TRUE(r.ok()) << r.message;
  EXPECT_EQ(r.ipopt, std::string("IPOPT ") + BFLOW_TEST_IPOPT_VERSION);
  EXPECT_EQ(r.linear_solver, std::string("mumps ") + BFLOW_TEST_MUMPS_VERSION);
}

// SPRAL where IPOPT has it (IPOPT 3.14 of the default build), with the crossing's exact
// solution; refused naming the build's IPOPT where not.
TEST(LinearSolverTest, SpralSolvesWhereIpoptHasItAndIsRefusedElsewhere) {
  const auto exact = examples::exact_switching_case("crossing");
  FesdOptions o;
  o.newton = false;
  o.solver.linear_solver = "spral";
  if (!BFLOW_TEST_HAS_SPRAL) {
    bool unavailable = false;
    const std::string message = testing::message_of([&] {
      try {
        simulate_crossing(o);
      } catch (const LinearSolverUnavailable&) {
        unavailable = true;
        throw;
      }
    });
    EXPECT_TRUE(unavailable);
    EXPECT_EQ(message, "fesd: linear solver \"spral\" (SPRAL) is not in this build's IPOPT " +
                           std::string(BFLOW_TEST_IPOPT_VERSION) +
                           "; configure with -DBFLOW_IPOPT=wheel (IPOPT 3.14 with SPRAL, "
                           "scripts/install-deps), or use mumps");
    return;
  }
  const FesdResult r = simulate_crossing(o);
  ASSERT_TRUE(r.ok()) << r.message;
  EXPECT_EQ(r.linear_solver, std::string("spral (IPOPT ") + BFLOW_TEST_IPOPT_VERSION + "'s)");
  ASSERT_EQ(r.switch_times.size(), 1u);
  EXPECT_NEAR(r.switch_times[0], exact.switch_times[0], 1e-9);
  EXPECT_NEAR(r.x_end[0], exact.x_end[0], 1e-9);
}

// MKL's PARDISO only where IPOPT was built with MKL: the wheel's IPOPT has no MKL.
TEST(LinearSolverTest, PardisoMklIsRefusedWithoutMkl) {
  try {
    check_linear_solver("pardisomkl", "ocp");
  } catch (const LinearSolverUnavailable& e) {
    EXPECT_EQ(std::string(e.what()),
              "ocp: linear solver \"pardisomkl\" (MKL's PARDISO) is not in this build's IPOPT " +
                  std::string(BFLOW_TEST_IPOPT_VERSION) +
                  "; it needs an IPOPT built with Intel MKL, or use mumps");
  }
}

// A named HSL library: with IPOPT 3.14 loaded by that name and refused with the loader's
// reason; IPOPT 3.11 loads only libhsl.so and refuses any name before trying it.
TEST(LinearSolverTest, ANamedHslLibraryIsLoadedByItsNameOrRefused) {
  const std::string path = "/nonexistent/libcoinhsl.so";
  const std::string message =
      testing::message_of([&] { check_linear_solver("ma57", path, "fesd"); });
  if (ipopt_3_14()) {
    EXPECT_EQ(message, "fesd: linear solver \"ma57\" needs HSL's " + path +
                           ", which cannot be loaded (" + path +
                           ": cannot open shared object file: No such file or directory); name "
                           "a library that holds MA57 (docs/ocp.md, \"Linear solvers\"), or use "
                           "mumps");
  } else {
    EXPECT_EQ(message, "fesd: this build's IPOPT " + std::string(BFLOW_TEST_IPOPT_VERSION) +
                           " loads its linear solvers from fixed names (libhsl.so, "
                           "libpardiso.so) and cannot load \"" +
                           path + "\"; configure with -DBFLOW_IPOPT=wheel for IPOPT 3.14");
  }
  // The C library loads but has no MA57: named as such.
  if (ipopt_3_14()) {
    EXPECT_THAT(testing::message_of([] { check_linear_solver("ma57", "libc.so.6", "fesd"); }),
                ::testing::HasSubstr("(libc.so.6 has no routine ma57ad (nor ma57ad_): it was "
                                     "built without MA57)"));
  }
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

// The message of a missing HSL library: the solver, the first file tried with the loader's
// reason, where to get Coin-HSL and where to put it.
void expect_missing_hsl(const std::string& message, const std::string& who,
                        const std::string& name) {
  const std::string files = linear_solver_library(name, who);
  const std::string first = files.substr(0, files.find(' '));
  EXPECT_THAT(message, StartsWith(who + ": linear solver \"" + name + "\" needs HSL's " + first));
  EXPECT_THAT(message,
              ::testing::HasSubstr("which cannot be loaded (" + loader_error(first.c_str()) +
                                   "); get Coin-HSL "
                                   "(https://licences.stfc.ac.uk/product/coin-hsl)"));
  EXPECT_THAT(message,
              ::testing::HasSubstr("the directory holding " + first + " on LD_LIBRARY_PATH"));
  EXPECT_THAT(message, ::testing::EndsWith("(docs/ocp.md, \"Linear solvers\"), or use mumps"));
}

// Without Coin-HSL every HSL solver is refused up front, naming the solver, the file, the
// loader's reason and where to get HSL; fesd_simulate refuses it before any step (IPOPT itself
// would end the process for ma97).
TEST(LinearSolverTest, AMissingHslLibraryIsReportedBeforeIpoptRuns) {
  if (loader_error("libhsl.so").empty() || loader_error("libcoinhsl.so").empty())
    GTEST_SKIP() << "an HSL library is installed here";
  for (const char* name : {"ma27", "ma57", "ma77", "ma86", "ma97"}) {
    EXPECT_EQ(linear_solver_load_error(name, "libhsl.so"), loader_error("libhsl.so")) << name;
    EXPECT_THROW(check_linear_solver(name, "fesd"), LinearSolverUnavailable) << name;
  }
  FesdOptions o;
  o.solver.linear_solver = "ma97";
  o.newton = false;
  std::string message;
  try {
    simulate_crossing(o);
    ADD_FAILURE() << "expected LinearSolverUnavailable";
  } catch (const LinearSolverUnavailable& e) {
    message = e.what();
  }
  expect_missing_hsl(message, "fesd", "ma97");
  // The caller's string option wins over linear_solver, and is checked the same way.
  o.solver.linear_solver = "mumps";
  o.solver.ipopt_string_options = {{"linear_solver", "ma27"}};
  EXPECT_THROW(simulate_crossing(o), LinearSolverUnavailable);
}

TEST(LinearSolverTest, AMissingPardisoLibraryIsReportedToo) {
  const std::string reason = loader_error("libpardiso.so");
  if (reason.empty()) GTEST_SKIP() << "libpardiso.so is installed here";
  const std::string message = testing::message_of([] { check_linear_solver("pardiso", "ocp"); });
  EXPECT_EQ(message,
            "ocp: linear solver \"pardiso\" needs PARDISO's libpardiso.so, which cannot "
            "be loaded (" +
                reason + "); put the directory holding libpardiso.so on LD_LIBRARY_PATH" +
                (ipopt_3_14() ? " or name the file (linear_solver_library, "
                                "--linear-solver-library)"
                              : "") +
                " (docs/ocp.md, \"Linear solvers\"), or use mumps");
}

// MUMPS explicitly is the default.
TEST(LinearSolverTest, MumpsExplicitlyIsTheDefault) {
  FesdOptions o;
  o.newton = false;
  const FesdResult by_default = simulate_crossing(o);
  o.solver.linear_solver = "mumps";
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
  // IPOPT 3.14 opens the HSL library with RTLD_DEEPBIND, which AddressSanitizer's dlopen
  // refuses by ending the process (google/sanitizers#611).
  if (kAddressSanitizer && ipopt_3_14())
    GTEST_SKIP() << "IPOPT 3.14 loads HSL with RTLD_DEEPBIND, which AddressSanitizer refuses";
  FesdOptions o;
  o.newton = false;
  o.solver.ipopt_string_options = {{"linear_system_scaling", "mc19"}};
  const std::string message = testing::message_of([&] { simulate_crossing(o); });
  EXPECT_EQ(message,
            "fesd: IPOPT refused its options (Invalid_Option) with linear solver \"mumps\"; "
            "print_level 5 shows IPOPT's reason");
}

}  // namespace
}  // namespace bflow

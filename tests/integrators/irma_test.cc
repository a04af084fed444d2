// IRMA ([F] Section 7.1): the closed-form chain of exponentials (examples/irma.h) against the
// event-driven engine, two independent computations of the same switch times and x(T).
#include "bflow/examples/irma.h"

#include <gtest/gtest.h>

#include "bflow/fesd/fesd.h"
#include "bflow/integrators/hybrid_flow.h"
#include "bflow/integrators/model_adapter.h"

namespace bflow {
namespace {

using examples::Irma;

TEST(IrmaTest, ExactSolutionSitsOnItsThresholdsAndRelaxesBetweenThem) {
  const Irma irma;
  const examples::IrmaSolution exact = examples::exact_irma(irma, Irma::initial_state(), 100.0);
  ASSERT_GE(exact.switches.size(), 2u);
  for (std::size_t k = 1; k < exact.switches.size(); ++k) {
    EXPECT_GT(exact.switches[k].t, exact.switches[k - 1].t);
  }
  // Restarting from a switch state reproduces the rest of the solution (the chain is
  // consistent with itself), to rounding.
  const double t_switch = exact.switches[1].t;
  const examples::IrmaSolution first =
      examples::exact_irma(irma, Irma::initial_state(), t_switch + 1e-3);
  const examples::IrmaSolution rest = examples::exact_irma(irma, first.x, 100.0 - t_switch - 1e-3);
  EXPECT_LE((rest.x - exact.x).cwiseAbs().maxCoeff(), 1e-15);
}

TEST(IrmaTest, EventDrivenEngineMeetsTheExactSwitchTimesAndState) {
  const Irma irma;
  const double t_end = 100.0;
  const examples::IrmaSolution exact = examples::exact_irma(irma, Irma::initial_state(), t_end);
  const auto model = adapt(EventDrivenView<Irma>{irma});
  FlowOptions options;
  options.integrator.rtol = 1e-12;
  options.integrator.atol = 1e-15;
  const FlowResult r = simulate(model, Irma::initial_state(), t_end, options);
  ASSERT_TRUE(r.ok()) << r.message;
  ASSERT_EQ(r.events.size(), exact.switches.size());
  for (std::size_t k = 0; k < exact.switches.size(); ++k) {
    EXPECT_NEAR(r.events[k].t, exact.switches[k].t, 1e-8) << "switch " << k;
    ASSERT_EQ(r.events[k].surfaces.size(), 1u);
    EXPECT_EQ(r.events[k].surfaces[0], exact.switches[k].surface) << "switch " << k;
  }
  // States are O(0.01 - 1); rtol 1e-12 over ~100 minutes of relaxation.
  EXPECT_LE((r.x - exact.x).cwiseAbs().maxCoeff(), 1e-10);
}

}  // namespace
}  // namespace bflow

// The integration order of FESD on IRMA ([F] Figure 6): the first 100 minutes, N_FE = 3,
// N_sim = 8, 16, 32, error against the closed form. FESD keeps the order of its Runge-Kutta
// scheme across the switches: Radau IIA 1 and 2 stages (orders 1 and 3), Gauss-Legendre 1
// stage (order 2); fitted slopes within 0.5. bench/fesd_order.cc runs the full experiment.
#include <cmath>
#include <vector>

#include <gtest/gtest.h>

#include "bflow/examples/irma.h"
#include "bflow/integrators/fesd.h"

namespace bflow {
namespace {

// Least-squares slope of log error against log h.
double fitted_order(CollocationScheme scheme, int stages) {
  const examples::Irma irma;
  const double t_end = 100.0;
  const auto exact = examples::exact_irma(irma, examples::Irma::initial_state(), t_end);
  const auto model = adapt_step(irma);
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  int n = 0;
  for (int steps : {8, 16, 32}) {
    FesdOptions o;
    o.scheme = scheme;
    o.stages = stages;
    o.steps = steps;
    o.sensitivities = false;
    const FesdResult r = fesd_simulate(model, examples::Irma::initial_state(), t_end, o);
    EXPECT_TRUE(r.ok()) << r.message;
    const double error = (r.x_end - exact.x).cwiseAbs().maxCoeff();
    const double x = std::log(t_end / (3.0 * steps)), y = std::log(error);
    sx += x;
    sy += y;
    sxx += x * x;
    sxy += x * y;
    ++n;
  }
  return (n * sxy - sx * sy) / (n * sxx - sx * sx);
}

// Measured: 1.07, 3.2 and 2.1.
TEST(FesdOrderTest, RadauAndGaussKeepTheirOrderAcrossTheSwitches) {
  EXPECT_NEAR(fitted_order(CollocationScheme::kRadauIIA, 1), 1.0, 0.5);
  EXPECT_NEAR(fitted_order(CollocationScheme::kRadauIIA, 2), 3.0, 0.5);
  EXPECT_NEAR(fitted_order(CollocationScheme::kGaussLegendre, 1), 2.0, 0.5);
}

}  // namespace
}  // namespace bflow

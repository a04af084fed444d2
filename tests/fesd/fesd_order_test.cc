// The integration order of FESD on IRMA ([F] Figure 6): the first 100 minutes, N_FE = 3,
// error against the closed form. FESD keeps the order of its Runge-Kutta scheme across the
// switches: Radau IIA 1, 2 and 3 stages (orders 1, 3, 5), Gauss-Legendre 1 and 2 stages (orders
// 2 and 4); fitted slopes within 0.5, on N_sim where the error is above round-off.
// bench/fesd_order.cc runs the full experiment (N_sim 1 to 300, 4 stages too).
#include <cmath>
#include <initializer_list>
#include <vector>

#include <gtest/gtest.h>

#include "bflow/examples/irma.h"
#include "bflow/fesd/fesd.h"

namespace bflow {
namespace {

// Least-squares slope of log error against log h.
double fitted_order(CollocationScheme scheme, int stages, std::initializer_list<int> n_sim) {
  const examples::Irma irma;
  const double t_end = 100.0;
  const auto exact = examples::exact_irma(irma, examples::Irma::initial_state(), t_end);
  const auto model = adapt_step(irma);
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  int n = 0;
  for (int steps : n_sim) {
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

// Measured: 1.07, 3.2, 5.41, 2.1 and 4.26.
TEST(FesdOrderTest, RadauAndGaussKeepTheirOrderAcrossTheSwitches) {
  EXPECT_NEAR(fitted_order(CollocationScheme::kRadauIIA, 1, {8, 16, 32}), 1.0, 0.5);
  EXPECT_NEAR(fitted_order(CollocationScheme::kRadauIIA, 2, {8, 16, 32}), 3.0, 0.5);
  EXPECT_NEAR(fitted_order(CollocationScheme::kRadauIIA, 3, {16, 32, 64}), 5.0, 0.5);
  EXPECT_NEAR(fitted_order(CollocationScheme::kGaussLegendre, 1, {8, 16, 32}), 2.0, 0.5);
  EXPECT_NEAR(fitted_order(CollocationScheme::kGaussLegendre, 2, {16, 32, 64}), 4.0, 0.5);
}

}  // namespace
}  // namespace bflow

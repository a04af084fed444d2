#include "bflow/integrators/dopri5.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <utility>

#include "bflow/core/errors.h"

namespace bflow {

const char* to_string(IntegrationStatus status) {
  switch (status) {
    case IntegrationStatus::kReachedEnd:
      return "reached the end";
    case IntegrationStatus::kCrossing:
      return "surface crossing";
    case IntegrationStatus::kStepSizeUnderflow:
      return "step-size underflow";
    case IntegrationStatus::kTooManySteps:
      return "too many steps";
    case IntegrationStatus::kNonFinite:
      return "non-finite state";
    case IntegrationStatus::kSolverFailure:
      return "solver failure";
    case IntegrationStatus::kTooManyEvents:
      return "too many events";
    case IntegrationStatus::kOverflow:
      return "overflow";
  }
  return "unknown";
}

namespace {

// Dormand & Prince (1980) tableau and Hairer's dense output of order 4.
constexpr double c2 = 1.0 / 5, c3 = 3.0 / 10, c4 = 4.0 / 5, c5 = 8.0 / 9;
constexpr double a21 = 1.0 / 5;
constexpr double a31 = 3.0 / 40, a32 = 9.0 / 40;
constexpr double a41 = 44.0 / 45, a42 = -56.0 / 15, a43 = 32.0 / 9;
constexpr double a51 = 19372.0 / 6561, a52 = -25360.0 / 2187, a53 = 64448.0 / 6561,
                 a54 = -212.0 / 729;
constexpr double a61 = 9017.0 / 3168, a62 = -355.0 / 33, a63 = 46732.0 / 5247, a64 = 49.0 / 176,
                 a65 = -5103.0 / 18656;
constexpr double a71 = 35.0 / 384, a73 = 500.0 / 1113, a74 = 125.0 / 192, a75 = -2187.0 / 6784,
                 a76 = 11.0 / 84;
constexpr double e1 = 71.0 / 57600, e3 = -71.0 / 16695, e4 = 71.0 / 1920, e5 = -17253.0 / 339200,
                 e6 = 22.0 / 525, e7 = -1.0 / 40;
constexpr double d1 = -12715105075.0 / 11282082432, d3 = 87487479700.0 / 32700410799,
                 d4 = -10690763975.0 / 1880347072, d5 = 701980252875.0 / 199316789632,
                 d6 = -1453857185.0 / 822651844, d7 = 69997945.0 / 29380423;

double value_of(double x) { return x; }
template <int N>
double value_of(const ceres::Jet<double, N>& x) {
  return x.a;
}
bool all_finite(double x) { return std::isfinite(x); }
template <int N>
bool all_finite(const ceres::Jet<double, N>& x) {
  return std::isfinite(x.a) && x.v.allFinite();
}
// Per-direction accumulators of the tangent error norm: for each tangent direction c, the
// squared Euclidean norms of its local error and of the tangent at the step's two ends. Empty for
// double.
template <typename T>
struct TangentNorm {
  void clear() {}
  void add(const T&, const T&, const T&) {}
  void add_damped(const T&, const T&, const T&, const T&) {}
  double error(double, double) const { return 0.0; }
};
template <int N>
struct TangentNorm<ceres::Jet<double, N>> {
  using Jet = ceres::Jet<double, N>;
  Eigen::Array<double, N, 1> error_sq, low_sq, size0_sq, size1_sq;
  bool damped = false;
  void clear() {
    error_sq.setZero();
    low_sq.setZero();
    size0_sq.setZero();
    size1_sq.setZero();
    damped = false;
  }
  /** A component's local error estimate err (its tangent parts) at a step x0 -> x1. */
  void add(const Jet& err, const Jet& x0, const Jet& x1) {
    error_sq += err.v.array().square();
    size0_sq += x0.v.array().square();
    size1_sq += x1.v.array().square();
  }
  /** The same for a pair whose estimate is `high` damped by a lower-order one, `low` (DOP853). */
  void add_damped(const Jet& high, const Jet& low, const Jet& x0, const Jet& x1) {
    add(high, x0, x1);
    low_sq += low.v.array().square();
    damped = true;
  }
  // max over directions c of |e_c| / (atol + rtol max(|v_c(t)|, |v_c(t + h)|)), Euclidean norms:
  // each direction is held to rtol relative to its own size, the way a derivative's accuracy is
  // judged (|D dx - D_ref dx| / |D_ref dx|), not to the state's per-component scale.
  // Damped (DOP853), e_c is each direction's own |e5_c| gamma_c, gamma_c = |e5_c| / sqrt(|e5_c|^2 +
  // 0.01 |e3_c|^2): DOP853's rule applied to that direction as if it were a system of its own.
  // The state's gamma would not do: it is 0 wherever the state's estimate is (an equilibrium),
  // whatever the tangents do.
  double error(double rtol, double atol) const {
    const auto scale = atol + rtol * size0_sq.max(size1_sq).sqrt();
    if (!damped) return (error_sq.sqrt() / scale).maxCoeff();
    // |e5|^2 <= denominator^2, so the floor (reached only when both are 0) gives 0, not 0 / 0.
    const Eigen::Array<double, N, 1> denominator =
        (error_sq + 0.01 * low_sq).sqrt().max(std::numeric_limits<double>::min());
    return (error_sq / denominator / scale).maxCoeff();
  }
};

// The Dormand-Prince 5(4) pair (Hairer, Norsett & Wanner, Solving ODEs I, II.5), first same as
// last (stage 7 is F at the new point), with Hairer's dense output of order 4.
template <typename T>
class Dp54Stages {
 public:
  static constexpr const char* kName = "dopri5";
  /** Step-size control: h *= 0.9 error^(-kExponent), 1 / (order of the error estimate + 1). */
  static constexpr double kExponent = 0.2;
  explicit Dp54Stages(int d) : d_(d), k1_(d), k2_(d), k3_(d), k4_(d), k5_(d), k6_(d), k7_(d) {}
  /** F at the step's start (filled by the caller before the first step). */
  std::vector<T>& first() { return k1_; }
  /** F at the trial step's end. */
  const std::vector<T>& last() const { return k7_; }

  // One trial step from x into next; field(in, out, t) evaluates F_b.
  template <typename Field>
  void attempt(const std::vector<T>& x, double h, double t, std::vector<T>& stage,
               std::vector<T>& next, Field&& field) {
    for (int i = 0; i < d_; ++i) stage[i] = x[i] + h * (a21 * k1_[i]);
    field(stage, k2_, t + c2 * h);
    for (int i = 0; i < d_; ++i) stage[i] = x[i] + h * (a31 * k1_[i] + a32 * k2_[i]);
    field(stage, k3_, t + c3 * h);
    for (int i = 0; i < d_; ++i) {
      stage[i] = x[i] + h * (a41 * k1_[i] + a42 * k2_[i] + a43 * k3_[i]);
    }
    field(stage, k4_, t + c4 * h);
    for (int i = 0; i < d_; ++i) {
      stage[i] = x[i] + h * (a51 * k1_[i] + a52 * k2_[i] + a53 * k3_[i] + a54 * k4_[i]);
    }
    field(stage, k5_, t + c5 * h);
    for (int i = 0; i < d_; ++i) {
      stage[i] =
          x[i] + h * (a61 * k1_[i] + a62 * k2_[i] + a63 * k3_[i] + a64 * k4_[i] + a65 * k5_[i]);
    }
    field(stage, k6_, t + h);
    for (int i = 0; i < d_; ++i) {
      next[i] =
          x[i] + h * (a71 * k1_[i] + a73 * k3_[i] + a74 * k4_[i] + a75 * k5_[i] + a76 * k6_[i]);
    }
    field(next, k7_, t + h);
  }
  /** The accepted step's end becomes the next step's start. */
  void accept() { k1_.swap(k7_); }
  template <typename Scale>
  void prepare_error(double, const Scale&) {}
  /** The local error estimate of component i. */
  T error(int i, double h) const {
    return h * (e1 * k1_[i] + e3 * k3_[i] + e4 * k4_[i] + e5 * k5_[i] + e6 * k6_[i] + e7 * k7_[i]);
  }
  /** Component i's share of the tangents' error norm, given its error(i, h). */
  void add_tangent_error(int, double, const T& error, const T& x0, const T& x1,
                         TangentNorm<T>& norm) const {
    norm.add(error, x0, x1);
  }
  template <typename Field>
  void prepare_dense(const std::vector<T>&, double, double, std::vector<T>&, Field&&) {}
  /** Component i at theta on the dense output of the step x -> next. */
  T dense(int i, const T& x, const T& next, double h, double theta) const {
    const double theta1 = 1.0 - theta;
    const T r2 = next - x;
    const T r3 = h * k1_[i] - r2;
    const T r4 = r2 - h * k7_[i] - r3;
    const T r5 =
        h * (d1 * k1_[i] + d3 * k3_[i] + d4 * k4_[i] + d5 * k5_[i] + d6 * k6_[i] + d7 * k7_[i]);
    return x + theta * (r2 + theta1 * (r3 + theta * (r4 + theta1 * r5)));
  }
  /** The same, values only. */
  double dense_value(int i, double x, double next, double h, double theta) const {
    const double theta1 = 1.0 - theta;
    const double r2 = next - x;
    const double r3 = h * value_of(k1_[i]) - r2;
    const double r4 = r2 - h * value_of(k7_[i]) - r3;
    const double r5 = h * (d1 * value_of(k1_[i]) + d3 * value_of(k3_[i]) + d4 * value_of(k4_[i]) +
                           d5 * value_of(k5_[i]) + d6 * value_of(k6_[i]) + d7 * value_of(k7_[i]));
    return x + theta * (r2 + theta1 * (r3 + theta * (r4 + theta1 * r5)));
  }

 private:
  int d_;
  std::vector<T> k1_, k2_, k3_, k4_, k5_, k6_, k7_;
};

// Dormand & Prince's 8(5,3) pair as in Hairer's DOP853 (Solving ODEs I, II.10): 12 stages and
// F at the new point (stage 13, first same as last), the error estimate of order 5 damped by the
// one of order 3, and a dense output of order 7 that takes three more stages, evaluated only
// for a step whose dense output is used (a crossing located in it).
namespace dp853 {
// The coefficients of DOP853 (rows 13-15 of kA and kC: the dense output's extra stages).
constexpr double kC[16] = {0.0,
                           0.05260015195876773,
                           0.0789002279381516,
                           0.1183503419072274,
                           0.2816496580927726,
                           0.3333333333333333,
                           0.25,
                           0.3076923076923077,
                           0.6512820512820513,
                           0.6,
                           0.8571428571428571,
                           1.0,
                           1.0,
                           0.1,
                           0.2,
                           0.7777777777777778};
constexpr double kB[12] = {0.054293734116568765,
                           0.0,
                           0.0,
                           0.0,
                           0.0,
                           4.450312892752409,
                           1.8915178993145003,
                           -5.801203960010585,
                           0.3111643669578199,
                           -0.1521609496625161,
                           0.20136540080403034,
                           0.04471061572777259};
constexpr double kE3[13] = {-0.18980075407240762,
                            0.0,
                            0.0,
                            0.0,
                            0.0,
                            4.450312892752409,
                            1.8915178993145003,
                            -5.801203960010585,
                            -0.4226823213237919,
                            -0.1521609496625161,
                            0.20136540080403034,
                            0.02265179219836082,
                            0.0};
constexpr double kE5[13] = {0.01312004499419488,
                            0.0,
                            0.0,
                            0.0,
                            0.0,
                            -1.2251564463762044,
                            -0.4957589496572502,
                            1.6643771824549864,
                            -0.35032884874997366,
                            0.3341791187130175,
                            0.08192320648511571,
                            -0.022355307863886294,
                            0.0};
constexpr double kA[16][16] = {
    {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
    {0.05260015195876773, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
     0.0},
    {0.0197250569845379, 0.0591751709536137, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
     0.0, 0.0, 0.0},
    {0.02958758547680685, 0.0, 0.08876275643042054, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
     0.0, 0.0, 0.0, 0.0},
    {0.2413651341592667, 0.0, -0.8845494793282861, 0.924834003261792, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
     0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
    {0.037037037037037035, 0.0, 0.0, 0.17082860872947386, 0.12546768756682242, 0.0, 0.0, 0.0, 0.0,
     0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
    {0.037109375, 0.0, 0.0, 0.17025221101954405, 0.06021653898045596, -0.017578125, 0.0, 0.0, 0.0,
     0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
    {0.03709200011850479, 0.0, 0.0, 0.17038392571223998, 0.10726203044637328, -0.015319437748624402,
     0.008273789163814023, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
    {0.6241109587160757, 0.0, 0.0, -3.3608926294469414, -0.868219346841726, 27.59209969944671,
     20.154067550477894, -43.48988418106996, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0},
    {0.47766253643826434, 0.0, 0.0, -2.4881146199716677, -0.590290826836843, 21.230051448181193,
     15.279233632882423, -33.28821096898486, -0.020331201708508627, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
     0.0},
    {-0.9371424300859873, 0.0, 0.0, 5.186372428844064, 1.0914373489967295, -8.149787010746927,
     -18.52006565999696, 22.739487099350505, 2.4936055526796523, -3.0467644718982196, 0.0, 0.0, 0.0,
     0.0, 0.0, 0.0},
    {2.273310147516538, 0.0, 0.0, -10.53449546673725, -2.0008720582248625, -17.9589318631188,
     27.94888452941996, -2.8589982771350235, -8.87285693353063, 12.360567175794303,
     0.6433927460157636, 0.0, 0.0, 0.0, 0.0, 0.0},
    {0.054293734116568765, 0.0, 0.0, 0.0, 0.0, 4.450312892752409, 1.8915178993145003,
     -5.801203960010585, 0.3111643669578199, -0.1521609496625161, 0.20136540080403034,
     0.04471061572777259, 0.0, 0.0, 0.0, 0.0},
    {0.056167502283047954, 0.0, 0.0, 0.0, 0.0, 0.0, 0.25350021021662483, -0.2462390374708025,
     -0.12419142326381637, 0.15329179827876568, 0.00820105229563469, 0.007567897660545699,
     -0.008298, 0.0, 0.0, 0.0},
    {0.03183464816350214, 0.0, 0.0, 0.0, 0.0, 0.028300909672366776, 0.053541988307438566,
     -0.05492374857139099, 0.0, 0.0, -0.00010834732869724932, 0.0003825710908356584,
     -0.00034046500868740456, 0.1413124436746325, 0.0, 0.0},
    {-0.42889630158379194, 0.0, 0.0, 0.0, 0.0, -4.697621415361164, 7.683421196062599,
     4.06898981839711, 0.3567271874552811, 0.0, 0.0, 0.0, -0.0013990241651590145,
     2.9475147891527724, -9.15095847217987, 0.0}};
constexpr double kD[4][16] = {
    {-8.428938276109013, 0.0, 0.0, 0.0, 0.0, 0.5667149535193777, -3.0689499459498917,
     2.38466765651207, 2.117034582445028, -0.871391583777973, 2.2404374302607883,
     0.6315787787694688, -0.08899033645133331, 18.148505520854727, -9.194632392478356,
     -4.436036387594894},
    {10.427508642579134, 0.0, 0.0, 0.0, 0.0, 242.28349177525817, 165.20045171727028,
     -374.5467547226902, -22.113666853125306, 7.733432668472264, -30.674084731089398,
     -9.332130526430229, 15.697238121770845, -31.139403219565178, -9.35292435884448,
     35.81684148639408},
    {19.985053242002433, 0.0, 0.0, 0.0, 0.0, -387.0373087493518, -189.17813819516758,
     527.8081592054236, -11.57390253995963, 6.8812326946963, -1.0006050966910838,
     0.7777137798053443, -2.778205752353508, -60.19669523126412, 84.32040550667716,
     11.99229113618279},
    {-25.69393346270375, 0.0, 0.0, 0.0, 0.0, -154.18974869023643, -231.5293791760455,
     357.6391179106141, 93.40532418362432, -37.45832313645163, 104.0996495089623, 29.8402934266605,
     -43.53345659001114, 96.32455395918828, -39.17726167561544, -149.72683625798564}};
}  // namespace dp853

template <typename T>
class Dp853Stages {
 public:
  static constexpr const char* kName = "dop853";
  static constexpr double kExponent = 0.125;
  explicit Dp853Stages(int d)
      : d_(d),
        k_(16, std::vector<T>(static_cast<std::size_t>(d))),
        dense_(4, std::vector<T>(static_cast<std::size_t>(d))) {}
  std::vector<T>& first() { return k_[0]; }
  const std::vector<T>& last() const { return k_[12]; }

  template <typename Field>
  void attempt(const std::vector<T>& x, double h, double t, std::vector<T>& stage,
               std::vector<T>& next, Field&& field) {
    for (int s = 1; s < 12; ++s) {
      combine(x, h, dp853::kA[s], s, stage);
      field(stage, k_[s], t + dp853::kC[s] * h);
    }
    combine(x, h, dp853::kB, 12, next);
    field(next, k_[12], t + h);
    dense_ready_ = false;
  }
  void accept() { k_[0].swap(k_[12]); }
  // gamma = |e5| / sqrt(|e5|^2 + 0.01 |e3|^2) over the scaled components (values only), so that
  // error(i) = h gamma e5_i and the RMS of error(i) / scale_i is DOP853's error norm.
  template <typename Scale>
  void prepare_error(double, const Scale& scale) {
    double sum5 = 0.0, sum3 = 0.0;
    for (int i = 0; i < d_; ++i) {
      double high = 0.0, low = 0.0;
      for (int r = 0; r < 13; ++r) {
        const double k = value_of(k_[r][i]);
        high += dp853::kE5[r] * k;
        low += dp853::kE3[r] * k;
      }
      const double s = scale(i);
      sum5 += (high / s) * (high / s);
      sum3 += (low / s) * (low / s);
    }
    gamma_ = sum5 == 0.0 && sum3 == 0.0 ? 0.0 : std::sqrt(sum5 / (sum5 + 0.01 * sum3));
  }
  T error(int i, double h) const {
    T sum = dp853::kE5[0] * k_[0][i];
    for (int r = 1; r < 13; ++r) {
      if (dp853::kE5[r] != 0.0) sum += dp853::kE5[r] * k_[r][i];
    }
    return (h * gamma_) * sum;
  }
  // The tangents' estimate is damped per direction from their own e5 and e3 (TangentNorm), not
  // by gamma_, which the state sets.
  void add_tangent_error(int i, double h, const T&, const T& x0, const T& x1,
                         TangentNorm<T>& norm) const {
    T high = dp853::kE5[0] * k_[0][i];
    T low = dp853::kE3[0] * k_[0][i];
    for (int r = 1; r < 13; ++r) {
      if (dp853::kE5[r] != 0.0) high += dp853::kE5[r] * k_[r][i];
      if (dp853::kE3[r] != 0.0) low += dp853::kE3[r] * k_[r][i];
    }
    norm.add_damped(h * high, h * low, x0, x1);
  }
  // The three extra stages of the dense output, once per step (before accept()).
  template <typename Field>
  void prepare_dense(const std::vector<T>& x, double h, double t, std::vector<T>& stage,
                     Field&& field) {
    if (dense_ready_) return;
    for (int s = 13; s < 16; ++s) {
      combine(x, h, dp853::kA[s], s, stage);
      field(stage, k_[s], t + dp853::kC[s] * h);
    }
    // F3 ... F6 of the interpolant (below), once per step: the root searches evaluate it often.
    for (int r = 0; r < 4; ++r) {
      for (int i = 0; i < d_; ++i) {
        T sum = dp853::kD[r][0] * k_[0][i];
        for (int s = 1; s < 16; ++s) {
          if (dp853::kD[r][s] != 0.0) sum += dp853::kD[r][s] * k_[s][i];
        }
        dense_[static_cast<std::size_t>(r)][static_cast<std::size_t>(i)] = h * sum;
      }
    }
    dense_ready_ = true;
  }
  T dense(int i, const T& x, const T& next, double h, double theta) const {
    return interpolate<T>(i, x, next, h, theta, [](const T& v) -> const T& { return v; });
  }
  double dense_value(int i, double x, double next, double h, double theta) const {
    return interpolate<double>(i, x, next, h, theta, [](const T& v) { return value_of(v); });
  }

 private:
  // out = x + h sum_{r < s} a[r] k_r
  void combine(const std::vector<T>& x, double h, const double* a, int s,
               std::vector<T>& out) const {
    for (int i = 0; i < d_; ++i) {
      T sum = a[0] * k_[0][i];
      for (int r = 1; r < s; ++r) {
        if (a[r] != 0.0) sum += a[r] * k_[r][i];
      }
      out[i] = x[i] + h * sum;
    }
  }
  // Hairer's contd8: x + theta (F0 + (1 - theta) (F1 + theta (F2 + (1 - theta) (F3 + theta (F4
  // + (1 - theta) (F5 + theta F6)))))), F0 = next - x, F1 = h f_old - F0,
  // F2 = 2 F0 - h (f_new + f_old), F3..F6 = h sum_s D_{r,s} k_s.
  template <typename S, typename Part>
  S interpolate(int i, const S& x, const S& next, double h, double theta, Part part) const {
    const double theta1 = 1.0 - theta;
    const S f0 = next - x;
    const S f1 = h * part(k_[0][i]) - f0;
    const S f2 = 2.0 * f0 - h * (part(k_[12][i]) + part(k_[0][i]));
    S f[4];
    for (int r = 0; r < 4; ++r) f[r] = part(dense_[static_cast<std::size_t>(r)][i]);
    return x +
           theta *
               (f0 +
                theta1 *
                    (f1 +
                     theta *
                         (f2 + theta1 * (f[0] + theta * (f[1] + theta1 * (f[2] + theta * f[3]))))));
  }

  int d_;
  std::vector<std::vector<T>> k_;      // k_0 ... k_11, k_12 = F(next), k_13 ... k_15 dense output
  std::vector<std::vector<T>> dense_;  // F3 ... F6 of the dense output, set by prepare_dense()
  double gamma_ = 1.0;
  bool dense_ready_ = false;
};

template <typename T, template <typename> class Method>
class Stepper {
 public:
  Stepper(const SegmentModel& model, Signs sides, const IntegratorOptions& options)
      : model_(model),
        sides_(sides),
        options_(options),
        d_(model.states()),
        n_(model.surfaces()),
        method_(d_),
        stage_(d_),
        scratch_(d_),
        next_(d_),
        values_(d_),
        h_values_(n_),
        g_(n_),
        g_next_(n_),
        theta_(n_),
        g_trial_(n_),
        rate_(n_),
        rate_next_(n_),
        probe_(n_),
        g_middle_(n_),
        velocity_(d_),
        field_(d_),
        ratios_(d_),
        armed_(n_) {}

  SegmentResult run(double t0, double t_end, std::vector<T>& x, bool watch) {
    SegmentResult result;
    result_ = &result;
    double t = t0;
    result.t = t;
    if (watch) {
      surface_g(x, g_);
      for (int j = 0; j < n_; ++j) armed_[j] = g_[j] > 0.0;
    }
    if (!field(x, method_.first(), t, result)) return result;
    for (int i = 0; i < d_; ++i) {
      // Every later step starts from a field checked finite (error_norm()); the first one too.
      if (!all_finite(method_.first()[i])) {
        return fail(result, IntegrationStatus::kNonFinite, t, x,
                    label() + ": F_b(x) row " + std::to_string(i) + " is non-finite (" +
                        format_number(value_of(method_.first()[i])) +
                        ") at t = " + format_number(t) + ", x = " + format_vector(values(x)) +
                        " (b = \"" + sides_.str() + "\")");
      }
    }
    if (watch && n_ > 0) surface_g_and_rates(x, method_.first(), g_, rate_);
    // The estimate can be tiny when x0 is near zero; steps then grow by up to 5x each. One that
    // is not a positive number (a field of 1e300 makes its ratios 0/0) starts at the floor.
    const double first_floor = 10 * options_.min_step * std::max(1.0, std::abs(t0));
    double h = options_.initial_step;
    if (!(h > 0.0)) {
      const double estimate = initial_step(x, t0, t_end);
      h = estimate > first_floor ? estimate : first_floor;
    }
    bool rejected_last = false;
    // Bounded: accepted steps by max_steps, rejected ones by max_steps too, and the rejections
    // in a row by the step size, which each one divides by at least 1 / 0.9 down to its floor
    // (the tests against the floor are written to hold for a NaN step as well).
    while (true) {
      h = std::min(h, options_.max_step);
      // Within 1% of the end, stretch the step to land on it (no sliver of a last step).
      const bool last = t + 1.01 * h >= t_end;
      if (last) h = t_end - t;
      if (result.steps >= options_.max_steps) {
        return fail(result, IntegrationStatus::kTooManySteps, t, x,
                    label() + ": max_steps = " + std::to_string(options_.max_steps) +
                        " steps taken, stopped at t = " + format_number(t) +
                        " before t_end = " + format_number(t_end));
      }
      if (result.rejected_steps >= options_.max_steps) {
        return fail(result, IntegrationStatus::kTooManySteps, t, x,
                    label() + ": max_steps = " + std::to_string(options_.max_steps) +
                        " rejected steps (and " + std::to_string(result.steps) +
                        " accepted), stopped at t = " + format_number(t) +
                        " before t_end = " + format_number(t_end));
      }
      if (!attempt(x, h, t, result)) return result;
      const double error = error_norm(x);
      const double floor = options_.min_step * std::max(1.0, std::abs(t));
      if (std::isnan(error)) {
        // A non-finite trial state: retry smaller, as a rejection.
        ++result.rejected_steps;
        h *= 0.2;
        rejected_last = true;
        if (!(h > floor)) {
          return fail(
              result, IntegrationStatus::kNonFinite, t, x,
              label() + ": the state becomes non-finite just after t = " + format_number(t));
        }
        continue;
      }
      if (error > 1.0) {  // +inf included: an error beyond the double range relative to atol
        ++result.rejected_steps;
        h *= std::max(0.2, 0.9 * std::pow(error, -Stages::kExponent));
        rejected_last = true;
        if (!(h > floor)) {
          return fail(result, IntegrationStatus::kStepSizeUnderflow, t, x,
                      label() + ": step size " + format_number(h) + " underflows at t = " +
                          format_number(t) + " (min_step " + format_number(options_.min_step) +
                          " relative to max(1, |t|)): the error estimate " + format_number(error) +
                          " does not fall as the step shrinks");
        }
        continue;
      }
      ++result.steps;
      if (!last && t + h == t) {
        return fail(result, IntegrationStatus::kStepSizeUnderflow, t, x,
                    label() + ": step size " + format_number(h) + " no longer advances t = " +
                        format_number(t) + " (the tolerances ask for more than double precision)");
      }
      if (watch && n_ > 0) {
        double theta = 0.0;
        if (locate_crossing(x, h, theta, result.crossed)) {
          dense(x, h, theta, next_);
          x = next_;
          result.t = t + theta * h;
          result.crossing_times.assign(static_cast<std::size_t>(n_), INFINITY);
          for (int j = 0; j < n_; ++j) {
            const double theta_j = theta_[static_cast<std::size_t>(j)];
            if (theta_j <= 1.0)
              result.crossing_times[static_cast<std::size_t>(j)] = t + theta_j * h;
          }
          result.status = IntegrationStatus::kCrossing;
          return result;
        }
      }
      t = last ? t_end : t + h;
      x.swap(next_);
      method_.accept();  // first same as last
      if (last) {
        result.t = t;
        result.status = IntegrationStatus::kReachedEnd;
        return result;
      }
      const double grow =
          error == 0.0 ? 5.0
                       : std::min(5.0, std::max(0.2, 0.9 * std::pow(error, -Stages::kExponent)));
      h *= rejected_last ? std::min(1.0, grow) : grow;
      rejected_last = false;
    }
  }

 private:
  bool field(const std::vector<T>& x, std::vector<T>& dx, double t, SegmentResult& result) {
    model_.field(x.data(), sides_, dx.data());
    ++result.field_evaluations;
    (void)t;
    return true;
  }

  Eigen::VectorXd values(const std::vector<T>& x) const {
    Eigen::VectorXd out(d_);
    for (int i = 0; i < d_; ++i) out[i] = value_of(x[i]);
    return out;
  }

  SegmentResult& fail(SegmentResult& result, IntegrationStatus status, double t,
                      const std::vector<T>&, std::string message) {
    result.status = status;
    result.t = t;
    result.message = std::move(message);
    return result;
  }

  double scale(double a, double b) const {
    return options_.absolute_tolerance() + options_.rtol * std::max(std::abs(a), std::abs(b));
  }

  double initial_step(const std::vector<T>& x, double t0, double t_end) {
    // Hairer, Norsett & Wanner, Solving ODEs I, II.4: from the size of x, x' and x''.
    double size0 = 0, size1 = 0;
    for (int i = 0; i < d_; ++i) {
      const double s = scale(value_of(x[i]), 0.0);
      size0 += std::pow(value_of(x[i]) / s, 2);
      size1 += std::pow(value_of(method_.first()[i]) / s, 2);
    }
    size0 = std::sqrt(size0 / d_);
    size1 = std::sqrt(size1 / d_);
    double h0 = (size0 < 1e-5 || size1 < 1e-5) ? 1e-6 : 0.01 * size0 / size1;
    h0 = std::min(h0, t_end - t0);
    // A field or state beyond the double range once scaled (ratios inf / inf, 0 / 0): no
    // estimate; the caller starts from its floor.
    if (!(h0 > 0.0) || !std::isfinite(h0)) return 0.0;
    for (int i = 0; i < d_; ++i) stage_[i] = x[i] + h0 * method_.first()[i];
    model_.field(stage_.data(), sides_, scratch_.data());
    double size2 = 0;
    for (int i = 0; i < d_; ++i) {
      size2 += std::pow(value_of(scratch_[i] - method_.first()[i]) / scale(value_of(x[i]), 0.0), 2);
    }
    size2 = std::sqrt(size2 / d_) / h0;
    const double h1 = std::max(size1, size2) <= 1e-15
                          ? std::max(1e-6, h0 * 1e-3)
                          : std::pow(0.01 / std::max(size1, size2), Stages::kExponent);
    return std::min(100 * h0, h1);
  }

  // One trial step from x: fills the stages and next_ (method_.last() = F(next_)).
  bool attempt(const std::vector<T>& x, double h, double t, SegmentResult& result) {
    method_.attempt(x, h, t, stage_, next_,
                    [&](const std::vector<T>& in, std::vector<T>& out, double at) {
                      field(in, out, at, result);
                    });
    last_h_ = h;
    last_t_ = t;
    return true;
  }

  // The RMS over components of |e_i| / (atol + rtol max(|x_i|, |x_i(t + h)|)): NaN when the
  // trial state or its field is not finite, +inf only when the norm itself is beyond the double
  // range (a tiny atol), never a spurious one from squaring a large ratio.
  double error_norm(const std::vector<T>& x) {
    double sum = 0;
    const bool tangents = options_.tangents_in_error_norm;
    if (tangents) tangent_norm_.clear();
    for (int i = 0; i < d_; ++i) {
      if (!all_finite(next_[i]) || !all_finite(method_.last()[i])) return NAN;
    }
    method_.prepare_error(last_h_,
                          [&](int i) { return scale(value_of(x[i]), value_of(next_[i])); });
    for (int i = 0; i < d_; ++i) {
      const T err = method_.error(i, last_h_);
      ratios_[i] = value_of(err) / scale(value_of(x[i]), value_of(next_[i]));
      sum += std::pow(ratios_[i], 2);
      if (tangents) method_.add_tangent_error(i, last_h_, err, x[i], next_[i], tangent_norm_);
    }
    double state = std::sqrt(sum / d_);
    if (!std::isfinite(state)) {
      // A ratio above 1e154: the same norm with the largest ratio factored out.
      double largest = 0.0;
      for (int i = 0; i < d_; ++i) largest = std::max(largest, std::abs(ratios_[i]));
      sum = 0.0;
      if (std::isfinite(largest)) {
        for (int i = 0; i < d_; ++i) sum += std::pow(ratios_[i] / largest, 2);
      }
      state = std::isfinite(largest) ? largest * std::sqrt(sum / d_) : largest;
    }
    if (!tangents) return state;
    return std::max(state, tangent_norm_.error(options_.rtol, options_.absolute_tolerance()));
  }

  // x(t + theta h) on the dense output of the last accepted step.
  void dense(const std::vector<T>& x, double h, double theta, std::vector<T>& out) {
    prepare_dense(x, h);
    for (int i = 0; i < d_; ++i) out[i] = method_.dense(i, x[i], next_[i], h, theta);
  }

  // x(t + theta h) on the dense output, values only, into values_.
  void dense_values(const std::vector<T>& x, double h, double theta) {
    prepare_dense(x, h);
    for (int i = 0; i < d_; ++i) {
      values_[i] = method_.dense_value(i, value_of(x[i]), value_of(next_[i]), h, theta);
    }
  }

  // The method's extra stages for its dense output, if it has any (once per step).
  void prepare_dense(const std::vector<T>& x, double h) {
    method_.prepare_dense(x, h, last_t_, stage_,
                          [&](const std::vector<T>& in, std::vector<T>& out, double) {
                            model_.field(in.data(), sides_, out.data());
                            ++result_->field_evaluations;
                          });
  }

  // g at theta on the dense output, values only.
  void dense_g(const std::vector<T>& x, double h, double theta, std::vector<double>& g) {
    dense_values(x, h, theta);
    signed_surfaces(g);
  }

  void signed_surfaces(std::vector<double>& g) {
    model_.surface_values(values_.data(), h_values_.data());
    for (int j = 0; j < n_; ++j) g[j] = sides_.plus(j) ? h_values_[j] : -h_values_[j];
  }

  void surface_g(const std::vector<T>& x, std::vector<double>& g) {
    for (int i = 0; i < d_; ++i) values_[i] = value_of(x[i]);
    signed_surfaces(g);
  }

  // g_j and dg_j/dt = s_j Dh_j(x) . f at x, moving along the field f: one evaluation of the
  // surfaces on Jets (SegmentModel::surface_rates), no difference quotient.
  void surface_g_and_rates(const std::vector<T>& x, const std::vector<T>& f, std::vector<double>& g,
                           std::vector<double>& rate) {
    for (int i = 0; i < d_; ++i) {
      values_[i] = value_of(x[i]);
      velocity_[i] = value_of(f[i]);
    }
    model_.surface_rates(values_.data(), velocity_.data(), h_values_.data(), probe_.data());
    for (int j = 0; j < n_; ++j) {
      const double s = sides_.plus(j) ? 1.0 : -1.0;
      g[j] = s * h_values_[j];
      rate[j] = s * probe_[j];
    }
  }

  // The rounding error of g_j on the dense output of a step with end values g0, g1 and end
  // rates s0, s1 (per unit theta): a few ulps of the largest term of the interpolant.
  static double rounding(double g0, double g1, double s0, double s1) {
    return 16 * std::numeric_limits<double>::epsilon() *
           std::max({std::abs(g0), std::abs(g1), std::abs(s0), std::abs(s1)});
  }

  // The minimum over theta in [0, 1] of the quartic q with q(0) = g0, q(1) = g1, q'(0) = s0,
  // q'(1) = s1 and q(1/2) = g_half: the cubic Hermite interpolant plus c theta^2 (1 - theta)^2.
  // On 16 cells; refined by golden sections only when a cell is below both ends (a dip), so that
  // the common case (g_j monotone towards an end) costs 17 evaluations of q and nothing else.
  static double quartic_minimum(double g0, double g1, double s0, double s1, double g_half) {
    const double hermite_half = 0.5 * (g0 + g1) + 0.125 * (s0 - s1);
    const double c = 16.0 * (g_half - hermite_half);
    const auto q = [&](double t) {
      const double t2 = t * t, t3 = t2 * t, u = t * (1.0 - t);
      return (2 * t3 - 3 * t2 + 1) * g0 + (t3 - 2 * t2 + t) * s0 + (3 * t2 - 2 * t3) * g1 +
             (t3 - t2) * s1 + c * u * u;
    };
    constexpr int kCells = 16;
    int best = 0;
    double q_best = g0;
    for (int i = 1; i <= kCells; ++i) {
      const double value = q(static_cast<double>(i) / kCells);
      if (value < q_best) best = i, q_best = value;
    }
    if (!(q_best < std::min(g0, g1))) return q_best;
    double a = std::max(0, best - 1) / static_cast<double>(kCells);
    double b = std::min(kCells, best + 1) / static_cast<double>(kCells);
    for (int iteration = 0; iteration < 16; ++iteration) {
      const double u = a + 0.3819660112501051 * (b - a), v = b - 0.3819660112501051 * (b - a);
      const double q_u = q(u), q_v = q(v);
      q_best = std::min({q_best, q_u, q_v});
      (q_u < q_v ? b : a) = q_u < q_v ? v : u;
    }
    return q_best;
  }

  // Brent's minimisation (values only) of sigma g_j on the dense output over theta in (0, 1): a
  // local minimum (sigma = +1) or maximum (sigma = -1). theta to about sqrt(eps), which puts the
  // value within a few ulps of the extreme value (the error is quadratic in theta). Returns
  // theta; g_at is g_j there.
  double extremum(const std::vector<T>& x, double h, int j, double sigma, double& g_at) {
    constexpr double kGolden = 0.3819660112501051;  // (3 - sqrt(5)) / 2
    constexpr double kRelative = 1.5e-8;
    constexpr double kAbsolute = 1e-12;
    const auto f = [&](double theta) {
      dense_g(x, h, theta, g_trial_);
      return sigma * g_trial_[static_cast<std::size_t>(j)];
    };
    double a = 0.0, b = 1.0;
    // best: lowest value so far; second: the one before; third: the one before that.
    double best = kGolden, second = best, third = best;
    double f_best = f(best), f_second = f_best, f_third = f_best;
    double step = 0.0, previous = 0.0;
    for (int iteration = 0; iteration < 100; ++iteration) {
      const double middle = 0.5 * (a + b);
      const double tol1 = kRelative * std::abs(best) + kAbsolute;
      const double tol2 = 2.0 * tol1;
      if (std::abs(best - middle) <= tol2 - 0.5 * (b - a)) break;
      bool golden = true;
      if (std::abs(previous) > tol1) {
        // Parabola through the three best points.
        const double r = (best - second) * (f_best - f_third);
        double q = (best - third) * (f_best - f_second);
        double p = (best - third) * q - (best - second) * r;
        q = 2.0 * (q - r);
        if (q > 0.0) p = -p;
        q = std::abs(q);
        const double before = previous;
        previous = step;
        if (std::abs(p) < std::abs(0.5 * q * before) && p > q * (a - best) && p < q * (b - best)) {
          step = p / q;
          const double u = best + step;
          if (u - a < tol2 || b - u < tol2) step = middle >= best ? tol1 : -tol1;
          golden = false;
        }
      }
      if (golden) {
        previous = best >= middle ? a - best : b - best;
        step = kGolden * previous;
      }
      const double u = std::abs(step) >= tol1 ? best + step : best + (step > 0.0 ? tol1 : -tol1);
      const double f_u = f(u);
      if (f_u <= f_best) {
        (u >= best ? a : b) = best;
        third = second;
        f_third = f_second;
        second = best;
        f_second = f_best;
        best = u;
        f_best = f_u;
      } else {
        (u < best ? a : b) = u;
        if (f_u <= f_second || second == best) {
          third = second;
          f_third = f_second;
          second = u;
          f_second = f_u;
        } else if (f_u <= f_third || third == best || third == second) {
          third = u;
          f_third = f_u;
        }
      }
    }
    g_at = sigma * f_best;
    return best;
  }

  // Illinois iteration on [lo, hi] with g_j(lo) > 0 >= g_j(hi), to a few ulps of theta: the root
  // when g_j changes sign once there. Returns a theta where g_j <= 0.
  double root(const std::vector<T>& x, double h, int j, double lo, double hi, double g_lo,
              double g_hi) {
    int side = 0;
    std::vector<double>& g = g_trial_;
    for (int iteration = 0; iteration < 100 && hi - lo > 4e-16; ++iteration) {
      double mid = (lo * g_hi - hi * g_lo) / (g_hi - g_lo);
      if (!(mid > lo && mid < hi)) mid = 0.5 * (lo + hi);
      dense_g(x, h, mid, g);
      if (g[j] > 0.0) {
        lo = mid;
        g_lo = g[j];
        if (side == -1) g_hi *= 0.5;
        side = -1;
      } else {
        hi = mid;
        g_hi = g[j];
        if (side == 1) g_lo *= 0.5;
        side = 1;
      }
    }
    return hi;
  }

  // dg_j/dt = s_j Dh_j(x) . F_b(x) at theta on the dense output, with the model's own field and
  // normals (Jets): the quantity the driver's transversality test is made of.
  double exact_rate(const std::vector<T>& x, double h, int j, double theta) {
    dense_values(x, h, theta);
    model_.field(values_.data(), sides_, field_.data());
    ++result_->field_evaluations;
    const Eigen::Map<const Eigen::VectorXd> state(values_.data(), d_);
    const Eigen::MatrixXd normals = model_.surface_normals(state);
    const double rate = normals.row(j).dot(Eigen::Map<const Eigen::VectorXd>(field_.data(), d_));
    return sides_.plus(j) ? rate : -rate;
  }

  // Where g_j touches zero near theta: the zero of dg_j/dt (from - to +), by bisection to a few
  // ulps of theta. A crossing reported there reaches the driver with eta . F ~ 0, which it
  // rejects as grazing; Brent's theta (sqrt(eps)) would leave eta . F ~ 1e-8 instead.
  double tangency(const std::vector<T>& x, double h, int j, double theta) {
    double lo = std::max(0.0, theta - 1e-6), hi = std::min(1.0, theta + 1e-6);
    if (!(exact_rate(x, h, j, lo) < 0.0 && exact_rate(x, h, j, hi) >= 0.0)) {
      lo = 0.0;
      hi = 1.0;
      if (!(exact_rate(x, h, j, lo) < 0.0 && exact_rate(x, h, j, hi) >= 0.0)) return theta;
    }
    for (int iteration = 0; iteration < 100 && hi - lo > 4e-16; ++iteration) {
      const double mid = 0.5 * (lo + hi);
      if (!(mid > lo && mid < hi)) break;
      (exact_rate(x, h, j, mid) < 0.0 ? lo : hi) = mid;
    }
    return hi;
  }

  // The band of a near miss at theta: kBandFactor sum_i |dh_j/dx_i| (atol + rtol |x_i|), the
  // change of g_j under a state error of one tolerance unit in every component.
  double miss_band(const std::vector<T>& x, double h, int j, double theta) {
    dense_values(x, h, theta);
    const Eigen::Map<const Eigen::VectorXd> state(values_.data(), d_);
    const Eigen::MatrixXd normals = model_.surface_normals(state);
    const double atol = options_.absolute_tolerance();
    double band = 0.0;
    for (int i = 0; i < d_; ++i) {
      band += std::abs(normals(j, i)) * (atol + options_.rtol * std::abs(values_[i]));
    }
    return kBandFactor * band;
  }

  // After an accepted step x -> next_: the first crossing in (0, 1], if any. Besides the sign
  // changes of g_j between the ends, a watched g_j that is > 0 at both ends may dip to <= 0 and
  // come back inside the step (a crossing pair near a tangency), and an unwatched one (<= 0 at
  // both ends, e.g. just crossed) may rise above 0 and come back. Both are looked for only where
  // the end values and rates allow them (cheap tests below); then the extreme of g_j on the
  // dense output is found and, if it is on the other side, the crossing is located before it
  // (after it for the rise). A minimum that stays > 0 within the error band is a NearMiss.
  bool locate_crossing(const std::vector<T>& x, double h, double& theta_first,
                       std::vector<int>& crossed) {
    surface_g_and_rates(next_, method_.last(), g_next_, rate_next_);
    std::vector<double>& theta = theta_;
    std::fill(theta.begin(), theta.end(), 2.0);
    misses_.clear();
    bool any = false;
    bool have_middle = false;  // g at theta = 1/2, computed once for all surfaces when needed
    for (int j = 0; j < n_; ++j) {
      const auto js = static_cast<std::size_t>(j);
      const double g0 = g_[js], g1 = g_next_[js];
      const double s0 = h * rate_[js], s1 = h * rate_next_[js];  // dg_j/dtheta at the ends
      if (!armed_[js]) {
        armed_[js] = g1 > 0.0;
        // Out to the watched side and back within the step: a maximum of g_j above zero.
        if (g1 <= 0.0 && s0 > 0.0 && s1 < 0.0) {
          double g_max = 0.0;
          const double top = extremum(x, h, j, -1.0, g_max);
          if (g_max > rounding(g0, g1, s0, s1)) {
            theta[js] = root(x, h, j, top, 1.0, g_max, g1);
            any = true;
          }
        }
        continue;
      }
      if (g1 <= 0.0) {
        theta[js] = root(x, h, j, 0.0, 1.0, g0, g1);
        any = true;
        continue;
      }
      // g_j > 0 at both ends. It can dip inside only if it turns (falling at the start, rising
      // at the end) or if it is small against what it changes in one step at the end rates.
      const bool turns = s0 < 0.0 && s1 > 0.0;
      const bool close = std::min(g0, g1) <= std::max(std::abs(s0), std::abs(s1));
      if (!turns && !close) continue;
      // Then a quartic model of g_j on the step (exact for an affine h_j): the searches below
      // run only if it comes below half the lower end value somewhere inside.
      if (!have_middle) {
        dense_g(x, h, 0.5, g_middle_);
        have_middle = true;
      }
      if (!(quartic_minimum(g0, g1, s0, s1, g_middle_[js]) < 0.5 * std::min(g0, g1))) continue;
      double g_min = 0.0;
      const double bottom = extremum(x, h, j, 1.0, g_min);
      const double noise = rounding(g0, g1, s0, s1);
      if (g_min < -noise) {
        theta[js] = root(x, h, j, 0.0, bottom, g0, g_min);
        any = true;
        continue;
      }
      if (g_min <= noise) {
        // Zero to rounding at an interior minimum: a touch, reported at the tangency itself.
        if (std::min(g0, g1) > 2.0 * noise) {
          theta[js] = tangency(x, h, j, bottom);
          any = true;
        }
        continue;
      }
      // The closest approach: inside the step when the rates turn (it may then sit at an end,
      // to the accuracy of the rates), or wherever g_j is below both ends.
      double closest = bottom, g_closest = g_min;
      if (turns && g0 < g_closest) closest = 0.0, g_closest = g0;
      if (turns && g1 < g_closest) closest = 1.0, g_closest = g1;
      if (!turns && !(g_min < std::min(g0, g1) - noise)) continue;
      const double band = miss_band(x, h, j, closest);
      if (g_closest < band) {
        misses_.push_back({NearMiss{j, last_t_ + closest * h, g_closest, band}, closest});
      }
    }
    const double first =
        any ? *std::min_element(theta.begin(), theta.end()) : std::numeric_limits<double>::max();
    for (const auto& [miss, at] : misses_) {
      if (at <= first) result_->near_misses.push_back(miss);
    }
    if (!any) {
      g_.swap(g_next_);
      rate_.swap(rate_next_);
      return false;
    }
    theta_first = first;
    // Crossings within a few ulps of the first are the same crossing.
    const double same = 8e-16 * std::max(1.0, 1.0 / h);
    for (int j = 0; j < n_; ++j) {
      if (theta[static_cast<std::size_t>(j)] <= theta_first + same) crossed.push_back(j);
    }
    return true;
  }

  // A near miss is a minimum g_min > 0 below kBandFactor tolerance units (miss_band()).
  static constexpr double kBandFactor = 8.0;

  const SegmentModel& model_;
  const Signs sides_;
  const IntegratorOptions& options_;
  const int d_;
  const int n_;
  using Stages = Method<T>;
  static std::string label() { return Stages::kName; }

  Stages method_;
  std::vector<T> stage_, scratch_, next_;
  std::vector<double> values_, h_values_, g_, g_next_;
  TangentNorm<T> tangent_norm_;
  std::vector<double> theta_, g_trial_;  // scratch of locate_crossing(), no allocation per step
  // dg_j/dt at x and at next_, and scratch of surface_g_and_rates().
  std::vector<double> rate_, rate_next_, probe_, g_middle_, velocity_;
  std::vector<double> field_;   // F_b at a dense-output point (exact_rate())
  std::vector<double> ratios_;  // |e_i| / scale_i of the last trial step (error_norm())
  // Near misses of the step being checked, with their theta; kept if not after the crossing.
  std::vector<std::pair<NearMiss, double>> misses_;
  SegmentResult* result_ = nullptr;  // the result run() is filling
  std::vector<char> armed_;
  double last_h_ = 0.0;
  double last_t_ = 0.0;  // start of the last attempted step
};

}  // namespace

namespace {
template <typename T, template <typename> class Method>
SegmentResult rk_segment(const SegmentModel& model, Signs sides, double t0, double t_end,
                         const std::vector<T>& x0, const IntegratorOptions& options,
                         std::vector<T>* x_out, bool watch) {
  std::vector<T> x = x0;
  Stepper<T, Method> stepper(model, sides, options);
  SegmentResult result = stepper.run(t0, t_end, x, watch);
  *x_out = std::move(x);
  return result;
}
}  // namespace

namespace internal {
template <typename T>
SegmentResult dopri5_segment(const SegmentModel& model, Signs sides, double t0, double t_end,
                             const std::vector<T>& x0, const IntegratorOptions& options,
                             std::vector<T>* x_out, bool watch) {
  return rk_segment<T, Dp54Stages>(model, sides, t0, t_end, x0, options, x_out, watch);
}
}  // namespace internal

namespace {

void check_request(const std::string& name, const SegmentModel& model,
                   const SegmentRequest& request, const IntegratorOptions& options) {
  const int d = model.states();
  if (request.x0.size() != d || (request.v0.size() > 0 && request.v0.rows() != d)) {
    throw InvalidArgument(name + ": x0 has " + std::to_string(request.x0.size()) +
                          " numbers and the tangents " + std::to_string(request.v0.rows()) +
                          " rows; the model has d = " + std::to_string(d) + " states");
  }
  if (!request.x0.allFinite() || !request.v0.allFinite()) {
    throw InvalidArgument(name +
                          ": x0 or the tangents are not finite: x0 = " + format_vector(request.x0));
  }
  if (request.sides.size() != model.surfaces()) {
    throw InvalidArgument(name + ": sides \"" + request.sides.str() + "\" name " +
                          std::to_string(request.sides.size()) + " surfaces, the model has " +
                          std::to_string(model.surfaces()));
  }
  if (!(request.t_end >= request.t0) || !std::isfinite(request.t_end)) {
    throw InvalidArgument(name + ": need finite t_end >= t0, got t0 = " +
                          format_number(request.t0) + ", t_end = " + format_number(request.t_end));
  }
  if (!(options.rtol >= IntegratorOptions::kMinRtol) || !std::isfinite(options.rtol) ||
      !(options.absolute_tolerance() >= IntegratorOptions::kMinAtol) ||
      !std::isfinite(options.absolute_tolerance())) {
    throw InvalidArgument(name +
                          ": need a finite rtol >= " + format_number(IntegratorOptions::kMinRtol) +
                          " and a finite atol >= " + format_number(IntegratorOptions::kMinAtol) +
                          ", got rtol = " + format_number(options.rtol) +
                          ", atol = " + format_number(options.absolute_tolerance()));
  }
  if (!(options.initial_step >= 0.0) || !(options.min_step >= 0.0) || !(options.max_step > 0.0) ||
      !std::isfinite(options.initial_step) || !std::isfinite(options.min_step)) {
    throw InvalidArgument(name + ": need initial_step >= 0, min_step >= 0 and max_step > 0, got " +
                          format_number(options.initial_step) + ", " +
                          format_number(options.min_step) + ", " + format_number(options.max_step));
  }
  if (options.max_steps < 1) {
    throw InvalidArgument(name + ": max_steps must be positive, got " +
                          std::to_string(options.max_steps));
  }
}

template <typename T, template <typename> class Method>
SegmentResult run_chunk(const SegmentModel& model, const SegmentRequest& request,
                        const IntegratorOptions& options, double t_end, Eigen::Index first,
                        int width, bool watch, Eigen::MatrixXd* v) {
  const int d = model.states();
  std::vector<T> x(static_cast<std::size_t>(d));
  for (int i = 0; i < d; ++i) {
    if constexpr (std::is_same_v<T, double>) {
      x[i] = request.x0[i];
    } else {
      x[i] = T(request.x0[i]);
      for (int c = 0; c < width; ++c) x[i].v[c] = request.v0(i, first + c);
    }
  }
  std::vector<T> x_end;
  SegmentResult result =
      rk_segment<T, Method>(model, request.sides, request.t0, t_end, x, options, &x_end, watch);
  result.x.resize(d);
  for (int i = 0; i < d; ++i) {
    if constexpr (std::is_same_v<T, double>) {
      result.x[i] = x_end[i];
    } else {
      result.x[i] = x_end[i].a;
      for (int c = 0; c < width; ++c) (*v)(i, first + c) = x_end[i].v[c];
    }
  }
  return result;
}

// Both Dormand-Prince pairs: the state alone, or k tangents in chunks.
template <template <typename> class Method>
SegmentResult integrate_chunks(const SegmentModel& model, const SegmentRequest& request,
                               const IntegratorOptions& options) {
  check_request(Method<double>::kName, model, request, options);
  const Eigen::Index k = request.v0.cols();
  Eigen::MatrixXd v(model.states(), k);
  if (k == 0) {
    SegmentResult result =
        run_chunk<double, Method>(model, request, options, request.t_end, 0, 0, true, &v);
    result.v = v;
    return result;
  }
  // The first chunk finds where the segment ends; the others integrate to exactly there.
  SegmentResult result;
  for (Eigen::Index first = 0; first < k; first += kTangentChunk) {
    const int width = static_cast<int>(std::min<Eigen::Index>(kTangentChunk, k - first));
    const bool watch = first == 0;
    const double t_end = watch ? request.t_end : result.t;
    SegmentResult chunk;
    switch (tangent_width(width)) {
      case 1:
        chunk = run_chunk<Jet1, Method>(model, request, options, t_end, first, width, watch, &v);
        break;
      case 2:
        chunk = run_chunk<Jet2, Method>(model, request, options, t_end, first, width, watch, &v);
        break;
      case 4:
        chunk = run_chunk<Jet4, Method>(model, request, options, t_end, first, width, watch, &v);
        break;
      case 6:
        chunk = run_chunk<Jet6, Method>(model, request, options, t_end, first, width, watch, &v);
        break;
      default:
        chunk =
            run_chunk<JetChunk, Method>(model, request, options, t_end, first, width, watch, &v);
        break;
    }
    if (watch) {
      result = std::move(chunk);
      const bool stopped = result.status == IntegrationStatus::kReachedEnd ||
                           result.status == IntegrationStatus::kCrossing;
      if (!stopped) break;  // a failure: the other chunks would fail the same way
      continue;
    }
    result.field_evaluations += chunk.field_evaluations;
    if (chunk.status != IntegrationStatus::kReachedEnd) {
      result.status = chunk.status;
      result.message = chunk.message;
      break;
    }
  }
  result.v = v;
  return result;
}

}  // namespace

SegmentResult Dopri5Integrator::integrate(const SegmentModel& model, const SegmentRequest& request,
                                          const IntegratorOptions& options) {
  return integrate_chunks<Dp54Stages>(model, request, options);
}

SegmentResult Dop853Integrator::integrate(const SegmentModel& model, const SegmentRequest& request,
                                          const IntegratorOptions& options) {
  return integrate_chunks<Dp853Stages>(model, request, options);
}

#define BFLOW_DOPRI5_INSTANTIATE(T)                                                                \
  template SegmentResult internal::dopri5_segment<T>(                                              \
      const SegmentModel&, Signs, double, double, const std::vector<T>&, const IntegratorOptions&, \
      std::vector<T>*, bool);
BFLOW_DOPRI5_INSTANTIATE(double)
BFLOW_DOPRI5_INSTANTIATE(Jet1)
BFLOW_DOPRI5_INSTANTIATE(Jet2)
BFLOW_DOPRI5_INSTANTIATE(Jet4)
BFLOW_DOPRI5_INSTANTIATE(Jet6)
BFLOW_DOPRI5_INSTANTIATE(JetChunk)
#undef BFLOW_DOPRI5_INSTANTIATE

}  // namespace bflow

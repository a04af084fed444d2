// Dormand & Prince's 8(5,3) pair (DOP853): the tableau; the stepper is explicit_rk_stepper.h.
#include "bflow/integrators/dop853.h"

#include <cmath>
#include <vector>

#include "explicit_rk_stepper.h"

namespace bflow {

namespace {

using explicit_rk::TangentNorm;
using explicit_rk::value_of;

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
        dense_(4, std::vector<T>(static_cast<std::size_t>(d))),
        high_(static_cast<std::size_t>(d)) {}
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
  // error_value(i) = h gamma e5_i and the RMS of error_value(i) / scale_i is DOP853's error
  // norm. Keeps each component's e5 for error_value().
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
      high_[static_cast<std::size_t>(i)] = high;
      const double s = scale(i);
      sum5 += (high / s) * (high / s);
      sum3 += (low / s) * (low / s);
    }
    gamma_ = sum5 == 0.0 && sum3 == 0.0 ? 0.0 : std::sqrt(sum5 / (sum5 + 0.01 * sum3));
  }
  double error_value(int i, double h) const {
    return (h * gamma_) * high_[static_cast<std::size_t>(i)];
  }
  // The tangents' estimate is damped per direction from their own e5 and e3 (TangentNorm), not
  // by gamma_, which the state sets.
  void add_tangent_error(int i, double h, const T& x0, const T& x1, TangentNorm<T>& norm) const {
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
  std::vector<double> high_;           // e5 of each component's value, set by prepare_error()
  double gamma_ = 1.0;
  bool dense_ready_ = false;
};

}  // namespace

struct Dop853Integrator::Steppers : explicit_rk::StepperCache<Dp853Stages> {};

Dop853Integrator::Dop853Integrator() : steppers_(std::make_unique<Steppers>()) {}
Dop853Integrator::~Dop853Integrator() = default;
Dop853Integrator::Dop853Integrator(Dop853Integrator&&) noexcept = default;
Dop853Integrator& Dop853Integrator::operator=(Dop853Integrator&&) noexcept = default;

SegmentResult Dop853Integrator::integrate(const SegmentModel& model, const SegmentRequest& request,
                                          const IntegratorOptions& options) {
  if (!steppers_) steppers_ = std::make_unique<Steppers>();  // a moved-from object
  return explicit_rk::integrate_chunks<Dp853Stages>(model, request, options, *steppers_);
}

}  // namespace bflow

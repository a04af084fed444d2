#include "bflow/integrators/hybrid_flow.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <string>

#include "bflow/core/errors.h"
#include "bflow/integrators/cvodes.h"
#include "bflow/integrators/dop853.h"
#include "bflow/integrators/dopri5.h"

namespace bflow {

Backend parse_backend(const std::string& name) {
  if (name == "auto") return Backend::kAutomatic;
  if (name == "dopri5") return Backend::kDopri5;
  if (name == "dop853") return Backend::kDop853;
  if (name == "cvodes-bdf") return Backend::kCvodesBdf;
  if (name == "cvodes-adams") return Backend::kCvodesAdams;
  throw InvalidArgument("integrator \"" + name +
                        "\" is unknown; choose auto, dopri5, dop853, cvodes-bdf or cvodes-adams");
}

Backend choose_backend(Backend backend, double rtol, int states, int surfaces) {
  if (backend != Backend::kAutomatic) return backend;
  const bool high_order =
      rtol <= kAutomaticHighOrderRtol || states >= kAutomaticHighOrderStates || surfaces == 0;
  return high_order ? Backend::kDop853 : Backend::kDopri5;
}

Grouping parse_grouping(const std::string& name) {
  if (name == "auto") return Grouping::kAutomatic;
  if (name == "window") return Grouping::kFixedWindow;
  if (name == "none") return Grouping::kNone;
  throw InvalidArgument("grouping \"" + name + "\" is unknown; choose auto, window or none");
}

const char* to_string(Grouping grouping) {
  switch (grouping) {
    case Grouping::kAutomatic:
      return "auto";
    case Grouping::kFixedWindow:
      return "window";
    case Grouping::kNone:
      return "none";
  }
  return "unknown";
}

const char* to_string(Backend backend) {
  switch (backend) {
    case Backend::kDopri5:
      return "dopri5";
    case Backend::kDop853:
      return "dop853";
    case Backend::kCvodesBdf:
      return "cvodes-bdf";
    case Backend::kCvodesAdams:
      return "cvodes-adams";
    case Backend::kAutomatic:
      return "auto";
  }
  return "unknown";
}

namespace {

std::string indices_text(const std::vector<int>& indices) {
  std::string text = "[";
  for (std::size_t i = 0; i < indices.size(); ++i) {
    text += (i ? ", " : "") + std::to_string(indices[i]);
  }
  return text + "]";
}

Signs starting_sides(const SegmentModel& model, const Eigen::VectorXd& x0,
                     const FlowOptions& options) {
  const int n = model.surfaces();
  if (options.initial_sides) {
    if (options.initial_sides->size() != n) {
      throw InvalidArgument("initial_sides \"" + options.initial_sides->str() + "\" names " +
                            std::to_string(options.initial_sides->size()) +
                            " surfaces, the model has " + std::to_string(n));
    }
    // A side may be given only where h_j(x0) cannot tell it: within what the integrator's
    // tolerance moves h_j, |Dh_j(x0)|_1 (atol + rtol |x0|_inf). A state is known only to that
    // accuracy, and the engine's own states sit as close to a surface on its other side (a run
    // that ends at a crossing it did not take, a point projected onto a section). Beyond it,
    // the side h_j(x0) has is the only one the flow can start on.
    const Signs sides = *options.initial_sides;
    if (n > 0) {
      Eigen::VectorXd h(n);
      model.surface_values(x0.data(), h.data());
      const Eigen::MatrixXd normals = model.surface_normals(x0);
      for (int j = 0; j < n; ++j) {
        if (!std::isfinite(h[j]) || h[j] == 0.0 || (h[j] > 0.0) == sides.plus(j)) continue;
        const IntegratorOptions& integ = options.integrator;
        const double band =
            normals.row(j).lpNorm<1>() *
            (integ.absolute_tolerance() + integ.rtol * x0.lpNorm<Eigen::Infinity>());
        if (!(std::abs(h[j]) <= band)) {
          throw InvalidArgument(
              "initial_sides \"" + sides.str() + "\" puts x0 on side " +
              (sides.plus(j) ? "+" : "-") + " of surface " + std::to_string(j) + ", but h_" +
              std::to_string(j) + "(x0) = " + format_number(h[j]) +
              " is beyond what the integration tolerance moves h there (" + format_number(band) +
              " = |Dh_j(x0)|_1 (atol + rtol |x0|_inf)): a side may be given only where x0 is on "
              "the surface to that tolerance");
        }
      }
    }
    return sides;
  }
  Eigen::VectorXd h(n);
  model.surface_values(x0.data(), h.data());
  std::uint64_t bits = 0;
  for (int j = 0; j < n; ++j) {
    if (!std::isfinite(h[j]) || h[j] == 0.0) {
      throw InvalidArgument("x0 = " + format_vector(x0) + " has h_" + std::to_string(j) + " = " +
                            format_number(h[j]) + ": its side of surface " + std::to_string(j) +
                            " is undecided; give FlowOptions::initial_sides");
    }
    if (h[j] > 0) bits |= std::uint64_t{1} << j;
  }
  return Signs(n, bits);
}

// Normal speeds below this fraction of |eta| |F| count as this fast in the grouping window.
constexpr double kMinGroupingMargin = 1e-2;

// A real number m 2^e (0.5 <= |m| < 1, or m = 0) with an exponent of its own, for the quantities
// of the grouping rule: products and quotients of norms, speeds and tolerances that are huge or
// tiny never leave its range, so every decision compares the true magnitudes and only a number
// that is reported (to_double()) can overflow. m = NaN is "undefined" (a non-finite input, a
// division by zero): it stays undefined through every operation, and every comparison with it is
// false, so nothing is grouped on it.
class Wide {
 public:
  Wide() = default;
  /** x exactly; undefined unless x is finite. */
  explicit Wide(double x) {
    if (std::isfinite(x)) {
      m_ = std::frexp(x, &e_);
    } else {
      m_ = std::numeric_limits<double>::quiet_NaN();
    }
  }
  static Wide undefined() { return Wide(std::numeric_limits<double>::quiet_NaN()); }
  /** m 2^e, renormalised; undefined unless m is finite. */
  static Wide from_parts(double m, long e) {
    Wide w(m);
    if (w.defined() && w.m_ != 0.0) {
      w.e_ = static_cast<int>(std::clamp<long>(e + w.e_, -kExponentLimit, kExponentLimit));
    }
    return w;
  }

  bool defined() const { return !std::isnan(m_); }
  double mantissa() const { return m_; }
  int exponent() const { return e_; }
  Wide abs() const { return from_parts(std::abs(m_), e_); }
  /** The nearest double: +-inf beyond the double range, subnormal or 0 below it; NaN if
      undefined. */
  double to_double() const { return std::ldexp(m_, e_); }
  /** Decimal: format_number() within the double range, four digits beyond it (2^1100 as
      "1.359e+331"). */
  std::string text() const {
    const double value = to_double();
    if (std::isfinite(value) || !defined()) return format_number(value);
    const double decimal = std::log10(std::abs(m_)) + e_ * std::log10(2.0);
    double exponent = std::floor(decimal);
    double digits = std::round(std::pow(10.0, decimal - exponent) * 1000.0) / 1000.0;
    if (digits >= 10.0) {
      digits /= 10.0;
      exponent += 1.0;
    }
    char buffer[48];
    std::snprintf(buffer, sizeof buffer, "%s%.3fe%+.0f", m_ < 0.0 ? "-" : "", digits, exponent);
    return buffer;
  }

  friend Wide operator-(const Wide& a) { return from_parts(-a.m_, a.e_); }
  friend Wide operator*(const Wide& a, const Wide& b) {
    return from_parts(a.m_ * b.m_, static_cast<long>(a.e_) + b.e_);
  }
  /** Undefined when b is 0. */
  friend Wide operator/(const Wide& a, const Wide& b) {
    return from_parts(a.m_ / b.m_, static_cast<long>(a.e_) - b.e_);
  }
  friend Wide operator+(const Wide& a, const Wide& b) {
    if (!a.defined() || !b.defined()) return undefined();
    if (a.m_ == 0.0) return b;
    if (b.m_ == 0.0) return a;
    const Wide& big = a.e_ >= b.e_ ? a : b;
    const Wide& small = a.e_ >= b.e_ ? b : a;
    const long shift = static_cast<long>(big.e_) - small.e_;
    if (shift > 1100) return big;  // below half an ulp of big, even as a subnormal
    return from_parts(big.m_ + std::ldexp(small.m_, static_cast<int>(-shift)), big.e_);
  }
  friend Wide operator-(const Wide& a, const Wide& b) { return a + (-b); }
  // False when either side is undefined.
  friend bool operator<(const Wide& a, const Wide& b) { return (a - b).m_ < 0.0; }
  friend bool operator<=(const Wide& a, const Wide& b) { return (a - b).m_ <= 0.0; }
  /** The larger; undefined when either is. */
  friend Wide max(const Wide& a, const Wide& b) {
    if (!a.defined() || !b.defined()) return undefined();
    return a < b ? b : a;
  }

 private:
  // Exponents stay far inside int; the clamp only guards against pathological chains.
  static constexpr long kExponentLimit = 1L << 20;
  double m_ = 0.0;
  int e_ = 0;
};

// The Euclidean norm, each entry scaled by the power of two of the largest first: neither the
// squares overflow nor the entries far below the largest underflow. Undefined if an entry is.
Wide euclidean_norm(const std::vector<Wide>& v) {
  int top = std::numeric_limits<int>::min();
  for (const Wide& x : v) {
    if (!x.defined()) return Wide::undefined();
    if (x.mantissa() != 0.0) top = std::max(top, x.exponent());
  }
  if (top == std::numeric_limits<int>::min()) return Wide(0.0);
  double sum = 0.0;
  for (const Wide& x : v) {
    const double scaled = std::ldexp(x.mantissa(), x.exponent() - top);  // |scaled| < 1
    sum += scaled * scaled;
  }
  return Wide::from_parts(std::sqrt(sum), top);
}

std::vector<Wide> wide_vector(const Eigen::Ref<const Eigen::RowVectorXd>& v) {
  std::vector<Wide> out;
  out.reserve(static_cast<std::size_t>(v.size()));
  for (Eigen::Index i = 0; i < v.size(); ++i) out.emplace_back(v[i]);
  return out;
}

// a . b, each product and partial sum with its own exponent. Undefined if an entry is.
Wide wide_dot(const std::vector<Wide>& a, const std::vector<Wide>& b) {
  Wide sum(0.0);
  for (std::size_t i = 0; i < a.size(); ++i) sum = sum + a[i] * b[i];
  return sum;
}

struct Event {
  EventRecord record;
  std::optional<JumpMap> jump;
  /** Non-empty when a number of the record is beyond the double range: the run ends with
      kOverflow and this message (no jump is built). */
  std::string overflow;
};

Event make_event(const SegmentModel& model, const SegmentResult& segment, Signs sides,
                 const FlowOptions& options) {
  const int d = model.states();
  const int n_model = model.surfaces();
  const Eigen::VectorXd& rho = segment.x;
  const double t1 = segment.t;
  Event event;
  EventRecord& record = event.record;
  record.t = t1;
  record.rho = rho;
  record.sides_before = sides;

  const Eigen::MatrixXd dh = model.surface_normals(rho);
  Eigen::VectorXd h(n_model);
  model.surface_values(rho.data(), h.data());
  Eigen::VectorXd f_before(d);
  model.field(rho.data(), sides, f_before.data());

  // The crossing-time uncertainty of each surface: the integrator's tolerance on the state,
  // seen through the surface's normal and normal speed (header comment, "Grouping"). A state
  // error e with |e_i| <= tol_i moves h_j by at most sum_i |dh_j/dx_i| tol_i, so a coordinate the
  // surface does not depend on does not widen its window. Every quantity is a Wide: a tolerance
  // of 1e200 times a normal of 1e200, or |F| of 1e200, has no finite double (square), while the
  // window they give is an ordinary number.
  const Wide rtol(options.integrator.rtol);
  const Wide atol(options.integrator.absolute_tolerance());
  std::vector<Wide> tolerance;
  for (Eigen::Index i = 0; i < d; ++i) tolerance.push_back(atol + rtol * Wide(std::abs(rho[i])));
  const Wide time_floor(16.0 * std::numeric_limits<double>::epsilon() * std::abs(t1));
  const std::vector<Wide> field = wide_vector(f_before.transpose());
  const Wide f_norm = euclidean_norm(field);
  const Wide min_margin(kMinGroupingMargin);
  const Wide safety(options.grouping_safety);
  // sum_i |dh_j/dx_i| tol_i, and the normal speed max(|Dh_j . F|, kMinGroupingMargin |Dh_j| |F|):
  // a crossing slower than kMinGroupingMargin (eta . F below that fraction of |eta| |F|) counts
  // as that fast. As sum_i |dh_j/dx_i| tol_i <= |Dh_j| |tol|, its window stays below
  // 2 grouping_safety / kMinGroupingMargin times the time the trajectory takes to move by one
  // tolerance |tol|, so grouping never flips a side by more than a bounded number of tolerances
  // early. A vanishing normal or field leaves the speed zero and sigma undefined.
  const auto weighted_tolerance = [&](int j) {
    Wide sum(0.0);
    for (Eigen::Index i = 0; i < d; ++i) {
      sum = sum + Wide(dh(j, i)).abs() * tolerance[static_cast<std::size_t>(i)];
    }
    return sum;
  };
  const auto normal_speed = [&](int j) {
    const std::vector<Wide> normal_row = wide_vector(dh.row(j));
    const Wide normal = euclidean_norm(normal_row);
    return max(wide_dot(normal_row, field).abs(), min_margin * normal * f_norm);
  };
  const auto sigma = [&](int j) { return weighted_tolerance(j) / normal_speed(j) + time_floor; };
  // How long after t1 each surface is located to cross: 0 for the first crossing; the backend's
  // root in the same step; else, for a surface approaching, the linearised time to reach it from
  // rho (a tiny extrapolation: only windows are compared). Undefined for the others (receding,
  // or a value that is not finite), which never join.
  std::vector<Wide> delay(static_cast<std::size_t>(n_model), Wide::undefined());
  std::vector<double> located(static_cast<std::size_t>(n_model), t1);
  for (int j = 0; j < n_model; ++j) {
    const std::size_t uj = static_cast<std::size_t>(j);
    const bool crossed =
        std::find(segment.crossed.begin(), segment.crossed.end(), j) != segment.crossed.end();
    if (crossed) {
      delay[uj] = Wide(0.0);
    } else if (uj < segment.crossing_times.size() && std::isfinite(segment.crossing_times[uj])) {
      located[uj] = segment.crossing_times[uj];
      delay[uj] = Wide(located[uj]) - Wide(t1);
    } else {
      const double s = sides.plus(j) ? 1.0 : -1.0;
      const Wide rate = Wide(s) * wide_dot(wide_vector(dh.row(j)), field);
      if (rate < Wide(0.0)) {
        delay[uj] = Wide(s * h[j]) / -rate;
        located[uj] = (Wide(t1) + delay[uj]).to_double();
      }
    }
  }
  Wide sigma_first(0.0);
  for (int j : segment.crossed) sigma_first = max(sigma_first, sigma(j));
  const Wide automatic_window = Wide(2.0) * safety * sigma_first;

  std::vector<int> group = segment.crossed;
  Wide window_used = options.grouping == Grouping::kAutomatic ? automatic_window
                     : options.grouping == Grouping::kFixedWindow
                         ? Wide(options.simultaneity_window)
                         : Wide(0.0);
  for (int j = 0; j < n_model; ++j) {
    const std::size_t uj = static_cast<std::size_t>(j);
    if (std::find(group.begin(), group.end(), j) != group.end() || !delay[uj].defined()) {
      continue;
    }
    Wide window(0.0);
    switch (options.grouping) {
      case Grouping::kAutomatic:
        window = safety * (sigma(j) + sigma_first);
        break;
      case Grouping::kFixedWindow:
        window = Wide(options.simultaneity_window);
        break;
      case Grouping::kNone:
        window = Wide(0.0);
        break;
    }
    // False for an undefined delay or window: a surface joins only on a defined comparison.
    if (delay[uj] <= window) {
      group.push_back(j);
      window_used = max(window_used, window);
    }
  }
  std::sort(group.begin(), group.end());
  record.surfaces = group;
  record.automatic_window = automatic_window.to_double();
  record.window = window_used.to_double();
  for (int j : group) record.crossing_times.push_back(located[static_cast<std::size_t>(j)]);
  record.spread = *std::max_element(record.crossing_times.begin(), record.crossing_times.end()) -
                  *std::min_element(record.crossing_times.begin(), record.crossing_times.end());
  const int n = static_cast<int>(group.size());

  // Oriented normals: the flow crosses from the current side to the other.
  Eigen::MatrixXd eta(n, d);
  std::uint64_t flip = 0;
  for (int k = 0; k < n; ++k) {
    const int j = group[static_cast<std::size_t>(k)];
    eta.row(k) = (sides.plus(j) ? -1.0 : 1.0) * dh.row(j);
    flip |= std::uint64_t{1} << j;
  }
  record.sides_after = sides.flipped(flip);
  Eigen::VectorXd f_after(d);
  model.field(rho.data(), record.sides_after, f_after.data());
  // Cosines from vectors scaled by their largest entry first, so that a field of 1e200 (whose
  // squared norm overflows) is judged by its direction, not reported as grazing.
  const auto direction = [](Eigen::VectorXd v) {
    v /= v.cwiseAbs().maxCoeff();
    return Eigen::VectorXd(v.normalized());
  };
  const Eigen::VectorXd u_before = direction(f_before);
  const Eigen::VectorXd u_after = direction(f_after);
  for (int k = 0; k < n; ++k) {
    const int j = group[static_cast<std::size_t>(k)];
    const Eigen::VectorXd normal = direction(eta.row(k).transpose());
    const double before = normal.dot(u_before);
    const double after = normal.dot(u_after);
    record.margin_before.push_back(before);
    record.margin_after.push_back(after);
    if (!(before >= options.grazing_threshold)) {
      throw InvalidArgument(
          "grazing at t = " + format_number(segment.t) + ": surface " + std::to_string(j) +
          " is reached with eta . F / (|eta| |F|) = " + format_number(before) +
          " < grazing_threshold " + format_number(options.grazing_threshold) +
          " at rho = " + format_vector(rho) + "; the B-derivative does not exist at a tangency");
    }
    if (!(after > 0.0)) {
      throw InvalidArgument(
          "sliding at t = " + format_number(segment.t) + ": after crossing surface " +
          std::to_string(j) + " the field F_" + record.sides_after.str() +
          " points back into it (eta . F / (|eta| |F|) = " + format_number(after) +
          ") at rho = " + format_vector(rho) +
          "; the flow is not event-selected there. Simulate sliding with FESD (bflow/fesd/fesd.h, "
          "bflow fesd)");
    }
  }

  // After the transversality checks (a vanishing field or normal is grazing, not overflow): every
  // number of the record must be finite. One that is not ends the run: no window is reported as
  // infinite, and no surface is grouped on one.
  const auto overflow = [&]() -> std::string {
    std::string what;
    if (!std::isfinite(record.automatic_window)) {
      what = "the automatic grouping window = " + automatic_window.text();
    } else if (!std::isfinite(record.window)) {
      what = "the grouping window = " + window_used.text();
    } else if (!std::isfinite(record.spread)) {
      // A crossing time first, then the spread of finite ones.
      for (int j : group) {
        const std::size_t uj = static_cast<std::size_t>(j);
        if (!std::isfinite(located[uj])) {
          what = "the located crossing time of surface " + std::to_string(j) + " = " +
                 (Wide(t1) + delay[uj]).text();
          break;
        }
      }
      if (what.empty()) {
        const auto [low, high] =
            std::minmax_element(record.crossing_times.begin(), record.crossing_times.end());
        what = "the spread of the crossing times = " + (Wide(*high) - Wide(*low)).text();
      }
    }
    if (what.empty()) return what;
    // The terms of sigma_j for the surface of the group with the largest one.
    int widest = group.front();
    for (int j : group) {
      if (sigma(widest) < sigma(j)) widest = j;
    }
    const std::string js = std::to_string(widest);
    return "the event at t = " + format_number(t1) + ", surfaces " + indices_text(group) + ": " +
           what + " is beyond the double range (surface " + js + ": sum_i |dh_" + js +
           "/dx_i| (atol + rtol |rho_i|) = " + weighted_tolerance(widest).text() +
           ", normal speed " + normal_speed(widest).text() + ", |F(rho)| = " + f_norm.text() +
           "); its grouping cannot be reported. Tighten rtol or rescale the model";
  }();
  if (!overflow.empty()) {
    event.overflow = overflow;
    return event;
  }

  // Limits F_w(rho) for the words w of the group, placed into the model's sides.
  auto full_sides = [sides, group](Signs w) {
    std::uint64_t mask = 0;
    for (std::size_t k = 0; k < group.size(); ++k) {
      if (w.plus(static_cast<int>(k))) mask |= std::uint64_t{1} << group[k];
    }
    return sides.flipped(mask);
  };
  try {
    if (n <= JumpMap::kMaxEnumeratedSurfaces) {
      // The word of no flip is F before the crossing, the word of every flip F after it.
      const Eigen::Index words = Eigen::Index{1} << n;
      Eigen::MatrixXd table(d, words);
      table.col(0) = f_before;
      table.col(words - 1) = f_after;
      for (Eigen::Index w = 1; w + 1 < words; ++w) {
        model.field(rho.data(), full_sides(Signs(n, static_cast<std::uint64_t>(w))),
                    table.col(w).data());
      }
      event.jump.emplace(eta, table);
    } else {
      // The model must outlive the jump map (documented on flow_derivative()).
      event.jump.emplace(eta, [&model, rho, full_sides](Signs w, Eigen::Ref<Eigen::VectorXd> out) {
        model.field(rho.data(), full_sides(w), out.data());
      });
    }
  } catch (const InvalidArgument& e) {
    throw InvalidArgument("event at t = " + format_number(segment.t) + ", surfaces " +
                          indices_text(group) + ": " + e.what());
  }
  return event;
}

FlowNotice near_grazing(const NearMiss& miss) {
  FlowNotice notice;
  notice.kind = FlowNotice::Kind::kNearGrazing;
  notice.surfaces = {miss.surface};
  notice.times = {miss.t};
  notice.gap = miss.g_min;
  notice.band = miss.band;
  notice.message = "near grazing: surface " + std::to_string(miss.surface) +
                   " passed at t = " + format_number(miss.t) +
                   " at distance g = " + format_number(miss.g_min) + ", inside the band " +
                   format_number(miss.band) +
                   " where the integration error could hide a crossing; tighten rtol to decide";
  return notice;
}

// The newest event and the one before it: their gaps, and a notice when crossings of different
// surfaces were resolved as separate events closer than the near-simultaneity band. The times
// and windows are finite (make_event); a gap or a band they give beyond the double range is
// returned as a message (the run then ends with kOverflow), and nothing is recorded.
std::string note_neighbours(FlowResult& result, const FlowOptions& options) {
  if (result.events.size() < 2) return {};
  EventRecord& before = result.events[result.events.size() - 2];
  EventRecord& after = result.events.back();
  const double last_before =
      *std::max_element(before.crossing_times.begin(), before.crossing_times.end());
  const double first_after =
      *std::min_element(after.crossing_times.begin(), after.crossing_times.end());
  const auto between = [&] {
    return "between the events at t = " + format_number(before.t) +
           " and t = " + format_number(after.t) + ": ";
  };
  // Finite operands: the difference is exact to one rounding or +-infinity, never NaN.
  const double gap = first_after - last_before;
  if (!std::isfinite(gap)) {
    return between() + "the gap " + format_number(first_after) + " - " +
           format_number(last_before) + " is beyond the double range";
  }
  bool other_surface = false;
  for (int j : after.surfaces) {
    other_surface |=
        std::find(before.surfaces.begin(), before.surfaces.end(), j) == before.surfaces.end();
  }
  // Nonnegative finite operands: the product is +infinity at worst, never NaN.
  const double band =
      options.near_simultaneity_band * std::max(before.automatic_window, after.automatic_window);
  if (other_surface && gap < band && !std::isfinite(band)) {
    return between() + "the near-simultaneity band " +
           format_number(options.near_simultaneity_band) + " x " +
           format_number(std::max(before.automatic_window, after.automatic_window)) +
           " is beyond the double range; the notice for a gap of " + format_number(gap) +
           " cannot be reported. Lower near_simultaneity_band or tighten rtol";
  }
  before.gap = std::min(before.gap, gap);
  after.gap = std::min(after.gap, gap);
  if (!other_surface || !(gap < band)) return {};
  FlowNotice notice;
  notice.kind = FlowNotice::Kind::kNearSimultaneous;
  notice.surfaces = before.surfaces;
  notice.surfaces.insert(notice.surfaces.end(), after.surfaces.begin(), after.surfaces.end());
  notice.times = {last_before, first_after};
  notice.gap = gap;
  notice.band = band;
  notice.message =
      "near-simultaneous crossings not grouped: surfaces " + indices_text(before.surfaces) +
      " at t = " + format_number(last_before) + " and " + indices_text(after.surfaces) +
      " at t = " + format_number(first_after) + ", " + format_number(gap) +
      " apart (grouping window " + format_number(after.window) + ", band " + format_number(band) +
      "); the derivative holds only for perturbations that keep this order. "
      "Tighten rtol to confirm, or group them (FlowOptions::grouping)";
  result.notices.push_back(std::move(notice));
  return {};
}

// The Runge-Kutta integrators a thread keeps between runs, with their steppers' storage: a
// caller that simulates many short runs (a sweep's samples, the peers' timing loop, a Newton
// iteration on a return map) builds its stage vectors once per thread, not once per run. A kept
// integrator gives what a new one gives (every segment rebinds the model, its sides and the
// options; tests/integrators/integrator_test.cc). A run that starts while the thread's own is
// in use (a model whose field simulates) gets a new one. CVODES is built per run.
class IntegratorLease {
 public:
  explicit IntegratorLease(Backend backend) {
    const int slot = backend == Backend::kDopri5 ? 0 : backend == Backend::kDop853 ? 1 : -1;
    if (slot >= 0 && !kept_.busy[slot]) {
      std::unique_ptr<SegmentIntegrator>& integrator = kept_.integrators[slot];
      if (!integrator) integrator = make_integrator(backend);
      kept_.busy[slot] = true;
      slot_ = slot;
      integrator_ = integrator.get();
    } else {
      own_ = make_integrator(backend);
      integrator_ = own_.get();
    }
  }
  ~IntegratorLease() {
    if (slot_ >= 0) kept_.busy[slot_] = false;
  }
  IntegratorLease(const IntegratorLease&) = delete;
  IntegratorLease& operator=(const IntegratorLease&) = delete;
  SegmentIntegrator* operator->() const { return integrator_; }

 private:
  struct Kept {
    std::unique_ptr<SegmentIntegrator> integrators[2];  // dopri5, dop853
    bool busy[2] = {false, false};
  };
  static thread_local Kept kept_;
  std::unique_ptr<SegmentIntegrator> own_;
  SegmentIntegrator* integrator_ = nullptr;
  int slot_ = -1;
};
thread_local IntegratorLease::Kept IntegratorLease::kept_;

FlowResult run(const SegmentModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
               double t_final, const Eigen::MatrixXd* directions, const FlowOptions& options,
               FlowDerivative* derivative) {
  const int d = model.states();
  if (x0.size() != d || !x0.allFinite()) {
    throw InvalidArgument("x0 must have d = " + std::to_string(d) + " finite numbers, got " +
                          format_vector(x0));
  }
  if (!(t_final >= 0.0) || !std::isfinite(t_final)) {
    throw InvalidArgument("t must be finite and >= 0, got " + format_number(t_final));
  }
  if (!(options.simultaneity_window >= 0.0) || !std::isfinite(options.simultaneity_window)) {
    throw InvalidArgument("simultaneity_window must be finite and >= 0, got " +
                          format_number(options.simultaneity_window));
  }
  if (!(options.grouping_safety > 0.0) || !std::isfinite(options.grouping_safety)) {
    throw InvalidArgument("grouping_safety must be finite and > 0, got " +
                          format_number(options.grouping_safety));
  }
  if (!(options.near_simultaneity_band >= 1.0) || !std::isfinite(options.near_simultaneity_band)) {
    throw InvalidArgument("near_simultaneity_band must be finite and >= 1, got " +
                          format_number(options.near_simultaneity_band));
  }
  FlowResult result;
  result.sides = starting_sides(model, x0, options);
  result.backend = choose_backend(options.backend, options.integrator.rtol, d, model.surfaces());
  const IntegratorLease integrator(result.backend);
  SegmentRequest request;
  request.sides = result.sides;
  request.t0 = 0.0;
  request.t_end = t_final;
  request.x0 = x0;
  if (derivative != nullptr) {
    request.v0 = Eigen::MatrixXd::Identity(d, d);
  } else if (directions != nullptr) {
    request.v0 = *directions;
  } else {
    request.v0.resize(d, 0);
  }
  while (true) {
    const SegmentResult segment = integrator->integrate(model, request, options.integrator);
    result.steps += segment.steps;
    result.field_evaluations += segment.field_evaluations;
    result.t = segment.t;
    result.x = segment.x;
    // A band beyond the double range (huge tolerances or normals): every passage is inside it,
    // but the notice could not report it.
    const auto unbounded = std::find_if(segment.near_misses.begin(), segment.near_misses.end(),
                                        [](const NearMiss& m) { return !std::isfinite(m.band); });
    if (unbounded != segment.near_misses.end()) {
      result.status = IntegrationStatus::kOverflow;
      result.message = "near grazing of surface " + std::to_string(unbounded->surface) +
                       " at t = " + format_number(unbounded->t) +
                       " at distance g = " + format_number(unbounded->g_min) +
                       ": the band where the integration error could hide a crossing, 8 sum_i "
                       "|dh/dx_i| (atol + rtol |x_i|), is beyond the double range; tighten the "
                       "tolerances or rescale the model";
      break;
    }
    for (const NearMiss& miss : segment.near_misses) result.notices.push_back(near_grazing(miss));
    if (segment.status == IntegrationStatus::kCrossing) {
      Event event = make_event(model, segment, request.sides, options);
      if (!event.overflow.empty()) {
        result.status = IntegrationStatus::kOverflow;
        result.message = std::move(event.overflow);
        break;
      }
      if (derivative != nullptr) {
        derivative->append_transition(segment.v);
        derivative->append_jump(std::move(*event.jump), segment.t, event.record.surfaces);
        request.v0 = Eigen::MatrixXd::Identity(d, d);
      } else {
        request.v0 = segment.v;
        if (request.v0.cols() > 0) event.jump->apply_block(segment.v, request.v0);
      }
      request.sides = event.record.sides_after;
      request.t0 = segment.t;
      request.x0 = segment.x;
      result.events.push_back(std::move(event.record));
      std::string overflow = note_neighbours(result, options);
      if (!overflow.empty()) {
        result.events.pop_back();  // its gap is unknown: events keeps the complete records
        result.status = IntegrationStatus::kOverflow;
        result.message = std::move(overflow);
        break;
      }
      if (static_cast<int>(result.events.size()) > options.max_events) {
        result.status = IntegrationStatus::kTooManyEvents;
        result.message = std::to_string(result.events.size()) +
                         " events by t = " + format_number(segment.t) + " (max_events " +
                         std::to_string(options.max_events) +
                         "): the trajectory may be Zeno (events accumulating)";
        break;
      }
      continue;
    }
    result.status = segment.status;
    result.message = segment.message;
    if (segment.status == IntegrationStatus::kReachedEnd) {
      if (derivative != nullptr) {
        derivative->append_transition(segment.v);
        Eigen::VectorXd field(d);
        model.field(segment.x.data(), request.sides, field.data());
        derivative->set_time_derivative(field);
      } else {
        result.v = segment.v;
      }
    }
    break;
  }
  result.sides = request.sides;
  if (derivative != nullptr) {
    for (const FlowNotice& notice : result.notices) derivative->add_notice(notice);
  }
  return result;
}

}  // namespace

FlowResult simulate(const SegmentModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                    double t_final, const FlowOptions& options) {
  return run(model, x0, t_final, nullptr, options, nullptr);
}

FlowResult simulate(const SegmentModel& model, const Eigen::Ref<const Eigen::VectorXd>& x0,
                    double t_final, const Eigen::Ref<const Eigen::MatrixXd>& directions,
                    const FlowOptions& options) {
  if (directions.rows() != model.states() || !directions.allFinite()) {
    throw InvalidArgument("directions must be finite with d = " + std::to_string(model.states()) +
                          " rows, got " + std::to_string(directions.rows()) + " x " +
                          std::to_string(directions.cols()));
  }
  const Eigen::MatrixXd copy = directions;
  return run(model, x0, t_final, &copy, options, nullptr);
}

FlowDerivative flow_derivative(const SegmentModel& model,
                               const Eigen::Ref<const Eigen::VectorXd>& x0, double t_final,
                               const FlowOptions& options, FlowResult* trajectory) {
  FlowDerivative derivative(model.states());
  FlowResult result = run(model, x0, t_final, nullptr, options, &derivative);
  if (!result.ok()) {
    throw InvalidArgument(std::string("flow_derivative: the simulation ended with ") +
                          to_string(result.status) + ": " + result.message);
  }
  if (trajectory != nullptr) *trajectory = std::move(result);
  return derivative;
}

std::unique_ptr<SegmentIntegrator> make_integrator(Backend backend) {
  switch (backend) {
    case Backend::kDopri5:
      return std::make_unique<Dopri5Integrator>();
    case Backend::kDop853:
      return std::make_unique<Dop853Integrator>();
    case Backend::kCvodesBdf:
      return std::make_unique<CvodesIntegrator>(CvodesMethod::kBdf);
    case Backend::kCvodesAdams:
      return std::make_unique<CvodesIntegrator>(CvodesMethod::kAdams);
    case Backend::kAutomatic:
      throw InvalidArgument(
          "make_integrator: \"auto\" names no backend until the tolerance and the model are "
          "known; resolve it with choose_backend(backend, rtol, states, surfaces)");
  }
  throw InvalidArgument(std::string("integrator ") + to_string(backend) + " is unknown");
}

}  // namespace bflow

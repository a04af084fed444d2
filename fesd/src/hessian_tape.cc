#include "bflow/fesd/hessian_tape.h"

#include <cmath>
#include <cstring>
#include <unordered_map>

#include "bflow/core/errors.h"

namespace bflow {
namespace fesd {

namespace {

using Op = HessianTape::Op;
using Test = HessianTape::Test;

// A node of the expression graph: an input, a constant or an operation on earlier nodes (so the
// node order is a topological order).
enum class Kind : unsigned char { kInput, kConstant, kOperation };
struct Node {
  Kind kind;
  Op op;
  int x, y;  // operands (-1: none)
  double c;  // a constant's value, kPowC's exponent, kCPow's base; an input's index
};

struct Key {
  Kind kind;
  Op op;
  int x, y;
  std::uint64_t c;
  bool operator==(const Key& o) const {
    return kind == o.kind && op == o.op && x == o.x && y == o.y && c == o.c;
  }
};
struct KeyHash {
  std::size_t operator()(const Key& k) const {
    std::size_t h = static_cast<std::size_t>(k.kind) * 31u + static_cast<std::size_t>(k.op);
    h = h * 1000003u ^ static_cast<std::size_t>(k.x + 1);
    h = h * 1000003u ^ static_cast<std::size_t>(k.y + 1);
    h = h * 1000003u ^ static_cast<std::size_t>(k.c ^ (k.c >> 29));
    return h;
  }
};

std::uint64_t bits(double c) {
  std::uint64_t b;
  std::memcpy(&b, &c, sizeof b);
  return b;
}

bool commutative(Op op) { return op == Op::kAdd || op == Op::kMul; }

}  // namespace

struct HessianProgram::Graph::Impl {
  std::vector<Node> nodes;
  std::unordered_map<Key, int, KeyHash> index;
  std::vector<Guard> guards;

  int add_node(Kind kind, Op op, int x, int y, double c) {
    const Key key{kind, op, x, y, bits(c)};
    const auto it = index.find(key);
    if (it != index.end()) return it->second;
    nodes.push_back({kind, op, x, y, c});
    const int id = static_cast<int>(nodes.size()) - 1;
    index.emplace(key, id);
    return id;
  }
  int constant(double value) { return add_node(Kind::kConstant, Op::kAdd, -1, -1, value); }
  bool is_constant(int n, double* value = nullptr) const {
    const Node& node = nodes[static_cast<std::size_t>(n)];
    if (node.kind != Kind::kConstant) return false;
    if (value != nullptr) *value = node.c;
    return true;
  }
  bool is_zero(int n) const {
    double c;
    return is_constant(n, &c) && c == 0.0;
  }

  static double apply(Op op, double x, double y, double c) {
    switch (op) {
      case Op::kAdd:
        return x + y;
      case Op::kSub:
        return x - y;
      case Op::kMul:
        return x * y;
      case Op::kDiv:
        return x / y;
      case Op::kNeg:
        return -x;
      case Op::kSqrt:
        return std::sqrt(x);
      case Op::kSin:
        return std::sin(x);
      case Op::kCos:
        return std::cos(x);
      case Op::kTan:
        return std::tan(x);
      case Op::kExp:
        return std::exp(x);
      case Op::kLog:
        return std::log(x);
      case Op::kLog1p:
        return std::log1p(x);
      case Op::kSinh:
        return std::sinh(x);
      case Op::kCosh:
        return std::cosh(x);
      case Op::kTanh:
        return std::tanh(x);
      case Op::kAtan:
        return std::atan(x);
      case Op::kCbrt:
        return std::cbrt(x);
      case Op::kAsin:
        return std::asin(x);
      case Op::kAcos:
        return std::acos(x);
      case Op::kExpm1:
        return std::expm1(x);
      case Op::kLog10:
        return std::log10(x);
      case Op::kLog2:
        return std::log2(x);
      case Op::kPowC:
        return std::pow(x, c);
      case Op::kCPow:
        return std::pow(c, x);
      case Op::kAtan2:
        return std::atan2(x, y);
    }
    return 0.0;
  }

  // op(x[, y]) with constants folded and the identities x + 0, x * 1, x * 0, 0 / y, x / 1, --x
  // applied (x * 0 = 0 also for an infinite x: a structural zero, as the lanes HessianJet
  // leaves out), operands of + and * ordered, equal nodes merged.
  int make(Op op, int x, int y = -1, double c = 0.0) {
    double vx = 0.0, vy = 0.0;
    const bool cx = is_constant(x, &vx);
    const bool cy = y >= 0 && is_constant(y, &vy);
    if (cx && (y < 0 || cy)) return constant(apply(op, vx, vy, c));
    switch (op) {
      case Op::kAdd:
        if (cx && vx == 0.0) return y;
        if (cy && vy == 0.0) return x;
        break;
      case Op::kSub:
        if (cy && vy == 0.0) return x;
        if (cx && vx == 0.0) return make(Op::kNeg, y);
        if (x == y) return constant(0.0);
        break;
      case Op::kMul:
        if ((cx && vx == 0.0) || (cy && vy == 0.0)) return constant(0.0);
        if (cx && vx == 1.0) return y;
        if (cy && vy == 1.0) return x;
        if (cx && vx == -1.0) return make(Op::kNeg, y);
        if (cy && vy == -1.0) return make(Op::kNeg, x);
        break;
      case Op::kDiv:
        if (cx && vx == 0.0) return constant(0.0);
        if (cy && vy == 1.0) return x;
        break;
      case Op::kNeg: {
        const Node& n = nodes[static_cast<std::size_t>(x)];
        if (n.kind == Kind::kOperation && n.op == Op::kNeg) return n.x;
        break;
      }
      case Op::kPowC:
        if (c == 0.0) return constant(1.0);
        if (c == 1.0) return x;
        break;
      default:
        break;
    }
    if (commutative(op) && y >= 0 && y < x) std::swap(x, y);
    return add_node(Kind::kOperation, op, x, y, c);
  }
  int add(int x, int y) { return make(Op::kAdd, x, y); }
  int sub(int x, int y) { return make(Op::kSub, x, y); }
  int mul(int x, int y) { return make(Op::kMul, x, y); }
  int div(int x, int y) { return make(Op::kDiv, x, y); }
  int neg(int x) { return make(Op::kNeg, x); }
  int num(double c) { return constant(c); }

  // Extends d (each node's derivative along one input, as a node) over the nodes
  // [d.size(), end), in order: input `lane_input`'s is 1, the other inputs' and the constants'
  // 0, an operation's its rule on its operands'. The nodes it creates lie beyond `end`.
  void sweep(std::vector<int>& d, std::size_t end, int lane_input);

  // The derivative of node n along a direction, from its operands' derivatives dx, dy: the
  // first derivatives of HessianJet's functions (hessian_jet.h), as nodes.
  int derivative(int n, int dx, int dy) {
    const Node node = nodes[static_cast<std::size_t>(n)];
    const int x = node.x, y = node.y;
    const bool zx = is_zero(dx), zy = y < 0 || is_zero(dy);
    if (zx && zy) return num(0.0);
    switch (node.op) {
      case Op::kAdd:
        return add(dx, dy);
      case Op::kSub:
        return sub(dx, dy);
      case Op::kMul:
        return add(mul(dx, y), mul(x, dy));
      case Op::kDiv:
        return div(sub(dx, mul(n, dy)), y);  // (dx - (x / y) dy) / y
      case Op::kNeg:
        return neg(dx);
      case Op::kSqrt:
        return mul(dx, div(num(0.5), n));
      case Op::kSin:
        return mul(dx, make(Op::kCos, x));
      case Op::kCos:
        return neg(mul(dx, make(Op::kSin, x)));
      case Op::kTan:
        return mul(dx, add(num(1.0), mul(n, n)));
      case Op::kExp:
        return mul(dx, n);
      case Op::kLog:
        return div(dx, x);
      case Op::kLog1p:
        return div(dx, add(num(1.0), x));
      case Op::kSinh:
        return mul(dx, make(Op::kCosh, x));
      case Op::kCosh:
        return mul(dx, make(Op::kSinh, x));
      case Op::kTanh:
        return mul(dx, sub(num(1.0), mul(n, n)));
      case Op::kAtan:
        return div(dx, add(num(1.0), mul(x, x)));
      case Op::kCbrt:
        return div(dx, mul(num(3.0), mul(n, n)));
      case Op::kAsin:
        return div(dx, make(Op::kSqrt, sub(num(1.0), mul(x, x))));
      case Op::kAcos:
        return neg(div(dx, make(Op::kSqrt, sub(num(1.0), mul(x, x)))));
      case Op::kExpm1:
        return mul(dx, add(n, num(1.0)));
      case Op::kLog10:
        return div(dx, mul(x, num(std::log(10.0))));
      case Op::kLog2:
        return div(dx, mul(x, num(std::log(2.0))));
      case Op::kPowC:
        // p x^(p - 1) dx (p = 2: 2 x dx, exactly as HessianJet).
        return mul(dx, mul(num(node.c), make(Op::kPowC, x, -1, node.c - 1.0)));
      case Op::kCPow:
        // s^y log(s) dy; s = 0: 0^y has derivatives 0 (HessianJet's pow(0, y)).
        if (node.c == 0.0) return num(0.0);
        return mul(dx, mul(n, num(std::log(node.c))));
      case Op::kAtan2:  // atan2(y, x) with y = node.x, x = node.y: (x dy - y dx) / (x^2 + y^2)
        return div(sub(mul(y, dx), mul(x, dy)), add(mul(x, x), mul(y, y)));
    }
    return num(0.0);
  }
};

void HessianProgram::Graph::Impl::sweep(std::vector<int>& d, std::size_t end, int lane_input) {
  const int zero = num(0.0), one = num(1.0);
  const std::size_t begin = d.size();
  d.resize(end, zero);
  for (std::size_t n = begin; n < end; ++n) {
    const Node node = nodes[n];
    if (node.kind == Kind::kInput) {
      d[n] = static_cast<int>(node.c) == lane_input ? one : zero;
    } else if (node.kind == Kind::kOperation) {
      const int dx = d[static_cast<std::size_t>(node.x)];
      const int dy = node.y >= 0 ? d[static_cast<std::size_t>(node.y)] : zero;
      d[n] = derivative(static_cast<int>(n), dx, dy);
    }
  }
}

HessianProgram::Graph::Graph() : impl(std::make_unique<Impl>()) {}
HessianProgram::Graph::~Graph() = default;
int HessianProgram::Graph::input(int k) {
  return impl->add_node(Kind::kInput, Op::kAdd, -1, -1, static_cast<double>(k));
}
int HessianProgram::Graph::constant(double value) { return impl->constant(value); }
int HessianProgram::Graph::unary(Op op, int x, double c) { return impl->make(op, x, -1, c); }
int HessianProgram::Graph::binary(Op op, int x, int y) { return impl->make(op, x, y); }
void HessianProgram::Graph::guard(Test test, int x, int y, bool outcome) {
  impl->guards.push_back({test, x, y, outcome});
}

namespace {

// The program of a graph's `roots`: the nodes they and the guards need, in order (operands
// first), each a register (constants preset); inputs[k] the register of input node k (-1: not
// read). Returns each node's register (-1: not in the program).
std::vector<std::int32_t> emit(const HessianProgram::Graph::Impl& g, const std::vector<int>& roots,
                               int input_count, std::vector<HessianProgram::Instruction>& code,
                               std::vector<HessianProgram::Guard>& guards,
                               std::vector<double>& registers, std::vector<std::int32_t>& inputs) {
  std::vector<char> needed(g.nodes.size(), 0);
  std::vector<int> stack;
  const auto need = [&](int n) {
    if (n >= 0 && !needed[static_cast<std::size_t>(n)]) {
      needed[static_cast<std::size_t>(n)] = 1;
      stack.push_back(n);
    }
  };
  for (int n : roots) need(n);
  for (const HessianProgram::Guard& guard : g.guards) {
    need(guard.x);
    need(guard.y);
  }
  while (!stack.empty()) {
    const int n = stack.back();
    stack.pop_back();
    const Node& node = g.nodes[static_cast<std::size_t>(n)];
    if (node.kind == Kind::kOperation) {
      need(node.x);
      need(node.y);
    }
  }
  std::vector<std::int32_t> reg(g.nodes.size(), -1);
  inputs.assign(static_cast<std::size_t>(input_count), -1);
  for (std::size_t n = 0; n < g.nodes.size(); ++n) {
    if (!needed[n]) continue;
    const Node& node = g.nodes[n];
    const auto r = static_cast<std::int32_t>(registers.size());
    reg[n] = r;
    registers.push_back(node.kind == Kind::kConstant ? node.c : 0.0);
    if (node.kind == Kind::kInput) {
      inputs[static_cast<std::size_t>(node.c)] = r;
    } else if (node.kind == Kind::kOperation) {
      code.push_back({node.op, r, reg[static_cast<std::size_t>(node.x)],
                      node.y >= 0 ? reg[static_cast<std::size_t>(node.y)] : -1, node.c});
    }
  }
  for (const HessianProgram::Guard& guard : g.guards) {
    guards.push_back({guard.test, reg[static_cast<std::size_t>(guard.x)],
                      guard.y >= 0 ? reg[static_cast<std::size_t>(guard.y)] : -1, guard.outcome});
  }
  return reg;
}

}  // namespace

std::unique_ptr<HessianProgram> HessianProgram::derive(Graph& graph, const Shape& shape,
                                                       const std::vector<int>& outputs) {
  Graph::Impl& g = *graph.impl;
  const int lanes = static_cast<int>(shape.lanes.size());
  BFLOW_ASSERT(lanes <= HessianJet::kLanes);
  // The weights, the factor product: inputs after the block's own. L = sum_{r < scaled}
  // (P w_r) f_r + sum_{r >= scaled} w_r f_r, so that each second derivative of a scaled output
  // costs one product by its weight P w_r; S = sum_{r < scaled} w_r f_r for the value and the
  // gradient.
  const int product =
      g.add_node(Kind::kInput, Op::kAdd, -1, -1, static_cast<double>(shape.inputs + shape.outputs));
  int s = g.num(0.0), lagrangian = g.num(0.0);
  for (int r = 0; r < shape.outputs; ++r) {
    const int w = g.add_node(Kind::kInput, Op::kAdd, -1, -1, static_cast<double>(shape.inputs + r));
    const int f = outputs[static_cast<std::size_t>(r)];
    if (r < shape.scaled) {
      s = g.add(s, g.mul(w, f));
      lagrangian = g.add(lagrangian, g.mul(g.mul(product, w), f));
    } else {
      lagrangian = g.add(lagrangian, g.mul(w, f));
    }
  }

  // Forward derivatives along each lane over the graph's nodes (in order, operands first):
  // d[i][n] = d node n / d lane i, for the nodes that exist when the sweep starts.
  std::vector<std::vector<int>> d(static_cast<std::size_t>(lanes));
  const auto sweep = [&](int i, std::size_t end) {
    g.sweep(d[static_cast<std::size_t>(i)], end, shape.lanes[static_cast<std::size_t>(i)]);
  };
  const std::size_t first = g.nodes.size();
  for (int i = 0; i < lanes; ++i) sweep(i, first);
  std::vector<int> grad_l(static_cast<std::size_t>(lanes)), grad_s(static_cast<std::size_t>(lanes));
  for (int i = 0; i < lanes; ++i) {
    grad_l[static_cast<std::size_t>(i)] =
        d[static_cast<std::size_t>(i)][static_cast<std::size_t>(lagrangian)];
    grad_s[static_cast<std::size_t>(i)] =
        d[static_cast<std::size_t>(i)][static_cast<std::size_t>(s)];
  }
  // Second derivatives: the sweeps continued over the first derivatives' nodes.
  const std::size_t second = g.nodes.size();
  for (int j = 0; j < lanes; ++j) sweep(j, second);
  std::vector<int> hessian(static_cast<std::size_t>(HessianJet::at(lanes, 0)));
  for (int i = 0; i < lanes; ++i) {
    for (int j = 0; j <= i; ++j) {
      hessian[static_cast<std::size_t>(HessianJet::at(i, j))] =
          d[static_cast<std::size_t>(j)]
           [static_cast<std::size_t>(grad_l[static_cast<std::size_t>(i)])];
    }
  }

  auto program = std::unique_ptr<HessianProgram>(new HessianProgram);
  HessianProgram& p = *program;
  p.shape_ = shape;
  std::vector<int> roots = hessian;
  if (shape.gradient) roots.insert(roots.end(), grad_s.begin(), grad_s.end());
  roots.push_back(s);
  std::vector<std::int32_t> inputs;
  const std::vector<std::int32_t> reg =
      emit(g, roots, shape.inputs + shape.outputs + 1, p.code_, p.guards_, p.registers_, inputs);
  p.input_registers_.assign(inputs.begin(), inputs.begin() + shape.inputs);
  p.weight_registers_.assign(inputs.begin() + shape.inputs,
                             inputs.begin() + shape.inputs + shape.outputs);
  p.product_register_ = inputs.back();
  for (int n : hessian) p.hessian_registers_.push_back(reg[static_cast<std::size_t>(n)]);
  if (shape.gradient) {
    for (int n : grad_s) p.gradient_registers_.push_back(reg[static_cast<std::size_t>(n)]);
  }
  p.value_register_ = reg[static_cast<std::size_t>(s)];
  return program;
}

bool HessianProgram::execute(const std::vector<Instruction>& code, const std::vector<Guard>& guards,
                             double* r) {
  for (const Instruction& i : code) {
    const double x = r[i.x];
    double out;
    switch (i.op) {
      case Op::kAdd:
        out = x + r[i.y];
        break;
      case Op::kSub:
        out = x - r[i.y];
        break;
      case Op::kMul:
        out = x * r[i.y];
        break;
      case Op::kDiv:
        out = x / r[i.y];
        break;
      case Op::kNeg:
        out = -x;
        break;
      case Op::kAtan2:
        out = std::atan2(x, r[i.y]);
        break;
      default:
        out = Graph::Impl::apply(i.op, x, 0.0, i.c);
        break;
    }
    r[i.dst] = out;
  }
  for (const Guard& g : guards) {
    const double x = r[g.x];
    const double y = g.y >= 0 ? r[g.y] : 0.0;
    bool holds = false;
    switch (g.test) {
      case Test::kLess:
        holds = x < y;
        break;
      case Test::kGreater:
        holds = x > y;
        break;
      case Test::kLessEq:
        holds = x <= y;
        break;
      case Test::kGreaterEq:
        holds = x >= y;
        break;
      case Test::kEqual:
        holds = x == y;
        break;
      case Test::kNotEqual:
        holds = x != y;
        break;
      case Test::kSignBit:
        holds = std::signbit(x);
        break;
      case Test::kFinite:
        holds = std::isfinite(x);
        break;
      case Test::kNan:
        holds = std::isnan(x);
        break;
      case Test::kInf:
        holds = std::isinf(x);
        break;
      case Test::kFloor:
        holds = std::floor(x) == y;
        break;
      case Test::kCeil:
        holds = std::ceil(x) == y;
        break;
    }
    if (holds != g.outcome) return false;
  }
  return true;
}

namespace {

// Writes values[k] into register to[k] (-1: not read).
void load(const std::vector<std::int32_t>& to, const double* values, double* r) {
  for (std::size_t k = 0; k < to.size(); ++k) {
    if (to[k] >= 0) r[to[k]] = values[k];
  }
}
// out[k] = register from[k]; whether every one is finite.
bool gather(const std::vector<std::int32_t>& from, const double* r, double* out) {
  bool finite = true;
  for (std::size_t k = 0; k < from.size(); ++k) {
    out[k] = r[from[k]];
    finite = finite && std::isfinite(out[k]);
  }
  return finite;
}

}  // namespace

HessianProgram::Outcome HessianProgram::run(const double* in, const double* w, double product,
                                            double* hessian, double* gradient, double* value) {
  double* r = registers_.data();
  load(input_registers_, in, r);
  load(weight_registers_, w, r);
  if (product_register_ >= 0) r[product_register_] = product;
  if (!execute(code_, guards_, r)) return Outcome::kGuardFailed;
  *value = r[value_register_];
  // Every output written, then whether all are finite.
  const bool hessian_finite = gather(hessian_registers_, r, hessian);
  const bool gradient_finite = gather(gradient_registers_, r, gradient);
  const bool finite = hessian_finite && gradient_finite && std::isfinite(*value);
  return finite ? Outcome::kDone : Outcome::kNotFinite;
}

std::unique_ptr<JacobianProgram> JacobianProgram::derive(
    HessianProgram::Graph& graph, int inputs, const std::vector<int>& outputs,
    const std::vector<std::pair<int, int>>& entries) {
  HessianProgram::Graph::Impl& g = *graph.impl;
  // One forward sweep per input column the entries name, over the traced nodes.
  std::vector<int> column_lane(static_cast<std::size_t>(inputs), -1);
  std::vector<int> columns;
  for (const auto& [row, col] : entries) {
    BFLOW_ASSERT(row >= 0 && row < static_cast<int>(outputs.size()) && col >= 0 && col < inputs);
    if (column_lane[static_cast<std::size_t>(col)] < 0) {
      column_lane[static_cast<std::size_t>(col)] = static_cast<int>(columns.size());
      columns.push_back(col);
    }
  }
  const std::size_t traced = g.nodes.size();
  std::vector<std::vector<int>> d(columns.size());
  for (std::size_t lane = 0; lane < columns.size(); ++lane) g.sweep(d[lane], traced, columns[lane]);
  std::vector<int> roots;
  roots.reserve(entries.size());
  for (const auto& [row, col] : entries) {
    roots.push_back(d[static_cast<std::size_t>(column_lane[static_cast<std::size_t>(col)])]
                     [static_cast<std::size_t>(outputs[static_cast<std::size_t>(row)])]);
  }
  auto program = std::unique_ptr<JacobianProgram>(new JacobianProgram);
  JacobianProgram& p = *program;
  const std::vector<std::int32_t> reg =
      emit(g, roots, inputs, p.code_, p.guards_, p.registers_, p.input_registers_);
  for (int n : roots) p.value_registers_.push_back(reg[static_cast<std::size_t>(n)]);
  return program;
}

HessianProgram::Outcome JacobianProgram::run(const double* in, double* values) {
  double* r = registers_.data();
  load(input_registers_, in, r);
  if (!HessianProgram::execute(code_, guards_, r)) return HessianProgram::Outcome::kGuardFailed;
  return gather(value_registers_, r, values) ? HessianProgram::Outcome::kDone
                                             : HessianProgram::Outcome::kNotFinite;
}

}  // namespace fesd
}  // namespace bflow

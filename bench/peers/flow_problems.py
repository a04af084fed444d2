"""The problems of the sensitivity comparison (peer_flow.py), stated once for every Python tool:
the same fields as bflow's side (bench/peer_flow.cc, bflow/core/biped.h,
bflow/examples/three_surfaces.h).

field(name, x, s, m) -> the components of F_s(x): x a sequence of d scalars (floats, heyoka
expressions or JAX tracers), s the n side values s_j = +1 (side + of surface j, h_j > 0) or -1
(floats, heyoka parameters or a JAX array), m a namespace with sin, cos and exp. Each field is
polynomial in s, so one compiled integrator serves every mode (s as its parameters).
surfaces(name, x, m) -> h_1 ... h_n.
"""
import math

# d, n, start, final time; "events" says what the nominal trajectory meets.
PROBLEMS = {
    "chain": {"program": "chain", "d": 12, "n": 0, "t": 10.0,
              "x0": [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.3, 0.2, 0.1, 0.0, -0.1, -0.2],
              "title": "six coupled pendulums (d = 12), no event, T = 10"},
    "ball": {"program": "ball", "d": 2, "n": 1, "t": 2.5, "x0": [1.0, 0.0],
             "title": "ball on a damped spring ground (d = 2), 8 single crossings, T = 2.5"},
    "biped-tilt": {"program": "biped", "d": 6, "n": 2, "t": 0.6,
                   "x0": [0.0, 1.0, 0.2, 0.0, 0.0, 0.0],
                   "title": "mode-damping biped tilted by 0.2 (d = 6): foot 1 lands, then foot 0"},
    "biped": {"program": "biped", "d": 6, "n": 2, "t": 0.6,
              "x0": [0.0, 1.0, 0.0, 0.0, 0.0, 0.0],
              "title": "mode-damping biped from rest (d = 6): both feet land at once (t = 0.397)"},
    # x0: ThreeSurfaces::nominal_start() (three_surfaces.h), phi_{-1}(rho) under F_{---}, rounded to
    # double; the reference (bench/peer_flow.cc --reference --x0 crossing) computes it with
    # ReferenceFlow::backward in long double and hands every tool that start.
    "three": {"program": "three", "d": 5, "n": 3, "t": 1.5, "x0": None,
              "title": "three curved surfaces crossed at once (d = 5, t = 1), T = 1.5"},
}

THREE_RHO = [0.0, 0.0, 0.0, 0.5, -0.25]
THREE_CROSSING_TIME = 1.0

# bflow/core/biped.h defaults.
BIPED = {"m": 1.0, "J": 1.0, "g": 9.8, "l": 0.5, "psi": math.pi / 4, "kappa": 1.0, "beta": 1.0}
BALL = {"g": 9.81, "k": 400.0, "c": 4.0}
CHAIN_COUPLING = 0.5


def _chain(x, s, m):
    n = len(x) // 2
    q, p = x[:n], x[n:]
    out = list(p)
    for i in range(n):
        left = q[i - 1] if i > 0 else q[i]
        right = q[i + 1] if i + 1 < n else q[i]
        out.append(-m.sin(q[i]) + CHAIN_COUPLING * (left - 2.0 * q[i] + right))
    return out


def _ball(x, s, m):
    contact = (1.0 + s[0]) * 0.5
    return [x[1], -BALL["g"] + contact * (-BALL["k"] * x[0] - BALL["c"] * x[1])]


def _biped_feet(x, m):
    """Per foot j (side +1, -1): the penetration a_j and its gradient in q = (x, y, theta)."""
    b = BIPED
    feet = []
    for side in (1.0, -1.0):
        angle = x[2] + side * b["psi"]
        fx = x[0] + b["l"] * m.sin(angle)
        fy = x[1] - b["l"] * m.cos(angle)
        a = -fx * fx - fy
        da = [-2.0 * fx, -1.0, -2.0 * fx * b["l"] * m.cos(angle) - b["l"] * m.sin(angle)]
        feet.append((a, da))
    return feet


def _biped(x, s, m):
    b = BIPED
    contact = [(1.0 + s[0]) * 0.5, (1.0 + s[1]) * 0.5]
    beta = b["beta"] * (contact[0] + contact[1]) * 0.5  # beta/2 with one foot down, beta with two
    force = [0.0, -b["m"] * b["g"], 0.0]
    for j, (a, da) in enumerate(_biped_feet(x, m)):
        rate = da[0] * x[3] + da[1] * x[4] + da[2] * x[5]
        push = contact[j] * (b["kappa"] * a + beta * rate)
        force = [force[i] - push * da[i] for i in range(3)]
    return [x[3], x[4], x[5], force[0] / b["m"], force[1] / b["m"], force[2] / b["J"]]


def _three(x, s, m):
    s0, s1, s2 = s[0], s[1], s[2]
    w = (1.0 + s0) * 0.5 + (1.0 + s1) + (1.0 + s2) * 2.0  # b.bits()
    return [
        2.0 + 0.3 * s0 + 0.1 * s1 * s2 + 0.2 * m.sin(x[3] + 0.4 * w) - 0.2 * x[0] * x[1],
        2.0 - 0.25 * s1 + 0.1 * s0 + 0.3 * (1.0 + 0.2 * s2) * x[0] * x[2]
        + 0.15 * m.cos(x[4] + 0.3 * w),
        2.0 + 0.2 * s2 - 0.1 * s0 * s1 + 0.2 * (2.0 + s0) * x[1] * x[1]
        + 0.1 * (1.0 + 0.1 * w) * m.sin(2.0 * x[3]),
        x[4] + 0.4 * s0 + 0.1 * s1 * x[3] * x[3],
        -x[3] + 0.3 * s2 * m.cos(x[0]) - 0.1 * (1.0 + s1) * x[4],
    ]


def _three_surfaces(x, m):
    u = x[3] - 0.5
    return [
        x[0] + 0.3 * m.sin(x[1] - x[2]) + 0.5 * x[0] * x[0] - 0.2 * u * (1.0 + x[4]),
        x[1] - 0.25 * (m.exp(x[0]) - 1.0) + 0.3 * x[2] * x[2] + 0.2 * m.sin(x[4] + 0.25),
        x[2] + 0.2 * x[0] * x[1] - 0.3 * u * u + 0.25 * m.sin(x[0] + x[4] + 0.25),
    ]


_FIELDS = {"chain": _chain, "ball": _ball, "biped": _biped, "three": _three}


def field(name, x, s, m):
    return _FIELDS[PROBLEMS[name]["program"]](x, s, m)


def surfaces(name, x, m):
    program = PROBLEMS[name]["program"]
    if program == "chain":
        return []
    if program == "ball":
        return [-x[0]]
    if program == "biped":
        return [a for a, _ in _biped_feet(x, m)]
    return _three_surfaces(x, m)

#!/usr/bin/env python3
"""bflow from Python: a model with two surfaces crossed at once, written in SymPy, its jump map
and its flow's B-derivative against the closed form and finite differences; the biped scene; a
bad model refused. Prints what it checks and OK (exit status 1 on a mismatch).

    pip install ./python && python examples/python/tour.py
"""

import sys

import numpy as np
import sympy as sp

import bflow


def check(what, got, expected, tolerance):
    error = float(np.max(np.abs(np.asarray(got) - np.asarray(expected))))
    print(f"{what:58} error {error:.1e} (bound {tolerance:.0e})")
    return error <= tolerance


def main():
    ok = True
    # [B] (3.1): xdot = 1 - delta b, h = x. From x0 = -(1 + delta) / 2 both surfaces are crossed
    # at t = 1/2, and at t = 1 the B-derivative is (1 - delta) / (1 + delta) I ([B] (3.2)).
    x, y, delta = sp.symbols("x y delta")
    b = bflow.signs(2)
    pwconst = bflow.Model([x, y], field=[1 - delta * b[0], 1 - delta * b[1]], surfaces=[x, y],
                          parameters={delta: 0.25})
    D = bflow.flow_derivative(pwconst, [-0.625, -0.625], 1.0)
    print("events:", D.events)
    ok &= check("linear case: jacobian against (1 - delta)/(1 + delta) I", D.jacobian(),
                0.6 * np.eye(2), 1e-12)

    # A field whose pieces differ (the README's Quadrants): the derivative is piecewise linear.
    quadrants = bflow.Model([x, y], surfaces=[x, y], field={
        "--": [1.0, 0.6], "+-": [0.5, 1.0], "-+": [1.0, 1.2], "++": [0.5, 1.6]})
    B = bflow.JumpMap.at(quadrants, [0.0, 0.0])
    dx = np.array([-1.0, -0.5])
    print("B(dx) =", B.apply(dx), "crossing order", B.order(dx).order)
    ok &= check("README: B(dx) = (-0.5, -1.4)", B.apply(dx), [-0.5, -1.4], 1e-15)
    D = bflow.flow_derivative(quadrants, [-0.5, -0.3], 1.0)
    for orders, matrix in D.pieces():
        print("piece", orders, matrix.tolist())
    rng = np.random.default_rng(0)
    for k in range(4):
        v = rng.standard_normal(2)
        ok &= check(f"direction {k}: apply against one-sided differences (alpha 1e-6)",
                    D.apply(v), bflow.fd.one_sided(quadrants, [-0.5, -0.3], 1.0, v, 1e-6), 2e-9)

    # The biped of [B] Section 3.2.4 through the instant both feet touch the ground.
    D = bflow.flow_derivative(bflow.biped(), bflow.biped_initial_state(), 0.6)
    ok &= check("biped: D phi(x0; e_theta) against the README's digits",
                D.apply(np.eye(6)[2]), [0.01957, -0.09941, 0.9754, 0.6247, -0.383, 0.1063], 6e-5)

    try:
        bflow.Model([x, y], field=[sp.besselj(0, x), y], surfaces=[x])
        ok = False
    except bflow.ModelError as error:
        print("refused:", error)
    print("OK" if ok else "MISMATCH")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

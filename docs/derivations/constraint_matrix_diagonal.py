"""Diagonal limits of the mixed derivatives used by StokesSLP.constraint_matrix.

For a curve parametrised by arclength with tangent angle
theta(s) = theta0 + H s + H_s s^2/2 + ..., and r = z(u) - z(v), this expands
F(u, v) along u = a e, v = b e and reads d_u d_v F at u = v off the coefficient
of a b e^2. Run with sympy installed (it is not a dependency of hpcves):

    python docs/derivations/constraint_matrix_diagonal.py

Prints  H**2/6  and  -H**2 + I*H_s/3  (the latter times t^2 = e^{2 i theta0},
theta0 = 0 here).
"""
import sympy as sp

a, b, e, s = sp.symbols("a b e s", real=True)
H, H_s, H_ss, H_sss = sp.symbols("H H_s H_ss H_sss", real=True)

theta = H * s + H_s * s**2 / 2 + H_ss * s**3 / 6 + H_sss * s**4 / 24
tangent = sp.series(sp.exp(sp.I * theta), s, 0, 6).removeO()
z = sp.integrate(sp.expand(tangent), s)
r = sp.expand(z.subs(s, a * e) - z.subs(s, b * e))
w = sp.series(sp.expand(sp.cancel(r / (e * (a - b)))), e, 0, 4).removeO()   # r / (u - v)


def mixed_derivative_on_diagonal(F):
    second_order = sp.expand(sp.series(F, e, 0, 3).removeO().coeff(e, 2))
    return sp.simplify(second_order.coeff(a, 1).coeff(b, 1))


print("d_u d_v log(|r|^2 / (u - v)^2) ->", mixed_derivative_on_diagonal(sp.log(sp.expand(w * sp.conjugate(w)))))
print("d_u d_v (r / conj r)           ->", mixed_derivative_on_diagonal(sp.expand(w / sp.conjugate(w))))

"""The paper's robot written independently with sympy.physics.mechanics' Kane's method:
the reference that the Gibbs-Appell derivation is checked against (tests) and PyDy's
generated code is built from (benchmarks)."""

from __future__ import annotations

import sympy as sp


def kane_rrr():
    """The paper's robot from its figure with sympy.physics.mechanics' KanesMethod.

    The same model as gagen's built-in `rrr` (the same parameter names): link 1 turns
    about the vertical z axis, links 2 and 3 about their x axes, links along y, mass
    centres mid-link, joint couples T01z, T12x, T23x. Returns (kane, q, u, T); u = q'.
    """
    import sympy.physics.mechanics as me

    q = me.dynamicsymbols("q1:4")
    u = me.dynamicsymbols("u1:4")
    g, L1, L2, L3, m1, m2, m3 = sp.symbols("g L1 L2 L3 m1 m2 m3")
    Ix = sp.symbols("I1x I2x I3x")
    Iy = sp.symbols("I1y I2y I3y")
    Iz = sp.symbols("I1z I2z I3z")
    T = me.dynamicsymbols("T01z T12x T23x")
    N = me.ReferenceFrame("N")
    F1 = N.orientnew("F1", "Axis", (q[0], N.z))
    F2 = F1.orientnew("F2", "Axis", (q[1], F1.x))
    F3 = F2.orientnew("F3", "Axis", (q[2], F2.x))
    O = me.Point("O")
    O.set_vel(N, 0)
    A = O.locatenew("A", L1 * F1.y)
    B = A.locatenew("B", L2 * F2.y)
    centres = (O.locatenew("C1", L1 / 2 * F1.y), A.locatenew("C2", L2 / 2 * F2.y),
               B.locatenew("C3", L3 / 2 * F3.y))
    frames, masses = (F1, F2, F3), (m1, m2, m3)
    for C in centres:
        C.set_vel(N, C.pos_from(O).dt(N))
    bodies = [me.RigidBody(f"B{i + 1}", centres[i], frames[i], masses[i],
                           (me.inertia(frames[i], Ix[i], Iy[i], Iz[i]), centres[i]))
              for i in range(3)]
    loads = [(centres[i], -masses[i] * g * N.z) for i in range(3)]
    loads += [(F1, T[0] * F1.z - T[1] * F2.x), (F2, T[1] * F2.x - T[2] * F3.x),
              (F3, T[2] * F3.x)]
    kane = me.KanesMethod(N, q_ind=q, u_ind=u, kd_eqs=[q[i].diff() - u[i] for i in range(3)])
    kane.kanes_equations(bodies, loads)
    return kane, q, u, T

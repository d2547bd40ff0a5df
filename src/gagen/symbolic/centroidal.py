"""The centre of mass and the centroidal momentum matrix A_g, as a program of named
intermediates (Pinocchio's centerOfMass and ccrba: at the centre of mass g, world axes,
linear rows first).

The composite-rigid-body pass of `recursive` gives, for each moving body i, its subtree's
momentum for a unit rate of each of its joint's coordinates, (f, n) about its origin O_i
in its own frame (the CRBA's `_unit_momenta`: the columns the mass matrix projects on the
ancestors' axes). A_g's column is that momentum in world axes about g:

    (R_i f,  R_i n + (p_i - g) x R_i f),      g = sum_i (m_i p_i + R_i h_i) / sum_i m_i

with R_i, p_i the body's placement (`frames`: read from the placements, which the compiled
code computes once for all of these) and (m_i, h_i = m_i c_i) its mass and first moment. Bodies joined by fixed joints count as one (`model.merge`), and bodies welded to the
world are no part of the robot's mass, as in Pinocchio. The composites are taken in the
bodies' own frames, where a joint's rotation is sparse: the program is O(n) and shares the
joint transforms with the rest of the model's.

The velocity-dependent quantities (h_g, d/dt A_g, the bias d/dt A_g qd) are loops of the
compiled runtime over the same bodies (codegen/templates/model/centroidal.c.j2).
"""

from __future__ import annotations

from dataclasses import dataclass

import sympy as sp

from ..model.merge import merge_fixed_joints
from .differentiate import needed_definitions, recorder_after
from .gibbs_appell import Equations
from .recursive import _links, _rotate_inertia, _symmetric, _unit_momenta
from .vec3 import add, cross, mat_add, mat_mat, mat_neg, mat_scale, mat_vec, scale, skew, sub


@dataclass
class CentroidalProgram:
    """The centre of mass (3) and A_g (6 x nv, row-major), written in `intermediates`."""

    center_of_mass: list[sp.Expr]
    mass: sp.Expr  # of the moving bodies, in the parameters
    centroidal_map: list[sp.Expr]
    intermediates: list[tuple[sp.Symbol, sp.Expr]]
    # the named entries of `eqs.placements` the outputs read, by their index there: the
    # program leaves them undefined, to be read from the placements computed once
    placements: dict[sp.Symbol, int]


def centroidal_program(eqs: Equations) -> CentroidalProgram:
    """The centre of mass and A_g of `eqs`'s model (module docstring), continuing its program
    (`eqs.placements` must be there: symbolic.frames)."""
    model = eqs.model
    rec = recorder_after(eqs.intermediates)
    merged = merge_fixed_joints(model)
    links = _links(merged, eqs.coords, rec)
    body_index = {body.name: k for k, body in enumerate(model.bodies)}
    poses = []
    for link in links:  # (R, p) of the body in the world, as `placements` names them
        k = 15 * body_index[link.body.name]
        X = eqs.placements[k: k + 15]
        poses.append((tuple(tuple(X[3 * r: 3 * r + 3]) for r in range(3)), tuple(X[9:12])))
    mass = rec.name(sum((link.mass for link in links), sp.Integer(0)))
    first = add(*(add(scale(link.mass, p), mat_vec(R, link.h))
                  for link, (R, p) in zip(links, poses)))
    inverse_mass = rec.name(1 / mass)
    g = rec.named(scale(inverse_mass, first))
    composite = _composites(links, rec)
    columns: dict[int, tuple] = {}
    for i, link in enumerate(links):
        R, p = poses[i]
        arm = rec.named(sub(p, g))
        for column, (f, n) in _unit_momenta(link, *composite[i], rec):
            f_world = rec.named(mat_vec(R, f))
            n_world = rec.named(add(mat_vec(R, n), cross(arm, f_world)))
            columns[column] = (*f_world, *n_world)
    nv = eqs.n
    A = [columns[c][r] for r in range(6) for c in range(nv)]
    defined = {symbol for symbol, _ in rec.definitions}
    read = {e: k for k, e in enumerate(eqs.placements) if e in defined}
    program = needed_definitions([(s, e) for s, e in rec.definitions if s not in read],
                                 [*g, *A, mass])
    used = set().union(*(e.free_symbols for _, e in program), *(e.free_symbols for e in A),
                       *(e.free_symbols for e in g))
    return CentroidalProgram(center_of_mass=list(g), mass=mass, centroidal_map=A,
                             intermediates=program,
                             placements={s: k for s, k in read.items() if s in used})


def _composites(links, rec) -> list[tuple]:
    """Per link, its subtree's (mass, first moment, inertia about O_i) in its frame: the
    CRBA's backward pass (recursive._crba)."""
    mass = [link.mass for link in links]
    h = [link.h for link in links]
    I_O = [link.I_O for link in links]
    for i in reversed(range(len(links))):
        link = links[i]
        mass[i] = rec.name(mass[i])
        h[i] = rec.named(h[i])
        I_O[i] = _symmetric(I_O[i], rec)
        p = link.parent
        if p is None:
            continue
        h_up = link.to_parent(h[i], rec)
        I_up = _rotate_inertia(link.R, I_O[i], rec)
        d = skew(link.d)
        mass[p] = mass[p] + mass[i]
        h[p] = add(h[p], h_up, scale(mass[i], link.d))
        H = skew(h_up)
        I_O[p] = mat_add(I_O[p], I_up, mat_neg(mat_mat(H, d)), mat_neg(mat_mat(d, H)),
                         mat_neg(mat_mat(mat_scale(mass[i], d), d)))
    return list(zip(mass, h, I_O))

"""Merge bodies attached by fixed joints into their parents.

A body welded to its parent by a fixed joint adds no coordinate, so it is cheaper to fold
its mass properties into the parent and drop it. Its children keep their motion: they are
re-attached to the parent with the fixed joint's placement composed into their origin.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import sympy as sp

from .model import IDENTITY, WORLD, ZERO3, Body, Frame, Model

_ZERO33 = sp.ImmutableMatrix(sp.zeros(3, 3))


@dataclass
class _Host:
    """A kept body (or the world) and the pieces of mass merged into it, in its frame."""

    body: Body | None  # None for the world
    pieces: list[tuple[sp.Expr, sp.Matrix, sp.Matrix]] = field(default_factory=list)


def merge_fixed_joints(model: Model) -> Model:
    """Return a model without fixed joints, with the same motion and the same mass properties.

    Each fixed body's mass, mass centre and central inertia are moved into the frame of the
    nearest moving ancestor and combined with it (parallel-axis theorem). Bodies welded to
    the world never move, so they are dropped. Body order stays parents-first. Each merged
    body and its joint remain as named frames (`Model.extra_frames`) of their host.
    """
    if all(b.joint.moves for b in model.bodies):
        return model
    hosts, order, frames, placement = _hosts(model)
    bodies = tuple(_combined(hosts[name]) for name in order)
    return replace(model, bodies=bodies, extra_frames=tuple(frames) + tuple(
        replace(f, body=placement[f.body][0],
                xyz=sp.ImmutableMatrix(placement[f.body][1] + placement[f.body][2] * f.xyz),
                rotation=sp.ImmutableMatrix(placement[f.body][2] * f.rotation))
        for f in model.extra_frames))


def mass_pieces(model: Model) -> list[tuple[Body, list[tuple[sp.Expr, sp.Matrix, sp.Matrix]]]]:
    """Per moving body (in coordinate order): the body as `merge_fixed_joints` keeps it
    (joint origin composed through fixed joints, own mass properties) and the pieces of
    mass that the merge adds up into it: (mass, mass centre, central inertia) in its frame,
    its own first. Bodies welded to the world are in no list."""
    hosts, order, _, _ = _hosts(model)
    return [(hosts[name].body, [(hosts[name].body.mass, sp.Matrix(hosts[name].body.com),
                                 sp.Matrix(hosts[name].body.inertia))] + hosts[name].pieces)
            for name in order]


def _hosts(model: Model):
    """The moving bodies re-attached past fixed joints, each with the fixed bodies' mass
    pieces it takes in; their names, parents first; the merged bodies' frames; and where
    each body's frame sits (host, position, rotation)."""
    hosts: dict[str, _Host] = {}
    frames: list[Frame] = []
    # Where each body's frame sits: (host name, position, rotation) in the host's frame.
    placement: dict[str, tuple[str, sp.Matrix, sp.Matrix]] = {WORLD: (WORLD, ZERO3, IDENTITY)}
    order: list[str] = []
    for body in model.bodies:  # parents first, so the parent's placement is known
        host, p_host, r_host = placement[body.parent]
        xyz = sp.ImmutableMatrix(p_host + r_host * body.joint.origin_xyz)
        rot = sp.ImmutableMatrix(r_host * body.joint.origin_rotation)
        if body.joint.moves:
            if host == body.parent:  # parent kept: the placement is the identity
                moved = body
            else:
                moved = replace(body, parent=host,
                                joint=replace(body.joint, origin_xyz=xyz, origin_rotation=rot))
            hosts[body.name] = _Host(moved)
            order.append(body.name)
            placement[body.name] = (body.name, ZERO3, IDENTITY)
        else:
            placement[body.name] = (host, xyz, rot)
            # the merged link and its joint stay named frames, fixed to the host
            frames += [Frame(body.name, host, xyz, rot, "link"),
                       Frame(body.joint.name, host, xyz, rot, "joint")]
            if host != WORLD and not _massless(body):
                hosts[host].pieces.append(_piece_in_host(body, xyz, rot))
    return hosts, order, frames, placement


def _massless(body: Body) -> bool:
    # Only a structurally zero body can be skipped; a symbolic mass may later be non-zero.
    return sp.sympify(body.mass).is_zero is True and all(
        sp.sympify(e).is_zero is True for e in body.inertia)


def _piece_in_host(body: Body, xyz: sp.Matrix, rot: sp.Matrix) -> tuple:
    """The body's mass, mass centre and central inertia expressed in the host's axes."""
    com = xyz + rot * body.com
    inertia = symmetric(rot * body.inertia * rot.T)
    return body.mass, com, inertia


def _combined(host: _Host) -> Body:
    body = host.body
    if not host.pieces:
        return body  # nothing merged: keep the entries exactly as they were
    pieces = [(body.mass, sp.Matrix(body.com), sp.Matrix(body.inertia))] + host.pieces
    mass, com, inertia = combine_mass_properties(pieces)
    return replace(body, mass=mass, com=com, inertia=inertia)


def combine_mass_properties(pieces) -> tuple[sp.Expr, sp.ImmutableMatrix, sp.ImmutableMatrix]:
    """Total mass, mass centre and central inertia of rigidly joined pieces in one frame.

    Each piece is (mass, mass centre, central inertia). With zero total mass there is no
    mass centre: it is taken as the origin and the inertias are simply summed.
    """
    mass = sp.Add(*[m for m, _, _ in pieces])
    inertia = sp.Matrix(_ZERO33)
    for _, _, i_c in pieces:
        inertia += i_c
    if sp.sympify(mass).is_zero is True:
        return mass, ZERO3, sp.ImmutableMatrix(inertia)
    com = sp.Matrix(ZERO3)
    for m, c, _ in pieces:
        com += m * c
    com /= mass
    for m, c, _ in pieces:
        d = c - com
        inertia += m * ((d.T * d)[0, 0] * sp.eye(3) - d * d.T)
    return mass, sp.ImmutableMatrix(com), symmetric(inertia)


def symmetric(matrix: sp.Matrix) -> sp.ImmutableMatrix:
    """Mirror the upper triangle: rounding in R I R^T must not make an inertia asymmetric."""
    return sp.ImmutableMatrix(3, 3, lambda i, j: matrix[min(i, j), max(i, j)])

"""Built-in models: the paper's robot ``rrr`` and the N-link chain ``chain:N``."""

from __future__ import annotations

from importlib import resources

import sympy as sp

from .inputs import quote
from .model import Body, Joint, Model, ModelError, inertia_matrix, vector
from .modelfile import parse_model_text

BUILTIN_NAMES = ("rrr", "chain:N")
# The chain's joint axes cycle through these (in each link's frame): a spatial chain
# that couples all three directions, as real arms do.
_CHAIN_AXES = ((0, 0, 1), (1, 0, 0), (0, 1, 0))


def is_builtin(name: str) -> bool:
    return name == "rrr" or name.startswith("chain:")


def load_builtin(name: str) -> Model:
    if name == "rrr":
        text = resources.files("gagen").joinpath("model/rrr.yaml").read_text()
        return parse_model_text(text, "builtin:rrr")
    if name.startswith("chain:"):
        count = name.split(":", 1)[1]
        # isdigit() alone accepts '²' and other digits int() refuses
        if not (count.isascii() and count.isdigit() and len(count) <= 3 and 1 <= int(count) <= 64):
            raise ModelError(quote(name), "", "expected chain:N with 1 <= N <= 64 links")
        return chain(int(count))
    raise ModelError(quote(name), "", f"unknown built-in model (built-ins: {', '.join(BUILTIN_NAMES)})")


def chain(n: int) -> Model:
    """An n-link spatial chain: links of length L_i along their y axes, axes cycling z, x, y."""
    params: dict[str, float] = {"g": 9.81}
    bodies = []
    for i in range(1, n + 1):
        L, m, ix, iy, iz = sp.symbols(f"L{i} m{i} I{i}x I{i}y I{i}z")
        length, mass, radius = 0.3, 2.0, 0.03
        params.update({f"L{i}": length, f"m{i}": mass,
                       f"I{i}x": mass * length**2 / 12, f"I{i}y": mass * radius**2 / 2,
                       f"I{i}z": mass * length**2 / 12})
        offset = [0, sp.Symbol(f"L{i - 1}"), 0] if i > 1 else [0, 0, 0]
        joint = Joint(name=f"q{i}", type="revolute", origin_xyz=vector(offset),
                      axis=vector(_CHAIN_AXES[(i - 1) % 3]))
        bodies.append(Body(name=f"link{i}", parent=f"link{i - 1}" if i > 1 else "world",
                           joint=joint, mass=m, com=vector([0, L / 2, 0]),
                           inertia=inertia_matrix(ix, iy, iz)))
    return Model(name=f"chain{n}", bodies=tuple(bodies), parameters=params,
                 gravity=vector([0, 0, -sp.Symbol("g")]), source=f"builtin:chain:{n}",
                 description=f"{n}-link spatial chain, joint axes cycling z, x, y")

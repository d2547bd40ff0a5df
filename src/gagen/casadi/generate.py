"""The C of a model's CasADi functions: its table (gagen.casadi.table) wrapped into CasADi's
external-function API, as `<ident>_casadi.c` and its header `<ident>_casadi.h`.

Only numbers and checked identifiers reach the C: the model's C identifier (as its kernels
are named), numbers of frames and sizes, printed parameter defaults, and the port names of
the table. Frame names appear in the header's comment as `c_identifier`s, as in the model's
own header. No SymPy here: the sources come from a compiled model's manifest.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from importlib import resources

import jinja2

from .. import __version__
from ..manifest import JOINT_KINDS, ModelInfo
from .table import ENTRIES, INERTIA_METHODS, INERTIAL, Entry, Param

# a parameter's class: one flag of gagen.casadi.table's, or several inertial ones
_CLASSES = {int(flag) for flag in Param} | {c for c in range(1, int(INERTIAL) + 1)
                                            if not c & ~int(INERTIAL)}
_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_FLOATING = JOINT_KINDS["floating"]


@dataclass(frozen=True)
class Signature:
    """The names, sparsity patterns and work of a function of an entry, with or without p,
    or of its Jacobian: the same for every frame."""

    name: str
    entry: str
    with_p: int
    jacobian: bool
    names_in: tuple[str, ...]
    names_out: tuple[str, ...]
    patterns_in: tuple[str, ...]
    patterns_out: tuple[str, ...]
    work: int
    signature: str


def prefix_of(ident: str) -> str:
    """The prefix of a model's exported CasADi names (and files): `<ident>_casadi`, which no
    kernel of the model's own C (`<ident>_<kernel>`) is named; runs of underscores become
    one, as CasADi's function names must have."""
    if not _IDENT.match(ident):
        raise ValueError(f"'{ident}' is not a C identifier")
    return re.sub("_+", "_", f"{ident}_casadi")


def function_name(prefix: str, entry: str, with_p: bool = False) -> str:
    """The C and CasADi name of a function: `<prefix>_<entry>[_p]`."""
    return f"{prefix}_{entry}" + ("_p" if with_p else "")


class _Patterns:
    """The sparsity patterns used, each once, named gc_sp<k>."""

    def __init__(self):
        self.names: dict[tuple[int, ...], str] = {}

    def dense(self, rows: int, cols: int) -> str:
        return self._name((rows, cols, 1))

    def empty(self, rows: int, cols: int) -> str:
        return self._name((rows, cols) + (0,) * (cols + 1))

    def _name(self, pattern: tuple[int, ...]) -> str:
        if pattern not in self.names:
            self.names[pattern] = f"gc_sp{len(self.names)}"
        return self.names[pattern]

    def listing(self) -> list[tuple[str, tuple[int, ...]]]:
        return [(name, pattern) for pattern, name in self.names.items()]


def frame_levels(info: ModelInfo) -> list[list[int]]:
    """Per frame and velocity coordinate, the depth of the coordinate's body on the frame's
    path to the world (0: the root's), or -1 if the coordinate is not on that path."""
    depth: list[int] = []
    for parent, _, _ in info.bodies:
        depth.append(0 if parent < 0 else depth[parent] + 1)
    rows = []
    for _, body, _ in info.frames:
        level = [-1] * info.dof
        b = body
        while b >= 0:
            _, kind, column = info.bodies[b]
            if kind != JOINT_KINDS["fixed"] and column >= 0:
                for k in range(6 if kind == _FLOATING else 1):
                    level[column + k] = depth[b]
            b = info.bodies[b][0]
        rows.append(level)
    return rows


def plain_coordinates(info: ModelInfo) -> list[tuple[int, int]]:
    """(entry of q, velocity coordinate) of every coordinate that is a plain number."""
    out, iq, iv = [], 0, 0
    for joint in info.joints:
        if joint.type == "floating":
            iq, iv = iq + 7, iv + 6
        else:
            out.append((iq, iv))
            iq, iv = iq + 1, iv + 1
    return out


def _size(value, sizes: dict[str, int]) -> int:
    return sizes[value] if isinstance(value, str) else int(value)


def _c_number(value: float) -> str:
    if not math.isfinite(value):
        raise ValueError(f"a parameter's default is not finite ({value})")
    return repr(float(value))


def _comment_name(name: str) -> str:
    """A frame's name for a C comment: runs of characters other than [A-Za-z0-9_] become
    `_`, as c_identifier does (no description's text in the C)."""
    return re.sub(r"[^A-Za-z0-9_]+", "_", str(name)).strip("_") or "_"


def _environment() -> jinja2.Environment:
    return jinja2.Environment(
        loader=jinja2.FunctionLoader(
            lambda name: resources.files("gagen.casadi").joinpath("templates", name)
            .read_text()),
        undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True,
        keep_trailing_newline=True, autoescape=False)


def declared_kernels(ident: str, headers: list[str]) -> set[str]:
    """The kernels (`<ident>_<name>(...)`) that a model's C headers declare: their names."""
    pattern = re.compile(rf"\b{re.escape(ident)}_([A-Za-z0-9_]+)\s*\(")
    return {match.group(1) for text in headers for match in pattern.finditer(text)}


def generate_casadi(info: ModelInfo, ident: str, nreg: int, classes: list[int],
                    entries: tuple[Entry, ...] = ENTRIES,
                    kernels: set[str] | None = None,
                    degrees: list[int] | None = None,
                    masses: list[bool] | None = None) -> dict[str, str]:
    """The wrapper's C file and header, {file name: text}, for a model with manifest `info`
    whose kernels are named `<ident>_...` and whose regressor has `nreg` columns;
    `classes[k]`: parameter k's class (gagen.casadi.table's flags, from
    gagen.casadi.build.parameter_classes), which picks how its Jacobian columns are
    computed; `degrees[k]`: pi's degree in an inertial parameter (1, 2 or 4, from
    gagen.casadi.build.pi_degrees; default 4), which picks the stencil that is exact for it;
    `masses[k]`: whether the total mass depends on parameter k (default: every parameter),
    where the centroidal values need the quotient rule.
    With `kernels` (`declared_kernels`), the entries that need a kernel the model's C lacks
    are left out."""
    prefix = prefix_of(ident)
    if kernels is not None:
        entries = tuple(e for e in entries if set(e.requires) <= kernels)
    defaults = [value for _, value in info.parameters]
    nq, nv, np_ = info.nq, info.dof, len(defaults)
    if len(classes) != np_:
        raise ValueError(f"classes has {len(classes)} entries for {np_} parameters")
    if any(c not in _CLASSES for c in classes):
        raise ValueError("a parameter's class is not one of gagen.casadi.table's")
    degrees = [4] * np_ if degrees is None else [int(d) for d in degrees]
    if len(degrees) != np_ or any(d not in (0, 1, 2, 4) for d in degrees):
        raise ValueError("degrees must hold 0, 1, 2 or 4 per parameter")
    masses = [True] * np_ if masses is None else [bool(m) for m in masses]
    if len(masses) != np_:
        raise ValueError(f"masses has {len(masses)} entries for {np_} parameters")
    nframes = len(info.frames)
    sizes = {"nq": nq, "nv": nv, "np": np_, "nreg": nreg}
    patterns = _Patterns()
    functions: list[Signature] = []
    summary: list[str] = []
    rendered = []
    for entry in entries:
        ins = [(port.name, _size(port.rows, sizes)) for port in entry.inputs]
        outs = [(port.name, _size(port.rows, sizes), _size(port.cols, sizes))
                for port in entry.outputs]
        rendered.append(_rendered_entry(entry, ident, ins, outs))
        for with_p in (False, True):
            functions += _signatures(function_name(prefix, entry.name, with_p), entry,
                                     with_p, ins, outs, patterns, np_,
                                     _work_sizes(entry, ins, outs, sizes, with_p))
        summary.append(f"{function_name(prefix, entry.name)}({_ports(_with_frame(entry, ins))})"
                       f" -> ({_ports([(n, f'{r}x{c}' if c > 1 else r) for n, r, c in outs])})")
    context = {
        "header": f"generated by gagen {__version__} for model '{ident}'; do not edit",
        "ident": ident, "prefix": prefix, "PREFIX": prefix.upper(),
        "nq": nq, "nv": nv, "np": np_, "nreg": nreg, "nframes": nframes,
        "max_in": max(len(e.inputs) for e in entries) + 1,
        "max_out": max(len(e.outputs) for e in entries),
        "zeros": max(nq, nv, np_, 1),
        "defaults": [_c_number(v) for v in defaults],
        "classes": [int(c) for c in classes] or [0],
        "degrees": degrees or [0],
        "masses": [1 if m else 0 for m in masses] or [0],
        "nbodies": len(info.moving_bodies),
        "plain": plain_coordinates(info),
        "floating": info.floating_joints(),
        "levels": frame_levels(info),
        "entries": rendered,
        "patterns": patterns.listing(),
        "functions": functions,
        "summary": summary,
        "frame_names": [_comment_name(name) for name, _, _ in info.frames],
    }
    env = _environment()
    return {f"{prefix}.c": env.get_template("casadi.c.j2").render(context),
            f"{prefix}.h": env.get_template("casadi.h.j2").render(context)}


def _ports(ports) -> str:
    return ", ".join(f"{name}[{size}]" for name, size in ports)


def _work_sizes(entry: Entry, ins, outs, sizes, with_p: bool) -> dict[str, int]:
    """Upper bounds of the doubles of work a call and its Jacobian take (module
    docstring of templates/casadi.c.j2: the wrapper checks them as it takes)."""
    nq, nv, np_, nreg = sizes["nq"], sizes["nv"], sizes["np"], sizes["nreg"]
    numel = [r * c for _, r, c in outs]
    widest = max([nq, nv, np_] + [n for _, n in ins])
    central = widest + 2 * sum(numel)
    widths = [nv if k == 0 and entry.tangent and entry.jacobian else n
              for k, (_, n) in enumerate(ins)]
    blocks = sum(m * (sum(widths) + (np_ if with_p else 0)) for m in numel)
    # gc_dpi's list of dpi/dp's non-zeros (3 NREG NP) and its own work (NP + 4 NREG)
    regressor_dp = nv * nreg + 3 * nreg * np_ + np_ + 4 * nreg
    mass_matrix_dp = 3 * nv * nreg + 3 * nreg * np_ + np_ + 4 * nreg + nv + nv * np_
    body = entry.work_size({**sizes, "central": central, "regressor_dp": regressor_dp,
                            "mass_matrix_dp": mass_matrix_dp,
                            "delassus_dp": nv * nv * (np_ + 1) + 18 * nv + mass_matrix_dp},
                           with_p)
    # gc_p_columns: p stepped, the value at p and at one step, pi twice
    p_columns = np_ + 2 * sum(numel) + 2 * nreg + 8 if with_p else 0
    return {"value": sum(numel) + 8,
            "jacobian": sum(numel) + blocks + body + 2 * central + widest + p_columns + 64}


def _rendered_entry(entry: Entry, ident: str, ins, outs) -> dict:
    def c(text):
        return None if text is None else text.format(ident=ident).strip()

    return {"name": entry.name, "doc": entry.doc, "inputs": entry.inputs,
            "outputs": entry.outputs, "value": c(entry.value), "jacobian": c(entry.jacobian),
            "p_jacobian": c(entry.p_jacobian), "tangent": entry.tangent,
            "depends": int(entry.depends), "inertia": INERTIA_METHODS.index(entry.inertia),
            "per_frame": entry.per_frame,
            "in_sizes": [n for _, n in ins], "out_rows": [r for _, r, _ in outs],
            "out_cols": [col for _, _, col in outs]}


def _with_frame(entry: Entry, ins):
    """The inputs, and the frame's number after them for a frame function."""
    return ins + ([("frame", 1)] if entry.per_frame else [])


def _signatures(name: str, entry: Entry, with_p: bool, ins, outs, patterns: _Patterns,
                np_: int, work) -> tuple[Signature, Signature]:
    """A function's signature and its Jacobian's, in CasADi's convention: the Jacobian's
    inputs are the function's, then its outputs (out_<name>, not read: no non-zeros);
    its outputs jac_<output>_<input>, output by output (none by a frame's number)."""
    ins = _with_frame(entry, ins) + ([("p", np_)] if with_p else [])
    names_in = tuple(n for n, _ in ins)
    names_out = tuple(n for n, _, _ in outs)
    pat_in = tuple(patterns.dense(n, 1) for _, n in ins)
    pat_out = tuple(patterns.dense(r, c) for _, r, c in outs)
    signature = f"({_ports(ins)}) -> ({_ports([(n, r * c) for n, r, c in outs])})"
    common = {"entry": entry.name, "with_p": 1 if with_p else 0}
    value = Signature(name=name, jacobian=False, names_in=names_in, names_out=names_out,
                      patterns_in=pat_in, patterns_out=pat_out, work=work["value"],
                      signature=signature, **common)
    jac_in = names_in + tuple(f"out_{n}" for n in names_out)
    jac_pat_in = pat_in + tuple(patterns.empty(r, c) for _, r, c in outs)
    jac_out = tuple(f"jac_{o}_{i}" for o in names_out for i in names_in)
    jac_pat_out = tuple(patterns.empty(r * c, 1) if i == "frame" else patterns.dense(r * c, n)
                        for _, r, c in outs for i, n in ins)
    jacobian = Signature(name=f"jac_{name}", jacobian=True, names_in=jac_in,
                         names_out=jac_out, patterns_in=jac_pat_in, patterns_out=jac_pat_out,
                         work=work["jacobian"], signature=f"the Jacobian of {name}", **common)
    return value, jacobian

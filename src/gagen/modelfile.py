"""Read model files (YAML or JSON, DESIGN.md section 4) into a validated Model."""

from __future__ import annotations

import json
import keyword
import re
from pathlib import Path
from typing import Any

import sympy as sp
import yaml
from sympy.parsing.sympy_parser import TokenError, parse_expr, standard_transformations

from .model import (
    JOINT_TYPES,
    WORLD,
    Body,
    Joint,
    Limits,
    Model,
    ModelError,
    inertia_matrix,
    rotation_from_rpy,
    vector,
)

_IDENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def load_model_file(path: str | Path) -> Model:
    path = Path(path)
    source = str(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ModelError(source, "", f"cannot read model file: {exc.strerror}") from None
    return parse_model_text(text, source, fmt=path.suffix.lower().lstrip("."))


def parse_model_text(text: str, source: str, fmt: str = "yaml") -> Model:
    data = _parse_document(text, source, fmt)
    return model_from_dict(data, source)


def _parse_document(text: str, source: str, fmt: str) -> dict:
    if fmt == "json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ModelError(source, f"line {exc.lineno}, column {exc.colno}",
                             f"malformed JSON: {exc.msg}") from None
    else:
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else ""
            problem = getattr(exc, "problem", None) or str(exc)
            raise ModelError(source, where, f"malformed YAML: {problem}") from None
    if not isinstance(data, dict):
        raise ModelError(source, "", "a model file must hold a mapping with 'bodies'")
    return data


class _ExprParser:
    """Parses entries that are numbers or expressions in the declared parameters."""

    def __init__(self, names: list[str], source: str):
        self.source = source
        self.local = {}
        self.aliases = []  # (name, placeholder) for names that are not Python identifiers
        for k, name in enumerate(sorted(names, key=len, reverse=True)):
            if _IDENT.match(name) and not keyword.iskeyword(name):
                self.local[name] = sp.Symbol(name)
            else:
                placeholder = f"__gagen_param_{k}"
                self.aliases.append((name, placeholder))
                self.local[placeholder] = sp.Symbol(name)

    def __call__(self, value: Any, element: str) -> sp.Expr:
        if isinstance(value, bool):
            raise ModelError(self.source, element, f"expected a number or expression, got {value!r}")
        if isinstance(value, (int, float)):
            return sp.sympify(value)
        if not isinstance(value, str):
            raise ModelError(self.source, element, f"expected a number or expression, got {value!r}")
        text = value
        for name, placeholder in self.aliases:
            text = re.sub(r"(?<![A-Za-z0-9_])" + re.escape(name) + r"(?![A-Za-z0-9_])",
                          placeholder, text)
        try:
            expr = parse_expr(text, local_dict=dict(self.local),
                              transformations=standard_transformations, evaluate=True)
        except (SyntaxError, TokenError, TypeError, ValueError, AttributeError,
                sp.SympifyError) as exc:  # sympy's parser raises all of these
            raise ModelError(self.source, element, f"cannot parse expression '{value}': {exc}") from None
        if not isinstance(expr, sp.Expr):
            raise ModelError(self.source, element, f"'{value}' is not an algebraic expression")
        return expr

    def vec(self, value: Any, element: str, length: int = 3) -> list[sp.Expr]:
        if not isinstance(value, (list, tuple)) or len(value) != length:
            raise ModelError(self.source, element, f"expected a list of {length} entries, got {value!r}")
        return [self(v, f"{element}[{i}]") for i, v in enumerate(value)]


def _require(mapping: dict, key: str, source: str, element: str):
    if key not in mapping:
        raise ModelError(source, element, f"missing '{key}'")
    return mapping[key]


def model_from_dict(data: dict, source: str) -> Model:
    known = {"name", "gravity", "parameters", "bodies", "description"}
    extra = set(data) - known
    if extra:
        raise ModelError(source, "", f"unknown top-level key(s) {', '.join(sorted(map(str, extra)))}")
    params = data.get("parameters") or {}
    if not isinstance(params, dict):
        raise ModelError(source, "parameters", "expected a mapping of name: default value")
    parameters: dict[str, float] = {}
    for name, value in params.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ModelError(source, f"parameter '{name}'", f"default value {value!r} is not a number")
        parameters[str(name)] = float(value)
    parse = _ExprParser(list(parameters), source)
    gravity = vector(parse.vec(data.get("gravity", [0, 0, "-g"] if "g" in parameters else [0, 0, -9.81]),
                               "gravity"))
    raw_bodies = _require(data, "bodies", source, "")
    if not isinstance(raw_bodies, list) or not raw_bodies:
        raise ModelError(source, "bodies", "expected a non-empty list of bodies")
    bodies = []
    coordinate_index = 0
    for k, raw in enumerate(raw_bodies):
        body, moved = _body_from_dict(raw, k, coordinate_index, parse, source)
        coordinate_index += moved
        bodies.append(body)
    name = str(data.get("name") or Path(source).stem)
    return Model(name=name, bodies=tuple(bodies), parameters=parameters, gravity=gravity,
                 source=source, description=str(data.get("description", "")))


def _body_from_dict(raw: Any, k: int, coordinate_index: int, parse: _ExprParser,
                    source: str) -> tuple[Body, int]:
    if not isinstance(raw, dict):
        raise ModelError(source, f"bodies[{k}]", "expected a mapping")
    name = str(_require(raw, "name", source, f"bodies[{k}]"))
    where = f"body '{name}'"
    extra = set(raw) - {"name", "parent", "joint", "mass", "com", "inertia"}
    if extra:
        raise ModelError(source, where, f"unknown key(s) {', '.join(sorted(map(str, extra)))}")
    parent = str(raw.get("parent", WORLD))
    rj = raw.get("joint") or {}
    if not isinstance(rj, dict):
        raise ModelError(source, f"{where}, joint", "expected a mapping")
    jtype = str(rj.get("type", "revolute"))
    if jtype not in JOINT_TYPES:
        raise ModelError(source, f"{where}, joint",
                         f"unknown joint type '{jtype}' (expected one of {', '.join(JOINT_TYPES)})")
    moves = jtype != "fixed"
    default_name = f"q{coordinate_index + 1}" if moves else f"{name}_fixed"
    jname = str(rj.get("name", default_name))
    origin = rj.get("origin") or {}
    if not isinstance(origin, dict):
        raise ModelError(source, f"{where}, joint origin", "expected a mapping with xyz and rpy")
    xyz = parse.vec(origin.get("xyz", [0, 0, 0]), f"{where}, joint origin xyz")
    rpy = parse.vec(origin.get("rpy", [0, 0, 0]), f"{where}, joint origin rpy")
    axis = parse.vec(rj.get("axis", [0, 0, 1]), f"{where}, joint axis")
    limits = rj.get("limits")
    joint = Joint(name=jname, type=jtype, origin_xyz=vector(xyz),
                  origin_rotation=rotation_from_rpy(*rpy), axis=vector(axis),
                  limits=Limits(**limits) if isinstance(limits, dict) else None)
    mass = parse(raw.get("mass", 0), f"{where}, mass")
    com = parse.vec(raw.get("com", [0, 0, 0]), f"{where}, com")
    inertia = raw.get("inertia", [0, 0, 0, 0, 0, 0])
    values = parse.vec(inertia, f"{where}, inertia", length=6)
    body = Body(name=name, parent=parent, joint=joint, mass=mass, com=vector(com),
                inertia=inertia_matrix(*values))
    return body, int(moves)

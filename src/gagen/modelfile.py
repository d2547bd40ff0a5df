"""Read model files (YAML or JSON, DESIGN.md section 4) into a validated Model."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import sympy as sp
import yaml

from .expressions import ExpressionError, ExpressionParser
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
        self.parser = ExpressionParser(names)

    def __call__(self, value: Any, element: str) -> sp.Expr:
        if isinstance(value, bool) or not isinstance(value, (int, float, str)):
            raise ModelError(self.source, element, f"expected a number or expression, got {value!r}")
        if isinstance(value, float) and not math.isfinite(value):
            raise ModelError(self.source, element, f"the value {value!r} is not finite")
        if isinstance(value, (int, float)):
            return sp.sympify(value)
        try:
            return self.parser.parse(value)
        except ExpressionError as exc:
            raise ModelError(self.source, element, f"cannot use '{value}': {exc}") from None

    def vec(self, value: Any, element: str, length: int = 3) -> list[sp.Expr]:
        if not isinstance(value, (list, tuple)) or len(value) != length:
            raise ModelError(self.source, element, f"expected a list of {length} entries, got {value!r}")
        return [self(v, f"{element}[{i}]") for i, v in enumerate(value)]


def _check_keys(mapping: dict, allowed: set[str], source: str, element: str) -> None:
    """Refuse misspelt keys: a silently ignored 'axes' would give a wrong model."""
    extra = set(mapping) - allowed
    if extra:
        raise ModelError(source, element, f"unknown key(s) {', '.join(sorted(map(str, extra)))}"
                         f" (expected: {', '.join(sorted(allowed))})")


def _limits(raw: Any, source: str, element: str) -> Limits | None:
    if raw is None:
        return None
    if not isinstance(raw, dict):
        raise ModelError(source, element, "expected a mapping of lower, upper, effort, velocity")
    _check_keys(raw, {"lower", "upper", "effort", "velocity"}, source, element)
    values = {}
    for key, value in raw.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ModelError(source, f"{element} {key}", f"expected a number, got {value!r}")
        values[key] = float(value)
    return Limits(**values)


def _require(mapping: dict, key: str, source: str, element: str):
    if key not in mapping:
        raise ModelError(source, element, f"missing '{key}'")
    return mapping[key]


def model_from_dict(data: dict, source: str) -> Model:
    _check_keys(data, {"name", "gravity", "parameters", "bodies", "description"}, source, "")
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
    _check_keys(raw, {"name", "parent", "joint", "mass", "com", "inertia"}, source, where)
    parent = str(raw.get("parent", WORLD))
    rj = raw.get("joint") or {}
    if not isinstance(rj, dict):
        raise ModelError(source, f"{where}, joint", "expected a mapping")
    _check_keys(rj, {"name", "type", "origin", "axis", "limits"}, source, f"{where}, joint")
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
    _check_keys(origin, {"xyz", "rpy"}, source, f"{where}, joint origin")
    xyz = parse.vec(origin.get("xyz", [0, 0, 0]), f"{where}, joint origin xyz")
    rpy = parse.vec(origin.get("rpy", [0, 0, 0]), f"{where}, joint origin rpy")
    axis = parse.vec(rj.get("axis", [0, 0, 1]), f"{where}, joint axis")
    joint = Joint(name=jname, type=jtype, origin_xyz=vector(xyz),
                  origin_rotation=rotation_from_rpy(*rpy), axis=vector(axis),
                  limits=_limits(rj.get("limits"), source, f"{where}, joint limits"))
    mass = parse(raw.get("mass", 0), f"{where}, mass")
    com = parse.vec(raw.get("com", [0, 0, 0]), f"{where}, com")
    inertia = raw.get("inertia", [0, 0, 0, 0, 0, 0])
    values = parse.vec(inertia, f"{where}, inertia", length=6)
    body = Body(name=name, parent=parent, joint=joint, mass=mass, com=vector(com),
                inertia=inertia_matrix(*values))
    return body, int(moves)

"""Read model files (YAML or JSON, DESIGN.md section 4) into a validated Model."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import sympy as sp
import yaml

from . import inputs
from .expressions import MAX_MAGNITUDE, ExpressionError, ExpressionParser
from .inputs import check_body_count, describe, name_field, quote, read_description
from .model import (
    JOINT_TERMS,
    JOINT_TYPES,
    WORLD,
    Body,
    Joint,
    Limits,
    Model,
    ModelError,
    check_model_inertias,
    inertia_matrix,
    rotation_from_rpy,
    vector,
)

# libyaml's loader is about 5x faster and bounds nesting; both construct only plain data
_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def load_model_file(path: str | Path, strict: bool = False) -> Model:
    """Read and validate a YAML or JSON model file (DESIGN.md section 4).

    An inertia slightly off physical warns (`gagen.errors.InertiaWarning`), or is refused
    when `strict`."""
    path = Path(path)
    data = read_description(path, "model file", inputs.MAX_MODEL_FILE_BYTES)
    return parse_model_text(data, str(path), fmt=path.suffix.lower().lstrip("."),
                            strict=strict)


def parse_model_text(text: str | bytes, source: str, fmt: str = "yaml",
                     strict: bool = False) -> Model:
    """A Model from the text (or undecoded bytes) of a model file."""
    data = _parse_document(text, source, fmt)
    model = model_from_dict(data, source)
    check_model_inertias(model, strict)
    return model


def _parse_document(text: str | bytes, source: str, fmt: str) -> dict:
    if fmt == "json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ModelError(source, f"line {exc.lineno}, column {exc.colno}",
                             f"malformed JSON: {exc.msg}") from None
        except (UnicodeDecodeError, RecursionError, ValueError) as exc:
            raise ModelError(source, "", f"malformed JSON: {_short_reason(exc)}") from None
    else:
        try:
            data = yaml.load(text, Loader=_SAFE_LOADER)
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else ""
            problem = getattr(exc, "problem", None) or _short_reason(exc)
            raise ModelError(source, where, f"malformed YAML: {problem}") from None
        except (RecursionError, ValueError, OverflowError) as exc:
            # PyYAML lets Python's own limits through: nesting depth, the 4300-digit cap
            raise ModelError(source, "", f"malformed YAML: {_short_reason(exc)}") from None
    if not isinstance(data, dict):
        raise ModelError(source, "", "a model file must hold a mapping with 'bodies'")
    return data


def _short_reason(exc: BaseException) -> str:
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return text if len(text) <= 120 else text[:120] + "..."


def _finite_number(value: Any, source: str, element: str) -> float:
    """A plain number of a model file as a float within gagen's magnitude bound."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ModelError(source, element, f"expected a number, got {describe(value)}")
    try:
        number = float(value)
    except OverflowError:
        number = math.inf
    if not math.isfinite(number) or abs(number) > MAX_MAGNITUDE:
        raise ModelError(source, element, f"the value {describe(value)} is not a finite "
                         f"number of at most {MAX_MAGNITUDE:g} in magnitude")
    return number


class _ExprParser:
    """Parses entries that are numbers or expressions in the declared parameters."""

    def __init__(self, names: list[str], source: str):
        self.source = source
        self.parser = ExpressionParser(names)

    def __call__(self, value: Any, element: str) -> sp.Expr:
        if isinstance(value, str):
            try:
                return self.parser.parse(value)
            except ExpressionError as exc:
                raise ModelError(self.source, element, f"cannot use {quote(value)}: {exc}") from None
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ModelError(self.source, element,
                             f"expected a number or expression, got {describe(value)}")
        number = _finite_number(value, self.source, element)
        return sp.Integer(value) if isinstance(value, int) else sp.Float(number)

    def vec(self, value: Any, element: str, length: int = 3) -> list[sp.Expr]:
        if not isinstance(value, (list, tuple)) or len(value) != length:
            raise ModelError(self.source, element,
                             f"expected a list of {length} entries, got {describe(value)}")
        return [self(v, f"{element}[{i}]") for i, v in enumerate(value)]


def _check_keys(mapping: dict, allowed: set[str], source: str, element: str) -> None:
    """Refuse misspelt keys: a silently ignored 'axes' would give a wrong model."""
    extra = set(mapping) - allowed
    if extra:
        shown = ", ".join(sorted(describe(key) for key in list(extra)[:10]))
        raise ModelError(source, element, f"unknown key(s) {shown}"
                         f" (expected: {', '.join(sorted(allowed))})")


def _limits(raw: Any, source: str, element: str) -> Limits | None:
    if raw is None:
        return None
    if not isinstance(raw, dict):
        raise ModelError(source, element, "expected a mapping of lower, upper, effort, velocity")
    _check_keys(raw, {"lower", "upper", "effort", "velocity"}, source, element)
    values = {key: _finite_number(value, source, f"{element} {key}") for key, value in raw.items()}
    return Limits(**values)


def _require(mapping: dict, key: str, source: str, element: str):
    if key not in mapping:
        raise ModelError(source, element, f"missing '{key}'")
    return mapping[key]


def model_from_dict(data: dict, source: str) -> Model:
    _check_keys(data, {"name", "gravity", "parameters", "bodies", "description", "constraints"},
                source, "")
    params = data.get("parameters") or {}
    if not isinstance(params, dict):
        raise ModelError(source, "parameters", "expected a mapping of name: default value")
    parameters: dict[str, float] = {}
    for key, value in params.items():
        name = name_field(key, source, "parameters")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ModelError(source, f"parameter {quote(name)}",
                             f"default value {describe(value)} is not a number")
        parameters[name] = _finite_number(value, source, f"parameter {quote(name)}")
    parse = _ExprParser(list(parameters), source)
    gravity = vector(parse.vec(data.get("gravity", [0, 0, "-g"] if "g" in parameters else [0, 0, -9.81]),
                               "gravity"))
    raw_bodies = _require(data, "bodies", source, "")
    if not isinstance(raw_bodies, list) or not raw_bodies:
        raise ModelError(source, "bodies", "expected a non-empty list of bodies")
    check_body_count(len(raw_bodies), source, "bodies")
    bodies = []
    coordinate_index = 0
    for k, raw in enumerate(raw_bodies):
        body, moved = _body_from_dict(raw, k, coordinate_index, parse, source)
        coordinate_index += moved
        bodies.append(body)
    name = name_field(data.get("name") or Path(source).stem, source, "name")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise ModelError(source, "description", f"expected text, got {describe(description)}")
    model = Model(name=name, bodies=tuple(bodies), parameters=parameters, gravity=gravity,
                  source=source, description=description)
    if "constraints" in data:
        from .constraints import attach_constraints

        model = attach_constraints(model, data["constraints"])
    return model


def _body_from_dict(raw: Any, k: int, coordinate_index: int, parse: _ExprParser,
                    source: str) -> tuple[Body, int]:
    if not isinstance(raw, dict):
        raise ModelError(source, f"bodies[{k}]", "expected a mapping")
    name = name_field(_require(raw, "name", source, f"bodies[{k}]"), source, f"bodies[{k}] name")
    where = f"body {quote(name)}"
    _check_keys(raw, {"name", "parent", "joint", "mass", "com", "inertia"}, source, where)
    parent = name_field(raw.get("parent", WORLD), source, f"{where}, parent")
    rj = raw.get("joint") or {}
    if not isinstance(rj, dict):
        raise ModelError(source, f"{where}, joint", "expected a mapping")
    _check_keys(rj, {"name", "type", "origin", "axis", "limits", *JOINT_TERMS}, source,
                f"{where}, joint")
    jtype = rj.get("type", "revolute")
    if not isinstance(jtype, str) or jtype not in JOINT_TYPES:
        raise ModelError(source, f"{where}, joint", f"unknown joint type {describe(jtype)} "
                         f"(expected one of {', '.join(JOINT_TYPES)})")
    moves = jtype != "fixed"
    default_name = f"q{coordinate_index + 1}" if moves else f"{name}_fixed"
    jname = name_field(rj.get("name", default_name), source, f"{where}, joint name")
    origin = rj.get("origin") or {}
    if not isinstance(origin, dict):
        raise ModelError(source, f"{where}, joint origin", "expected a mapping with xyz and rpy")
    _check_keys(origin, {"xyz", "rpy"}, source, f"{where}, joint origin")
    xyz = parse.vec(origin.get("xyz", [0, 0, 0]), f"{where}, joint origin xyz")
    rpy = parse.vec(origin.get("rpy", [0, 0, 0]), f"{where}, joint origin rpy")
    axis = parse.vec(rj.get("axis", [0, 0, 1]), f"{where}, joint axis")
    terms = {key: parse(rj.get(key, 0), f"{where}, joint {key}") for key in JOINT_TERMS}
    joint = Joint(name=jname, type=jtype, origin_xyz=vector(xyz),
                  origin_rotation=rotation_from_rpy(*rpy), axis=vector(axis),
                  limits=_limits(rj.get("limits"), source, f"{where}, joint limits"), **terms)
    mass = parse(raw.get("mass", 0), f"{where}, mass")
    com = parse.vec(raw.get("com", [0, 0, 0]), f"{where}, com")
    inertia = raw.get("inertia", [0, 0, 0, 0, 0, 0])
    values = parse.vec(inertia, f"{where}, inertia", length=6)
    body = Body(name=name, parent=parent, joint=joint, mass=mass, com=vector(com),
                inertia=inertia_matrix(*values))
    return body, int(moves)

"""Every model-file error is a ModelError that names the file, the element and the reason,
whether the file is YAML or JSON; a failed `gagen build` writes nothing."""

from __future__ import annotations

import copy
import json
import re

import pytest
import yaml

import gagen
from gagen import ModelError
from gagen.app.cli import main

BASE = {
    "name": "arm",
    "gravity": [0, 0, "-g"],
    "parameters": {"g": 9.81, "L": 0.5, "m1": 2.0, "m2": 1.5, "a": 1.0},
    "bodies": [
        {"name": "link1",
         "joint": {"name": "q1", "type": "revolute", "axis": [0, 0, 1]},
         "mass": "m1", "com": [0, "L/2", 0], "inertia": [0.1, 0.1, 0.1, 0, 0, 0]},
        {"name": "link2", "parent": "link1",
         "joint": {"name": "q2", "type": "revolute",
                   "origin": {"xyz": [0, "L", 0], "rpy": [0, 0, 0]}, "axis": ["a", 0, 0]},
         "mass": "m2", "com": [0, "L/2", 0], "inertia": [0.05, 0.04, 0.03, 0.001, 0, 0]},
        {"name": "link3", "parent": "link2",
         "joint": {"name": "q3", "type": "prismatic", "axis": [0, 1, 0]},
         "mass": 1.0, "com": [0, 0.1, 0], "inertia": [0.01, 0.01, 0.01, 0, 0, 0]},
    ],
}
FORMATS = ["yaml", "json"]


def write(tmp_path, doc, fmt: str, stem: str = "model"):
    path = tmp_path / f"{stem}.{fmt}"
    path.write_text(yaml.safe_dump(doc, sort_keys=False) if fmt == "yaml" else json.dumps(doc))
    return path


def variant(**changes):
    """BASE with changes given as 'dotted.path=value', e.g. bodies.1.parent."""
    doc = copy.deepcopy(BASE)
    for dotted, value in changes.items():
        *parents, last = dotted.split("__")
        node = doc
        for key in parents:
            node = node[int(key)] if isinstance(node, list) else node[key]
        if isinstance(node, list):
            node[int(last)] = value
        else:
            node[last] = value
    return doc


def assert_model_error(path, element: str, reason: str, load: bool = True) -> ModelError:
    """The error names the file and the element exactly, and its reason matches `reason`."""
    with pytest.raises(ModelError) as info:
        if load:
            gagen.load(path, backend="lambdify")
        else:
            gagen.resolve_model(path)
    err = info.value
    message = str(err)
    assert err.source == str(path), message
    assert err.element == element, message
    assert re.search(reason, err.reason), message
    expected = f"{path}: {element}: {err.reason}" if element else f"{path}: {err.reason}"
    assert message == expected
    return err


@pytest.mark.parametrize("fmt", FORMATS)
def test_base_model_is_valid(tmp_path, fmt):
    dyn = gagen.load(write(tmp_path, BASE, fmt), backend="lambdify")
    assert dyn.coordinates == ["q1", "q2", "q3"]
    assert dyn.mass_matrix([0.1, 0.2, 0.3]).shape == (3, 3)


# (id, changes to BASE, element, reason regex)
CASES = [
    # tree structure
    ("unknown parent", {"bodies__1__parent": "nope"}, "body 'link2'", r"unknown parent 'nope'"),
    ("cyclic parents", {"bodies__0__parent": "link3"}, "body 'link1'",
     r"cyclic parent chain among bodies link1, link2, link3: a model must be a tree"),
    ("own parent", {"bodies__1__parent": "link2"}, "body 'link2'",
     r"cyclic parent chain among bodies link2, link3"),
    ("duplicate body name", {"bodies__2__name": "link1"}, "body 'link1'", r"duplicate body name"),
    ("world as a body", {"bodies__0__name": "world"}, "body 'world'", r"'world' is reserved"),
    ("duplicate coordinate", {"bodies__2__joint__name": "q1"}, "body 'link3', joint 'q1'",
     r"duplicate coordinate name 'q1' \(also used by body 'link1'\)"),
    # undeclared symbols, wherever they are
    ("undeclared in com", {"bodies__1__com": [0, "L/2 + zz", 0]}, "body 'link2', com[1]",
     r"undeclared symbol zz \(declare it under 'parameters'\)"),
    ("undeclared in mass", {"bodies__1__mass": "m2*k"}, "body 'link2', mass",
     r"undeclared symbol k\b"),
    ("undeclared in inertia", {"bodies__1__inertia": ["Ixx", 0.04, 0.03, 0, 0, 0]},
     "body 'link2', inertia[0]", r"undeclared symbol Ixx"),
    ("undeclared in origin", {"bodies__1__joint__origin": {"xyz": [0, "h", 0]}},
     "body 'link2', joint origin xyz[1]", r"undeclared symbol h\b"),
    ("undeclared in origin rpy", {"bodies__1__joint__origin": {"rpy": ["phi", 0, 0]}},
     "body 'link2', joint origin rpy[0]", r"undeclared symbol phi"),
    ("undeclared in axis", {"bodies__1__joint__axis": [1, "b", 0]},
     "body 'link2', joint axis[1]", r"undeclared symbol b\b"),
    ("undeclared in gravity", {"gravity": [0, "G", "-g*c"]}, "gravity[1]",
     r"undeclared symbol G\b"),
    # physical sense
    ("negative mass", {"bodies__1__mass": -1}, "body 'link2', mass",
     r"mass must be non-negative, got -1\b"),
    ("negative mass parameter", {"parameters__m2": -1.5}, "body 'link2', mass",
     r"mass must be non-negative, got -1.5"),
    ("inertia not positive semi-definite", {"bodies__1__inertia": [1, 1, 1, 2, 0, 0]},
     "body 'link2', inertia", r"inertia tensor is not positive semi-definite"),
    ("negative principal moment", {"bodies__1__inertia": [-0.1, 0.1, 0.1, 0, 0, 0]},
     "body 'link2', inertia", r"not positive semi-definite"),
    ("triangle inequality", {"bodies__1__inertia": [0.1, 0.1, 0.3, 0, 0, 0]},
     "body 'link2', inertia", r"break the triangle inequality"),
    ("zero axis", {"bodies__1__joint__axis": [0, 0, 0]}, "body 'link2', joint 'q2'",
     r"zero joint axis"),
    ("zero axis through a parameter", {"parameters__a": 0.0}, "body 'link2', joint 'q2'",
     r"zero joint axis"),
    ("unknown joint type", {"bodies__1__joint__type": "ball"}, "body 'link2', joint",
     r"unknown joint type 'ball' \(expected one of revolute, .*, floating\)"),
    # parameters
    ("non-numeric default", {"parameters__g": "abc"}, "parameter 'g'",
     r"default value 'abc' is not a number"),
    ("boolean default", {"parameters__L": True}, "parameter 'L'", r"default value True is not"),
    ("null default", {"parameters__L": None}, "parameter 'L'", r"default value None is not"),
    ("list default", {"parameters__L": [1, 2]}, "parameter 'L'", r"is not a number"),
    ("non-finite default", {"parameters__L": float("inf")}, "parameter 'L'", r"not a finite"),
    ("parameters not a mapping", {"parameters": [1, 2]}, "parameters", r"expected a mapping"),
    # unknown keys
    ("unknown top-level key", {"colour": "red"}, "", r"unknown key\(s\) 'colour'"),
    ("unknown body key", {"bodies__1__masss": 2.0}, "body 'link2'", r"unknown key\(s\) 'masss'"),
    # expressions
    ("unparsable expression", {"bodies__1__mass": "m2*("}, "body 'link2', mass",
     r"cannot use 'm2\*\(': syntax error"),
    ("unparsable vector entry", {"bodies__1__com": [0, "L/", 0]}, "body 'link2', com[1]",
     r"cannot use 'L/': syntax error"),
    ("not algebraic", {"bodies__1__mass": "m2 < 1"}, "body 'link2', mass",
     r"'m2 < 1' is not allowed"),
    ("boolean entry", {"bodies__1__mass": True}, "body 'link2', mass",
     r"expected a number or expression, got True"),
    ("null entry", {"bodies__1__com": [0, None, 0]}, "body 'link2', com[1]",
     r"expected a number or expression, got None"),
    ("short vector", {"bodies__1__com": [0, 0]}, "body 'link2', com",
     r"expected a list of 3 entries"),
    ("short inertia", {"bodies__1__inertia": [0.1, 0.1, 0.1]}, "body 'link2', inertia",
     r"expected a list of 6 entries"),
    # shape of the document
    ("no bodies", {"bodies": []}, "bodies", r"non-empty list"),
    ("bodies not a list", {"bodies": {"link1": {}}}, "bodies", r"non-empty list"),
    ("body not a mapping", {"bodies__1": "link2"}, "bodies[1]", r"expected a mapping"),
    ("body without a name", {"bodies__1": {"parent": "link1"}}, "bodies[1]", r"missing 'name'"),
    ("joint not a mapping", {"bodies__1__joint": "revolute"}, "body 'link2', joint",
     r"expected a mapping"),
    ("origin not a mapping", {"bodies__1__joint__origin": [0, 0, 0]},
     "body 'link2', joint origin", r"expected a mapping"),
]


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("changes,element,reason", [c[1:] for c in CASES],
                         ids=[c[0] for c in CASES])
def test_model_file_errors(tmp_path, fmt, changes, element, reason):
    path = write(tmp_path, variant(**changes), fmt)
    assert_model_error(path, element, reason, load=fmt == "yaml")


def test_missing_bodies_key(tmp_path):
    doc = copy.deepcopy(BASE)
    del doc["bodies"]
    for fmt in FORMATS:
        assert_model_error(write(tmp_path, doc, fmt), "", r"missing 'bodies'")


MALFORMED_YAML = {
    "unclosed bracket": ("bodies: [\n  - name: x\n", r"line \d+, column \d+"),
    "bad indentation": ("name: x\n  bodies:\n - name: a\n", r"line 2, column \d+"),
    "tab": ("name: x\nbodies:\n\t- name: a\n", r"line 3, column 1"),
    "unclosed quote": ("name: 'x\nbodies: []\n", r"line \d+, column \d+"),
}


@pytest.mark.parametrize("text,where", MALFORMED_YAML.values(), ids=MALFORMED_YAML.keys())
def test_malformed_yaml(tmp_path, text, where):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ModelError) as info:
        gagen.load(path, backend="lambdify")
    err = info.value
    assert err.source == str(path)
    assert re.fullmatch(where, err.element), err.element
    assert err.reason.startswith("malformed YAML: ")
    assert str(err).startswith(f"{path}: line ")


@pytest.mark.parametrize("text,where", [
    ('{"bodies": [}', "line 1, column 13"),
    ('{\n  "name": "x",\n  "bodies": []\n  "gravity": [0, 0, -9.81]\n}', "line 4, column 3"),
    ('{"name": "x", }', "line 1, column 15"),
    ("", "line 1, column 1"),
    ("name: x\nbodies: []\n", "line 1, column 1"),  # YAML is not JSON
])
def test_malformed_json(tmp_path, text, where):
    path = tmp_path / "bad.json"
    path.write_text(text)
    err = assert_model_error(path, where, r"^malformed JSON: ", load=False)
    assert len(err.reason) > len("malformed JSON: ")


@pytest.mark.parametrize("fmt,text", [("yaml", "- a\n- b\n"), ("yaml", ""), ("yaml", "42\n"),
                                      ("json", "[1, 2]"), ("json", '"bodies"')])
def test_document_is_not_a_mapping(tmp_path, fmt, text):
    path = tmp_path / f"doc.{fmt}"
    path.write_text(text)
    assert_model_error(path, "", r"must hold a mapping with 'bodies'")


def test_unreadable_and_unknown_files(tmp_path):
    missing = tmp_path / "absent.yaml"
    assert_model_error(missing, "", r"cannot read model file")
    with pytest.raises(ModelError, match=r"not a built-in model"):
        gagen.resolve_model(tmp_path / "model.txt")
    for name in ("chain:0", "chain:x", "chain:65"):
        with pytest.raises(ModelError, match=r"chain:N"):
            gagen.resolve_model(name)


# ------------------------------------------------- misspelt keys and values that are not numbers


KEYS_AND_VALUES = [
    ("unknown joint key", {"bodies__1__joint__axes": [1, 0, 0]}, "body 'link2', joint",
     r"unknown key"),
    ("unknown origin key", {"bodies__1__joint__origin": {"xzy": [0, 1, 0]}},
     "body 'link2', joint origin", r"unknown key"),
    ("unknown limits key", {"bodies__1__joint__limits": {"lowr": -1.0}},
     "body 'link2', joint limits", r"unknown key"),
    ("non-finite com", {"bodies__1__com": [0, "1/0", 0]}, "body 'link2', com[1]",
     r"not finite"),
    ("non-finite gravity", {"gravity": [0, 0, "-g/0"]}, "gravity[2]", r"not finite"),
    ("imaginary unit is not a symbol", {"bodies__1__com": [0, "I", 0]}, "body 'link2', com[1]",
     r"undeclared symbol I\b"),
    ("non-finite through a parameter", {"bodies__1__com": [0, "1/(L - L)", 0]},
     "body 'link2', com[1]", r"not finite"),
]


@pytest.mark.parametrize("changes,element,reason", [c[1:] for c in KEYS_AND_VALUES],
                         ids=[c[0] for c in KEYS_AND_VALUES])
def test_misspelt_keys_and_values_that_are_not_numbers(tmp_path, changes, element, reason):
    assert_model_error(write(tmp_path, variant(**changes), "yaml"), element, reason, load=False)


def test_expressions_cannot_run_code(tmp_path):
    marker = tmp_path / "ran"
    doc = variant(bodies__1__mass=f"__import__('pathlib').Path({str(marker)!r}).touch() or m2")
    path = write(tmp_path, doc, "yaml")
    try:
        with pytest.raises(ModelError):
            gagen.resolve_model(path)
    finally:
        assert not marker.exists(), "the model file ran code"


# ------------------------------------------------------------------------ command line


def test_failed_build_writes_nothing(tmp_path, capsys):
    bad = write(tmp_path, variant(bodies__1__parent="nope"), "yaml", stem="bad")
    out = tmp_path / "out"
    code = main(["build", str(bad), "--out", str(out)])
    assert code == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith("gagen: error: ")
    assert f"{bad}: body 'link2': unknown parent 'nope'" in captured.err
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.yaml"]


def test_build_failing_after_loading_writes_nothing(tmp_path, capsys, monkeypatch):
    """The model loads but the build fails later: no folder is left behind."""
    from gagen.building import builder as build_module
    from gagen.model import ModelError as Error

    def failing(model, *args, **kwargs):
        raise Error(model.source, "body 'link2'", "cannot be derived")

    monkeypatch.setattr(build_module, "generate_sources", failing)
    good = write(tmp_path, variant(), "json", stem="good")
    out = tmp_path / "nested" / "out"
    code = main(["build", str(good), "--out", str(out)])
    assert code == 2
    err = capsys.readouterr().err
    assert f"gagen: error: {good}: body 'link2': cannot be derived" in err
    assert not out.exists()
    assert not out.parent.exists()


def test_malformed_file_on_the_command_line(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("bodies: [\n")
    out = tmp_path / "out"
    assert main(["build", str(bad), "--out", str(out)]) == 2
    assert not out.exists()
    err = capsys.readouterr().err
    assert err.startswith(f"gagen: error: {bad}: line ") and "malformed YAML" in err
    assert main(["info", str(bad)]) == 2
    assert "malformed YAML" in capsys.readouterr().err

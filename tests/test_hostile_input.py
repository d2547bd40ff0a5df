"""Hostile and careless files are refused quickly with a one-line ModelError (issue 11,
classes 5 and 6): bounded expressions, never-expanded YAML aliases, no XML entities,
encodings by the format's own rules, bounded sizes, and clean errors for odd values.

Each refusal is asserted to take well under a second (a hang would take minutes), with a
message that names the file and the element.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
import yaml

from gagen.errors import ModelError
from gagen.model import inputs
from gagen.model.modelfile import load_model_file, parse_model_text
from gagen.model.resolve import resolve_model
from gagen.model.urdf import load_urdf, parse_urdf_text

DATA = Path(__file__).parent / "data" / "urdf"


def pendulum(mass="m", length="L", **extra) -> dict:
    """A one-link pendulum model document; any field can be replaced by a payload."""
    doc = {"name": "pendulum", "parameters": {"m": 1.0, "L": 0.5, "g": 9.81},
           "bodies": [{"name": "link", "mass": mass, "com": [0, length, 0],
                       "inertia": [0.1, 0.1, 0.1, 0, 0, 0]}]}
    doc.update(extra)
    return doc


def refused(document, fmt="yaml", source="hostile.yaml") -> ModelError:
    """Parse `document` and return the ModelError, asserting it came fast and on one line."""
    text = document if isinstance(document, (str, bytes)) else yaml.safe_dump(document)
    start = time.perf_counter()
    with pytest.raises(ModelError) as info:
        parse_model_text(text, source, fmt=fmt)
    elapsed = time.perf_counter() - start
    message = str(info.value)
    assert elapsed < 2.0, f"took {elapsed:.1f} s to refuse"
    assert "\n" not in message and "\r" not in message
    assert len(message) < 400, message
    assert message.startswith(source)
    return info.value


# ------------------------------------------------------------------- bounded expressions

@pytest.mark.parametrize("payload, reason", [
    ("9**9**9", "exponent"),
    ("2**10**10", "exponent"),
    ("(L+1)**100000", "exponent"),
    ("10**400", "exponent"),
    ("1e300*1e300", "larger than"),
    ("exp(exp(exp(100)))", "larger than"),
    ("1" * 5000, "characters"),                         # past Python's 4300-digit limit
    ("L" + "+L" * 3000, "characters"),                 # a sum thousands deep
    ("-" * 900 + "L", "nested"),                       # a unary tower
    ("sin(" * 120 + "L" + ")" * 120, "nested"),
    ("L+" * 450 + "L", "nested"),
    ("+".join(["L*L*L*L"] * 60), "terms"),
    ("sin(L, L)", "takes 1 argument"),
    ("atan2(L)", "takes 2 arguments"),
    ("sqrt(-1)", "real"),
    ("asin(2)", "real"),
    ("1/(L-L)", "not finite"),
    ("__import__('os').system('true')", "not allowed"),
    ("L.__class__", "not allowed"),
    ("[L]*10**9", "not allowed"),
])
def test_hostile_expressions_are_refused_fast_naming_the_element(payload, reason):
    error = refused(pendulum(mass=payload))
    assert "body 'link', mass" in str(error)
    assert reason in str(error)


def test_integers_past_the_float_range_are_refused():
    error = refused(pendulum(mass=10**400))
    assert "body 'link', mass" in str(error) and "finite number" in str(error)
    error = refused("name: x\nparameters: {m: " + "9" * 5000 + "}\nbodies: []\n")
    assert "malformed YAML" in str(error) or "parameter" in str(error)


def test_huge_parameter_defaults_and_limits_are_refused():
    assert "parameter 'm'" in str(refused(pendulum(parameters={"m": 1e308 * 10, "L": 1})))
    doc = pendulum()
    doc["bodies"][0]["joint"] = {"limits": {"lower": -1e301}}
    assert "joint limits lower" in str(refused(doc))


def test_plain_expressions_still_read_exactly():
    model = parse_model_text(yaml.safe_dump(pendulum(mass="2*m**2 + sin(pi/6) - sqrt(4)")),
                             "ok.yaml")
    assert str(model.bodies[0].mass) == "2*m**2 - 3/2"


# -------------------------------------------------------------- never expand a value

ALIAS_BOMB = """\
a: &a ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]
b: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a]
c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b]
d: &d [*c, *c, *c, *c, *c, *c, *c, *c, *c]
e: &e [*d, *d, *d, *d, *d, *d, *d, *d, *d]
f: &f [*e, *e, *e, *e, *e, *e, *e, *e, *e]
g: &g [*f, *f, *f, *f, *f, *f, *f, *f, *f]
h: &h [*g, *g, *g, *g, *g, *g, *g, *g, *g]
i: &i [*h, *h, *h, *h, *h, *h, *h, *h, *h]
"""


BOMB_PLACES = {
    "name": "name: *i\nbodies: [{name: link}]",
    "description": "name: x\ndescription: *i\nbodies: [{name: link}]",
    "parameter key": "name: x\nparameters: {*i : 1}\nbodies: [{name: link}]",
    "parameter value": "name: x\nparameters: {m: *i}\nbodies: [{name: link}]",
    "body name": "name: x\nbodies: [{name: *i}]",
    "parent": "name: x\nbodies: [{name: link, parent: *i}]",
    "mass": "name: x\nbodies: [{name: link, mass: *i}]",
    "inertia": "name: x\nbodies: [{name: link, inertia: *i}]",
    "joint": "name: x\nbodies: [{name: link, joint: *i}]",
    "joint type": "name: x\nbodies: [{name: link, joint: {type: *i}}]",
    "joint limit": "name: x\nbodies: [{name: link, joint: {limits: {lower: *i}}}]",
    "bodies": "name: x\nbodies: *i",
}


@pytest.mark.parametrize("place", sorted(BOMB_PLACES))
def test_yaml_alias_bombs_are_never_expanded_in_messages(place):
    """9**9 'lol's: any str() of the value would take minutes and gigabytes."""
    error = refused(ALIAS_BOMB + BOMB_PLACES[place] + "\n")
    assert str(error).count("lol") <= 1


def test_unknown_keys_are_listed_without_expanding_them():
    doc = {"name": "x", "bodies": [{"name": "l"}], **{f"k{n}": n for n in range(100)}}
    message = str(refused(doc))
    assert "unknown key" in message and len(message) < 400


# --------------------------------------------------------------------------- XML

BILLION_LAUGHS = """<?xml version="1.0"?>
<!DOCTYPE robot [
  <!ENTITY a "aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa">
  <!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">
  <!ENTITY c "&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;">
  <!ENTITY d "&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;">
]>
<robot name="&d;"><link name="base"/></robot>
"""
EXTERNAL_ENTITY = """<?xml version="1.0"?>
<!DOCTYPE robot [<!ENTITY secret SYSTEM "file:///etc/passwd">]>
<robot name="&secret;"><link name="base"/></robot>
"""
DOCTYPE_ONLY = """<?xml version="1.0"?>
<!DOCTYPE robot SYSTEM "http://example.invalid/robot.dtd">
<robot name="x"><link name="base"/></robot>
"""


@pytest.mark.parametrize("document", [BILLION_LAUGHS, EXTERNAL_ENTITY, DOCTYPE_ONLY])
def test_urdf_dtds_and_entities_are_refused(document):
    start = time.perf_counter()
    with pytest.raises(ModelError, match="must not declare a DTD"):
        parse_urdf_text(document, "evil.urdf")
    assert time.perf_counter() - start < 1.0


def pendulum_urdf(name: str) -> str:
    return f"""<robot name="{name}">
  <link name="base"/>
  <link name="arm"><inertial><mass value="1.5"/><origin xyz="0 0 -0.4"/>
    <inertia ixx="0.1" iyy="0.1" izz="0.02" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="hinge" type="revolute"><parent link="base"/><child link="arm"/>
    <axis xyz="0 1 0"/></joint>
</robot>
"""


@pytest.mark.parametrize("encoding", ["iso-8859-1", "utf-16", "utf-8"])
def test_urdf_encodings_follow_the_xml_declaration(tmp_path, encoding):
    text = f'<?xml version="1.0" encoding="{encoding}"?>\n' + pendulum_urdf("Bras-à-bras")
    path = tmp_path / "arm.urdf"
    path.write_bytes(text.encode(encoding))
    model = load_urdf(path)
    assert model.name == "Bras-à-bras" and model.coordinates == ["hinge"]


@pytest.mark.parametrize("encoding", ["utf-8-sig", "utf-16", "utf-32"])
@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_model_file_encodings_are_detected(tmp_path, encoding, suffix):
    doc = pendulum(name="Pendule-à-ressort")
    text = json.dumps(doc) if suffix == ".json" else yaml.safe_dump(doc, allow_unicode=True)
    path = tmp_path / f"m{suffix}"
    path.write_bytes(text.encode(encoding))
    if suffix == ".yaml" and encoding == "utf-32":  # YAML 1.1 defines UTF-8 and UTF-16 only
        with pytest.raises(ModelError, match="m.yaml"):
            load_model_file(path)
        return
    assert load_model_file(path).name == "Pendule-à-ressort"


def test_undecodable_bytes_are_a_model_error(tmp_path):
    for suffix in (".yaml", ".json", ".urdf"):
        path = tmp_path / f"bad{suffix}"
        path.write_bytes(b"\xff\xfe\xfa\x00garbage\x80\x81" * 10)
        with pytest.raises(ModelError, match="bad"):
            resolve_model(path)


def test_files_past_the_size_limit_are_refused_before_reading(tmp_path, monkeypatch):
    monkeypatch.setattr(inputs, "MAX_FILE_BYTES", 1000)
    monkeypatch.setattr(inputs, "MAX_MODEL_FILE_BYTES", 1000)
    path = tmp_path / "big.urdf"
    path.write_text(pendulum_urdf("x") + " " * 2000)
    with pytest.raises(ModelError, match="at most 1,000 bytes"):
        load_urdf(path)
    path = tmp_path / "big.yaml"
    path.write_text(yaml.safe_dump(pendulum()) + "#" * 2000)
    with pytest.raises(ModelError, match="at most 1,000 bytes"):
        load_model_file(path)


def test_too_many_bodies_are_refused_before_any_is_read(monkeypatch):
    monkeypatch.setattr(inputs, "MAX_BODIES", 3)
    doc = pendulum()
    doc["bodies"] = [{"name": f"b{k}", "parent": f"b{k - 1}" if k else "world"}
                     for k in range(4)]
    assert "4 bodies" in str(refused(doc))
    links = "".join(f'<link name="l{k}"/>' for k in range(4))
    with pytest.raises(ModelError, match="4 bodies"):
        parse_urdf_text(f'<robot name="r">{links}</robot>', "many.urdf")


@pytest.mark.parametrize("fmt, text", [
    ("yaml", "[" * 100000 + "]" * 100000),
    ("json", "[" * 100000 + "]" * 100000),
    ("yaml", "a: " + "{b: " * 5000 + "1" + "}" * 5000),
])
def test_deeply_nested_documents_are_a_model_error(fmt, text):
    refused(text, fmt=fmt, source=f"deep.{fmt}")


# ----------------------------------------------------------------- names and built-ins

@pytest.mark.parametrize("name", ["chain:²", "chain:0", "chain:", "chain:65", "chain:-3",
                                  "chain:1e3", "chain:" + "9" * 5000])
def test_bad_chain_sizes_are_one_line_model_errors(name):
    with pytest.raises(ModelError, match="expected chain:N") as info:
        resolve_model(name)
    assert len(str(info.value)) < 200


@pytest.mark.parametrize("field, value", [
    ("name", ["a", "list"]), ("name", {"a": 1}), ("name", "x" * 1000), ("name", 10**100),
    ("description", ["a", "list"]),
])
def test_model_names_must_be_short_text(field, value):
    refused(pendulum(**{field: value}))


def test_body_and_joint_names_must_be_short_text():
    doc = pendulum()
    doc["bodies"][0]["name"] = "y" * 5000
    assert "has 5000 characters" in str(refused(doc))
    doc = pendulum()
    doc["bodies"][0]["joint"] = {"name": [1, 2]}
    assert "joint name" in str(refused(doc))


def test_long_urdf_names_are_refused():
    with pytest.raises(ModelError, match="characters"):
        parse_urdf_text(pendulum_urdf("r" * 10000), "long.urdf")


def test_a_model_error_is_always_one_line():
    doc = pendulum()
    doc["bodies"][0]["name"] = "evil\nname\r\u2028x"
    doc["bodies"][0]["mass"] = "nope"
    message = str(refused(doc))
    assert "evil\\nname\\r\\u2028x" in message

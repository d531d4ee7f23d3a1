"""MkDocs hooks: the reference pages' generated parts, made from the code at every build so they cannot drift.

A page asks for a part with a marker line `<!-- generated: NAME -->`; the hook replaces it with the Markdown that
GENERATORS[NAME] makes. An unknown name stops the build. Parts:

- protocol: every topic and service of client_protocol/interface.py (type, direction, rate, who may use it,
  what it does, an example frame), every event kind and its detail's fields (client_protocol/events.py), and the
  definition of every type they use, from client_protocol/definitions.py;
- cli: every subcommand of `vr-teleop` and its options, read from the argparse parsers;
- config-*: the configuration files' fields (and the menu commands), from their pydantic models' JSON Schemas.
"""

from __future__ import annotations

import argparse
import json
import re
from collections.abc import Callable, Iterable
from typing import Any

MARKER = re.compile(r"^<!-- generated: ([\w-]+) -->$", re.MULTILINE)


def on_page_markdown(markdown: str, page: Any, **_: Any) -> str:
    def replace(match: re.Match[str]) -> str:
        name = match.group(1)
        if name not in GENERATORS:
            raise ValueError(f"{page.file.src_path}: unknown generated part {name!r}; known: {', '.join(GENERATORS)}")
        return GENERATORS[name]()

    return MARKER.sub(replace, markdown)


# ---- Markdown helpers ----------------------------------------------------------------------------------------------

def cell(text: Any) -> str:
    """Text safe inside a Markdown table cell."""
    return str(text).replace("\\", "\\\\").replace("|", "\\|").replace("\n", " ").strip()


def code(text: Any) -> str:
    return f"`{cell(text)}`" if str(text) else ""


def table(header: Iterable[str], rows: Iterable[Iterable[Any]]) -> str:
    header = list(header)
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def anchor(name: str) -> str:
    """The id of a heading for a name such as `geometry_msgs/PoseStamped` or `/vr/head_pose`."""
    return re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-")


# ---- protocol ------------------------------------------------------------------------------------------------------

DIRECTIONS = {"publish": "client publishes", "subscribe": "client subscribes", "call": "client calls"}
OPS = {"publish": "publish", "subscribe": "subscribe", "call": "call_service"}


def who_may(policy: Any, endpoint: Any) -> list[str]:
    """The roles whose use of the endpoint the server's access policy lets through."""
    from vr_teleop_server.core.access import ROLES, AccessDenied

    allowed = []
    for role in ROLES:
        try:
            policy.check(role, OPS[endpoint.direction], endpoint.name)
        except AccessDenied:
            continue
        allowed.append(role)
    return allowed


def type_closure(roots: Iterable[str]) -> dict[str, tuple[str, str]]:
    """Every type the roots use, with their dependencies: name -> (kind "msg" or "srv", definition text)."""
    from client_protocol.definitions import MESSAGES, SERVICES
    from client_protocol.registry import normalize_type_name, parse_definition

    found: dict[str, tuple[str, str]] = {}
    todo = [normalize_type_name(r) for r in roots]
    while todo:
        name = todo.pop()
        if name in found:
            continue
        if name in SERVICES:
            found[name] = ("srv", SERVICES[name])
            halves = SERVICES[name].split("---")
        elif name in MESSAGES:
            found[name] = ("msg", MESSAGES[name])
            halves = [MESSAGES[name]]
        else:
            raise ValueError(f"{name} is used by the interface but defined nowhere in client_protocol/definitions.py")
        for half in halves:
            todo += [f.type for f in parse_definition(name, half).fields if "/" in f.type]
    return dict(sorted(found.items()))


def uses(name: str, kind: str, text: str) -> list[str]:
    from client_protocol.registry import parse_definition

    halves = text.split("---") if kind == "srv" else [text]
    return sorted({f.type for half in halves for f in parse_definition(name, half).fields if "/" in f.type})


def protocol() -> str:
    from client_protocol.interface import ENDPOINTS
    from client_protocol.registry import normalize_type_name
    from vr_teleop_server.core.access import ROLES, AccessPolicy

    policy = AccessPolicy({f"token-{role}": role for role in ROLES})
    out = ["## Summary\n\n",
           "Directions are from the client's side. *Who may use it* is what the server's access policy "
           "(`vr_teleop_server/core/access.py`) lets each role do when the server has tokens; without tokens every "
           "client may do everything (see [Roles, tokens and TLS](../guides/security.md)).\n\n"]
    rows = []
    for e in ENDPOINTS:
        type_name = normalize_type_name(e.type)
        rows.append([f"[{code(e.name)}](#{anchor(e.name)})", f"[{code(type_name)}](#{anchor(type_name)})",
                     DIRECTIONS[e.direction], cell(e.rate or "on call"), ", ".join(who_may(policy, e))])
    out.append(table(["Name", "Type", "Direction", "Rate", "Who may use it"], rows))
    out.append("\n## Topics and services\n")

    for e in ENDPOINTS:
        type_name = normalize_type_name(e.type)
        kind = "service" if e.direction == "call" else "topic"
        out.append(f"\n### `{e.name}` {{#{anchor(e.name)}}}\n")
        out.append(f"A {kind}: {DIRECTIONS[e.direction]}; type [`{type_name}`](#{anchor(type_name)}); "
                   f"rate {e.rate or 'on call'}; who may use it: {', '.join(who_may(policy, e)) or 'nobody'}.\n")
        out.append(f"\n{e.doc}\n")
        out.append("\nExample frame:\n\n```json\n" + json.dumps(e.example_frame(), indent=2) + "\n```\n")
    out.append(events())
    out.append(vocabulary())
    out.append("\n## Types\n\nEach type as ROS writes it (`.msg`, or `.srv` with the request above `---` and the "
               "response below). `vr-teleop schema` writes the non-standard ones as files (with a `package.xml` "
               "each) under `client_protocol/schemas/msg/`, and a JSON Schema per type beside them.\n")
    for name, (kind, text) in type_closure(e.type for e in ENDPOINTS).items():
        out.append(f"\n### `{name}` {{#{anchor(name)}}}\n\n```text\n{text.strip() or '# (no fields)'}\n```\n")
        used = uses(name, kind, text)
        if used:
            out.append("\nUses " + ", ".join(f"[`{u}`](#{anchor(u)})" for u in used) + ".\n")
    return "".join(out)


def events() -> str:
    """Every event kind on vr_teleop_msgs/Event with its source and its detail's fields (client_protocol/events.py)."""
    from client_protocol.events import KINDS, EventLevel

    out = ["\n## Events {#events}\n\n",
           f"[`/vr_teleop/events`](#{anchor('/vr_teleop/events')}) (and the experimenter's labels on "
           f"[`/study/labels`](#{anchor('/study/labels')})) carry `vr_teleop_msgs/Event`: `source`, `kind`, `level` "
           f"(one of {', '.join(code(v.value) for v in EventLevel)}) and `detail`, a JSON object in a string whose "
           "fields each kind defines. The server checks every event it sends against its kind's fields; "
           "`vr-teleop schema` writes them as `event.<kind>.json` (and the lists of kinds and levels as "
           "`events.json`). Read states from these fields, never from a sentence.\n\n"]
    rows = []
    for kind, spec in KINDS.items():
        schema = spec.model.model_json_schema()
        required = set(schema.get("required", ()))
        fields = "<br>".join(
            f"{code(key)}: {schema_type(prop, schema.get('$defs'))}" + ("" if key in required else " (optional)")
            + (f"; {cell(prop['description'])}" if prop.get("description") else "")
            for key, prop in schema.get("properties", {}).items())
        spelled = spec.wire.replace("{", "<").replace("}", ">") if spec.wire else kind.value
        rows.append([code(spelled), code(spec.source), cell(spec.doc), fields or "none"])
    out.append(table(["Kind", "Source", "When", "Detail fields"], rows))
    return "".join(out)


def vocabulary() -> str:
    """The shared words of autonomy and ownership (client_protocol/vocabulary.py), each enum with its values."""
    from client_protocol import vocabulary as v

    out = ["\n## Vocabularies {#vocabularies}\n\n",
           "The strings these fields take, one enum each in `client_protocol/vocabulary.py` (a Python client may "
           "import them: a member equals its string, `AutonomyLevel.SUPERVISED == \"supervised\"`). Send and "
           "compare exactly these values; the server names no others.\n\n"]
    rows = [[code(kind.__name__), ", ".join(code(m.value) for m in kind), cell(" ".join((kind.__doc__ or "").split()))]
            for kind in v.VOCABULARIES]
    out.append(table(["Enum", "Values", "What they name"], rows))
    return "".join(out)


# ---- command line --------------------------------------------------------------------------------------------------

def subcommands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], Any]]:
    """(words after `vr-teleop`, parser) for the parser and each of its subcommands, depth first."""
    found = [(path, parser)]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found += subcommands(sub, path + (name,))
    return found


def expanded_help(action: argparse.Action, prog: str) -> str:
    """The help text as `--help` prints it (argparse's %(default)s and friends filled in)."""
    if not action.help or action.help == argparse.SUPPRESS:
        return ""
    params = {k: v for k, v in vars(action).items() if v is not argparse.SUPPRESS}
    if params.get("choices") is not None:
        params["choices"] = ", ".join(map(str, params["choices"]))
    return action.help % {**params, "prog": prog}


def value_of(action: argparse.Action) -> str:
    if action.nargs == 0:
        return ""
    if action.choices is not None and not isinstance(action, argparse._SubParsersAction):
        return " \\| ".join(code(c) for c in action.choices)
    return code(action.metavar or (action.dest.upper() if action.option_strings else action.dest))


def option_rows(actions: Iterable[argparse.Action], title: str, prog: str) -> list[list[str]]:
    rows = []
    for action in actions:
        if isinstance(action, argparse._SubParsersAction):
            rows += [[f"[{code(name)}](#{anchor(title + ' ' + name)})", "", "",
                      cell(next((c.help for c in action._choices_actions if c.dest == name), "") or "")]
                     for name in action.choices]
            continue
        names = ", ".join(code(s) for s in action.option_strings) or code(action.dest)
        default = action.default
        shown = "" if default in (None, argparse.SUPPRESS, False, []) or action.nargs == 0 else code(default)
        rows.append([names, value_of(action), shown, cell(expanded_help(action, prog))])
    return rows


def cli() -> str:
    from vr_teleop_server.cli import build_parser

    out = []
    for path, parser in subcommands(build_parser()):
        title = " ".join(("vr-teleop",) + path)
        level = "#" * min(2 + max(len(path) - 1, 0), 4)
        out.append(f"\n{level} `{title}` {{#{anchor(title)}}}\n\n")
        if parser.description:
            out.append(parser.description.strip() + "\n\n")
        out.append("```text\n" + parser.format_usage().strip() + "\n```\n\n")
        groups = [g for g in parser._action_groups if g._group_actions]
        for group in groups:  # `serve`'s options come in groups (the robot, --backend luxai...): one table each
            if len(groups) > 1 and group.title not in ("options", "positional arguments"):
                out.append(f"\n**{group.title}**" + (f": {group.description}" if group.description else "")
                           + "\n\n")
            out.append(table(["Option or subcommand", "Value", "Default", "What it does"],
                             option_rows(group._group_actions, title, parser.prog)))
        if parser.epilog:
            out.append("\n```text\n" + parser.epilog.strip() + "\n```\n")
    return "".join(out)


# ---- configuration files -------------------------------------------------------------------------------------------

def model_anchor(root: str, name: str) -> str:
    """A nested model's heading id, under its file's root model (two files may each have an `Item`)."""
    return anchor(f"{root}-{name}") if root != name else anchor(name)


def schema_type(prop: dict[str, Any], defs: dict[str, Any] | None = None, root: str = "") -> str:
    """A JSON Schema property's type, in words, with links to the sections of nested models (enums inline)."""
    defs = defs or {}
    if "$ref" in prop:
        name = prop["$ref"].rsplit("/", 1)[-1]
        if "properties" not in defs.get(name, {}):
            return schema_type(defs.get(name, {}), defs, root)
        return f"[{name}](#{model_anchor(root, name)})"
    if "enum" in prop:
        return "one of " + ", ".join(code(v) for v in prop["enum"])
    if "const" in prop:
        return code(prop["const"])
    for key in ("anyOf", "oneOf", "allOf"):
        if key in prop:
            return " or ".join(schema_type(p, defs, root) for p in prop[key])
    kind = prop.get("type", "any")
    if kind == "array":
        return "list of " + schema_type(prop.get("items", {}), defs, root)
    if kind == "object" and isinstance(prop.get("additionalProperties"), dict):
        return "map of name to " + schema_type(prop["additionalProperties"], defs, root)
    return {"number": "number", "integer": "integer", "string": "text", "boolean": "true/false",
            "null": "null", "object": "mapping"}.get(kind, kind)


BOUNDS = (("minimum", "≥"), ("exclusiveMinimum", ">"), ("maximum", "≤"), ("exclusiveMaximum", "<"),
          ("minLength", "length ≥"), ("maxLength", "length ≤"), ("minItems", "items ≥"),
          ("maxItems", "items ≤"), ("pattern", "matches"))


def constraints(prop: dict[str, Any]) -> str:
    parts = [f"{word} {code(prop[key])}" for key, word in BOUNDS if key in prop]
    for alt in prop.get("anyOf", ()):
        parts += [f"{word} {code(alt[key])}" for key, word in BOUNDS if key in alt]
    return ", ".join(parts)


def model_section(title: str, model: Any) -> str:
    """One table per model the file uses (the file's own first), then the whole JSON Schema, folded."""
    schema = model.model_json_schema()
    out = []
    root = schema.get("title", model.__name__)
    defs = {root: schema, **schema.get("$defs", {})}
    for name, definition in defs.items():
        props = definition.get("properties")
        if not props:
            continue
        required = set(definition.get("required", ()))
        out.append(f"\n#### {name} {{#{model_anchor(root, name)}}}\n\n")
        if definition.get("description"):
            out.append(definition["description"].strip() + "\n\n")
        rows = []
        for key, prop in props.items():
            default = ("required" if key in required else code(json.dumps(prop["default"])) if "default" in prop
                       else "")  # a default made by a factory: the meaning says what it is
            rows.append([code(key), schema_type(prop, defs, root), default, constraints(prop),
                         cell(prop.get("description", ""))])
        out.append(table(["Key", "Type", "Default", "Bounds", "Meaning"], rows))
    out.append(f'\n??? note "JSON Schema of {title}"\n\n    ```json\n')
    out.append("".join(f"    {line}\n" for line in json.dumps(schema, indent=2).splitlines()))
    out.append("    ```\n")
    return "".join(out)


def config_teleop() -> str:
    from vr_teleop_server.teleop import TeleopSettings

    return model_section("the teleop settings file", TeleopSettings)


def config_menu() -> str:
    from menus.commands import COMMANDS
    from menus.model import MenuFile

    rows = []
    for name, model in sorted(COMMANDS.items()):
        schema = model.model_json_schema()
        required = set(schema.get("required", ()))
        args = "<br>".join(
            f"{code(key)}: {schema_type(prop, schema.get('$defs'))}"
            + (f", default {code(json.dumps(prop['default']))}" if "default" in prop else "")
            + (f", {constraints(prop)}" if constraints(prop) else "")
            + (f"; {cell(prop['description'])}" if prop.get("description") else "")
            for key, prop in schema.get("properties", {}).items())
        rows.append([code(name), args or "none"])
    return (model_section("a menu file", MenuFile) + "\n#### Commands {#menu-commands}\n\n"
            "An item's `command` is one of these; its `args` are checked against the command's fields when the file "
            "is loaded.\n\n" + table(["Command", "Arguments"], rows))


def config_study() -> str:
    from vr_teleop_server.study.classroom_file import ClassroomStudy
    from vr_teleop_server.study.studyfile import Study

    return model_section("a study file", Study) + model_section("a classroom study file", ClassroomStudy)


def config_motivation() -> str:
    from vr_teleop_server.features.motivation import MotivationConfig

    return model_section("the motivation file", MotivationConfig)


def config_godspeed() -> str:
    from vr_teleop_server.questionnaires.instrument import Instrument

    return model_section("a questionnaire file", Instrument)


GENERATORS: dict[str, Callable[[], str]] = {
    "protocol": protocol,
    "cli": cli,
    "config-teleop": config_teleop,
    "config-menu": config_menu,
    "config-study": config_study,
    "config-motivation": config_motivation,
    "config-godspeed": config_godspeed,
}

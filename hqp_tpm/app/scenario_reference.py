"""The field reference of scenario files, generated from the code that parses them (so it cannot drift).

Every field a scenario file may hold is read through a :class:`~hqp_tpm.app.scenario_values.Section` accessor
(``number``, ``vector``, ``string``, ``boolean``, ``table``, ``tables``, ``raw``, ``has``) with the field's name
as a string literal. This module reads those calls from the parser modules' source (``app/scenario.py``,
``app/build.py``, ``app/policy_builders/*.py``), with the default and the choices given in the call, and
files each under the section of the file it belongs to (:data:`SECTIONS`: which function reads which
section). A parser function that reads fields and is not in :data:`SECTIONS` is an error, so a new field
or builder cannot be left out of ``docs/scenario_format.md``.

    python -m hqp_tpm.app.scenario_reference            # print the reference (Markdown)
    python -m hqp_tpm.app.scenario_reference --write    # update docs/scenario_format.md between its markers
"""

from __future__ import annotations

import ast
import importlib
import sys
from dataclasses import dataclass
from pathlib import Path

ACCESSORS = {"number": "number", "vector": "list of numbers", "string": "string", "boolean": "true/false",
             "table": "table", "tables": "array of tables", "raw": "see below", "has": None}

#: (module, function, receiver variable) -> section heading. ``None`` as receiver: any variable.
SECTIONS: dict[tuple[str, str, str | None], str] = {
    ("hqp_tpm.app.scenario", "parse", "top"): "top level",
    ("hqp_tpm.app.scenario", "parse", "sc"): "[scenario]",
    ("hqp_tpm.app.scenario", "read", None): "[scenario]",
    ("hqp_tpm.app.scenario", "parse", "t"): "[[tasks]] (every task)",
    ("hqp_tpm.app.build", "build", "t"): "[[tasks]] (every task)",
    ("hqp_tpm.app.build", "build_run", "t"): "[[tasks]] (every task)",
    ("hqp_tpm.app.build", "build_run", "lim"): "[limits]",
    ("hqp_tpm.app.build", "initial_configuration", "sec"): "[initial]",
    ("hqp_tpm.app.build", "obstacles_from", "sec"): "[[obstacles]]",
    ("hqp_tpm.app.build", "build", "lim"): "[limits]",
    ("hqp_tpm.app.build", "build_task", "sec"): "[[tasks]] (every task)",
    ("hqp_tpm.app.build", "gains", "sec"): "[[tasks]] (every task)",
    ("hqp_tpm.app.build", "_axes", "sec"): "[[tasks]] type = \"frame_position\", \"com\"",
    ("hqp_tpm.app.build", "_joints", "sec"): "[[tasks]] type = \"manipulability\", \"joint_limit\"",
    ("hqp_tpm.app.build", "trajectory", "sec"): "[[tasks]] target",
    ("hqp_tpm.app.build", "trajectory", "tab"): "target = { type = ... } (a trajectory table)",
    ("hqp_tpm.app.build", "build_policy", "sec"): "[policy] type = \"fixed\" (the default)",
    ("hqp_tpm.app.scenario_plant", "plant_config", "sec"): "[plant]",
    ("hqp_tpm.app.scenario_plant", "_contacts", "sec"): "[plant] contacts (a floating base on its soles)",
    **{("hqp_tpm.app.build", f"_{kind}", "sec"): f"[[tasks]] type = \"{kind}\"" for kind in (
        "frame_position", "frame_orientation", "frame_pose", "pointing", "com", "posture", "force",
        "quaternion_orientation", "manipulability", "joint_limit")},
}
_POLICY_MODULES = ("algorithm1", "whole_body", "switching", "admittance", "petric")
SECTIONS.update({
    ("hqp_tpm.app.policy_builders.algorithm1", "_repulsion", "tab"):
        "[policy.ee_repulsion], [policy.body_repulsion] (algorithm1)",
    ("hqp_tpm.app.policy_builders.switching", "operator_from", "sec"): "[policy] type = \"switching\", \"admittance\"",
    ("hqp_tpm.app.policy_builders.switching", "operator_from", "tab"): "[policy.operator] (switching, admittance)",
})

#: Helpers that read a field whose name they get as an argument: name -> (index of that argument, type).
HELPERS = {"trajectory": (1, 'list of numbers, "hold", or a trajectory table (below)'),
           "_repulsion": (1, "table (below)"), "task_of": (2, "string (a task name)")}


@dataclass
class Field:
    section: str
    name: str
    kind: str
    default: str
    choices: str
    where: str  # module.function, for the reader of the code

    @property
    def required(self) -> bool:
        return self.default == "required"


def _text(node, namespace: dict) -> str:
    try:
        return repr(ast.literal_eval(node))
    except ValueError:
        pass
    try:  # a module-level constant such as tuple(LEVELS)
        return repr(eval(compile(ast.Expression(node), "<field>", "eval"), dict(namespace)))  # noqa: S307 - our code
    except Exception:  # noqa: BLE001 - a local expression: show it as written
        return ast.unparse(node)


def _sections_for(module: str, func: str, receiver: str) -> str | None:
    if (module, func, receiver) in SECTIONS:
        return SECTIONS[(module, func, receiver)]
    if (module, func, None) in SECTIONS:
        return SECTIONS[(module, func, None)]
    if module.startswith("hqp_tpm.app.policy_builders."):
        kind = module.rsplit(".", 1)[1]
        if func.startswith("build_") and receiver == "sec":
            return f"[policy] type = \"{kind}\""
        if receiver in ("tab", "sub", "t", "op", "sec"):
            return f"[policy] type = \"{kind}\": sub-tables"
    return None


def fields() -> list[Field]:
    """Every field read by the parser modules, in source order, filed under its section."""
    modules = ["hqp_tpm.app.scenario", "hqp_tpm.app.build", "hqp_tpm.app.scenario_plant",
               *(f"hqp_tpm.app.policy_builders.{m}" for m in _POLICY_MODULES)]
    out: list[Field] = []
    unmapped = []
    for name in modules:
        mod = importlib.import_module(name)
        tree = ast.parse(Path(mod.__file__).read_text(encoding="utf-8"))
        for func in [n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)]:
            for call in ast.walk(func):
                if (isinstance(call, ast.Call) and isinstance(call.func, ast.Name) and call.args
                        and isinstance(call.args[0], ast.Name) and call.args[0].id in ("sec", "tab")):
                    helper = HELPERS.get(call.func.id)
                    consts = [a for a in call.args[1:] if isinstance(a, ast.Constant) and isinstance(a.value, str)]
                    if helper is None:
                        if consts:
                            unmapped.append(f"{name}.{func.name}: {call.func.id}({call.args[0].id}, "
                                            f"{consts[0].value!r}, ...) (add it to HELPERS)")
                        continue
                    idx, kind = helper
                    key = call.args[idx] if len(call.args) > idx else None
                    section = _sections_for(name, func.name, call.args[0].id)
                    if isinstance(key, ast.Constant) and section is not None:
                        out.append(Field(section, key.value, kind, "optional" if call.func.id != "task_of" else
                                         _text(call.args[-1], vars(mod)), "", f"{name}.{func.name}"))
                    continue
                if not (isinstance(call, ast.Call) and isinstance(call.func, ast.Attribute)
                        and call.func.attr in ACCESSORS and isinstance(call.func.value, ast.Name)
                        and call.args and isinstance(call.args[0], ast.Constant)
                        and isinstance(call.args[0].value, str)):
                    continue
                receiver = call.func.value.id
                if receiver in ("np", "os", "self", "math", "re", "path", "p", "data", "robot", "pin"):
                    continue
                section = _sections_for(name, func.name, receiver)
                if section is None:
                    unmapped.append(f"{name}.{func.name}: {receiver}.{call.func.attr}({call.args[0].value!r})")
                    continue
                kind = ACCESSORS[call.func.attr]
                if kind is None:  # has(): only a presence test, the field is read elsewhere
                    continue
                default_node = call.args[-1] if len(call.args) > 1 and call.func.attr != "vector" else None
                if call.func.attr == "vector":
                    dim = call.args[1] if len(call.args) > 1 else None
                    if dim is not None and not (isinstance(dim, ast.Constant) and dim.value is None):
                        kind = f"list of numbers ({_text(call.args[1], vars(mod))})"
                    default_node = call.args[2] if len(call.args) > 2 else None
                for kw in call.keywords:
                    if kw.arg == "default":
                        default_node = kw.value
                    if kw.arg == "dim" and call.func.attr == "vector":
                        kind = f"list of numbers ({_text(kw.value, vars(mod))})"
                default = "required" if default_node is None else _text(default_node, vars(mod))
                if call.func.attr == "tables":
                    default = "none"
                if default == "None":
                    default = "optional"
                choices = next((_text(kw.value, vars(mod)) for kw in call.keywords if kw.arg == "choices"), "")
                out.append(Field(section, call.args[0].value, kind, default, choices, f"{name}.{func.name}"))
    if unmapped:
        raise RuntimeError("scenario fields read outside a known section (add the function to SECTIONS): "
                           + "; ".join(unmapped))
    return out


def reference() -> str:
    """The Markdown tables: one per section, one row per field (merged when several functions read it)."""
    by_section: dict[str, dict[str, Field]] = {}
    for f in fields():
        sec = by_section.setdefault(f.section, {})
        old = sec.get(f.name)
        if old is None:
            sec[f.name] = f
        elif f.where not in old.where:
            old.where += f", {f.where}"
    lines = ["<!-- fields: begin (generated by `python -m hqp_tpm.app.scenario_reference --write` from the parser "
             "code; do not edit by hand) -->", ""]
    common = set(by_section.get("[[tasks]] (every task)", {}))
    for section, items in by_section.items():
        if section.startswith("[[tasks]] type"):
            items = {k: v for k, v in items.items() if k not in common}
            if not items:
                continue
        lines += [f"### {section}", "", "| field | type | default | choices | read by |", "|---|---|---|---|---|"]
        for f in items.values():
            where = ", ".join(f"`{w.replace('hqp_tpm.app.', '')}`" for w in f.where.split(", "))
            lines.append(f"| `{f.name}` | {f.kind} | {f.default} | {f.choices} | {where} |")
        lines.append("")
    lines.append("<!-- fields: end -->")
    return "\n".join(lines) + "\n"


BEGIN, END = "<!-- fields: begin", "<!-- fields: end -->"


def update(doc: Path) -> bool:
    """Replace the generated part of ``doc``; True if it changed."""
    text = doc.read_text(encoding="utf-8")
    i, j = text.index(BEGIN), text.index(END) + len(END) + 1
    new = text[:i] + reference() + text[j:]
    if new != text:
        doc.write_text(new, encoding="utf-8")
    return new != text


if __name__ == "__main__":
    if "--write" in sys.argv:
        path = Path(__file__).resolve().parents[2] / "docs" / "scenario_format.md"
        print(f"{path}: {'updated' if update(path) else 'current'}")
    else:
        print(reference(), end="")

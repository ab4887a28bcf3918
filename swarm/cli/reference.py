"""docs/cli.md, the command-line reference, generated from the argument parsers (swarm.cli.parser):

    python -m swarm.cli.reference > docs/cli.md

Every command (nested ones too: swarm secure init), its one-line summary and description, its usage and
each option with its help, choices and default, in the order the parser defines them. The output depends on
the parsers only: the usage lines are written here (not by argparse, whose layout follows the terminal's
width and the Python version) and wrapped at WIDTH columns. tests/protocol/test_docs.py holds docs/cli.md
equal to render().
"""

from __future__ import annotations

import argparse
import re
import sys
from typing import Iterator, cast

from swarm.cli.parser import build_parser

WIDTH = 100  # usage lines wrap here
REGENERATE = "python -m swarm.cli.reference > docs/cli.md"


def commands(parser: argparse.ArgumentParser | None = None) -> Iterator[tuple[argparse.ArgumentParser, str]]:
    """Every parser with its one-line summary, depth first in the order they are defined: swarm, swarm sim,
    swarm scenario, swarm scenario show, ..."""
    parser = parser or build_parser()
    yield parser, parser.description or ""
    yield from _children(parser)


def _children(parser: argparse.ArgumentParser) -> Iterator[tuple[argparse.ArgumentParser, str]]:
    for action in _subcommands(parser):
        summaries = {a.dest: a.help or "" for a in action._choices_actions}
        for name, child in action.choices.items():
            yield child, summaries.get(name, "")
            yield from _children(child)


def _subcommands(parser: argparse.ArgumentParser) -> list[argparse._SubParsersAction]:
    return [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]


def documented(action: argparse.Action) -> bool:
    """An option or argument the page describes: not the subcommand (a list of commands instead), not -h
    (every command's: said once at the top)."""
    return action.help != argparse.SUPPRESS and not isinstance(action, (argparse._SubParsersAction,
                                                                         argparse._HelpAction))


# --------------------------------------------------------------------------- usage


def _metavar(action: argparse.Action) -> str:
    if action.metavar is not None:
        return action.metavar if isinstance(action.metavar, str) else " ".join(action.metavar)
    if action.choices is not None:
        return "{" + ",".join(str(c) for c in action.choices) + "}"
    return action.dest.upper() if action.option_strings else action.dest


def _value(action: argparse.Action) -> str:
    """What follows the option (or what stands for the positional argument), as argparse writes it."""
    m = _metavar(action)
    if isinstance(action, argparse._SubParsersAction):
        return f"{m} ..."
    if action.nargs is None:
        return m
    if action.nargs == "?":
        return f"[{m}]"
    if action.nargs == "*":
        return f"[{m} ...]"
    if action.nargs == "+":
        return f"{m} [{m} ...]"
    if action.nargs == argparse.REMAINDER:
        return "..."
    return " ".join([m] * cast(int, action.nargs))


def _usage_form(action: argparse.Action) -> str:
    if not action.option_strings:
        return _value(action)
    if isinstance(action, argparse.BooleanOptionalAction):
        return " | ".join(action.option_strings)
    flag = action.option_strings[0]
    return flag if action.nargs == 0 else f"{flag} {_value(action)}"


def usage(parser: argparse.ArgumentParser) -> str:
    """The usage line(s): optionals (a mutually exclusive group as [a | b]) then positionals, wrapped at WIDTH
    with continuation lines under the first argument."""
    exclusive = {id(a): g for g in parser._mutually_exclusive_groups for a in g._group_actions}
    parts, done = [], set()
    for action in [a for a in parser._actions if a.option_strings]:
        group = exclusive.get(id(action))
        if group is not None:
            if id(group) in done:
                continue
            done.add(id(group))
            inner = " | ".join(_usage_form(a) for a in group._group_actions)
            parts.append(f"({inner})" if group.required else f"[{inner}]")
        elif action.help != argparse.SUPPRESS:
            form = _usage_form(action)
            parts.append(form if action.required else f"[{form}]")
    parts += [_value(a) for a in parser._actions if not a.option_strings and a.help != argparse.SUPPRESS]
    head = f"usage: {parser.prog} "
    lines, line = [], head
    for part in parts:
        if line != head and line.strip() and len(line) + len(part) > WIDTH:
            lines.append(line.rstrip())
            line = " " * len(head)
        line += part + " "
    lines.append(line.rstrip())
    return "\n".join(lines)


# --------------------------------------------------------------------------- markdown

_CODE = re.compile(r"(`[^`]*`)")


def _md(text: str) -> str:
    """Prose for markdown: one line; outside `code` spans, the characters that would start emphasis or an
    HTML tag are escaped ('robot<ID>', '/**'); underscores inside words (rmw_zenoh) are left as they are."""
    text = " ".join(text.split())
    out = []
    for k, chunk in enumerate(_CODE.split(text)):
        if k % 2 == 0:
            chunk = chunk.replace("\\", "\\\\").replace("*", "\\*")
            chunk = re.sub(r"<(?=[A-Za-z/!?])", r"\\<", chunk)
            chunk = re.sub(r"(?<![A-Za-z0-9])_|_(?![A-Za-z0-9])", r"\\_", chunk)
        out.append(chunk)
    return "".join(out)


def _help(action: argparse.Action, prog: str) -> str:
    """The help text, with argparse's %(default)s-style fields filled in as --help does."""
    text = action.help or ""
    if "%" in text:
        params = {k: v for k, v in dict(vars(action), prog=prog).items() if v is not argparse.SUPPRESS}
        if params.get("choices") is not None:
            params["choices"] = ", ".join(str(c) for c in params["choices"])
        text = text % params
    return text


def _default(action: argparse.Action) -> str | None:
    """The default worth writing: not None, not the False of a switch, not the empty list of a repeatable flag."""
    d = action.default
    if isinstance(action, argparse.BooleanOptionalAction):  # True or False: the flag that it stands for
        return action.option_strings[0 if d else 1] if isinstance(d, bool) else None
    if d is None or d is argparse.SUPPRESS or action.nargs == 0 or d == []:
        return None
    return '""' if d == "" else str(d)


def _option(action: argparse.Action, prog: str) -> str:
    if action.option_strings:
        names = ", ".join(action.option_strings)
        name = names if action.nargs == 0 else f"{names} {_value(action)}"
    else:
        name = _value(action)
    line = f"- `{name}`"
    text = _md(_help(action, prog))
    if text:
        line += f": {text}"
    notes = []
    if action.required and action.option_strings:
        notes.append("Required.")
    if action.choices is not None and action.metavar is not None:  # the usage names the metavar, not them
        notes.append("Choices: " + ", ".join(f"`{c}`" for c in action.choices) + ".")
    default = _default(action)
    if default is not None:
        notes.append(f"Default: `{default}`.")
    if notes:
        line += (" " if text.endswith(".") else ". ") if text else ": "
    return line + " ".join(notes)


def _anchor(prog: str) -> str:
    return "#" + prog.replace(" ", "-")


def _examples(epilog: str) -> list[str]:
    """An epilog 'Example(s): A | B' as a list of commands, each in code (a trailing '(...)' is a comment)."""
    head, _, rest = epilog.partition(":")
    out = []
    for item in rest.split(" | "):
        item = item.strip()
        m = re.fullmatch(r"(.*?)\s+\((.*)\)", item)
        out.append(f"- `{m.group(1)}` ({_md(m.group(2))})" if m else f"- `{item}`")
    return [f"{head}:", ""] + out


def _section(parser: argparse.ArgumentParser, summary: str) -> list[str]:
    lines = [f"## {parser.prog}", ""]
    if summary:  # a sentence (but "swarm sim over ..." keeps the command's name as it is written)
        sentence = summary if summary.startswith("swarm ") else summary[0].upper() + summary[1:]
        lines += [_md(sentence) + ("" if summary.endswith(".") else "."), ""]
    if parser.description and parser.description != summary:
        lines += [_md(parser.description), ""]
    lines += ["```text", usage(parser), "```", ""]
    for action in _subcommands(parser):
        lines += ["**Commands**", ""]
        for c in action._choices_actions:
            prog = action.choices[c.dest].prog
            lines.append(f"- [`{c.dest}`]({_anchor(prog)}): {_md(c.help or '')}")
        lines.append("")
    for group in parser._action_groups:
        actions = [a for a in group._group_actions if documented(a)]
        if not actions:
            continue
        title = ("Arguments" if group is parser._positionals else "Options" if group is parser._optionals
                 else cast(str, group.title))
        lines += [f"**{_md(title[0].upper() + title[1:])}**", ""]
        if group.description:
            lines += [_md(group.description), ""]
        lines += [_option(a, parser.prog) for a in actions] + [""]
    exclusive = [g for g in parser._mutually_exclusive_groups if len(g._group_actions) > 1]
    for g in exclusive:
        flags = " and ".join(f"`{a.option_strings[0]}`" for a in g._group_actions)
        lines += [f"{flags} exclude each other.", ""]
    if parser.epilog:
        epilog = " ".join(parser.epilog.split())
        lines += (_examples(epilog) if re.match(r"Examples?:", epilog) else [_md(epilog)]) + [""]
    return lines


def render() -> str:
    """docs/cli.md's text."""
    parsers = list(commands())
    lines = [
        "# Command-line reference",
        "",
        "This page is generated from the argument parsers (swarm/cli/parser.py): do not edit it, regenerate it "
        f"with `{REGENERATE}`. A test fails when it differs from the code.",
        "",
        "Every command takes `-h`/`--help`. A flag beats the scenario file, which beats the built-in default; "
        "the exit codes are in [metrics.md](metrics.md#exit-codes).",
        "",
        "Commands: " + ", ".join(f"[`{p.prog}`]({_anchor(p.prog)})" for p, _ in parsers[1:]) + ".",
        "",
    ]
    for parser, summary in parsers:
        lines += _section(parser, summary)
    return "\n".join(lines).rstrip("\n") + "\n"


if __name__ == "__main__":
    sys.stdout.write(render())

"""Every option of every ``tpnet`` command has help text and shows its default: the
test walks every parser that ``tpnet_ref.cli.build_parser`` builds."""
from __future__ import annotations

import argparse

import pytest

from tpnet_ref.cli import build_parser


def _parsers(parser: argparse.ArgumentParser, path: tuple[str, ...] = ("tpnet",)):
    yield " ".join(path), parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, path + (name,))


PARSERS = dict(_parsers(build_parser()))
SKIP = (argparse._HelpAction, argparse._SubParsersAction, argparse._VersionAction)


def _options(parser: argparse.ArgumentParser):
    return [a for a in parser._actions if not isinstance(a, SKIP)]


def test_the_walk_reaches_every_command():
    assert {"tpnet predict", "tpnet train run", "tpnet train bench", "tpnet train score",
            "tpnet sim run", "tpnet data generate", "tpnet eval", "tpnet animate",
            "tpnet export onnx"} <= set(PARSERS)
    assert sum(len(_options(p)) for p in PARSERS.values()) > 150


@pytest.mark.parametrize("command", sorted(PARSERS))
def test_every_option_has_help_and_shows_its_default(command):
    parser = PARSERS[command]
    formatter = parser._get_formatter()
    missing, no_default = [], []
    for action in _options(parser):
        name = action.option_strings[0] if action.option_strings else action.dest
        if not (action.help or "").strip() or action.help == argparse.SUPPRESS:
            missing.append(name)
            continue
        shown = formatter._get_help_string(action)
        unset = (action.default is None or action.default is False or action.default == []
                 or action.default is argparse.SUPPRESS)
        if not unset and "(default" not in shown and "default:" not in shown:
            no_default.append(name)
    assert missing == [], f"{command}: options without help text: {missing}"
    assert no_default == [], f"{command}: options whose help hides the default: {no_default}"
    text = parser.format_help()                        # renders (no % left unescaped)
    assert "usage:" in text


def test_defaults_are_shown_as_typed():
    text = PARSERS["tpnet animate"].format_help()
    assert "(default: 2)" in text and "(default: 12)" in text           # --every, --fps
    gen = " ".join(PARSERS["tpnet data generate"].format_help().split())
    assert "(default: 4)" in gen and "(default: 600)" in gen             # --m, --steps
    assert "(default: 1 1.15 1.3 1.45 1.6)" in gen                        # --forces
    sim = " ".join(PARSERS["tpnet sim run"].format_help().split())
    assert "(default: ring_centre)" in sim and "rested 0.5 s" in sim     # --sleep: the pymunk scene

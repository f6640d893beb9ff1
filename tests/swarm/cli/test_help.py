"""Every `swarm ... --help` says the default of each option that has one."""

from __future__ import annotations

import argparse

from swarm.cli.main import build_parser


def _options(parser: argparse.ArgumentParser, path: str):
    """(command path, option string, default, help) of every option of ``parser`` and its subcommands."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _options(sub, f"{path} {name}")
        elif action.option_strings:
            yield path, action.option_strings[-1], action.default, action.help or ""


def test_every_option_with_a_default_says_it_in_its_help():
    silent = [
        f"{path} {option} (default {default!r})"
        for path, option, default, text in _options(build_parser(), "swarm")
        # [] is a repeatable option's "none given", False a flag's "off": nothing to say
        if default not in (None, False, [], argparse.SUPPRESS) and "default" not in text.lower()
    ]
    assert not silent, "--help does not say the default of: " + ", ".join(silent)

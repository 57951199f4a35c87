"""`lensfit --help` and every subcommand's --help are plain text: what argparse prints
holds no reST markup (double backquotes, interpreted text in single backquotes, roles such
as :func:, directives such as .. note::), only the words."""

from __future__ import annotations

import re

import pytest

from lensfit.cli import build_parser
from lensfit.cli.parser import subcommands

MARKUP = [
    ("double backquotes", re.compile(r"``")),
    ("interpreted text in backquotes", re.compile(r"`[^`\n]+`")),
    ("a role", re.compile(r":[a-z][a-z:+-]*:`")),
    ("a directive", re.compile(r"^\s*\.\. [A-Za-z][\w:+-]*::", re.M)),
]


def _helps() -> list[tuple[str, str]]:
    ap = build_parser()
    out = [("lensfit", ap.format_help())]
    out += [(f"lensfit {name}", p.format_help()) for name, p in subcommands(ap).items()]
    return out


def test_every_subcommand_has_a_help():
    assert len(subcommands(build_parser())) >= 14


@pytest.mark.parametrize("command,text", _helps(), ids=[c for c, _ in _helps()])
def test_help_is_plain_text(command, text):
    found = [(what, m.group(0)) for what, rx in MARKUP for m in rx.finditer(text)]
    assert not found, f"{command} --help prints reST markup: {found}"


def test_markup_is_caught():
    text = "The ``lensfit`` command; see :func:`lensfit.cli.main` and `x`\n.. note:: x"
    assert all(rx.search(text) for _, rx in MARKUP)

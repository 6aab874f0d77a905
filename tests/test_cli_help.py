"""What a newcomer reads in ``--help``: every argument of every verb says what it is, the
defaults say what they are (not "the model's" on the verb that makes the model), a ``--no-X``
switch does not print its own default backwards, and research knobs stand apart."""
from __future__ import annotations

import argparse

import pytest

from geoface.cli import build_parser


def _walk(parser, path):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _walk(sub, path + (name,))
        elif not isinstance(action, argparse._HelpAction):
            yield path, parser, action


ARGUMENTS = list(_walk(build_parser(), ("geoface",)))


def _name(path, action):
    return " ".join(path) + " " + ("/".join(action.option_strings) or action.dest)


def test_the_walk_finds_the_verbs():
    verbs = {" ".join(p) for p, _, _ in ARGUMENTS}
    assert len(ARGUMENTS) > 300
    assert {"geoface convert", "geoface hmd train", "geoface talk train", "geoface capture"} <= verbs


def test_every_argument_has_a_help_line():
    missing = [_name(p, a) for p, _, a in ARGUMENTS if not (a.help and a.help.strip())]
    assert not missing, f"arguments without help: {missing}"


def test_the_verbs_that_make_a_model_state_their_defaults():
    makers = {("geoface", "hmd", "train"), ("geoface", "talk", "train"), ("geoface", "texture", "train"),
              ("geoface", "ddpm", "train")}
    vague = [_name(p, a) for p, _, a in ARGUMENTS if p in makers and "the model's" in (a.help or "")]
    assert not vague, f"a default that is 'the model's' on the verb that creates the model: {vague}"


def test_switches_do_not_print_a_backwards_default():
    for path, parser, action in ARGUMENTS:
        if isinstance(action, argparse._StoreFalseAction):
            text = parser.format_help()
            opt = action.option_strings[0]
            block = text[text.index(opt, text.index("options:")):]
            block = block[:block.find("\n  -", 1) if "\n  -" in block[1:] else len(block)]
            assert "(default: True)" not in block, f"{' '.join(path)} {opt}: {block}"


def test_research_knobs_stand_apart():
    hmd_train = build_parser()._subparsers._group_actions[0].choices["hmd"]
    train = hmd_train._subparsers._group_actions[0].choices["train"]
    groups = {g.title: [a.option_strings[0] for a in g._group_actions if a.option_strings] for g in train._action_groups}
    assert {"--ablation", "--map-theta", "--gm-input", "--pm-per-component", "--pose-head-detach"} <= set(groups["experiments"])
    assert "--iters" not in groups["experiments"]
    assert "experiments:" in train.format_help()


@pytest.mark.parametrize("argv", [["convert", "--help"], ["hmd", "train", "--help"]])
def test_help_says_the_defaults(argv, capsys):
    with pytest.raises(SystemExit) as e:
        build_parser().parse_args(argv)
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "(default: True)" not in out
    if argv[0] == "hmd":
        assert "(default: rigid)" in out and "(default: off)" in out

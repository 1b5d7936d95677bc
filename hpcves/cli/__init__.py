"""The ``hpcves`` command line: a module per command, the terminal's pieces in cli/terminal.py.

Exit status: 0 done (or stopped cleanly with a checkpoint written, or at the model's limit:
psi left [0, 1] under the linear bending law), 1 the computation failed (diverged), 2 bad
input (configuration, files); ``hpcves status`` adds 3, work left.

A command's module is imported when the command runs (or ``--help`` lists it), so ``hpcves status``
loads neither the solver's figures nor the planner: click's lazily loaded subcommands.
"""
from __future__ import annotations

import importlib

import click

from hpcves.cli.terminal import fail, log_to_terminal
from hpcves.errors import ConfigError
from hpcves.files import faults
from hpcves.version import __version__

#: command -> ``module:function`` of its click command
COMMANDS = {
    "analyze": "hpcves.cli.analyze:analyze_command",
    "animate": "hpcves.cli.figures:animate_command",
    "campaign": "hpcves.cli.campaign:campaign_command",
    "run": "hpcves.cli.run:run_command",
    "shapes": "hpcves.cli.figures:shapes_command",
    "status": "hpcves.cli.status:status_command",
}


class LazyGroup(click.Group):
    """A click group whose commands are imported on first use (COMMANDS)."""

    def list_commands(self, ctx):
        return sorted(COMMANDS)

    def get_command(self, ctx, name):
        if name not in COMMANDS:
            return None
        module, function = COMMANDS[name].split(":")
        return getattr(importlib.import_module(module), function)


@click.group(cls=LazyGroup)
@click.version_option(__version__, prog_name="hpcves")
def main():
    """Two-phase vesicles in shear flow: simulations, campaigns, analysis."""
    log_to_terminal()
    try:
        faults.check_environment()
    except ConfigError as exc:
        fail(str(exc))

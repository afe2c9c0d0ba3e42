"""Entry point of the `tetweave` command group.

Subcommands live one per module (cli/decode.py, cli/encode.py, ...) and are imported only when used, so that
`tetweave --help` does not pay for importing torch. Every command reports user errors the same way: one line on
stderr, exit code 2, no traceback (see `_ErrorReportingGroup.invoke`).
"""

from __future__ import annotations

import importlib
import os
import sys

import click

from tetweave_codec import __version__
from tetweave_codec.errors import TetweaveError, error_line

# command name -> "module:attribute" of its click.Command, in the order `--help` lists them.
_SUBCOMMANDS = {
    "encode": "tetweave_codec.cli.encode:encode",
    "decode": "tetweave_codec.cli.decode:decode",
    "info": "tetweave_codec.cli.info:info",
    "render": "tetweave_codec.cli.render:render",
    "view": "tetweave_codec.cli.view:view",
    "bench": "tetweave_codec.cli.bench:bench",
}

EXIT_USAGE = 2  # bad input of any kind, as click itself uses for usage errors

# Commands that do no large matrix products: numpy's BLAS would start a thread pool at import whose idle threads
# spin, ~0.1 s of CPU per `tetweave decode` on two cores (docs/measurements/decode_speed.md). One thread unless the
# user chose otherwise; set before numpy is first imported (the command's module imports it).
ONE_BLAS_THREAD = ("decode", "info")


def fail(message: str, code: int = EXIT_USAGE) -> None:
    """Print one line on stderr and exit with `code`."""
    click.echo(f"tetweave: error: {message}", err=True)
    sys.exit(code)


class _ErrorReportingGroup(click.Group):
    """A click group that loads subcommands lazily and turns errors into one line on stderr."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return list(_SUBCOMMANDS)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        target = _SUBCOMMANDS.get(cmd_name)
        if target is None:
            return None
        module_name, attr = target.split(":")
        if cmd_name in ONE_BLAS_THREAD and "numpy" not in sys.modules:
            for variable in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
                os.environ.setdefault(variable, "1")
        return getattr(importlib.import_module(module_name), attr)

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except (click.exceptions.Exit, click.exceptions.Abort, click.ClickException, SystemExit):
            raise
        except (TetweaveError, OSError) as exc:  # bad input; unreadable input, unwritable output, full disk
            fail(error_line(exc))
        except MemoryError as exc:
            fail(error_line(exc), code=1)
        except KeyboardInterrupt:
            click.echo("tetweave: interrupted", err=True)
            sys.exit(130)
        except Exception as exc:  # a bug of ours: still one line, traceback on request
            if os.environ.get("TETWEAVE_DEBUG"):
                raise
            fail(f"{error_line(exc)}; set TETWEAVE_DEBUG=1 for a traceback", code=1)


@click.group(cls=_ErrorReportingGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="tetweave")
def main() -> None:
    """Compress triangle meshes by fitting a TetWeave point cloud, and rebuild them.

    \b
    Typical use:
      tetweave encode mesh.obj            # writes mesh.tw
      tetweave decode mesh.tw             # writes mesh.decoded.obj
      tetweave info mesh.tw
      tetweave render mesh.tw -o preview.png
      tetweave bench meshes/ --out results/
    """


if __name__ == "__main__":
    main()

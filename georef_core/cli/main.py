"""The `georef` command line. Commands are thin: they parse options and call a step function."""

from __future__ import annotations

import argparse
import sys

from ..errors import GeorefError


# the built parser, kept for the next main() call once keep_parser() was called: the resident solver's processes
# (solver_server.preload), where building it (every command's options) cost 10-30 ms of each served solve
_KEEP_PARSER = False
_PARSER = None


def keep_parser() -> None:
    global _KEEP_PARSER
    _KEEP_PARSER = True


def main(argv: list[str] | None = None) -> int:
    if argv is None:   # the `georef` command itself: a gnss solve goes to the resident solver when one listens
        from .solver_client import served_exit_code

        served = served_exit_code(sys.argv[1:])
        if served is not None:
            return served
    global _PARSER
    parser = _PARSER or build_parser()
    if _KEEP_PARSER:
        _PARSER = parser
    args = parser.parse_args(argv)
    import warnings

    def show_warning(message, category, filename, lineno, file=None, line=None):
        print(f"georef: warning: {message}", file=sys.stderr)

    warnings.showwarning = show_warning
    try:
        return int(args.func(args) or 0)
    except GeorefError as exc:
        print(f"georef: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("georef: interrupted", file=sys.stderr)
        return 130


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="georef", description="Directly georeferenced drone surveys.")
    sub = parser.add_subparsers(dest="command", required=True)
    from . import (dense_command, demo_command, georef_command, gnss_commands, simulate_command, steps_command,
                   volume_command)

    for command in (gnss_commands, simulate_command, georef_command, dense_command, volume_command, demo_command,
                    steps_command):
        command.register(sub)
    from . import design_command

    design_command.register(sub)
    from . import inventory_command

    inventory_command.register(sub)
    from . import dtm_command

    dtm_command.register(sub)
    from . import datum_command

    datum_command.register(sub)
    from . import contours_command, export_command

    contours_command.register(sub)
    export_command.register(sub)
    from .. import warmup

    w = sub.add_parser("warmup", help="compile every numba kernel into its on-disk cache ahead of use "
                                      "(`make install` runs it; a first solve then compiles nothing)")
    warmup.add_arguments(w)
    w.set_defaults(func=warmup.run)
    return parser


if __name__ == "__main__":
    sys.exit(main())

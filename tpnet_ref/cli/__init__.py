"""The ``tpnet`` console script.

Each sub-command lives in the module that implements it: the module exposes
``add_cli(subparsers)`` which registers its parser(s) and sets ``func`` on them. The
modules are imported only when ``tpnet`` runs, so ``import tpnet_ref`` stays light.
Errors that a user can fix (``ValueError``, ``TypeError``, ``FileNotFoundError``/``OSError``,
``KeyError`` from a malformed file, ``NonFiniteResultError`` and other ``ArithmeticError``,
``MemoryError``) become one line on stderr and exit status 2.
"""
from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from typing import Any

# module path -> the sub-commands it registers (for the record; each module's add_cli is called)
COMMAND_MODULES: tuple[str, ...] = (
    "tpnet_ref.cli.model",        # info, predict
    "tpnet_ref.cli.weights",      # import, compress, scrub-provenance, quantize
    "tpnet_ref.cli.sim",          # sim run|show|render
    "tpnet_ref.cli.data",         # data generate
    "tpnet_ref.cli.evaluation",   # eval, demo
    "tpnet_ref.cli.train",        # train run|export|bench|baselines|score
    "tpnet_ref.cli.specialize",   # specialize
    "tpnet_ref.cli.observe",      # observe
    "tpnet_ref.cli.export",       # export onnx
    "tpnet_ref.cli.crosscheck",   # vectors, crosscheck
)


def _shown(value: object) -> str:
    """A default as it is typed on the command line (lists space-separated)."""
    if isinstance(value, (list, tuple)):
        return " ".join(f"{v:g}" if isinstance(v, float) else str(v) for v in value)
    return f"{value:g}" if isinstance(value, float) else str(value)


class _Formatter(argparse.HelpFormatter):
    """Every option's help ends with its default (unless the help already says it; flags and
    options without a default show none): ``tests/test_cli_help.py`` walks every parser."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if (default is None or default is False or default is argparse.SUPPRESS
                or default == [] or "(default" in text or "default:" in text
                or isinstance(action, (argparse._HelpAction, argparse._VersionAction))):
            return text
        return f"{text} (default: {_shown(default).replace('%', '%%')})"


class _Parser(argparse.ArgumentParser):
    """argparse with one-line usage errors (``tpnet predict: error: ...``) and every default in
    the help (:class:`_Formatter`), for every sub-parser."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        kwargs.setdefault("formatter_class", _Formatter)
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="tpnet",
        description="TP-Net reference implementation: predict, simulate, evaluate, convert weights.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMAND_MODULES:
        importlib.import_module(name).add_cli(sub)
    return parser


#: short commands: they run the Numba engine's optional kernels (two-thread, first pass, fused
#: rollout) only where numba has them already, never stopping to compile them
#: (tpnet_ref.engines.compile_watch.TWO_THREAD_KERNELS_ON_DEMAND)
SHORT_COMMANDS = ("demo", "predict", "animate")


def _run(args: argparse.Namespace) -> int:
    """``args.func(args)``; one of :data:`SHORT_COMMANDS` compiles no two-thread kernel."""
    from ..engines import compile_watch
    before = compile_watch.TWO_THREAD_KERNELS_ON_DEMAND
    if args.command in SHORT_COMMANDS:
        compile_watch.TWO_THREAD_KERNELS_ON_DEMAND = False
    try:
        return args.func(args)
    finally:                    # main() called in a process that goes on (the tests)
        compile_watch.TWO_THREAD_KERNELS_ON_DEMAND = before


def watched(prefix: str, doing: str, fn: Any, *a: Any, stream: Any = None) -> Any:
    """``fn(*a)`` for a command that may compile Numba kernels (``tpnet eval``, ``animate``,
    ``predict`` on the Numba engine; ``tpnet demo`` says the same itself), on ``stream`` (default
    stdout; ``tpnet eval``'s progress goes to stderr, its stdout is its table): ``PREFIX: DOING
    (...)`` at once, ``compiling the Numba kernels ...`` when the first compilation starts
    (:class:`tpnet_ref.engines.compile_watch.CompileWatch`), the compile time after. An error stays one
    line on stderr (a command's arguments are checked inside ``fn``, after the first line)."""
    from ..engines.compile_watch import COMPILING, CompileWatch

    def say(text: str) -> None:
        print(f"{prefix}: {text}", file=stream or sys.stdout, flush=True)

    say(f"{doing} (a first run after install also compiles the Numba kernels, once)")
    with CompileWatch(lambda: say(COMPILING)) as w:
        result = fn(*a)
    if w.count:
        say(w.report())
    return result


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        rc = _run(args)
    except BrokenPipeError:              # `tpnet ... | head`: the reader left, nothing to report
        sys.stderr.close()
        return 0
    except (ValueError, TypeError, FileNotFoundError, KeyError, OSError, ArithmeticError,
            MemoryError, ImportError) as exc:
        # ImportError: MissingExtraError names the extra to install (tpnet_ref.extras)
        # ArithmeticError: NonFiniteResultError (float32 overflow) and the simulator's
        # FloatingPointError; MemoryError: a request larger than memory
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        msg = str(msg).strip().replace("\n", " ") or type(exc).__name__
        print(f"tpnet {args.command}: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"tpnet {args.command}: interrupted", file=sys.stderr)
        return 130
    return int(rc or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

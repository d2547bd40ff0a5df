"""Command line: `python -m gagen <command>`; each command module registers its own parser."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from .. import __version__
from ..errors import ModelError

MODEL_HELP = ("built-in name (rrr, chain:N), model file (.yaml, .yml, .json) or .urdf "
              "(default: rrr, the paper's robot)")


def add_model_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", nargs="?", default="rrr", help=MODEL_HELP)


def add_cache_dir_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cache-dir", metavar="DIR",
                        help="cache of compiled models (default: $GAGEN_CACHE_DIR or "
                        "~/.cache/gagen)")


def _build(args: argparse.Namespace) -> int:
    from ..build.builder import build
    from ..model.resolve import resolve_model

    model = resolve_model(args.model)
    out = Path(args.out) if args.out else (Path("generated") / model.name if args.model == "rrr"
                                           else None)
    start = time.perf_counter()
    path, report = build(model, out=out, cache_dir=args.cache_dir, fast_math=args.fast_math,
                         verbose=True)
    total = time.perf_counter() - start
    if report.cached:
        print(f"gagen: '{model.name}' is up to date in the cache")
    print(f"gagen: {model.name}: {model.dof} coordinates, {report.ops_before_cse} operations "
          f"before CSE, {report.ops_after_cse} after; total {total:.2f} s")
    print(f"gagen: module {path}")
    return 0


def _info(args: argparse.Namespace) -> int:
    from ..model.resolve import resolve_model

    model = resolve_model(args.model)
    print(f"model        {model.name}  ({model.source})")
    if model.description:
        print(f"description  {model.description}")
    print(f"bodies       {len(model.bodies)}")
    print(f"coordinates  {model.dof}: {', '.join(model.coordinates)}")
    print("parameters")
    for name, value in model.parameters.items():
        print(f"  {name:<24} {value:g}")
    return 0


def parser() -> argparse.ArgumentParser:
    top = argparse.ArgumentParser(
        prog="python -m gagen",
        description="Compiled Gibbs-Appell equations of motion for trees of rigid bodies.",
    )
    top.add_argument("--version", action="version", version=f"gagen {__version__}")
    top.add_argument("--traceback", action="store_true",
                     help="on an error, show Python's traceback instead of one line")
    sub = top.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("build", help="derive, generate C and compile a model",
                       description="Derive the Gibbs-Appell equations, generate C with CSE and "
                       "compile it through Cython. Prints each stage with its time and the "
                       "operation counts before and after CSE.")
    add_model_argument(p)
    p.add_argument("--out", metavar="DIR",
                   help="write sources and module here (default for rrr: generated/rrr; "
                   "other models: the cache)")
    add_cache_dir_argument(p)
    p.add_argument("--fast-math", action="store_true",
                   help="compile with -ffast-math (off by default: it may reorder floating point)")
    p.set_defaults(run=_build)

    p = sub.add_parser("info", help="show a model's coordinates and parameters")
    add_model_argument(p)
    p.set_defaults(run=_info)

    for register in _command_modules():
        register(sub)
    return top


def _command_modules():
    """Further commands, each module registering its subparsers."""
    from ..bench import register as register_bench
    from .paper import register as register_paper

    return [register_paper, register_bench]


# What a user can cause, and the exit code each gets: bad input (2) or a run that failed (1).
# Anything else is a bug in gagen and keeps its traceback.
def _exit_code(exc: BaseException) -> int | None:
    from ..build.builder import BuildError
    from ..runtime.dynamics import SingularMassMatrixError

    if isinstance(exc, (BuildError, SingularMassMatrixError, OSError, RuntimeError)):
        return 1
    if isinstance(exc, (ModelError, ValueError, TypeError, KeyError)):
        return 2
    return None


def main(argv: list[str] | None = None) -> int:
    """Run one command; a user's error prints one line `gagen: error: ...` (exit 1 or 2)."""
    args = parser().parse_args(argv)
    try:
        return args.run(args)
    except KeyboardInterrupt:
        print("gagen: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        code = _exit_code(exc)
        if code is None or args.traceback:
            raise
        print(f"gagen: error: {_one_line(exc)}", file=sys.stderr)
        return code


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    if isinstance(exc, KeyError):  # str(KeyError) is the repr of its argument
        text = str(exc.args[0]) if exc.args else text
    return text if len(text) <= 2000 else text[:2000] + " ..."


if __name__ == "__main__":
    sys.exit(main())

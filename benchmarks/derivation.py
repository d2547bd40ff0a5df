"""Derivation cost per model: time, intermediates, and operation counts before and after CSE.

    python benchmarks/derivation.py [--models rrr chain:3 ...] [--repeats 3]

Prints a markdown table; times are of cold derivations (SymPy's cache cleared). The
measurement lives in the package (`gagen.bench.scaling.derivation_rows`), so that
`python -m gagen bench` can run it from an installed gagen.
"""

from __future__ import annotations

import argparse

from gagen.bench.scaling import derivation_rows, derivation_table, structured_ops

__all__ = ["derivation_rows", "markdown_table", "structured_ops"]

DEFAULT_MODELS = ["rrr"] + [f"chain:{n}" for n in range(3, 11)]
markdown_table = derivation_table


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=DEFAULT_MODELS, metavar="MODEL",
                        help="built-in names or model files (default: rrr chain:3 ... chain:10)")
    parser.add_argument("--repeats", type=int, default=3,
                        help="derivations per model; the median time is shown (default: 3)")
    args = parser.parse_args(argv)
    print(markdown_table(derivation_rows(args.models, args.repeats)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

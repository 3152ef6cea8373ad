"""Run a benchmark with every training seed shifted: ``python scripts/seeded_bench.py K [--module M] ARGS``.

A run of ``bench_decompose`` is deterministic, so two versions of the code compared on one seed differ
by one path of training each; the same comparison over seeds 0..K shows the noise a difference must
clear (docs/benchmarks.md, the memory section's "Results unchanged"). Every call of
``backend.train.loop.seed_everything`` gets ``seed + K``; ARGS go to the benchmark
(default module ``backend.bench.bench_decompose``). Run it from the checkout to measure, with that
checkout on PYTHONPATH.
"""

from __future__ import annotations

import runpy
import sys


def main(argv: list[str]) -> None:
    if not argv or not argv[0].lstrip("-").isdigit():
        sys.exit("usage: python scripts/seeded_bench.py K [--module M] ARGS (K: the seed offset, an integer)")
    shift = int(argv.pop(0))
    module = "backend.bench.bench_decompose"
    if argv[:1] == ["--module"] and len(argv) > 1:
        module = argv[1]
        del argv[:2]
    import backend.train.loop as loop

    seed_everything = loop.seed_everything
    loop.seed_everything = lambda seed: seed_everything(seed + shift)
    sys.argv = [module.rsplit(".", 1)[-1], *argv]
    runpy.run_module(module, run_name="__main__")


if __name__ == "__main__":
    main(sys.argv[1:])

"""Figures and the markdown report of the paper's Section IV, from runs or their exports.

    python -m frl.report outputs/repro/runs     # run directories (TensorBoard + results.json)
    python -m frl.report docs/results/data --out docs/results.md   # the published report

:func:`frl.report.build.build_report` is the entry point; ``collect`` finds the runs,
``aggregate`` computes the per-figure numbers, ``plots`` and ``markdown`` write them.
"""

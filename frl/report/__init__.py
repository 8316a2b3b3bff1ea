"""Figures and the markdown report of the paper's Section IV, from runs or their exports.

    python -m frl.report runs/repro            # run directories (TensorBoard + results.json)
    python -m frl.report docs/results/data     # the committed result files

:func:`frl.report.build.build_report` is the entry point; ``collect`` finds the runs,
``aggregate`` computes the per-figure numbers, ``plots`` and ``markdown`` write them.
"""

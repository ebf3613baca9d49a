"""Evaluation of the monitor against the HF bench: the randomized duty-cycle suite
(``evaluation.dutycycle``, ``evaluation.suite``), the information bound on its targets
(``evaluation.bound``), the process models compared over noise seeds (``evaluation.seeds``),
the laws read at static holds (``evaluation.holds``), the output hashes of the monitor
(``evaluation.outputs_hash``) and the router-restart harness (``evaluation.restart``).

Each command is a module: ``python -m evaluation.suite --seeds 1-7 --workers 2``. Figures and
the commands reproducing them: docs/estimation.md, "Current figures".
"""

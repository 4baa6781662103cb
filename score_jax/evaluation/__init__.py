"""The evaluation layer, above the run layer: the end-of-run report (``report``), the one-call
robustness sweep (``robustness``), transfer to unseen sub-spaces of a trained run
(``transfer``), aggregate statistics over seeds (``stats``), and the paper's figures that
combine several runs' results (``paper_figures``)."""

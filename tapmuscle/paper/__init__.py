"""The paper's experiments on the simulated rig: the reproduction of section 4 (Tables 6, 7, 9,
Figs. 8-19; :mod:`tapmuscle.paper.reproduce`) and the rig's calibration targets that check the
simulated plant against the paper's rig (:mod:`tapmuscle.paper.rig_targets`)."""

from tapmuscle.paper.reproduce import (PAPER_RUNS, PAPER_TABLES, PaperRun, paper_findings, paper_tables,
                                       preliminary_theta, print_tables, run_paper)

__all__ = ["PaperRun", "PAPER_RUNS", "PAPER_TABLES", "paper_findings", "paper_tables", "preliminary_theta",
           "print_tables", "run_paper"]

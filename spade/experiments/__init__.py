"""Running and tracking the experiments that ``conf/experiment/*.yaml`` define (one file per row of a paper table).

``conf/experiment/`` says *what* a row is (data, model, margin, prerequisites, tags); this package is the code
that runs rows and keeps their records:

- :mod:`~spade.experiments.run`: one run, as ``python -m spade.train`` starts it (prerequisites, fit, test);
- :mod:`~spade.experiments.validation`: every config check that needs no training, before any run opens;
- :mod:`~spade.experiments.prerequisites` and :mod:`~spade.experiments.registry`: the experts and pretrained
  students a row needs, found in (or registered to) the MLflow Model Registry;
- :mod:`~spade.experiments.lifecycle`: run folders, signals, stale RUNNING runs, deterministic seeding;
- :mod:`~spade.experiments.tracking`: what each run logs to MLflow and the UI links it prints;
- :mod:`~spade.experiments.tables` and :mod:`~spade.experiments.reporting`: the paper's tables, which rows they
  hold, and ``python -m spade.report``'s fetching and rendering;
- :mod:`~spade.experiments.config`: composing the project's Hydra configs from code.
"""

"""Running and tracking the experiments that ``conf/experiment/*.yaml`` define (one file per row of a paper table).

``conf/experiment/`` says *what* a row is (data, model, margin, prerequisites, tags); this package is the code
that runs rows and keeps their records:

- :mod:`~spade.experiments.run`: one run, as ``python -m spade.train`` starts it (prerequisites, fit, test);
- :mod:`~spade.config.preflight`: every config check that needs no training, before any run opens;
- :mod:`~spade.experiments.prerequisites` and :mod:`~spade.tracking.registry`: the experts and pretrained
  students a row needs, found in (or registered to) the MLflow Model Registry;
- :mod:`~spade.experiments.lifecycle`: deterministic seeding, the best checkpoint across a resume;
- :mod:`~spade.tracking`: what each run logs to MLflow (one module per job: UI links, experiment
  tags, dataset inputs, descriptions, the run's start, status and end, the closing lines, the report);
- :mod:`~spade.tracking.tables` and :mod:`~spade.experiments.reporting`: the paper's tables, which rows they
  hold, and ``python -m spade.report``'s fetching and rendering.

Composing the project's Hydra configs from code is :func:`spade.utils.config.compose_config` (on the lowest floor,
so that every package may compose a config).
"""
